#!/usr/bin/env python3
"""The cases of the Dr.Jit comparison (python/tests/test_vs_drjit.py): the test scenes
(written as Umbra TOML), the adjoint pattern, Umbra's side, the error metrics, the
diagnosis of the OPL-tie case, and the table of docs/GRADIENTS.md
(`.venv/bin/python python/validation/drjit_cases.py`). The estimators themselves are in
drjit_reference.py.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from drjit_reference import (  # noqa: F401  (re-exported for the test)
    Result, SCENES, mc3, setup, tri3,
)
from adjoint_pattern import adjoint_pattern  # noqa: F401  (the test uses R.adjoint_pattern)
from icosphere import icosphere

# --------------------------------------------------------------------------------------
# Scenes and comparison

# (OBJ, rotation axis and angle in degrees, translation): the letter and the bent sheet of
# T.xml and arc.xml (python/validation/scenes), placed as there, and an icosphere (written
# by `icosphere_obj`, convex: the back half is culled by the facing test, and in mc3 also
# occluded).
OBJECTS = {
    "T": ("T.obj", [0.0, 1.0, 0.0], 20.0, [0.05, -0.02, 0.95]),
    "arc": ("arc.obj", [1.0, 0.0, 0.0], 10.0, [-0.05, 0.03, 0.75]),
    "sphere": ("icosphere.obj", [0.3, 1.0, 0.2], 17.0, [0.03, -0.04, 1.0]),
}


def icosphere_obj(path: Path, radius: float = 0.12, subdivisions: int = 1) -> None:
    """An icosphere OBJ (outward winding normals, centred at the origin)."""
    V, F = icosphere(subdivisions)
    P = V * radius
    for a, b, c in F:
        assert np.cross(P[b] - P[a], P[c] - P[a]) @ (P[a] + P[b] + P[c]) > 0
    with open(path, "w") as f:
        f.write(f"# icosphere, radius {radius} m, {subdivisions} subdivision(s), outward normals\n")
        f.writelines(f"v {x:.7f} {y:.7f} {z:.7f}\n" for x, y, z in P)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)


def scene_toml(obj: str, capture: str, kernel: str, obj_path: Path, scan: int = 4,
               bins: int = 128, bin_width: float = 0.008, start_opl: float = 1.62,
               sigma: float = 0.012, subdivision: float | None = None) -> str:
    """An Umbra TOML scene: the laser and wall of T.xml / arc.xml (1 m x 1 m wall of albedo
    0.8 at z = 0, projector of irradiance 1 at (0.4, -0.3, 0.5) aimed at (0.1, 0.1, 0)), a
    `scan` x `scan` grid, `bins` bins, box or Gaussian kernel, the object at `obj_path`
    placed as OBJECTS says with albedo 0.7, and tri3 visibility `none`: nothing here
    occludes a (measurement, triangle) pair that faces both wall points (the letter is
    planar, the sheet's concave side sees the whole wall, the sphere is convex)."""
    _, axis, angle, tr = OBJECTS[obj]
    kern = f'kernel = "gaussian"\nsigma_opl = {sigma}' if kernel == "gaussian" else 'kernel = "box"'
    sub = f"subdivision = {subdivision}\n" if subdivision is not None else ""
    return f"""capture_type = "{capture}"

[wall]
size = [1.0, 1.0]
albedo = 0.8

[laser]
origin = [0.4, -0.3, 0.5]
target = [0.1, 0.1, 0.0]
irradiance = 1.0

[detector]
origin = [-0.5, 0.0, 0.3]

[scan]
resolution = [{scan}, {scan}]

[film]
temporal_bins = {bins}
bin_width_opl = {bin_width}
start_opl = {start_opl}
{kern}

[[objects]]
file = "{obj_path.as_posix()}"
albedo = 0.7
transform = {{ rotate = [{{ axis = {axis}, angle = {angle} }}], translate = {tr} }}

[render]
visibility = "none"
{sub}"""


def load(obj: str, capture: str, kernel: str, directory: str | None = None, **kw):
    """The case's scene, written as TOML into `directory` (a new temporary one if None)."""
    import umbra

    d = Path(directory or tempfile.mkdtemp(prefix="umbra_drjit_"))
    if obj == "sphere":
        obj_path = d / OBJECTS[obj][0]
        if not obj_path.exists():
            icosphere_obj(obj_path)
    else:
        obj_path = SCENES / OBJECTS[obj][0]
    p = d / f"{obj}_{capture}_{kernel}.toml"
    p.write_text(scene_toml(obj, capture, kernel, obj_path, **kw))
    return umbra.load_scene(str(p))


def umbra_side(scene, adjoint, model: str, spp: int, seed: int) -> Result:
    import umbra

    t0 = time.perf_counter()
    H = np.asarray(umbra.render(scene, spp=spp, model=model, seed=seed), dtype=np.float64)
    g = umbra.grad(scene, adjoint, spp=spp, model=model, seed=seed)
    verts = g["vertices"] if isinstance(g["vertices"], list) else [g["vertices"]]
    return Result(H=H, loss=float(np.sum(adjoint.astype(np.float64) * H)),
                  vertices=[np.asarray(v, dtype=np.float64) for v in verts],
                  albedo=np.asarray(g["albedo"], dtype=np.float64),
                  seconds=time.perf_counter() - t0)


def errors(ref: Result, got: Result) -> dict:
    """Relative errors of `got` against `ref`: transient (L2), vertex gradient (max abs
    difference over the largest |component|, and the worst component's own relative error
    among components above 1 % of the largest), albedo gradient (per object, max)."""
    dH = np.linalg.norm(got.H - ref.H) / np.linalg.norm(ref.H)
    gv_r = np.concatenate([v.ravel() for v in ref.vertices])
    gv_g = np.concatenate([v.ravel() for v in got.vertices])
    big = np.abs(gv_r).max()
    v_err = np.abs(gv_g - gv_r).max() / big
    sel = np.abs(gv_r) > 0.01 * big
    v_comp = (np.abs(gv_g - gv_r)[sel] / np.abs(gv_r[sel])).max()
    a_err = (np.abs(got.albedo - ref.albedo) / np.abs(ref.albedo)).max()
    return dict(transient=dH, vertex=v_err, vertex_component=v_comp, albedo=a_err,
                loss=abs(got.loss - ref.loss) / abs(ref.loss), grad_max=big)


# The cases of the test and of the docs table: (object, capture, model, kernel).
OBJECT_NAMES = ("T", "arc", "sphere")
MODELS = (("tri3", "box"), ("tri3", "gaussian"), ("mc3", "gaussian"))
CASES = [(o, c, m, k) for m, k in MODELS for o in OBJECT_NAMES for c in ("single", "confocal")]
SPP, SEED = 128, 7

# The case whose placement puts two corners of 32 sub-triangles at an exact OPL tie (the
# letter's vertical edges are mirror-symmetric about the scan row y = 0.125 in confocal
# capture), and the width below which Umbra's src/film/pulse.rs drops a pulse piece
# (`NARROW` = 1e-7 times min(σ, bin width)); see docs/GRADIENTS.md.
TIE_CASE = ("T", "confocal", "tri3", "gaussian")


def umbra_narrow(scene) -> float:
    import umbra

    cap = umbra.capture(scene)
    return 1e-7 * min(float(cap["sigma"]), float(cap["width"]))


def run_case(obj, capture, model, kernel, precision="float32", directory=None, spp=SPP,
             seed=SEED, scene=None, **scene_kw):
    """(Dr.Jit result, Umbra result, errors) for one case."""
    scene = scene or load(obj, capture, kernel, directory, **scene_kw)
    adj = adjoint_pattern(tuple(scene.shape))
    if model == "mc3":
        ref = mc3(scene, adj, spp, seed, precision)
    else:
        ref = tri3(scene, adj, precision=precision)
    got = umbra_side(scene, adj, model, spp, seed)
    return ref, got, errors(ref, got)


def tie_diagnosis(directory=None) -> dict:
    """TIE_CASE three ways, float64 reference against Umbra's gradient: `exact` (the
    reference as is), `emulated` (the reference with Umbra's dropped narrow pieces
    emulated), `shifted` (the exact reference, letter moved by 1 µm along y, which opens
    the tie to ~2e-8 m of OPL, above Umbra's drop width)."""
    import umbra

    obj, cap, model, kernel = TIE_CASE
    scene = load(obj, cap, kernel, directory)
    adj = adjoint_pattern(tuple(scene.shape))
    got = umbra_side(scene, adj, model, SPP, SEED)
    exact = tri3(scene, adj, precision="float64")
    emu = tri3(scene, adj, precision="float64", emulate_dropped_pieces=umbra_narrow(scene))
    moved = scene.copy()
    moved.set_vertices(np.asarray(scene.vertices(0), np.float64) + [0.0, 1e-6, 0.0])
    got_m = umbra_side(moved, adj, model, SPP, SEED)
    ref_m = tri3(moved, adj, precision="float64")
    return dict(exact=errors(exact, got), emulated=errors(emu, got), shifted=errors(ref_m, got_m))


def quadrature_check(obj="arc", capture="confocal", directory=None, precision="float64"):
    """Differences of the Gaussian tri3 reference between the default quadrature and one
    with twice the nodes per segment and twice the segments: the quadrature's own error."""
    scene = load(obj, capture, "gaussian", directory)
    adj = adjoint_pattern(tuple(scene.shape))
    a = tri3(scene, adj, precision=precision)
    b = tri3(scene, adj, precision=precision, nodes=12, segments_per_sigma=4.0)
    return errors(b, a)


def main(argv=None):
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    setup(args.threads)
    d = tempfile.mkdtemp(prefix="umbra_drjit_")
    t_start = time.perf_counter()
    print(f"Dr.Jit reference (float32 / float64) against Umbra; mc3 spp {SPP}, seed {SEED}; "
          "4x4 scan, 128 bins of 8 mm, sigma 12 mm")
    print("| case | model, kernel | transient rel. L2 | vertex gradient | albedo gradient | "
          "worst vertex component |")
    print("|---|---|---|---|---|---|")
    for obj, cap, model, kernel in CASES:
        e = [run_case(obj, cap, model, kernel, p, d)[2] for p in ("float32", "float64")]
        f = lambda key: f"{e[0][key]:.1e} / {e[1][key]:.1e}"
        print(f"| {obj}-{cap} | {model}, {kernel} | {f('transient')} | {f('vertex')} | "
              f"{f('albedo')} | {f('vertex_component')} |", flush=True)
    diag = tie_diagnosis(d)
    for k, e in diag.items():
        print(f"tie case {'-'.join(TIE_CASE)}, {k}: vertex {e['vertex']:.1e} "
              f"(worst component {e['vertex_component']:.1e}), albedo {e['albedo']:.1e}, "
              f"transient {e['transient']:.1e}")
    e = quadrature_check(directory=d)
    print(f"quadrature (arc-confocal, float64, 2x nodes and segments): transient {e['transient']:.1e}, "
          f"vertex {e['vertex']:.1e}, albedo {e['albedo']:.1e}")
    print(f"total {time.perf_counter() - t_start:.1f} s")


if __name__ == "__main__":
    sys.exit(main())
