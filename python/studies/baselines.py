"""Issue 20's ground-truth study: Umbra's mesh fit against the classical reconstructions an
NLOS researcher would otherwise run, on hidden scenes rendered by mitransient (not by Umbra)
with known meshes (gt_scenes.py), confocal and single capture, noise-free and with Poisson
noise. Writes docs/BASELINES.md's tables (docs/baselines/ground_truth.md) and pictures.

Methods, each on the same measurement and the same voxel grid (the scan's columns, depths
0.4-1.6 m in 2 mm steps):
  umbra bp / fbp / lct / pf   `umbra recon --method M` (LCT confocal only)
  y-tal bp / fbp / fk          y-tal 0.20.0 (ytal_recon.py in .venv-ytal; fk confocal only),
                               its volume made a surface and scored by `umbra recon --volume`
  umbra fit                    `umbra fit --init auto` (default schedule): a fit from a
                               plane and one from a reconstruction's depth map (the LCT's,
                               confocal; the falloff-weighted backprojection's, single), the
                               lower loss kept (the reconstruction's within 1 %). Its
                               mesh.obj scored by `umbra recon --mesh`, and each start's as
                               "umbra fit (NAME start)"
A volume becomes a surface the usual way: per-column argmax depth where the column's peak is
at least 0.3 of the volume's maximum, triangulated as a height field. Every surface gets the
same score (`umbra::fit::score`): seen Chamfer, depth error over the truth's columns (mean,
90th percentile), completeness (share of the truth's seen points within 10 mm), and time.

    .venv/bin/python python/studies/baselines.py [--gt out/gt] [--out out/baselines]
        [--scenes letter,...] [--captures confocal,single] [--noise clean,poisson]
        [--methods ...] [--docs docs] [--scan 32] [--spp N]

The ground-truth data are made by gt_scenes.py (--gt holds them; missing cases are rendered).
Needs target/release/umbra, .venv-ytal (y-tal) and, for the pictures, matplotlib
(python/requirements-bench.txt).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)

UMBRA = os.environ.get("UMBRA_BIN", os.path.join(ROOT, "target", "release", "umbra"))
YTAL_PYTHON = os.environ.get("UMBRA_YTAL_PYTHON", os.path.join(ROOT, ".venv-ytal", "bin", "python"))
YTAL_RECON = os.path.join(HERE, "ytal_recon.py")

UMBRA_METHODS = ("bp", "fbp", "lct", "pf")
YTAL_METHODS = ("bp", "fbp", "fk")
CONFOCAL_ONLY = {"umbra lct", "y-tal fk"}
STARTS = ("plane", "sphere", "lct", "backprojection")   # --init auto's starts, each scored
FITS = ("umbra fit",) + tuple(f"umbra fit ({s} start)" for s in STARTS)
ALL_METHODS = ([f"umbra {m}" for m in UMBRA_METHODS] + [f"y-tal {m}" for m in YTAL_METHODS]
               + ["umbra fit"])
DEPTHS = (0.4, 1.6)
DEPTH_STEP = 0.002
THRESHOLD = 0.3
NO_SURFACE = "no 2 x 2 block"   # umbra recon: too few columns above the threshold
REUSE = False   # --reuse: keep fits and y-tal volumes already in --out, score them again


def run(cmd, **kw):
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return p.stdout


def read_toml(path):
    with open(path, "rb") as f:
        return tomllib.load(f)


def grid_args(scan):
    nz = int(round((DEPTHS[1] - DEPTHS[0]) / DEPTH_STEP))
    return ["--grid", f"{scan},{scan},{nz}", "--depths", f"{DEPTHS[0]},{DEPTHS[1]}"], (scan, scan, nz)


def umbra_recon(xml, out, scan, extra, truth=True):
    """`umbra recon` with the study's grid; its summary.toml (seconds, score, grid)."""
    g, _ = grid_args(scan)
    run([UMBRA, "recon", xml, *g, "--threshold", THRESHOLD, *(["--truth"] if truth else []),
         "-o", out, *extra])
    return read_toml(os.path.join(out, "summary.toml"))


def ytal_volume(xml, measured, method, out, scan, capture_h5):
    """y-tal's volume of `method` on the study's grid (via ytal_recon.py), scored by
    `umbra recon --volume`; the summary with y-tal's own reconstruction time."""
    os.makedirs(out, exist_ok=True)
    if not os.path.exists(capture_h5):
        run([UMBRA, "convert", xml, "--measured", measured, "-o", capture_h5])
    _, (nx, ny, nz) = grid_args(scan)
    half = 0.8  # the scan covers the 1.6 m wall (gt_scenes.WALL_HALF)
    grid = {"min": [-half, -half, DEPTHS[0]], "max": [half, half, DEPTHS[1]], "dims": [nx, ny, nz]}
    gpath = os.path.join(out, "grid.json")
    with open(gpath, "w") as f:
        json.dump(grid, f)
    vol, timing = os.path.join(out, "ytal_volume.npy"), os.path.join(out, "ytal_timing.json")
    # y-tal's bp and fbp build every index array at once (about 27 GB here): in chunks.
    chunks = ["--downscale", "32"] if method in ("bp", "fbp") else []
    if not (REUSE and os.path.exists(vol) and os.path.exists(timing)):
        run([YTAL_PYTHON, YTAL_RECON, capture_h5, gpath, method, vol, "--json", timing, *chunks])
    s = umbra_recon(xml, out, scan, ["--volume", vol])
    with open(timing) as f:
        s["seconds"] = json.load(f)["seconds"]
    return s


def umbra_fit(xml, measured, out, scan):
    """`umbra fit --init auto` (default schedule); its mesh scored like the rest, and each
    start's mesh (confocal: start-plane/, start-lct/) too. {variant: summary}."""
    os.makedirs(out, exist_ok=True)
    fit_dir = os.path.join(out, "fit")
    if not (REUSE and os.path.exists(os.path.join(fit_dir, "summary.toml"))):
        shutil.rmtree(fit_dir, ignore_errors=True)
        run([UMBRA, "fit", xml, "--measured", measured, "--truth", "--init", "auto", "-q",
             "-o", fit_dir])
    fit = read_toml(os.path.join(fit_dir, "summary.toml"))
    s = umbra_recon(xml, out, scan, ["--mesh", os.path.join(fit_dir, "mesh.obj")])
    s.update(seconds=fit["seconds"], relative_l2=fit["relative_l2"], init=fit["init"],
             unsupported_faces=fit.get("unsupported_faces", 0), _dir=out)
    found = {"umbra fit": s}
    for st in fit.get("starts", []):
        d = os.path.join(out, f"start-{st['init']}")
        v = umbra_recon(xml, d, scan,
                        ["--mesh", os.path.join(fit_dir, f"start-{st['init']}", "mesh.obj")])
        v.update(seconds=st["seconds"], relative_l2=st["relative_l2"], _dir=d)
        found[f"umbra fit ({st['init']} start)"] = v
    return found


def truth_depth(xml, out, scan, name):
    """The truth's depth map on the study's columns (for the pictures)."""
    import gt_scenes as gt
    obj = os.path.join(out, "truth.obj")
    with open(obj, "w") as f:
        base = 1
        for _, v, faces in gt.truth_meshes(name):
            f.writelines(f"v {x} {y} {z}\n" for x, y, z in v)
            f.writelines(f"f {a + base} {b + base} {c + base}\n" for a, b, c in faces)
            base += len(v)
    umbra_recon(xml, os.path.join(out, "truth"), scan, ["--mesh", obj], truth=False)
    return np.load(os.path.join(out, "truth", "depth.npy"))


def run_case(gt_dir, out, name, capture, noise, methods, scan, log=print):
    """Every method on one (scene, capture, noise) case; {method: summary}."""
    src = os.path.join(gt_dir, f"{name}-{capture}")
    xml = os.path.join(src, "scene.xml")
    measured = os.path.join(src, "target.npy" if noise == "clean" else "target_poisson.npy")
    case_out = os.path.join(out, f"{name}-{capture}-{noise}")
    os.makedirs(case_out, exist_ok=True)
    h5 = os.path.join(case_out, "capture.hdf5")
    results = {}
    for m in methods:
        if m in CONFOCAL_ONLY and capture != "confocal":
            continue
        d = os.path.join(case_out, m.replace(" ", "_"))
        t0 = time.time()
        try:
            kind, method = m.split(" ")
            if m == "umbra fit":
                found = umbra_fit(xml, measured, d, scan)
                s = found.pop("umbra fit")
                results.update(found)
            elif kind == "umbra":
                s = umbra_recon(xml, d, scan, ["--measured", measured, "--method", method])
            else:
                s = ytal_volume(xml, measured, method, d, scan, h5)
        except RuntimeError as e:
            log(f"  {m}: FAILED: {str(e).splitlines()[0]}")
            results[m] = {"error": str(e)}
            continue
        sc = s.get("score", {})
        log(f"  {m}: seen Chamfer {sc.get('seen_chamfer_mm', float('nan')):.2f} mm, depth "
            f"{sc.get('depth_error_mean_mm', float('nan')):.2f} / "
            f"{sc.get('depth_error_p90_mm', float('nan')):.2f} mm, completeness "
            f"{100 * sc.get('completeness', float('nan')):.0f} %, {s['seconds']:.1f} s "
            f"({time.time() - t0:.0f} s wall)")
        s.setdefault("_dir", d)
        results[m] = s
    results["_truth_depth"] = truth_depth(xml, case_out, scan, name).tolist()
    with open(os.path.join(case_out, "results.json"), "w") as f:
        json.dump(results, f)
    return results


def picture(path, title, results, methods):
    """Depth maps seen from the wall (+x to the left), the truth first, one depth scale."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    truth = np.array(results["_truth_depth"], float)
    shown = [("truth", truth)]
    for m in methods:
        if m in results and "score" in results[m]:
            shown.append((m, np.load(os.path.join(results[m]["_dir"], "depth.npy"))))
    lo, hi = np.nanmin(truth) - 0.05, np.nanmax(truth) + 0.05
    fig, axes = plt.subplots(1, len(shown), figsize=(2.1 * len(shown), 2.6))
    for ax, (m, d) in zip(np.atleast_1d(axes), shown):
        im = ax.imshow(d[::-1, ::-1], vmin=lo, vmax=hi, cmap="viridis")
        label = m.replace(" (", "\n(")
        if m != "truth":
            label += f"\n{results[m]['score']['seen_chamfer_mm']:.1f} mm"
        ax.set_title(label, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(title, fontsize=9)
    fig.colorbar(im, ax=list(np.atleast_1d(axes)), shrink=0.7, label="depth (m)")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def table(all_results, methods):
    """Markdown: one row per case, per method its seen Chamfer (mm) and each fit's ratio to
    the best baseline; then the detail."""
    fits = [m for m in methods if m in FITS]
    lines = ["| case | " + " | ".join(methods) + " | " + " | ".join(f"{f} / best baseline" for f in fits) + " |",
             "|---|" + "---|" * (len(methods) + len(fits))]
    for case, res in all_results.items():
        cells, best = [], np.inf
        for m in methods:
            s = res.get(m)
            if s is None:
                cells.append("n/a")
            elif "error" in s:
                cells.append("no surface" if NO_SURFACE in s["error"] else "failed")
            else:
                c = s["score"]["seen_chamfer_mm"]
                cells.append(f"{c:.2f}")
                if m not in FITS:
                    best = min(best, c)
        for f in fits:
            c = res.get(f, {}).get("score", {}).get("seen_chamfer_mm")
            cells.append(f"{c / best:.2f}" if c is not None and np.isfinite(best) else "n/a")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    lines += ["", "| case | method | seen Chamfer (mm) | depth error mean / p90 (mm) | "
              "completeness | columns filled | time (s) |", "|---|---|---|---|---|---|---|"]
    for case, res in all_results.items():
        for m in methods:
            s = res.get(m)
            if not s or "error" in s:
                continue
            sc = s["score"]
            lines.append(f"| {case} | {m} | {sc['seen_chamfer_mm']:.2f} | "
                         f"{sc['depth_error_mean_mm']:.2f} / {sc['depth_error_p90_mm']:.2f} | "
                         f"{100 * sc['completeness']:.0f} % | {100 * sc['columns_filled']:.0f} % | "
                         f"{s['seconds']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    import gt_scenes as gt
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gt", default=os.path.join(ROOT, "out", "gt"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "baselines"))
    ap.add_argument("--scenes", default=",".join(gt.SCENES))
    ap.add_argument("--captures", default="confocal,single")
    ap.add_argument("--noise", default="clean,poisson")
    ap.add_argument("--methods", default=",".join(ALL_METHODS))
    ap.add_argument("--scan", type=int, default=gt.SCAN)
    ap.add_argument("--spp", type=int, default=gt.SPP)
    ap.add_argument("--docs", default=os.path.join(ROOT, "docs"))
    ap.add_argument("--reuse", action="store_true",
                    help="keep the fits and y-tal volumes already in --out and score them again")
    args = ap.parse_args(argv)
    global REUSE
    REUSE = args.reuse
    methods = args.methods.split(",")
    for name in args.scenes.split(","):
        for capture in args.captures.split(","):
            if not os.path.exists(os.path.join(args.gt, f"{name}-{capture}", "target_poisson.npy")):
                gt.run_case(args.gt, name, capture, scan=args.scan, spp=args.spp)
            for noise in args.noise.split(","):
                case = f"{name}-{capture}-{noise}"
                print(case, flush=True)
                run_case(args.gt, args.out, name, capture, noise, methods, args.scan)
    if not args.docs:
        return
    # The table and the pictures: every case with results in --out (this run's and
    # earlier runs'), in the study's order, so that cases run apart make one table.
    all_results = {}
    for name in gt.SCENES:
        for capture in ("confocal", "single"):
            for noise in ("clean", "poisson"):
                case = f"{name}-{capture}-{noise}"
                path = os.path.join(args.out, case, "results.json")
                if os.path.exists(path):
                    with open(path) as f:
                        all_results[case] = json.load(f)
    columns = [m for m in ALL_METHODS if m != "umbra fit"] + list(FITS)
    os.makedirs(os.path.join(args.docs, "baselines"), exist_ok=True)
    for case, res in all_results.items():
        picture(os.path.join(args.docs, "baselines", f"{case}.png"), case, res, columns)
    with open(os.path.join(args.docs, "baselines", "ground_truth.md"), "w") as f:
        f.write("<!-- generated by python/studies/baselines.py; do not edit -->\n")
        f.write(f"Seen Chamfer (mm) per method; scan {args.scan} x {args.scan}; grid: the scan's "
                f"columns, depths {DEPTHS[0]}-{DEPTHS[1]} m in {1e3 * DEPTH_STEP:.0f} mm; "
                f"threshold {THRESHOLD}.\n\n")
        f.write(table(all_results, columns))


if __name__ == "__main__":
    main()
