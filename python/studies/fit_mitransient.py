"""Fit data made by another renderer: mitransient 1.3.1 (issue 6; docs/FITTING.md).

1. Writes a mitransient scene (Mitsuba XML, the subset Umbra reads, via umbra.dict_to_xml):
   the letter T of scenes/meshes/letter_t.obj turned 30 degrees about the vertical axis,
   1 m from the relay wall; confocal 32 x 32 scan over 1.6 m x 1.6 m, 512 bins of 4 mm from
   OPL 1.6 m (the capture of scenes/studies/letter_angled.toml).
2. Renders it with mitransient (llvm_ad_mono, transient_nlos_path, laser and hidden-geometry
   sampling, up to 6 bounces, box bins, mitransient's own scale) as two seeds of spp/2: their
   mean is the target (.npy, (sy, sx, T)), their difference measures its noise.
3. Renders the same XML with `umbra render --model path` (two seeds): checks that it gives
   the same transient (scale, L2) and keeps their mean as a comparison target.
4. Fits each target the same way: `umbra fit SCENE.xml --measured TARGET.npy --truth
   --init plane` (the fit fits its own intensity scale) and reads OUT/*/summary.toml.

    .venv/bin/python python/studies/fit_mitransient.py [--scan 32] [--bins 512]
        [--bin-width 0.004] [--spp 65536] [--umbra-spp 16384] [--no-umbra-fit]
        [--iters N | --config schedule.toml] [--out out/studies/mitransient] [--docs docs/studies]

Writes docs/studies/mitransient.md and mitransient_transients.png (--docs '' writes neither).
Needs target/release/umbra, the `umbra` Python package and mitransient (DESIGN.md section 7).

The laser and the SPAD sit at (0, -0.5, 0.8), not at letter_angled.toml's (0, -0.5, 1.5):
from there the letter shadows the laser -> x_l and x_s -> SPAD legs of some scan points,
which mitransient traces (those transients are 0) and Umbra does not (--laser 0,-0.5,1.5
shows the difference in the check of step 3).
"""
import argparse
import os
import shutil
import subprocess
import sys
import time
import tomllib

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "python", "validation"))
import mtutil  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before Mitsuba loads)

UMBRA = os.environ.get("UMBRA_BIN", os.path.join(ROOT, "target", "release", "umbra"))
MESH = os.path.join(ROOT, "scenes", "meshes", "letter_t.obj")


_rgb = mtutil.rgb


def write_scene(dest, scan=32, bins=512, bin_width=0.004, start_opl=1.6, spp=1024,
                laser=(0.0, -0.5, 0.8), angle=30.0, distance=1.0):
    """Writes dest/scene.xml (and the letter's OBJ next to it); returns the XML's path."""
    a = np.radians(angle)
    letter = np.eye(4)  # rotate about +y by `angle`, then move `distance` from the wall
    letter[0, 0] = letter[2, 2] = np.cos(a)
    letter[0, 2], letter[2, 0], letter[2, 3] = np.sin(a), -np.sin(a), distance
    laser = [float(x) for x in laser]
    scene = {
        "type": "scene",
        "integrator": mtutil.nlos_integrator("confocal", True),
        "laser": mtutil.projector(laser, [0.0, 0.0, 0.0]),
        "letter_t": {"type": "obj", "filename": "letter_t.obj", "face_normals": True,
                     "to_world": letter, "bsdf": {"type": "diffuse", "reflectance": _rgb(0.9)}},
        # The scan covers the whole rectangle: 1.6 m x 1.6 m.
        "relay_wall": mtutil.relay_wall(0.8, 0.8, laser, scan, bins, bin_width, start_opl, spp),
    }
    import umbra
    os.makedirs(dest, exist_ok=True)
    shutil.copyfile(MESH, os.path.join(dest, "letter_t.obj"))
    path = os.path.join(dest, "scene.xml")
    with open(path, "w") as f:
        f.write(umbra.dict_to_xml(scene))
    return path


def render_mitransient(xml, spp, dest, threads=2, seeds=(1, 2)):
    """Two mitransient renders of spp/2 each: saves target.npy (their mean) and the two
    renders in dest; returns (mean, render 1, render 2, seconds)."""
    mtutil.setup(threads)
    scene = mtutil.load_xml(xml)
    t0 = time.time()
    H1, H2 = (mtutil.render_scene(scene, spp=spp // 2, seed=s) for s in seeds)
    seconds = time.time() - t0
    H = ((H1.astype(np.float64) + H2) / 2).astype(np.float32)
    for name, a in (("target", H), ("target_seed1", H1), ("target_seed2", H2)):
        np.save(os.path.join(dest, name + ".npy"), a)
    return H, H1, H2, seconds


def noise(H1, H2):
    """Noise of the mean of two independent renders, from their difference d (per bin
    sigma of the mean = |d| / 2): relative RMS over the bins at or above half their scan
    point's peak, and relative L2 over the whole transient."""
    H = (H1.astype(np.float64) + H2) / 2
    d2 = ((H1.astype(np.float64) - H2) / 2) ** 2
    peak = H >= 0.5 * H.max(-1, keepdims=True)
    peak &= H > 0
    return {"peak": np.sqrt(d2[peak].mean() / (H[peak] ** 2).mean()),
            "l2": np.sqrt(d2.sum() / (H ** 2).sum())}


def umbra_render(xml, spp, seed, out, umbra=UMBRA):
    cmd = [umbra, "render", xml, "--model", "path", "--spp", str(spp), "--seed", str(seed),
           "-o", out, "--no-preview", "-q"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    return np.load(out)


def compare(M1, M2, U1, U2):
    """Umbra (U1, U2) against mitransient (M1, M2), two seeds each: ratio of the totals with
    its standard error, per-scan-point ratio range, scan points where only one is zero, and
    the relative L2 between the means against the value noise alone gives."""
    M1, M2, U1, U2 = (a.astype(np.float64) for a in (M1, M2, U1, U2))
    M, U = (M1 + M2) / 2, (U1 + U2) / 2
    pm, pu = M.sum(-1), U.sum(-1)
    se_m = np.sqrt((((M1 - M2).sum(-1) / 2) ** 2).sum()) / pm.sum()
    se_u = np.sqrt((((U1 - U2).sum(-1) / 2) ** 2).sum()) / pu.sum()
    ratio = pu.sum() / pm.sum()
    both = (pm > 0) & (pu > 0)
    per_point = pu[both] / pm[both]
    expected = np.sqrt(((M1 - M2) ** 2).sum() / 4 + ((U1 - U2) ** 2).sum() / 4)
    return {"ratio": ratio, "ratio_se": ratio * np.hypot(se_m, se_u),
            "point_min": per_point.min(), "point_max": per_point.max(),
            "only_umbra": int(((pm == 0) & (pu > 0)).sum()),
            "only_mitransient": int(((pu == 0) & (pm > 0)).sum()),
            "l2": np.linalg.norm(U - M) / np.linalg.norm(M),
            "l2_noise": expected / np.linalg.norm(M)}


def run_fit(xml, target, out, iters=None, config=None, extra=(), umbra=UMBRA):
    """`umbra fit` of the target from a plane against the XML's letter; returns its
    summary.toml with wall-clock seconds and load averages added."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [umbra, "fit", xml, "--measured", target, "--truth", "-o", out, "--init", "plane", "-q"]
    cmd += (["--iters", str(iters)] if iters else []) + (["--config", config] if config else [])
    cmd += list(extra)
    load_before = os.getloadavg()[0]
    t0 = time.time()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}")
    with open(os.path.join(out, "summary.toml"), "rb") as f:
        summary = tomllib.load(f)
    summary.update(wall_seconds=time.time() - t0, load=(load_before, os.getloadavg()[0]),
                   stdout=proc.stdout)
    return summary


def table(a, chk, cols):
    """Markdown: the capture and the render check, then one column per target
    (name, spp, render seconds, noise, fit summary)."""
    def row(label, fn):
        return f"| {label} | " + " | ".join(fn(*c) for c in cols) + " |"

    def chamfer(s, key):
        return s["chamfer"][key]

    lines = [
        "<!-- generated by python/studies/fit_mitransient.py; do not edit -->",
        f"Confocal {a.scan} x {a.scan} scan over 1.6 m x 1.6 m, {a.bins} bins of "
        f"{1e3 * a.bin_width:g} mm from OPL 1.6 m; letter T turned 30 degrees, 1 m from the "
        f"wall; laser and SPAD at ({a.laser}). Both targets: mean of two seeds, noise from "
        "their difference. The fits: `umbra fit scene.xml --measured TARGET.npy --truth "
        f"--init plane{' --iters %d' % a.iters if a.iters else ''}"
        f"{' --config ' + a.config if a.config else ''}` (scale fitted"
        f"{'' if a.config else ', default schedule'}).",
        "",
        "`umbra render --model path` / mitransient on the same XML, total: "
        f"{chk['ratio']:.4f} +- {chk['ratio_se']:.4f} (per scan point {chk['point_min']:.3f}"
        f"..{chk['point_max']:.3f}; scan points zero in mitransient only: {chk['only_umbra']}); "
        f"relative L2 {chk['l2']:.4f} against {chk['l2_noise']:.4f} from noise alone.",
        "",
        "| | " + " | ".join(f"{name} target" for name, *_ in cols) + " |",
        "|---|" + "---|" * len(cols),
        row("target spp (render time)", lambda n, spp, t, z, s: f"{spp} ({t:.0f} s)"),
        row("target noise: peak bins / relative L2",
            lambda n, spp, t, z, s: f"{100 * z['peak']:.1f} % / {100 * z['l2']:.1f} %"),
        row("**Chamfer, seen surface** (mm)", lambda n, spp, t, z, s: f"**{s['chamfer']['seen_mm']:.2f}**"),
        row("fit -> truth / seen truth -> fit (mm)", lambda n, spp, t, z, s:
            f"{chamfer(s, 'seen_fit_to_truth_mm'):.2f} / "
            f"{chamfer(s, 'seen_truth_to_fit_mm'):.2f}"),
        row("the same, 90th percentile (mm)", lambda n, spp, t, z, s:
            f"{chamfer(s, 'seen_fit_to_truth_p90_mm'):.1f} / "
            f"{chamfer(s, 'seen_truth_to_fit_p90_mm'):.1f}"),
        row("Chamfer, whole surface (mm)", lambda n, spp, t, z, s: f"{s['chamfer']['whole_mm']:.2f}"),
        row("relative L2 of the fit", lambda n, spp, t, z, s: f"{s['relative_l2']:.3f}"),
        row("fitted scale", lambda n, spp, t, z, s: f"{s['scale']:.4f}"),
        row("iterations; mesh", lambda n, spp, t, z, s:
            f"{s['iterations']}; {s['vertices']} vertices, {s['faces']} faces"),
        row("fit time (wall clock)", lambda n, spp, t, z, s:
            f"{s['seconds']:.0f} s ({s['wall_seconds']:.0f} s)"),
        row("load average before / after the fit (2 cores)",
            lambda n, spp, t, z, s: f"{s['load'][0]:.1f} / {s['load'][1]:.1f}"),
    ]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scan", type=int, default=32)
    ap.add_argument("--bins", type=int, default=512)
    ap.add_argument("--bin-width", type=float, default=0.004)
    ap.add_argument("--spp", type=int, default=65536, help="mitransient target spp (2 seeds)")
    ap.add_argument("--umbra-spp", type=int, default=16384,
                    help="Umbra path renders (2 seeds): the check and the comparison target")
    ap.add_argument("--no-umbra-fit", action="store_true", help="skip the comparison fit")
    ap.add_argument("--laser", default="0,-0.5,0.8", help="laser and SPAD position x,y,z")
    ap.add_argument("--iters", type=int, default=0)
    ap.add_argument("--config", default=None, help="fit schedule TOML")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "studies", "mitransient"))
    ap.add_argument("--docs", default=os.path.join(ROOT, "docs", "studies"))
    ap.add_argument("--threads", type=int, default=2, help="mitransient threads")
    a = ap.parse_args()
    laser = [float(x) for x in a.laser.split(",")]
    xml = write_scene(a.out, a.scan, a.bins, a.bin_width, spp=a.spp // 2, laser=laser)
    print(f"scene: {xml}", flush=True)
    H, H1, H2, mt_seconds = render_mitransient(xml, a.spp, a.out, a.threads)
    n = noise(H1, H2)
    print(f"mitransient: {a.spp} spp in {mt_seconds:.1f} s; noise of the target: "
          f"{100 * n['peak']:.2f} % per bin at the peaks, relative L2 {n['l2']:.4f}", flush=True)
    t0 = time.time()
    U1, U2 = (umbra_render(xml, a.umbra_spp // 2, s, os.path.join(a.out, f"umbra_seed{s}.npy"))
              for s in (1, 2))
    u_seconds = time.time() - t0
    np.save(os.path.join(a.out, "umbra_target.npy"), ((U1.astype(np.float64) + U2) / 2).astype(np.float32))
    chk = compare(H1, H2, U1, U2)
    print("umbra render / mitransient: total {ratio:.4f} +- {ratio_se:.4f}, per scan point "
          "{point_min:.3f}..{point_max:.3f}, zero only in mitransient at {only_umbra} points; "
          "relative L2 {l2:.4f} (noise alone {l2_noise:.4f})".format(**chk), flush=True)
    cols = []
    targets = [("mitransient", a.spp, mt_seconds, n, "target.npy", "fit")]
    if not a.no_umbra_fit:
        targets.append(("Umbra path", a.umbra_spp, u_seconds, noise(U1, U2), "umbra_target.npy",
                        "fit_umbra_target"))
    for name, spp, seconds, z, target, out in targets:
        s = run_fit(xml, os.path.join(a.out, target), os.path.join(a.out, out), a.iters, a.config)
        print(f"fit of the {name} target:\n{s['stdout']}", end="", flush=True)
        cols.append((name, spp, seconds, z, s))
    md = table(a, chk, cols)
    print(md, end="")
    if a.docs:
        os.makedirs(a.docs, exist_ok=True)
        with open(os.path.join(a.docs, "mitransient.md"), "w") as f:
            f.write(md)
        shutil.copyfile(os.path.join(a.out, "fit", "transients.png"),
                        os.path.join(a.docs, "mitransient_transients.png"))


if __name__ == "__main__":
    main()
