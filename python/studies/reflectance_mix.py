"""Would a mix of Lambertian and retroreflective (cos^m) reflectance fit an LCT capture
better than either alone (issue 20)? An offline check on one fitted geometry, no refit:
the mesh rendered with each reflectance (`umbra.fit` with a zero-length step: the fit's
own capture geometry, detector response and masking), then the measurement fitted by two
scales and a per-bin background in closed form.

    .venv/bin/python python/studies/reflectance_mix.py CAPTURE MESH_ALL.OBJ M

CAPTURE names ../shared/data/lct/data_CAPTURE.mat; MESH_ALL.OBJ a fit's mesh (vertex
colours as albedo); M the retroreflective falloff exponent. Prints the relative L2 of each
reflectance alone and of the mix, with their scales.
"""
import os
import sys
import tempfile

import numpy as np

import umbra

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
cap, mesh_path, m = sys.argv[1], sys.argv[2], float(sys.argv[3])
mat = os.path.join(ROOT, "..", "shared", "data", "lct", f"data_{cap}.mat")
toml = open(os.path.join(ROOT, "scenes", "lct.toml")).read() + (
    f'\n[[objects]]\nfile = "{os.path.abspath(mesh_path)}"\nalbedo = 0.8\ntwo_sided = true\n')
tp = os.path.join(tempfile.mkdtemp(prefix="umbra-mix-"), f"{cap}.toml")
with open(tp, "w") as f:
    f.write(toml)
sc = umbra.load_scene(tp)
H = {}
for refl, fall in [("lambertian", None), ("retroreflective", m)]:
    kw = dict(reflectance=refl, init="scene", background="constant",
              schedule=[dict(iters=1, solver="adam", lr=1e-12, large_steps=0.0)])
    if fall is not None: kw["retro_falloff"] = fall
    out = umbra.fit(sc, mat, **kw)
    R = np.asarray(out["render"], float); M = np.asarray(out["measured"], float)
    mask = R != 0
    H[refl] = np.where(mask, (R - out["background"]) / out["scale"], 0.0)
    print(refl, "alone (constant bg) relL2", out["relative_l2"], "floor", out["photon_noise_floor"])
fit_bins = (M != 0).any(axis=(0, 1)) | (H["lambertian"] != 0).any(axis=(0, 1))
first = np.argmax(fit_bins)
Ms = M[..., first:].reshape(-1, M.shape[-1] - first)
cols = [H[k][..., first:].reshape(Ms.shape) for k in ("lambertian", "retroreflective")]
def solve(use):
    # per-bin background: centre over scan points per bin
    Mc = Ms - Ms.mean(0)
    A = np.stack([c - c.mean(0) for c, u in zip(cols, use) if u], -1).reshape(-1, sum(use))
    x, *_ = np.linalg.lstsq(A, Mc.ravel(), rcond=None)
    r = Mc.ravel() - A @ x
    return np.sqrt((r ** 2).sum() / (Ms ** 2).sum()), x
for use, name in [((1, 0), "lambertian"), ((0, 1), f"retro m{m}"), ((1, 1), "mix")]:
    e, x = solve(use)
    print(f"{cap} {name:12s} per-bin bg: relL2 {e:.4f} coefs {x}")
