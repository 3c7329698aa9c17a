"""(Superseded by `fit::determined`, which every fit on photon counts now runs, against the
Poisson variance rather than the residual used here; kept as the session-17 analysis
behind it.) How well the data determine each part of a fitted surface: the signal a cluster of faces
adds to the fitted transient against the noise in the bins it lands in (issue 20, the
confocal bunny; notes/low-signal-faces.md). An offline check on a finished ground-truth
study (baselines.py --out DIR), no refit.

    .venv/bin/python python/studies/face_snr.py CASE [CASE ...] [--out out/bl-s17]
        [--gt out/gt-full] [--clusters 60]

Per case: the fit's mesh.obj (vertex albedo in its `v` lines) is cut into CLUSTERS
clusters of faces (k-means on the face centroids); for each, the fitted transient without
it (`umbra.render`, tri3, the scene's visibility: occlusion by the rest included) gives
the cluster's own part h_c = H - H_without_c. With the fit's scale s and background b and
the residual r = sH + b - M:

  SNR_c = s^2 |h_c|^2 / sum_i (h_ci^2 / |h_c|^2) var_i,   var_i = r_i^2 (smoothed),

the cluster's signal energy against the noise energy along it (the residual as the noise:
Poisson counts and model error alike), and dL_c = (|r - s h_c|^2 - |r|^2) / |M|^2, what
leaving it out costs the loss. Printed with each cluster's distance to the truth.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import umbra  # noqa: E402
from baselines import read_toml  # noqa: E402
from low_signal_faces import obj, samples_on  # noqa: E402


def kmeans(x, k, iters=30, seed=0):
    rng = np.random.default_rng(seed)
    c = x[rng.choice(len(x), k, replace=False)]
    for _ in range(iters):
        lab = ((x[:, None, :] - c[None]) ** 2).sum(-1).argmin(1)
        c = np.array([x[lab == j].mean(0) if (lab == j).any() else c[j] for j in range(k)])
    return lab


def scene_with(xml_text, V, A, F, tmp, tag):
    path = os.path.join(tmp, f"{tag}.obj")
    with open(path, "w") as f:
        for v, a in zip(V, A):
            f.write(f"v {v[0]} {v[1]} {v[2]} {a} {a} {a}\n")
        for t in F:
            f.write(f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")
    x = re.sub(r'<string name="filename" value="[^"]*"/>', f'<string name="filename" value="{path}"/>',
               xml_text, count=1)
    x = re.sub(r'(<shape type="obj"[^>]*>.*?<transform name="to_world">\s*<matrix value=")[^"]*',
               r'\g<1>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1', x, count=1, flags=re.S)
    xp = os.path.join(tmp, f"{tag}.xml")
    with open(xp, "w") as f:
        f.write(x)
    return umbra.load_scene(xp)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--out", default="out/bl-s17")
    ap.add_argument("--gt", default="out/gt-full")
    ap.add_argument("--clusters", type=int, default=60)
    a = ap.parse_args()
    for case in a.cases:
        name, capture, noise = case.split("-")
        src = os.path.join(a.gt, f"{name}-{capture}")
        xml_text = open(os.path.join(src, "scene.xml")).read().replace(
            'value="bunny_like.obj"', f'value="{os.path.abspath(src)}/bunny_like.obj"')
        M = np.load(os.path.join(src, "target.npy" if noise == "clean" else "target_poisson.npy")).astype(np.float64)
        fitd = os.path.join(a.out, case, "umbra_fit", "fit")
        summ = read_toml(os.path.join(fitd, "summary.toml"))
        s, b = summ["scale"], summ["background"]
        V, A, F = obj(os.path.join(fitd, "mesh.obj"))
        TV, _, TF = obj(os.path.join(a.out, case, "truth.obj"))
        T = samples_on(TV, TF, 20000)
        cent = V[F].mean(1)
        lab = kmeans(cent, a.clusters)
        with tempfile.TemporaryDirectory() as tmp:
            full = scene_with(xml_text, V, A, F, tmp, "all")
            H = umbra.render(full, model="tri3").astype(np.float64)
            r = s * H + b - M
            print(f"{case}: relative L2 {np.linalg.norm(r) / np.linalg.norm(M):.4f} "
                  f"(the fit's {summ['relative_l2']:.4f})", flush=True)
            # the residual's energy per bin, smoothed over 9 bins, as the noise variance
            k = np.ones(9) / 9
            var = np.apply_along_axis(lambda v: np.convolve(v, k, mode="same"), -1, r ** 2)
            rows = []
            for c in range(a.clusters):
                keep = lab != c
                if keep.all():
                    continue
                Hc = umbra.render(scene_with(xml_text, V, A, F[keep], tmp, "rest"), model="tri3")
                h = H - Hc.astype(np.float64)
                e = (h ** 2).sum()
                if e <= 0:
                    rows.append((c, (~keep).sum(), 0.0, 0.0, np.nan))
                    continue
                snr = s * s * e / ((h ** 2 * var).sum() / e)
                dl = (((r - s * h) ** 2).sum() - (r ** 2).sum()) / (M ** 2).sum()
                P = samples_on(V, F[~keep], 300)
                dist = np.array([np.sqrt(((T - p) ** 2).sum(1)).min() for p in P]).mean()
                rows.append((c, (~keep).sum(), snr, dl, 1e3 * dist))
            rows.sort(key=lambda t: t[2])
            for c, n, snr, dl, d in rows:
                print(f"  cluster {c:3d}: {n:4d} faces  SNR {snr:10.2f}  dL {dl:+.2e}  "
                      f"to truth {d:6.1f} mm", flush=True)


if __name__ == "__main__":
    main()
