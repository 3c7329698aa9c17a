"""A ground truth for albedo contrast on a flat board (issue 48), like the Stanford
resolution / dot charts: a 0.4 m x 0.4 m board (albedo 0.2) facing the relay wall at 0.5 m,
and 2 mm in front of it separate thin rectangles of albedo 0.9: three groups of three bars
(4, 3 and 2 cm wide, gaps equal to their width) and three squares (4, 3, 2 cm). Rendered
by mitransient 1.3.1 with hidden-geometry sampling OFF (it is biased where one hidden
shape occludes another), confocal, rectified (account_first_and_last_bounces = false),
then a capture model is added in numpy (a tailed detector response, counts, a direct
return per scan point with its exponential tail, a floor, Poisson draws) and the result
is fitted by `umbra fit --background per-point --irf calibrate --likelihood poisson` and
reconstructed by `umbra recon --method lct`.

    .venv/bin/python python/studies/chart_truth.py STEP [...]   (UMBRA_BIN: another binary)
      STEP: render | measure | fit | lct | analyse | all

Outputs in out/chart_truth/: scene_full.xml (the chart, for the record), scene_fit.xml
(the capture geometry alone, what `umbra` is given), H.npy / H_seed1.npy / H_seed2.npy
(mitransient, (ny, nx, T) float32, iy = wall y, ix = wall x), measured.npy (counts),
truth.json (every parameter of the capture model), fit/, lct/; the figure
docs/studies/chart_truth.png and docs/studies/chart_truth_profiles.png.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "python", "validation"))
sys.path.insert(0, HERE)

UMBRA = os.environ.get("UMBRA_BIN", os.path.join(ROOT, "target", "release", "umbra"))
OUT = os.path.join(ROOT, "out", "chart_truth")
DOCS = os.path.join(ROOT, "docs", "studies")

C = 299792458.0
PS = C * 1e-12                     # 1 ps of time = 0.2998 mm of OPL

# Capture geometry
SCAN = 32
WALL_HALF = 0.25                   # the scanned relay wall: 0.5 m x 0.5 m at z = 0
WALL_ALBEDO = 0.8
LASER = (0.0, -5.0, 5.0)          # laser / SPAD: far (flat irradiance over the scan), below the board line of sight
BIN_WIDTH = 0.004                  # OPL, m
BINS = 448                         # OPL 0 .. 1.792 m
START_OPL = 0.0

# The chart
BOARD_Z, BAR_Z = 0.5, 0.498
BOARD_HALF = 0.2
BOARD_ALBEDO, BAR_ALBEDO = 0.2, 0.9
BAR_LEN = 0.12


def _bars(width, x0, y0):
    """Three vertical bars (long along y) of `width`, gaps `width`, from x0; y0..y0+BAR_LEN."""
    return [(x0 + 2 * k * width, x0 + (2 * k + 1) * width, y0, y0 + BAR_LEN) for k in range(3)]


# name -> list of rectangles (x0, x1, y0, y1) in wall coordinates (m)
GROUPS = {
    "bars4": _bars(0.04, -0.185, 0.055),
    "bars3": _bars(0.03, 0.04, 0.055),
    "bars2": _bars(0.02, -0.185, -0.175),
    "dots": [(-0.02, 0.02, -0.135, -0.095),      # 4 cm square
             (0.06, 0.09, -0.13, -0.10),         # 3 cm
             (0.13, 0.15, -0.125, -0.105)],      # 2 cm
}

# Capture model (truth)
SIGMA_PS = 20.0
TAILS = ((0.30, 75.0), (0.35, 250.0))      # (area fraction, tau ps)
PEAK_COUNTS = 35.0                         # brightest signal bin, expected counts
DIRECT_TOTAL_MEAN = 1.0e4                  # direct return counts per scan point (mean)
DIRECT_CV = 0.4
DIRECT_OPL = 0.02                          # where the direct peak sits (m of OPL)
# the direct return's tail: per-bin value a_k D_p at the direct peak, decaying with tau_k
DIRECT_TAILS = ((2e-3, 333.0), (1e-3, 1000.0))
FLOOR = 0.5                                # counts per bin
SEED = 48


def run(cmd, **kw):
    t0 = time.time()
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({p.returncode}):\n"
                           f"{p.stdout[-2000:]}\n{p.stderr[-4000:]}")
    return p.stdout, time.time() - t0


def read_toml(path):
    with open(path, "rb") as f:
        return tomllib.load(f)


# ---------------------------------------------------------------- scene

def _rgb(v):
    import mtutil
    return mtutil.rgb(v)


def _rect(x0, x1, y0, y1, z, albedo):
    """A Mitsuba rectangle over [x0,x1] x [y0,y1] at depth z, its normal -z (towards the
    wall): translate @ rot_x(180) @ scale."""
    sx, sy = (x1 - x0) / 2, (y1 - y0) / 2
    m = np.array([[sx, 0, 0, (x0 + x1) / 2],
                  [0, -sy, 0, (y0 + y1) / 2],
                  [0, 0, -1.0, z],
                  [0, 0, 0, 1]])
    return {"type": "rectangle", "to_world": m,
            "bsdf": {"type": "diffuse", "reflectance": _rgb(albedo)}}


def scene_dict(hidden=True, spp=1024):
    import mtutil
    laser = [float(x) for x in LASER]
    # Hidden-geometry sampling off: mitransient 1.3.1's is biased where one hidden shape
    # occludes another (issue 48).
    scene = {"type": "scene", "integrator": mtutil.nlos_integrator("confocal", False),
             "laser": mtutil.projector(laser, [0.0, 0.0, 0.0])}
    if hidden:
        h = BOARD_HALF
        scene["board"] = _rect(-h, h, -h, h, BOARD_Z, BOARD_ALBEDO)
        for g, rects in GROUPS.items():
            for k, r in enumerate(rects):
                scene[f"{g}_{k}"] = _rect(*r, BAR_Z, BAR_ALBEDO)
    scene["relay_wall"] = mtutil.relay_wall(WALL_HALF, WALL_ALBEDO, laser, SCAN, BINS, BIN_WIDTH,
                                            START_OPL, spp)
    return scene


def scan_xy():
    c = ((np.arange(SCAN) + 0.5) / SCAN * 2 - 1) * WALL_HALF
    return np.meshgrid(c, c)      # X[iy, ix], Y[iy, ix]


def truth_albedo(n=None):
    """The chart's albedo seen along +z at the scan points (n=None) or on an n x n grid over
    the scan rectangle; 0 where no surface (the board's outside)."""
    if n is None:
        X, Y = scan_xy()
    else:
        c = ((np.arange(n) + 0.5) / n * 2 - 1) * WALL_HALF
        X, Y = np.meshgrid(c, c)
    a = np.where((np.abs(X) <= BOARD_HALF) & (np.abs(Y) <= BOARD_HALF), BOARD_ALBEDO, 0.0)
    for rects in GROUPS.values():
        for x0, x1, y0, y1 in rects:
            a = np.where((X >= x0) & (X <= x1) & (Y >= y0) & (Y <= y1), BAR_ALBEDO, a)
    return a


def _dict_to_xml():
    """umbra.dict_to_xml without importing the compiled extension (python/umbra needs it):
    its pure-Python section of python/umbra/__init__.py, executed on its own."""
    src = open(os.path.join(ROOT, "python", "umbra", "__init__.py")).read()
    a = src.index("# --- Mitsuba dicts -> Mitsuba XML")
    b = src.index("def dict_to_xml")
    b = src.index("\n\n\n", b) if "\n\n\n" in src[b:] else len(src)
    from collections.abc import Mapping
    from typing import Any

    class UmbraError(Exception):
        pass
    g = {"np": np, "Mapping": Mapping, "Any": Any, "UmbraError": UmbraError}
    exec(compile(src[a:b], "umbra/__init__.py (dict_to_xml)", "exec"), g)
    return g["dict_to_xml"]


def write_xml(path, scene):
    with open(path, "w") as f:
        f.write(_dict_to_xml()(scene))


def step_render(spp, threads=2):
    import mtutil
    mi, mitr = mtutil.setup(threads)
    os.makedirs(OUT, exist_ok=True)
    write_xml(os.path.join(OUT, "scene_full.xml"), scene_dict(True, spp // 2))
    write_xml(os.path.join(OUT, "scene_fit.xml"), scene_dict(False, spp // 2))
    scene = mtutil.load_xml(os.path.join(OUT, "scene_full.xml"))
    t0 = time.time()
    Hs = [mtutil.render_scene(scene, spp=spp // 2, seed=s) for s in (1, 2)]
    secs = time.time() - t0
    H = ((Hs[0].astype(np.float64) + Hs[1]) / 2).astype(np.float32)
    for name, a in (("H", H), ("H_seed1", Hs[0]), ("H_seed2", Hs[1])):
        np.save(os.path.join(OUT, name + ".npy"), a)
    import fit_mitransient as fm
    nz = fm.noise(*Hs)
    info = {"spp": spp, "seeds": [1, 2], "render_seconds": round(secs, 1), "threads": threads,
            "noise_peak": float(nz["peak"]), "noise_l2": float(nz["l2"]),
            "shape": list(H.shape), "total": float(H.astype(np.float64).sum())}
    with open(os.path.join(OUT, "render.json"), "w") as f:
        json.dump(info, f, indent=1)
    print(json.dumps(info), flush=True)


# ---------------------------------------------------------------- capture model

def emg_bins(edges_ps, sigma, tau):
    """Per-bin integrals of an exponentially modified Gaussian (unit area; Gaussian sigma,
    exponential tau; tau = 0: the Gaussian), on bin edges in ps (lag 0 at the core's
    centre). Integrated exactly from its CDF."""
    from math import erf
    erfv = np.vectorize(erf)
    t = np.asarray(edges_ps, float)
    G = 0.5 * (1 + erfv(t / (sigma * np.sqrt(2))))
    if tau == 0:
        cdf = G
    else:
        # CDF of Gaussian(0, s) + Exp(tau): Phi(t/s) - exp(-t/tau + s^2/(2 tau^2)) Phi(t/s - s/tau)
        z = t / sigma - sigma / tau
        logterm = -t / tau + sigma ** 2 / (2 * tau ** 2)
        Phi = 0.5 * (1 + erfv(z / np.sqrt(2)))
        cdf = G - np.exp(np.minimum(logterm, 700)) * Phi
    return np.diff(cdf)


def response_taps(bin_ps, lags_before=8, n=None):
    """The truth response on the measurement's bins: taps for lags -lags_before..n-1 (bins),
    the Gaussian core centred on lag 0's bin centre."""
    n = n or BINS
    k = np.arange(-lags_before, n + 1)
    edges = (k - 0.5) * bin_ps
    core_w = 1 - sum(w for w, _ in TAILS)
    r = core_w * emg_bins(edges, SIGMA_PS, 0)
    for w, tau in TAILS:
        r += w * emg_bins(edges, SIGMA_PS, tau)
    return r  # index i <-> lag i - lags_before


def step_measure():
    H = np.load(os.path.join(OUT, "H.npy")).astype(np.float64)
    ny, nx, T = H.shape
    bin_ps = BIN_WIDTH / PS
    lb = 8
    r = response_taps(bin_ps, lb, T)
    # (R ⊗ H)[t] = sum_l r[l] H[t - l]
    from numpy.fft import irfft, rfft
    L = 2 * T + len(r)
    Rf = rfft(np.concatenate([r, np.zeros(L - len(r))]))
    conv = irfft(rfft(H, n=L, axis=-1) * Rf, n=L, axis=-1)[..., lb:lb + T]
    conv = np.clip(conv, 0, None)
    scale = PEAK_COUNTS / conv.max()
    S = conv * scale
    # the direct return: amplitude smooth over the scan, CV ~0.4
    X, Y = scan_xy()
    u, v = X / WALL_HALF, Y / WALL_HALF
    field = 0.55 * u - 0.35 * v + 0.3 * u * v + 0.25 * (u ** 2 - 0.4)
    field = field - field.mean()
    field *= DIRECT_CV / field.std()
    D = DIRECT_TOTAL_MEAN * np.exp(field - np.log(np.exp(field).mean()))
    t_opl = START_OPL + (np.arange(T) + 0.5) * BIN_WIDTH
    # direct peak: the same response (core + tails), centred at DIRECT_OPL
    lag0 = int(round((DIRECT_OPL - START_OPL) / BIN_WIDTH - 0.5))
    peak_shape = np.zeros(T)
    src = np.zeros(T)
    src[lag0] = 1.0
    peak_shape = irfft(rfft(src, n=L) * Rf, n=L)[lb:lb + T]
    peak_shape = np.clip(peak_shape, 0, None)
    direct = D[..., None] * peak_shape[None, None]
    # its tail (after the direct peak), per bin: sum_k a_k D_p exp(-(t - t_d) / tau_k)
    dt = t_opl - DIRECT_OPL
    tail_shape = np.zeros(T)
    for a_k, tau_ps in DIRECT_TAILS:
        tail_shape += np.where(dt > 0, a_k * np.exp(-np.maximum(dt, 0) / (tau_ps * PS)), 0.0)
    tail = D[..., None] * tail_shape[None, None]
    floor = FLOOR * (1 + 0.2 * u - 0.1 * v)[..., None] * np.ones(T)
    mu = S + direct + tail + floor
    P = np.random.default_rng(SEED).poisson(mu).astype(np.float32)
    np.save(os.path.join(OUT, "measured.npy"), P)
    np.save(os.path.join(OUT, "mu.npy"), mu.astype(np.float32))
    np.save(os.path.join(OUT, "signal_counts.npy"), S.astype(np.float32))
    # truth numbers
    sig_start = int(np.flatnonzero(H.sum((0, 1)) > 0)[0])
    truth = {
        "bin_width_opl": BIN_WIDTH, "bin_ps": bin_ps, "start_opl": START_OPL, "bins": T,
        "response": {"sigma_ps": SIGMA_PS, "core_weight": 1 - sum(w for w, _ in TAILS),
                     "tail_weights": [w for w, _ in TAILS],
                     "tail_tau_ps": [t for _, t in TAILS],
                     "form": "core N(0, sigma) + sum_k w_k EMG(sigma, tau_k), unit area, "
                             "taps integrated per bin, core centred on lag 0"},
        "scale_counts_per_H": scale, "peak_signal_counts": float(S.max()),
        "signal_counts_total": float(S.sum()),
        "direct": {"opl": DIRECT_OPL, "mean_counts": float(D.mean()), "cv": float(D.std() / D.mean()),
                   "min": float(D.min()), "max": float(D.max()),
                   "field": "D = mean * exp(f)/mean(exp f), f = 0.55u - 0.35v + 0.3uv + "
                            "0.25(u^2-0.4) standardised to std 0.4; u,v = x,y / 0.25 m",
                   "shape": "the response above, centred at OPL 0.02 m"},
        "direct_tail": {"per_bin_amplitude_over_D": [a for a, _ in DIRECT_TAILS],
                        "tau_ps": [t for _, t in DIRECT_TAILS],
                        "form": "sum_k a_k D_p exp(-(t - 0.02 m)/(c tau_k)) per bin, t > 0.02 m",
                        "counts_per_bin_at_signal_start_mean":
                            float(tail[..., sig_start].mean()),
                        "total_over_D": float(tail_shape.sum())},
        "floor": {"mean": FLOOR, "field": "0.5 (1 + 0.2u - 0.1v)"},
        "seed": SEED, "first_signal_bin": sig_start,
        "first_signal_opl": START_OPL + sig_start * BIN_WIDTH,
        "chart": {"board": {"half": BOARD_HALF, "z": BOARD_Z, "albedo": BOARD_ALBEDO},
                  "bars_z": BAR_Z, "bar_albedo": BAR_ALBEDO, "groups": GROUPS},
        "total_counts": float(P.sum()), "max_count": float(P.max()),
    }
    with open(os.path.join(OUT, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    print(json.dumps({k: truth[k] for k in ("scale_counts_per_H", "peak_signal_counts",
                                            "signal_counts_total", "direct", "direct_tail",
                                            "first_signal_opl", "total_counts")}, indent=1))


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("step")
    ap.add_argument("--spp", type=int, default=65536)
    a = ap.parse_args()
    if a.step == "render":
        step_render(a.spp)
    elif a.step == "measure":
        step_measure()


# ---------------------------------------------------------------- umbra

FIT_CMD = ["fit", "scene_fit.xml", "--measured", "measured.npy", "--background", "per-point",
           "--irf", "calibrate", "--likelihood", "poisson", "--ignore-before", "0.8",
           "--init", "lct", "--threads", "2", "-q", "-o", "fit"]
LCT_DEPTHS = (0.3, 0.8)
LCT_NZ = 250


def lct_cmd(time_bin, out):
    return ["recon", "scene_fit.xml", "--measured", "measured.npy", "--method", "lct",
            "--ignore-before", "0.8", "--time-bin", str(time_bin), "--subtract-floor",
            "--snr", "0.1", "--grid", f"{SCAN},{SCAN},{LCT_NZ}",
            "--depths", f"{LCT_DEPTHS[0]},{LCT_DEPTHS[1]}", "-o", out]


def step_fit():
    _, secs = run([UMBRA, *FIT_CMD], cwd=OUT)
    with open(os.path.join(OUT, "fit_wall_seconds.txt"), "w") as f:
        f.write(f"{secs:.1f}\n")
    print(f"fit: {secs:.0f} s wall")


def step_lct():
    for tb in (1, 2):
        _, secs = run([UMBRA, *lct_cmd(tb, f"lct_tb{tb}")], cwd=OUT)
        print(f"lct time-bin {tb}: {secs:.1f} s")


# ---------------------------------------------------------------- analysis

def cell_fraction(n_sub=16):
    """Per scan point, the fraction of its scan cell (pitch x pitch) that is bar, board
    (not bar), and nothing."""
    A = truth_albedo(SCAN * n_sub).reshape(SCAN, n_sub, SCAN, n_sub)
    bar = (A == BAR_ALBEDO).mean((1, 3))
    board = (A == BOARD_ALBEDO).mean((1, 3))
    return bar, board


def lct_image(d):
    s = read_toml(os.path.join(d, "summary.toml"))
    v = np.load(os.path.join(d, "volume.npy"))
    nz = s["grid_dims"][2]
    z = s["grid_min"][2] + (np.arange(nz) + 0.5) * (s["grid_max"][2] - s["grid_min"][2]) / nz
    k = (z >= 0.4) & (z <= 0.6)
    img = v[:, :, k].max(2)
    return img, z[k][v[:, :, k].argmax(2)], s


def profiles(img):
    """Per bar group: the profile across its bars (mean over the scan rows inside the bars'
    middle), sampled (linear interpolation along x) at the bar and gap centres; the dip
    ratio of each gap = value at the gap centre / mean of its two bars' centre values."""
    X, Y = scan_xy()
    xs = X[0]
    out = {}
    for g in ("bars4", "bars3", "bars2"):
        rects = GROUPS[g]
        y0, y1 = rects[0][2], rects[0][3]
        rows = np.flatnonzero((Y[:, 0] >= y0 + 0.01) & (Y[:, 0] <= y1 - 0.01))
        prof = np.nanmean(img[rows], 0)
        bars = [float(np.interp((r[0] + r[1]) / 2, xs, prof)) for r in rects]
        gaps = [float(np.interp((a[1] + b[0]) / 2, xs, prof)) for a, b in zip(rects, rects[1:])]
        dips = [gaps[i] / ((bars[i] + bars[i + 1]) / 2) for i in range(len(gaps))]
        out[g] = {"rows": rows.tolist(), "profile": prof.tolist(), "bars": bars, "gaps": gaps,
                  "dip_ratios": dips, "resolved_70pc": bool(max(dips) < 0.7)}
    return out


def albedo_stats(A, margin=1):
    """Fitted albedo on whole bar cells and on whole board cells at least `margin` cells
    from any bar; their means, medians and ratios."""
    from numpy.lib.stride_tricks import sliding_window_view as sw
    bar_f, board_f = cell_fraction()
    bar_cells = bar_f >= 0.999
    pad = np.pad(bar_f, margin)
    near_bar = sw(pad, (2 * margin + 1,) * 2).max((2, 3)) > 0
    board_cells = (board_f >= 0.999) & ~near_bar
    fin = np.isfinite(A)
    ab, ad = A[bar_cells & fin], A[board_cells & fin]
    return {"margin_cells": margin, "bar_cells": int(bar_cells.sum()),
            "bar_cells_fitted": int((bar_cells & fin).sum()),
            "board_cells": int(board_cells.sum()),
            "board_cells_fitted": int((board_cells & fin).sum()),
            "bar_mean": float(ab.mean()), "bar_median": float(np.median(ab)),
            "bar_std": float(ab.std()),
            "board_mean": float(ad.mean()), "board_median": float(np.median(ad)),
            "board_std": float(ad.std()),
            "ratio_mean": float(ab.mean() / ad.mean()),
            "ratio_median": float(np.median(ab) / np.median(ad)),
            "ratio_truth": BAR_ALBEDO / BOARD_ALBEDO}, bar_cells, board_cells


def dots(img, board_level):
    """Each square's value at its centre (bilinear) over the board level."""
    X, Y = scan_xy()
    xs, ys = X[0], Y[:, 0]
    out = []
    for x0, x1, y0, y1 in GROUPS["dots"]:
        xc, yc = (x0 + x1) / 2, (y0 + y1) / 2
        col = np.array([np.interp(xc, xs, np.nan_to_num(img[i])) for i in range(SCAN)])
        out.append(float(np.interp(yc, ys, col) / board_level))
    return out


FITS = ("fit", "fit_seed2", "fit_x100", "fit_x100_iters380", "fit_fullscan", "fit_iters380",
        # Session 4: the direct tail in (it was zero before) and a floor per scan point.
        "fit_s4", "fit_s4_seed2", "fit_s4_x100",
        # and albedo rescaled, not clamped, at its bound.
        "fit_s4b", "fit_s4b_seed2", "fit_s4b_x100")
LCTS = ("lct_tb1", "lct_tb2", "lct_snr1", "lct_snr10", "lct_seed2", "lct_x100", "lct_x100_snr10", "lct_diag_clean_signal",
        "lct_diag_clean_snr10", "lct_diag_mu")


def step_analyse():
    truth = json.load(open(os.path.join(OUT, "truth.json")))
    At = truth_albedo()
    res = {"response_truth": truth["response"], "fits": {}, "lcts": {},
           "truth_at_scan_points": profiles(At)}
    mu = np.load(os.path.join(OUT, "mu.npy")).astype(np.float64)
    S = np.load(os.path.join(OUT, "signal_counts.npy")).astype(np.float64)
    first = int(round(0.8 / BIN_WIDTH))
    res["background_truth_mean_fitted_bins"] = float((mu - S)[..., first:].mean())
    for name in FITS:
        d = os.path.join(OUT, name)
        if not os.path.exists(os.path.join(d, "summary.toml")):
            continue
        s = read_toml(os.path.join(d, "summary.toml"))
        A = np.load(os.path.join(d, "albedo.npy"))
        Dm = np.load(os.path.join(d, "depth.npy"))
        st1, bar_cells, board_cells = albedo_stats(A, 1)
        st2, _, _ = albedo_stats(A, 2)
        bar_f, board_f = cell_fraction()
        r = {"summary": {k: v for k, v in s.items() if not isinstance(v, (dict, list))},
             "response": s.get("response"), "albedo": st1, "albedo_margin2": st2,
             "depth": {"bar_median": float(np.nanmedian(Dm[bar_cells])),
                       "board_median": float(np.nanmedian(Dm[board_cells])),
                       "board_cells_within_5mm": float(np.mean(np.abs(Dm[board_cells] - BOARD_Z) < 0.005)),
                       "outside_fitted": int(np.isfinite(Dm[(bar_f + board_f) == 0]).sum()),
                       "outside_cells": int(((bar_f + board_f) == 0).sum())},
             "profiles": profiles(A), "dots_over_board": dots(A, st1["board_median"])}
        res["fits"][name] = r
        print(f"== {name}: {s['seconds']:.0f} s, relative L2 {s['relative_l2']:.3f} (floor "
              f"{s.get('photon_noise_floor', float('nan')):.3f}), deviance/bin "
              f"{s.get('deviance_per_bin', float('nan')):.3f}, background {s['background']:.3f}"
              f" (truth mean {res['background_truth_mean_fitted_bins']:.3f})")
        print("   response:", s.get("response"))
        print("   albedo:", {k: round(v, 3) if isinstance(v, float) else v for k, v in st1.items()})
        print("   albedo margin 2:", {k: round(v, 3) if isinstance(v, float) else v for k, v in st2.items()})
        print("   depth:", r["depth"])
        print("   dips:", {g: (np.round(v["dip_ratios"], 2).tolist(), v["resolved_70pc"])
                           for g, v in r["profiles"].items()}, "dots/board:", np.round(r["dots_over_board"], 2).tolist())
    for name in LCTS:
        d = os.path.join(OUT, name)
        if not os.path.exists(os.path.join(d, "volume.npy")):
            continue
        img, _, _ = lct_image(d)
        _, bar_cells, board_cells = albedo_stats(np.ones((SCAN, SCAN)))
        board = float(np.median(img[board_cells]))
        r = {"profiles": profiles(img), "bar_over_board": float(np.median(img[bar_cells]) / board),
             "dots_over_board": dots(img, board)}
        res["lcts"][name] = r
        print(f"== {name}: bar/board {r['bar_over_board']:.2f}; dips",
              {g: (np.round(v["dip_ratios"], 2).tolist(), v["resolved_70pc"]) for g, v in r["profiles"].items()},
              "dots/board:", np.round(r["dots_over_board"], 2).tolist())
    print("truth at scan points dips:", {g: np.round(v["dip_ratios"], 2).tolist()
                                         for g, v in res["truth_at_scan_points"].items()})
    with open(os.path.join(OUT, "analysis.json"), "w") as f:
        json.dump(res, f, indent=1)
    A = np.load(os.path.join(OUT, "fit", "albedo.npy"))
    Dm = np.load(os.path.join(OUT, "fit", "depth.npy"))
    figures(res, A, Dm)
    figure_fits(res)


def figure_fits(res):
    """Every fit's albedo and the LCTs, seen from the wall."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ext = [WALL_HALF, -WALL_HALF, -WALL_HALF, WALL_HALF]
    panels = []
    for name, r in res["fits"].items():
        A = np.load(os.path.join(OUT, name, "albedo.npy"))
        a = r["albedo"]
        panels.append((f"{name} albedo (0 to its 99th pct)\nbar/board median {a['ratio_median']:.2f} (truth 4.5)",
                       np.nan_to_num(A, nan=0.0)[::-1, ::-1], (0, float(np.nanpercentile(A, 99)))))
    for name in ("lct_tb1", "lct_snr10", "lct_x100_snr10", "lct_diag_clean_snr10"):
        if name in res["lcts"]:
            img, _, _ = lct_image(os.path.join(OUT, name))
            panels.append((name, img[::-1, ::-1], None))
    fig, axes = plt.subplots(2, (len(panels) + 1) // 2, figsize=(3.0 * ((len(panels) + 1) // 2), 6.4))
    axes = axes.ravel()
    for ax, (t, im, lim) in zip(axes, panels):
        ax.imshow(im, cmap="magma", extent=ext, interpolation="nearest",
                  vmin=None if lim is None else lim[0], vmax=None if lim is None else lim[1])
        ax.set_title(t, fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in axes[len(panels):]:
        ax.axis("off")
    fig.savefig(os.path.join(DOCS, "chart_truth_fits.png"), dpi=110, bbox_inches="tight")
    plt.close(fig)


def figures(res, A, Dm):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    os.makedirs(DOCS, exist_ok=True)
    ext = [WALL_HALF, -WALL_HALF, -WALL_HALF, WALL_HALF]  # seen from the wall: +x left, +y up
    view = lambda a: a[::-1, ::-1]  # noqa: E731
    panels = [("truth albedo (bars 0.9, board 0.2)", view(truth_albedo(256)), "magma", (0, 1))]
    d = os.path.join(OUT, "lct_tb1")
    if os.path.exists(os.path.join(d, "volume.npy")):
        img, _, _ = lct_image(d)
        panels.append(("Umbra LCT, max over 0.4-0.6 m\n(--time-bin 1)", view(img), "magma", None))
    top = np.nanpercentile(A, 99.5)
    panels.append(("fit albedo (relative)", view(np.nan_to_num(A, nan=0.0)), "magma", (0, top)))
    panels.append(("fit depth (m), 0.45-0.55", view(Dm), "viridis", (0.45, 0.55)))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 3.4))
    for ax, (t, im, cm, lim) in zip(axes, panels):
        h = ax.imshow(im, cmap=cm, extent=ext, vmin=None if lim is None else lim[0],
                      vmax=None if lim is None else lim[1], interpolation="nearest")
        ax.set_title(t, fontsize=8)
        ax.set_xticks([0.2, 0, -0.2])
        ax.set_yticks([-0.2, 0, 0.2])
        ax.tick_params(labelsize=6)
        fig.colorbar(h, ax=ax, fraction=0.046, pad=0.02).ax.tick_params(labelsize=6)
    fig.suptitle("chart ground truth (mitransient, BSDF sampling) seen from the wall; "
                 "x axis: wall x (m, +x left)", fontsize=8)
    fig.savefig(os.path.join(DOCS, "chart_truth.png"), dpi=120, bbox_inches="tight")
    plt.close(fig)
    # profiles
    X, _ = scan_xy()
    xs = X[0]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2))
    for ax, g in zip(axes, ("bars4", "bars3", "bars2")):
        curves = [("truth at scan points", res["truth_at_scan_points"])]
        curves += [(f"{k} albedo", v["profiles"]) for k, v in res["fits"].items()]
        curves += [(k, res["lcts"][k]["profiles"]) for k in ("lct_tb1", "lct_snr10")
                   if k in res["lcts"]]
        for name, p in curves:
            prof = np.array(p[g]["profile"])
            r = GROUPS[g]
            sel = (xs >= r[0][0] - 0.03) & (xs <= r[-1][1] + 0.03)
            prof = prof / np.nanmax(prof[sel])
            ls = "--" if name.startswith("lct") else "-"
            ax.plot(xs[sel], prof[sel], marker="o", ls=ls, ms=3, label=name)
        for x0, x1, _, _ in GROUPS[g]:
            ax.axvspan(x0, x1, color="0.9")
        ax.set_title(f"{g}: mean over the bars' rows (max = 1)", fontsize=8)
        ax.set_xlabel("wall x (m)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=6)
    fig.savefig(os.path.join(DOCS, "chart_truth_profiles.png"), dpi=120, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__" and sys.argv[1:2] and sys.argv[1] in ("fit", "lct", "analyse"):
    {"fit": step_fit, "lct": step_lct, "analyse": step_analyse}[sys.argv[1]]()
