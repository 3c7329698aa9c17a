"""Would leaving faces of low signal out of the fitted surface help its seen Chamfer?
An offline check on a finished ground-truth study (baselines.py --out DIR), no refit.

    .venv/bin/python python/studies/low_signal_faces.py TAUS [--out out/bl-s17]
        [--gt out/gt-full]

Per case: each face of the fit's mesh.obj gets its three-bounce signal per unit area
(albedo x the legs' cos_x cos_wall / r^2 products summed over the 32 x 32 scan; confocal:
the leg squared; single: the laser leg at the wall centre times the sensor legs; no
occlusion), and the faces below TAU x the median are left out; the rest is scored by
`umbra recon --mesh --truth` as the study scores the fit. notes/low-signal-faces.md has the
results.
"""
import sys, os, glob, json
import numpy as np
sys.path.insert(0, "python/studies")
import baselines as bl

def obj(p):
    V, A, F = [], [], []
    for l in open(p):
        t = l.split()
        if not t: continue
        if t[0] == 'v':
            V.append([float(x) for x in t[1:4]]); A.append(float(t[4]) if len(t) > 4 else 1.0)
        if t[0] == 'f': F.append([int(x.split('/')[0]) - 1 for x in t[1:4]])
    return np.array(V), np.array(A), np.array(F)

def signal_per_area(V, A, F, confocal):
    u = (np.arange(32) + 0.5) / 32 * 1.6 - 0.8
    X, Y = np.meshgrid(u, u)
    S = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    x = (a + b + c) / 3
    n = np.cross(b - a, c - a); n /= np.linalg.norm(n, axis=1, keepdims=True)
    rho = A[F].mean(1)
    L = S if confocal else np.zeros((1, 3))
    def leg(P):  # (faces, points): cos_x * cos_wall / r^2, 0 where not facing
        d = P[None, :, :] - x[:, None, :]
        r2 = (d ** 2).sum(-1); r = np.sqrt(r2)
        cx = (d * n[:, None, :]).sum(-1) / r
        cw = (x[:, None, 2] - P[None, :, 2]) / r  # the wall's normal is +z
        return np.where((cx > 0) & (cw > 0), cx * cw / r2, 0.0)
    if confocal:
        g = leg(S); s = (rho[:, None] * g * g).sum(1)
    else:
        s = rho * leg(L)[:, 0] * leg(S).sum(1)
    return s

def samples_on(V, F, n, seed=0):
    """n points uniformly over the faces F of V (by area)."""
    rng = np.random.default_rng(seed)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    ar = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    k = rng.choice(len(F), n, p=ar / ar.sum())
    u, v = rng.random(n), rng.random(n)
    m = u + v > 1
    u[m], v[m] = 1 - u[m], 1 - v[m]
    return a[k] + u[:, None] * (b[k] - a[k]) + v[:, None] * (c[k] - a[k])


def write(p, V, A, F):
    with open(p, "w") as f:
        for v, al in zip(V, A): f.write(f"v {v[0]} {v[1]} {v[2]} {al} {al} {al}\n")
        for t in F: f.write(f"f {t[0]+1} {t[1]+1} {t[2]+1}\n")

def main():
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("taus")
    ap.add_argument("--out", default="out/bl-s17")
    ap.add_argument("--gt", default="out/gt-full")
    args = ap.parse_args()
    taus = [float(t) for t in args.taus.split(",")]
    for case_dir in sorted(glob.glob(os.path.join(args.out, "*-*-*"))):
        case = os.path.basename(case_dir)
        name, capture, noise = case.split("-")
        fitd = os.path.join(case_dir, "umbra_fit")
        mesh = os.path.join(fitd, "fit", "mesh.obj")
        if not os.path.exists(mesh): continue
        xml = os.path.join(args.gt, f"{name}-{capture}", "scene.xml")
        V, A, F = obj(mesh)
        s = signal_per_area(V, A, F, capture == "confocal")
        med = np.median(s[s > 0])
        r = json.load(open(os.path.join(case_dir, "results.json")))
        base = r["umbra fit"]["score"]["seen_chamfer_mm"]
        out = [f"{case:28s} {base:6.1f}"]
        for tau in taus:
            keep = s >= tau * med
            d = os.path.join(case_dir, "low_signal", f"tau-{tau}")
            os.makedirs(d, exist_ok=True)
            write(os.path.join(d, "m.obj"), V, A, F[keep])
            try:
                sc = bl.umbra_recon(xml, d, 32, ["--mesh", os.path.join(d, "m.obj")])["score"]
                out.append(f"t{tau}: {sc['seen_chamfer_mm']:6.1f} ({100*(1-keep.mean()):.0f}% cut, compl {sc['completeness']:.2f})")
            except RuntimeError as e:
                out.append(f"t{tau}: failed ({str(e).splitlines()[0]})")
        print(" | ".join(out), flush=True)


if __name__ == "__main__":
    main()
