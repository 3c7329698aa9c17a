"""Every Stanford LCT capture (../shared/data/lct/, O'Toole et al. 2018): Umbra's fit with
the reflectance model each needs, its relative L2 against the capture's photon floor and its
time, next to the light-cone transform (Umbra's `recon::lct`) and y-tal's f-k migration of the
same capture (issue 20; docs/BASELINES.md).

    .venv/bin/python python/studies/lct_captures.py [--captures diffuse_s,...]
        [--models lambertian,retroreflective] [--out out/lct_captures] [--docs docs]

Per capture and model: `umbra fit scenes/lct.toml --measured data_X.mat` (the documented
command, no other flags; `--init` only when given here; the defaults of docs/FITTING.md: bins before OPL
0.72 m left out, 8,2 binning, the capture model calibrated from the capture: a response
with tails, a gain field, a floor and the direct tails per scan point, Poisson deviance),
`--reflectance retroreflective` for the retroreflective model, with the sheeting's angular
falloff `--retro-falloff M` chosen per capture: a fit from a plane for each M of FALLOFFS
(~10 s each: retroreflective receivers have no boundary terms), the M of the lowest
relative L2 kept for the final fit. The reconstructions: `umbra recon --method lct --time-bin 8
--subtract-floor --snr 0.1` on 64 x 64 x 256 voxels over 0.2-1.2 m, and y-tal's fk
(ytal_recon.py) of the same preprocessed capture (`umbra convert --ignore-before 0.72
--time-bin 8`) on the same grid, both shown as front maximum projections over the depths
where the papers place the objects (0.25-0.9 m; 0.25-1.15 m for s_u, whose U stands at
1.02 m), next to the fit's albedo and depth seen
from the wall (`umbra recon --mesh mesh_all.obj` on the same columns: every fitted face,
dark ones too, since albedo is what shows a chart's bars; colour up to its 98th percentile).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
from baselines import UMBRA, YTAL_PYTHON, YTAL_RECON, read_toml, run  # noqa: E402

DATA = os.path.join(ROOT, "..", "shared", "data", "lct")
CAPTURES = ("diffuse_s", "s_u", "exit_sign", "outdoor_s", "resolution_chart_40cm",
            "resolution_chart_65cm", "dot_chart_40cm", "dot_chart_65cm")
SCAN = {"outdoor_s": 32}  # the others: 64 x 64


def grid(capture):
    n = SCAN.get(capture, 64)
    return ["--grid", f"{n},{n},256", "--depths", "0.2,1.2"]
SHOW = (0.25, 0.9)
# Depths shown per capture where the objects stand further (s_u's U at 1.02 m).
SHOW_AT = {"s_u": (0.25, 1.15)}


# The retroreflective model's angular falloff exponents tried per capture (cos^m).
FALLOFFS = (0, 2, 4, 8, 12, 16)


def fit_only(capture, model, d, init, falloff=None):
    """`umbra fit` of the capture with `model` into `d` (fresh); its summary."""
    shutil.rmtree(d, ignore_errors=True)
    mat = os.path.join(DATA, f"data_{capture}.mat")
    cmd = [UMBRA, "fit", os.path.join(ROOT, "scenes", "lct.toml"), "--measured", mat,
           *(["--init", init] if init else []), "-q", "-o", d]
    if model == "retroreflective":
        cmd += ["--reflectance", "retroreflective"]
        if falloff is not None:
            cmd += ["--retro-falloff", str(falloff)]
    run(cmd)
    return read_toml(os.path.join(d, "summary.toml"))


def choose_falloff(capture, out):
    """The falloff exponent of FALLOFFS whose fit from a plane has the lowest relative
    L2, and every one's relative L2 (the sweep)."""
    sweep = {}
    for m in FALLOFFS:
        d = os.path.join(out, f"{capture}-retro-sweep", f"m{m}")
        sweep[m] = fit_only(capture, "retroreflective", d, "plane", m)["relative_l2"]
        print(f"{capture} retroreflective, falloff {m}: relative L2 {sweep[m]:.4f}", flush=True)
    return min(sweep, key=sweep.get), sweep


def fit(capture, model, out, init="auto", falloff=None):
    """`umbra fit` of the capture with `model`; its summary, and the folder of the fitted
    surface's depth and albedo maps on the reconstructions' grid (depth.npy, albedo.npy)."""
    d = os.path.join(out, f"{capture}-{model}")
    mat = os.path.join(DATA, f"data_{capture}.mat")
    fit_only(capture, model, d, init, falloff)
    run([UMBRA, "recon", os.path.join(ROOT, "scenes", "lct.toml"), "--measured", mat,
         "--mesh", os.path.join(d, "mesh_all.obj"), *grid(capture), "-o", os.path.join(d, "seen")])
    return read_toml(os.path.join(d, "summary.toml")), os.path.join(d, "seen")


def lct(capture, out):
    """Umbra's LCT of the capture; its output folder (volume.npy, summary.toml)."""
    d = os.path.join(out, f"{capture}-lct")
    run([UMBRA, "recon", os.path.join(ROOT, "scenes", "lct.toml"), "--measured",
         os.path.join(DATA, f"data_{capture}.mat"), "--method", "lct", "--ignore-before",
         "0.72", "--time-bin", "8", "--subtract-floor", "--snr", "0.1", *grid(capture), "-o", d])
    return d


def fk(capture, out, grid_of):
    """y-tal's f-k migration of the capture on the LCT run's grid (`grid_of`: its
    summary.toml); the volume's path, or None with the reason printed."""
    d = os.path.join(out, f"{capture}-fk")
    os.makedirs(d, exist_ok=True)
    h5 = os.path.join(d, "capture.hdf5")
    run([UMBRA, "convert", os.path.join(ROOT, "scenes", "lct.toml"), "--measured",
         os.path.join(DATA, f"data_{capture}.mat"), "--ignore-before", "0.72", "--time-bin",
         "8", "-o", h5])
    g = read_toml(grid_of)
    gpath = os.path.join(d, "grid.json")
    with open(gpath, "w") as f:
        json.dump({"min": g["grid_min"], "max": g["grid_max"], "dims": g["grid_dims"]}, f)
    vol = os.path.join(d, "volume.npy")
    try:
        run([YTAL_PYTHON, YTAL_RECON, h5, gpath, "fk", vol, "--json", os.path.join(d, "timing.json")])
    except RuntimeError as e:
        print(f"{capture}: y-tal fk failed: {str(e).splitlines()[0]}", flush=True)
        return None
    return vol


def front(volume, z, window=SHOW):
    """Front maximum projection over `window` and the argmax depth there, seen from the
    wall (+x to the left)."""
    k = (z >= window[0]) & (z <= window[1])
    v = volume[:, :, k]
    return v.max(2)[::-1, ::-1], z[k][v.argmax(2)][::-1, ::-1]


def picture(path, capture, lct_dir, fk_vol, fits):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    g = read_toml(os.path.join(lct_dir, "summary.toml"))
    nz = g["grid_dims"][2]
    z = g["grid_min"][2] + (np.arange(nz) + 0.5) * (g["grid_max"][2] - g["grid_min"][2]) / nz
    show = SHOW_AT.get(capture, SHOW)
    panels = [("LCT (Umbra)", *front(np.load(os.path.join(lct_dir, "volume.npy")), z, show))]
    if fk_vol:
        panels.append(("f-k (y-tal)", *front(np.load(fk_vol), z, show)))
    cols = len(panels) + 2 * len(fits)
    fig, axes = plt.subplots(1, cols, figsize=(2.4 * cols, 2.8))
    axes = np.atleast_1d(axes)
    for ax, (name, mip, _) in zip(axes, panels):
        ax.imshow(mip, cmap="magma")
        ax.set_title(name, fontsize=8)
    for i, (model, seen, l2) in enumerate(fits):
        a = np.load(os.path.join(seen, "albedo.npy"))[::-1, ::-1]
        d = np.load(os.path.join(seen, "depth.npy"))[::-1, ::-1]
        # The colour scale's top at the 98th percentile, as the fit's own albedo.png: a few
        # bright vertices at a fitted board's rim would darken the rest.
        top = float(np.nanpercentile(a, 98)) if np.isfinite(a).any() else 1.0
        ax_a, ax_d = axes[len(panels) + 2 * i], axes[len(panels) + 2 * i + 1]
        ax_a.imshow(np.nan_to_num(a, nan=0.0), cmap="magma", vmin=0.0, vmax=top)
        ax_a.set_title(f"fit albedo, {model}\nrelative L2 {l2:.3f}", fontsize=8)
        ax_d.imshow(d, cmap="viridis", vmin=show[0], vmax=show[1])
        ax_d.set_title(f"fit depth\n{show[0]}-{show[1]} m", fontsize=8)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(capture, fontsize=9)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--captures", default=",".join(CAPTURES))
    ap.add_argument("--models", default="lambertian")
    ap.add_argument("--init", default=None,
                    help="umbra fit --init (default: none given, the fit's own: the LCT start)")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "lct_captures"))
    ap.add_argument("--docs", default=os.path.join(ROOT, "docs"))
    args = ap.parse_args(argv)
    rows, sweeps = [], []
    for c in args.captures.split(","):
        lct_dir = lct(c, args.out)
        fk_vol = fk(c, args.out, os.path.join(lct_dir, "summary.toml"))
        fits = []
        for m in args.models.split(","):
            falloff = None
            if m == "retroreflective":
                falloff, sweep = choose_falloff(c, args.out)
                sweeps.append((c, sweep))
            s, seen = fit(c, m, args.out, args.init, falloff)
            floor = s.get("photon_noise_floor")
            rows.append((c, m, falloff, s, floor))
            name = m if falloff is None else f"retro, cos^{falloff}"
            fits.append((name, seen, s["relative_l2"]))
            print(f"{c} {m}: relative L2 {s['relative_l2']:.3f} (floor {floor}), {s['seconds']:.0f} s",
                  flush=True)
        if args.docs:
            os.makedirs(os.path.join(args.docs, "baselines"), exist_ok=True)
            picture(os.path.join(args.docs, "baselines", f"lct_{c}.png"), c, lct_dir, fk_vol, fits)
    if args.docs:
        os.makedirs(os.path.join(args.docs, "baselines"), exist_ok=True)
        with open(os.path.join(args.docs, "baselines", "lct_captures.md"), "w") as f:
            f.write("<!-- generated by python/studies/lct_captures.py; do not edit -->\n")
            f.write("| capture | model | falloff m | relative L2 | photon floor | L2 / floor "
                    "| deviance / bin | held out | response σ (ps) | tails (weight at τ ps) "
                    "| fit time (s) |\n")
            f.write("|---|---|---|---|---|---|---|---|---|---|---|\n")
            for c, m, falloff, s, floor in rows:
                l2 = s["relative_l2"]
                ratio = f"{l2 / floor:.2f}" if floor else "n/a"
                fm = "" if falloff is None else str(falloff)
                num = lambda k: f"{s[k]:.2f}" if k in s else "n/a"  # noqa: E731
                r = s.get("response") or {}
                sigma = f"{r['sigma_ps']:.1f}" if r else "n/a"
                tails = ", ".join(f"{100 * w:.0f} % at {t:.0f}"
                                  for w, t in zip(r.get("tail_weights", []), r.get("tail_tau_ps", [])))
                f.write(f"| {c} | {m} | {fm} | {l2:.3f} | {floor:.3f} | {ratio} | "
                        f"{num('deviance_per_bin')} | {num('held_out_loss')} | {sigma} | "
                        f"{tails or 'none'} | {s['seconds']:.0f} |\n")
            start = f"--init {args.init}" if args.init else "with its default start (the LCT's surfaces)"
            f.write(f"\n(`umbra fit` {start}; fit time is all starts together.)\n")
            if sweeps:
                f.write("\nThe retroreflective model's falloff, fits from a plane (relative L2):\n\n")
                f.write("| capture | " + " | ".join(f"m = {m}" for m in FALLOFFS) + " |\n")
                f.write("|---|" + "---|" * len(FALLOFFS) + "\n")
                for c, sweep in sweeps:
                    f.write(f"| {c} | " + " | ".join(f"{sweep[m]:.3f}" for m in FALLOFFS) + " |\n")


if __name__ == "__main__":
    main()
