"""Fitting study of the visibility boundary terms (issue 18; docs/FITTING.md "Boundary terms").

Each case is fitted twice from the same start, with the boundary terms in the vertex
gradients (`--boundary-terms true`, the default) and without (`false`), back to back,
and the two runs are reported side by side: seen Chamfer distance to the truth, final
loss, fit time, and the per-gradient cost.

- `occluded`, `occluded_dark`: a bent plate 1 m from the wall, partly shadowed by a
  smaller plate 0.35 m in front of it (scenes/studies/occluded.toml; in
  occluded_dark.toml the occluder's albedo is 0.05 instead of 0.9). Target: Umbra's
  path tracer (multi-bounce) at --occluded-spp samples; start: the same plates displaced,
  the receiver flat (occluded_start.toml, `--init scene`); schedule
  occluded_schedule.toml; the model `tri3` with sub-triangle visibility (the scenes'
  `render.visibility`). The fit merges both plates into one mesh; its connected
  components are split again and each is measured against its own true plate
  (chamfer_parts.py): the receiver (the shadowed object) on its faces not fitted dark, as
  `mesh.obj` keeps them, the occluder on all its faces (the dark occluder is dark in
  truth, and `mesh.obj` drops it).
- `bunny:plane`, `bunny:sphere`: the bunny-like mesh of the recovery study
  (scenes/studies/bunny.toml, self-occluding; `tri3` with the default centroid
  visibility), its path-traced target at --target-spp, the default schedule, from a plane
  and from a sphere; Chamfer as `umbra fit` reports it (summary.toml).

    .venv/bin/python python/studies/fit_boundary.py [--cases occluded,bunny:plane,...]
        [--out out/studies/boundary] [--docs docs/studies] [--occluded-spp N]
        [--target-spp N] [--iters N] [--grad-reps N]

Writes docs/studies/boundary.md (the tables), boundary_loss.png (each case's two loss
curves) and boundary_occluded_side.png (the occluded fits seen from the side), next to the
fits' outputs under --out. Deterministic: fixed seeds (the scenes' `seed = 0`), `tri3`
noise-free, the same start for both runs. Needs a release build (`cargo build --release`)
and matplotlib.
"""
import argparse
import csv
import os
import resource
import shutil
import subprocess
import sys
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import chamfer_parts as cp  # noqa: E402

STUDIES = os.path.join(ROOT, "scenes", "studies")
DEFAULT_CASES = "occluded,occluded_dark,bunny:plane,bunny:sphere"
ZERO_SCHEDULE = 'checkpoint_every = 5\n[[stage]]\niters = 0\nsolver = "lbfgs"\nlr = 0.0\n'


def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(cmd, what):
    """Runs `cmd`; its output and the CPU time (user + system, s) it took."""
    c0 = cpu_seconds()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"{what}: {' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    proc.cpu = cpu_seconds() - c0
    return proc


def render_target(umbra, scene, out, spp):
    if not os.path.exists(out):
        run([umbra, "render", scene, "--model", "path", "--spp", str(spp), "-o", out, "-q",
             "--no-preview"], "target")
    return out


def fit(umbra, scene, target, out, extra):
    """One `umbra fit` of `target`; its summary, wall time and the load around it."""
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    cmd = [umbra, "fit", scene, "--measured", target, "--background", "none", "-o", out,
           "-q"] + extra
    load_before = os.getloadavg()[0]
    t0 = time.time()
    proc = run(cmd, "fit")
    wall = time.time() - t0
    with open(os.path.join(out, "summary.toml"), "rb") as f:
        s = tomllib.load(f)
    s["wall_seconds"] = wall
    s["cpu_seconds"] = proc.cpu
    s["load"] = (load_before, os.getloadavg()[0])
    s["cmd"] = " ".join(os.path.relpath(c, ROOT) if os.path.isabs(c) else c for c in cmd)
    return s


def read_loss(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return (np.array([int(r["iteration"]) for r in rows]),
            np.array([int(r["stage"]) for r in rows]),
            np.array([float(r["data_loss"]) for r in rows]))


def scene_with_mesh(scene, obj, path):
    """`scene`'s text with its [[objects]] replaced by the one mesh `obj` (world space,
    two-sided, as the fit renders it): for timing gradients on a fitted mesh."""
    with open(scene) as f:
        text = f.read()
    head = text.split("[[objects]]")[0]
    render = text[text.index("[render]"):]
    body = (f'{head}[[objects]]\nfile = "{os.path.abspath(obj)}"\nalbedo = 0.9\n'
            f"two_sided = true\n\n{render}")
    with open(path, "w") as f:
        f.write(body)
    return path


def grad_cost(umbra, scene, target, reps, out):
    """One `tri3` gradient (forward render and adjoint: one fit evaluation) of `scene`
    with and without the boundary terms, interleaved `reps` times: the median CPU time
    (user + system, s; less sensitive than wall time to other jobs on the machine) of
    each, and the relative difference of the two vertex gradients."""
    cpu = {True: [], False: []}
    grads = {}
    for _ in range(reps):
        for b in (True, False):
            npz = os.path.join(out, f"grad-{str(b).lower()}.npz")
            p = run([umbra, "grad", scene, "--target", target, "--model", "tri3",
                     "--boundary-terms", str(b).lower(), "-o", npz], "grad")
            cpu[b].append(p.cpu)
            with np.load(npz) as z:
                grads[b] = np.concatenate([z[k].ravel() for k in sorted(z.files)
                                           if k.startswith("vertices")])
    diff = np.linalg.norm(grads[True] - grads[False]) / np.linalg.norm(grads[False])
    return {True: float(np.median(cpu[True])), False: float(np.median(cpu[False])),
            "relative_difference": float(diff)}


def tri3_floor(umbra, scene, target, out):
    """The loss of the true objects under the fitted model (`tri3`, the scene's
    visibility, true albedos), scale fitted: what the target's noise and its
    multi-bounce light leave."""
    run([umbra, "render", scene, "--model", "tri3", "-o", out, "-q", "--no-preview"], "floor")
    h, m = np.load(out).astype(np.float64), np.load(target).astype(np.float64)
    s = max((h * m).sum() / (h * h).sum(), 0.0)
    return float(((s * h - m) ** 2).sum() / (m * m).sum())


def occluded_metrics(fit_dir, truth, views):
    """Per-part Chamfer (mm) of a fit of an occluded scene (module doc)."""
    path = os.path.join(fit_dir, "mesh_all.obj")
    v, f = cp.read_obj(path)
    vals = cp.read_obj_values(path)
    parts, lit = cp.split_parts(v, f, vals)
    tv, tf = truth
    tparts, _ = cp.split_parts(tv, tf)
    if len(parts) != 2 or len(tparts) != 2:
        sys.exit(f"{fit_dir}: expected 2 connected components, found {len(parts)}")
    receiver = lit[0] if lit[0] is not None else parts[0]
    r = cp.chamfer_seen(receiver, tparts[0], (v, f), truth, views, True)
    o = cp.chamfer_seen(parts[1], tparts[1], (v, f), truth, views, True)
    centre = parts[1][0].mean(axis=0)
    return {"receiver": r, "occluder": o, "occluder_centre": centre,
            "receiver_faces": len(receiver[1])}


def run_occluded(args, name):
    out = os.path.join(args.out, name)
    os.makedirs(out, exist_ok=True)
    truth_scene = os.path.join(STUDIES, name + ".toml")
    start_scene = os.path.join(STUDIES, "occluded_start.toml")
    schedule = os.path.join(STUDIES, "occluded_schedule.toml")
    zero = os.path.join(out, "zero.toml")
    with open(zero, "w") as f:
        f.write(ZERO_SCHEDULE)
    t0 = time.time()
    target = render_target(args.umbra, truth_scene, os.path.join(out, "target.npy"),
                           args.occluded_spp)
    target_seconds = time.time() - t0
    floor = tri3_floor(args.umbra, truth_scene, target, os.path.join(out, "truth_tri3.npy"))
    # The truth and the start as the fit sees them (world space, merged), evaluated.
    base = ["--init", "scene", "--config", zero]
    truth_fit = fit(args.umbra, truth_scene, target, os.path.join(out, "truth"), base)
    start_fit = fit(args.umbra, start_scene, target, os.path.join(out, "start"), base)
    truth = cp.read_obj(os.path.join(out, "truth", "mesh_all.obj"))
    with open(truth_scene, "rb") as f:
        sc = tomllib.load(f)["scan"]
    views = cp.viewpoints((0.0, 0.0, 0.0), sc["size"])
    runs = {}
    extra = ["--init", "scene", "--config", schedule]
    if args.iters:
        extra += ["--iters", str(args.iters)]
    for b in (True, False):
        d = os.path.join(out, f"boundary-{str(b).lower()}")
        print(f"   fit, boundary terms {b} ...", flush=True)
        s = fit(args.umbra, start_scene, target, d, extra + ["--boundary-terms", str(b).lower()])
        s["metrics"] = occluded_metrics(d, truth, views)
        s["dir"] = d
        runs[b] = s
    start_metrics = occluded_metrics(os.path.join(out, "start"), truth, views)
    grad_scene = scene_with_mesh(truth_scene, os.path.join(runs[True]["dir"], "mesh_all.obj"),
                                 os.path.join(out, "final_mesh.toml"))
    gs = grad_cost(args.umbra, grad_scene, target, args.grad_reps, out)
    gs_start = grad_cost(args.umbra, start_scene, target, 1, out)
    return {"kind": "occluded", "grad_start": gs_start, "name": name, "runs": runs, "floor": floor,
            "truth_loss_uniform_albedo": truth_fit["final_loss"], "start": start_fit,
            "start_metrics": start_metrics, "grad": gs, "target_seconds": target_seconds,
            "truth": truth}


def run_bunny(args, init):
    out = os.path.join(args.out, f"bunny-{init}")
    os.makedirs(out, exist_ok=True)
    scene = os.path.join(STUDIES, "bunny.toml")
    t0 = time.time()
    target = render_target(args.umbra, scene, os.path.join(args.out, "bunny_target.npy"),
                           args.target_spp)
    target_seconds = time.time() - t0
    runs = {}
    extra = ["--truth", "--init", init]
    if args.iters:
        extra += ["--iters", str(args.iters)]
    for b in (True, False):
        d = os.path.join(out, f"boundary-{str(b).lower()}")
        print(f"   fit, boundary terms {b} ...", flush=True)
        s = fit(args.umbra, scene, target, d, extra + ["--boundary-terms", str(b).lower()])
        s["dir"] = d
        runs[b] = s
    grad_scene = scene_with_mesh(scene, os.path.join(runs[True]["dir"], "mesh_all.obj"),
                                 os.path.join(out, "final_mesh.toml"))
    gs = grad_cost(args.umbra, grad_scene, target, args.grad_reps, out)
    return {"kind": "bunny", "name": f"bunny from {init}", "runs": runs, "grad": gs,
            "target_seconds": target_seconds}


def plot_losses(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = len(results)
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6.5 * cols, 3.8 * rows), squeeze=False)
    for ax, r in zip(axes.ravel(), results):
        for b, style in ((True, "-"), (False, "--")):
            it, stage, loss = read_loss(os.path.join(r["runs"][b]["dir"], "loss.csv"))
            ax.semilogy(it, loss, style, label=f"boundary terms {'on' if b else 'off'}")
        for k in np.nonzero(np.diff(stage))[0]:
            ax.axvline(it[k] + 0.5, color="grey", lw=0.6, alpha=0.6)
        if "floor" in r:
            ax.axhline(r["floor"], color="k", lw=0.8, ls=":",
                       label="true objects (tri3), full resolution")
        ax.set_title(r["name"])
        ax.set_xlabel("iteration (grey: stage boundaries)")
        ax.set_ylabel("data loss (stage resolution)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_side(results, path):
    """The occluded fits seen from above (x-z): truth, with and without boundary terms."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    occ = [r for r in results if r["kind"] == "occluded"]
    if not occ:
        return False
    fig, axes = plt.subplots(1, len(occ), figsize=(6.5 * len(occ), 4.2), squeeze=False)
    for ax, r in zip(axes.ravel(), occ):
        tv, tf = r["truth"]
        for (v, f), colour, label in [
                (r["truth"], "k", "truth"),
                (cp.read_obj(os.path.join(r["runs"][True]["dir"], "mesh_all.obj")), "C0",
                 "boundary terms on"),
                (cp.read_obj(os.path.join(r["runs"][False]["dir"], "mesh_all.obj")), "C1",
                 "boundary terms off"),
                (cp.read_obj(os.path.join(os.path.dirname(r["runs"][True]["dir"]), "start",
                                          "mesh_all.obj")), "0.6", "start")]:
            ax.plot(v[:, 0], v[:, 2], ".", ms=5 if colour == "k" else 2.5, color=colour,
                    label=label)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("z: distance from the wall (m)")
        ax.set_title(f"{r['name']}: every vertex, seen from above")
        ax.invert_yaxis()
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, markerscale=3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def table(results):
    mm = lambda x: f"{1e3 * x:.2f}"  # noqa: E731
    lines = []

    def timing(r, b):
        s = r["runs"][b]
        return (f"{s['seconds']:.0f} | {s['cpu_seconds']:.0f} | {r['grad'][b]:.2f} "
                f"| {s['load'][0]:.1f} / {s['load'][1]:.1f}")

    occ = [r for r in results if r["kind"] == "occluded"]
    if occ:
        lines += [
            "### Occluded plates (`tri3`, sub-triangle visibility; 16 x 16 scan)",
            "",
            "| case | boundary terms | **receiver: seen Chamfer (mm)** | receiver: fit -> truth / "
            "truth -> fit (mm) | receiver in the shadows: truth -> fit (mm) "
            "| occluder: seen Chamfer (mm) | final loss | relative L2 | fit time (s) "
            "| fit CPU (s) | gradient CPU (s) | load before / after |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in occ:
            m = r["start_metrics"]
            lines.append(
                f"| {r['name']} | (start) | {mm(m['receiver']['seen'])} "
                f"| {mm(m['receiver']['seen_fit_to_truth'])} / "
                f"{mm(m['receiver']['seen_truth_to_fit'])} "
                f"| {mm(m['receiver']['shadowed_truth_to_fit'])} "
                f"| {mm(m['occluder']['seen'])} | {r['start']['final_loss']:.4f} "
                f"| {r['start']['relative_l2']:.3f} | | | | |")
            for b in (True, False):
                s = r["runs"][b]
                m = s["metrics"]
                lines.append(
                    f"| {r['name']} | {'on' if b else 'off'} | **{mm(m['receiver']['seen'])}** "
                    f"| {mm(m['receiver']['seen_fit_to_truth'])} / "
                    f"{mm(m['receiver']['seen_truth_to_fit'])} "
                    f"| {mm(m['receiver']['shadowed_truth_to_fit'])} "
                    f"| {mm(m['occluder']['seen'])} | {s['final_loss']:.4f} "
                    f"| {s['relative_l2']:.3f} | {timing(r, b)} |")
        lines += [""]
        for r in occ:
            c = {b: r["runs"][b]["metrics"]["occluder_centre"] for b in (True, False)}
            m = r["runs"][True]["metrics"]["receiver"]
            lines.append(
                f"- {r['name']}: loss of the true plates under the fitted model "
                f"(`tri3`, true albedos) {r['floor']:.4f}; occluder's fitted centre "
                f"({', '.join(f'{x:.3f}' for x in c[True])}) m with the boundary terms, "
                f"({', '.join(f'{x:.3f}' for x in c[False])}) m without; receiver faces "
                f"kept (not fitted dark) {r['runs'][True]['metrics']['receiver_faces']} / "
                f"{r['runs'][False]['metrics']['receiver_faces']}; {100 * m['shadowed_share']:.0f} % "
                f"of the true receiver is in the shadow of one of the nine viewpoints; "
                f"the boundary terms change the vertex gradient by "
                f"{100 * r['grad_start']['relative_difference']:.1f} % at the start and "
                f"{100 * r['grad']['relative_difference']:.1f} % at the end (relative L2 "
                f"difference); gradient CPU ratio on / off "
                f"{r['grad'][True] / r['grad'][False]:.2f}, fit CPU ratio "
                f"{r['runs'][True]['cpu_seconds'] / r['runs'][False]['cpu_seconds']:.2f}.")
        lines += [""]
    bun = [r for r in results if r["kind"] == "bunny"]
    if bun:
        lines += [
            "### Bunny-like mesh (`tri3`, centroid visibility; 32 x 32 scan; default schedule)",
            "",
            "| case | boundary terms | **seen Chamfer (mm)** | fit -> truth / truth -> fit (mm) "
            "| whole-surface Chamfer (mm) | final loss | relative L2 | faces "
            "| fit time (s) | fit CPU (s) | gradient CPU (s) | load before / after |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in bun:
            for b in (True, False):
                s = r["runs"][b]
                c = s["chamfer"]
                lines.append(
                    f"| {r['name']} | {'on' if b else 'off'} | **{c['seen_mm']:.2f}** "
                    f"| {c['seen_fit_to_truth_mm']:.2f} / {c['seen_truth_to_fit_mm']:.2f} "
                    f"| {c['whole_mm']:.2f} | {s['final_loss']:.4f} | {s['relative_l2']:.3f} "
                    f"| {s['faces']} | {timing(r, b)} |")
        lines += [""]
        for r in bun:
            lines.append(
                f"- {r['name']}: the boundary terms change the vertex gradient at the final "
                f"mesh by {100 * r['grad']['relative_difference']:.1f} %; gradient CPU ratio "
                f"on / off {r['grad'][True] / r['grad'][False]:.2f}, fit CPU ratio "
                f"{r['runs'][True]['cpu_seconds'] / r['runs'][False]['cpu_seconds']:.2f}.")
        lines += [""]
    lines += ["Commands (each run twice, `--boundary-terms true` then `false`, back to back):",
              ""]
    for r in results:
        lines.append(f"- {r['name']}: `{r['runs'][True]['cmd']}`")
    lines += [""]
    lines.append(
        "*Fit time*: the fit's own (summary.toml `seconds`); *fit CPU*: user + system time of "
        "the whole `umbra fit` process; *gradient CPU*: median CPU time of one `tri3` gradient "
        "(render and adjoint, `umbra grad`, the cost of one fit evaluation) on the final mesh "
        "of the run with boundary terms, with and without them, interleaved. Every iteration "
        "count is the schedule's (110 for the plates, 190 for the bunny); an L-BFGS iteration "
        "may take several evaluations, which the fit does not report.")
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default=DEFAULT_CASES)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "studies", "boundary"))
    ap.add_argument("--docs", default=os.path.join(ROOT, "docs", "studies"))
    ap.add_argument("--iters", type=int, default=0)
    ap.add_argument("--occluded-spp", type=int, default=16384)
    ap.add_argument("--target-spp", type=int, default=4096)
    ap.add_argument("--grad-reps", type=int, default=3)
    ap.add_argument("--umbra", default=os.path.join(ROOT, "target", "release", "umbra"))
    args = ap.parse_args()
    os.makedirs(args.docs, exist_ok=True)
    os.makedirs(args.out, exist_ok=True)
    t_start = time.time()
    load_start = os.getloadavg()
    results = []
    for case in args.cases.split(","):
        print(f"== {case}", flush=True)
        if case.startswith("bunny:"):
            results.append(run_bunny(args, case.split(":")[1]))
        else:
            results.append(run_occluded(args, case))
    total = time.time() - t_start
    plot_losses(results, os.path.join(args.docs, "boundary_loss.png"))
    side = plot_side(results, os.path.join(args.docs, "boundary_occluded_side.png"))
    lines = ["<!-- generated by python/studies/fit_boundary.py; do not edit -->", ""]
    lines += table(results)
    lines += ["", f"Whole study: {total:.0f} s (load average {load_start[0]:.1f} at the start, "
              f"{os.getloadavg()[0]:.1f} at the end, 2 cores).", "",
              "![loss curves](boundary_loss.png)"]
    if side:
        lines += ["![occluded fits seen from above](boundary_occluded_side.png)"]
    with open(os.path.join(args.docs, "boundary.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
