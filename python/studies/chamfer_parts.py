"""Chamfer distances per part of a hidden scene (issue 18's boundary-term study).

`umbra fit` merges the scene's hidden objects into one mesh and reports the Chamfer
distance of that whole mesh to the whole truth (`fit::metrics`). In a scene where one
object shadows another, what the shadows change is the shadowed object; this module
splits a fitted mesh into its connected components (the fit keeps the objects'
components apart: positions move, faces are not merged) and measures each part against
its own true part, by the definition of `fit::metrics::chamfer_seen`:

- points: `n` area-stratified samples per surface (R2 sequence of barycentrics, as
  `sample_surface`);
- seen: a sample counts if it faces (fitted surfaces two-sided; the truth two-sided when
  its scene says so) and is unoccluded from at least one of the nine viewpoints on the
  scan rectangle (corners, edge midpoints, centre), occluders being the whole mesh it
  belongs to (the fitted mesh for fitted samples, the whole truth for true samples);
- distances: exact point-to-triangle distances to the other part, whole.

numpy only; deterministic.
"""
import numpy as np

G1, G2 = 0.7548776662466928, 0.5698402909980533


def read_obj(path):
    v, f = [], []
    with open(path) as fh:
        for line in fh:
            s = line.split()
            if not s:
                continue
            if s[0] == "v":
                v.append([float(x) for x in s[1:4]])
            elif s[0] == "f":
                idx = [int(t.split("/")[0]) - 1 for t in s[1:]]
                for k in range(1, len(idx) - 1):
                    f.append([idx[0], idx[k], idx[k + 1]])
    return np.array(v, float), np.array(f, np.int64).reshape(-1, 3)


def components(faces, n_vertices):
    """Connected components of the faces (shared vertices); a label per face."""
    parent = np.arange(n_vertices)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b, c in faces:
        ra, rb, rc = find(a), find(b), find(c)
        parent[rb] = ra
        parent[find(rc)] = ra
    roots = np.array([find(a) for a, _, _ in faces])
    _, label = np.unique(roots, return_inverse=True)
    return label


def sample_faces(v, f, n):
    """`n` area-stratified points and their faces (fit::metrics::sample_faces)."""
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    areas = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    total = areas.sum()
    pts, fid = [], []
    carry, k = 0.0, 0
    for i, a in enumerate(areas):
        carry += a / total * n
        count = int(np.floor(carry))
        carry -= count
        for _ in range(count):
            k += 1
            u, w = (0.5 + G1 * k) % 1.0, (0.5 + G2 * k) % 1.0
            if u + w > 1.0:
                u, w = 1.0 - u, 1.0 - w
            pts.append(p0[i] + u * (p1[i] - p0[i]) + w * (p2[i] - p0[i]))
            fid.append(i)
    return np.array(pts), np.array(fid, np.int64)


def occluded(p, q, v, f, eps=1e-6):
    """Whether the segment p[i] -> q (one point) hits any triangle strictly inside."""
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    out = np.zeros(len(p), bool)
    for s in range(0, len(p), 256):
        o = p[s:s + 256][:, None, :]              # (P, 1, 3)
        d = q[None, None, :] - o                  # (P, 1, 3), t in (0, 1)
        h = np.cross(d, e2[None])                 # (P, F, 3)
        a = np.einsum("pfk,fk->pf", h, e1)
        ok = np.abs(a) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
        sv = o - p0[None]
        u = inv * np.einsum("pfk,pfk->pf", sv, h)
        qv = np.cross(sv, e1[None])
        w = inv * np.einsum("pk,pfk->pf", d[:, 0], qv)
        t = inv * np.einsum("fk,pfk->pf", e2, qv)
        length = np.linalg.norm(d[:, 0], axis=1)[:, None]
        hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t * length > eps) & (t < 1 - 1e-9)
        out[s:s + 256] = hit.any(axis=1)
    return out


def viewpoints(center, size):
    cx, cy, cz = center
    return [np.array([cx + 0.5 * i * size[0], cy + 0.5 * j * size[1], cz])
            for j in (-1, 0, 1) for i in (-1, 0, 1)]


def seen_mask(points, fid, v, f, scene_v, scene_f, views, two_sided):
    n = np.cross(v[f[fid, 1]] - v[f[fid, 0]], v[f[fid, 2]] - v[f[fid, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    seen = np.zeros(len(points), bool)
    for x in views:
        facing = np.einsum("pk,pk->p", n, x[None] - points)
        cand = ~seen & ((facing > 0) | (two_sided & (facing < 0)))
        if cand.any():
            idx = np.nonzero(cand)[0]
            seen[idx] = ~occluded(points[idx], x, scene_v, scene_f)
    return seen


def point_triangle_distance(p, v, f):
    """Distance from each point to the nearest triangle (Ericson's closest point)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    out = np.empty(len(p))
    for s in range(0, len(p), 128):
        P = p[s:s + 128][:, None, :]
        ab, ac, ap = (b - a)[None], (c - a)[None], P - a[None]
        d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
        bp = P - b[None]
        d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
        cp = P - c[None]
        d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
        va = d3 * d6 - d5 * d4
        vb = d5 * d2 - d1 * d6
        vc = d1 * d4 - d3 * d2
        denom = va + vb + vc
        safe = lambda x: np.where(np.abs(x) > 1e-300, x, 1e-300)  # noqa: E731
        # Interior.
        vv = vb / safe(denom)
        ww = vc / safe(denom)
        q = a[None] + ab * vv[..., None] + ac * ww[..., None]
        # Edge AB.
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / safe(d1 - d3)
        q = np.where(m[..., None], a[None] + ab * t[..., None], q)
        # Edge AC.
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / safe(d2 - d6)
        q = np.where(m[..., None], a[None] + ac * t[..., None], q)
        # Edge BC.
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = (d4 - d3) / safe((d4 - d3) + (d5 - d6))
        q = np.where(m[..., None], b[None] + (c - b)[None] * t[..., None], q)
        # Vertices.
        q = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a[None], q)
        q = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b[None], q)
        q = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c[None], q)
        out[s:s + 128] = np.linalg.norm(P - q, axis=-1).min(axis=1)
    return out


def part(v, f, label, k):
    sub = f[label == k]
    used, inv = np.unique(sub, return_inverse=True)
    return v[used], inv.reshape(-1, 3)


def chamfer_seen(fit, truth, fit_scene, truth_scene, views, truth_two_sided, n=4000):
    """Chamfer (m) between the parts `fit` and `truth` ((v, f) each), seen-only and
    whole; `fit_scene` / `truth_scene` are the whole meshes that occlude them. Returns a
    dict with `seen`, `seen_fit_to_truth`, `seen_truth_to_fit`, `whole`, the seen shares,
    and `shadowed_truth_to_fit`: truth -> fit over the true points occluded from at
    least one of the viewpoints (those the shadows cover)."""
    fp, ff = sample_faces(*fit, n)
    tp, tf = sample_faces(*truth, n)
    fseen = seen_mask(fp, ff, *fit, *fit_scene, views, True)
    tseen = seen_mask(tp, tf, *truth, *truth_scene, views, truth_two_sided)
    df = point_triangle_distance(fp, *truth)
    dt = point_triangle_distance(tp, *fit)
    # Points in some viewpoint's shadow (facing it, but occluded).
    tn = np.cross(truth[0][truth[1][tf, 1]] - truth[0][truth[1][tf, 0]],
                  truth[0][truth[1][tf, 2]] - truth[0][truth[1][tf, 0]])
    shadowed = np.zeros(len(tp), bool)
    for x in views:
        facing = np.einsum("pk,pk->p", tn, x[None] - tp)
        cand = (facing > 0) | (truth_two_sided & (facing < 0))
        idx = np.nonzero(cand & ~shadowed)[0]
        if len(idx):
            shadowed[idx] = occluded(tp[idx], x, *truth_scene)
    return {
        "seen": 0.5 * (df[fseen].mean() + dt[tseen].mean()),
        "seen_fit_to_truth": df[fseen].mean(),
        "seen_truth_to_fit": dt[tseen].mean(),
        "whole": 0.5 * (df.mean() + dt.mean()),
        "fit_seen_share": fseen.mean(),
        "truth_seen_share": tseen.mean(),
        "shadowed_share": shadowed.mean(),
        "shadowed_truth_to_fit": dt[shadowed].mean() if shadowed.any() else float("nan"),
    }


def read_obj_values(path):
    """Vertex values (grey vertex colours, the fitted albedo) of an OBJ, or None."""
    vals = []
    with open(path) as fh:
        for line in fh:
            s = line.split()
            if s and s[0] == "v":
                if len(s) < 7:
                    return None
                vals.append(float(s[4]))
    return np.array(vals)


def split_parts(v, f, values=None, dark=0.25):
    """The connected components of (v, f), farthest from the wall (largest mean z)
    first, each as (v, f); with `values`, each also without the faces whose mean value
    is below `dark` times the largest (as `mesh.obj` is `mesh_all.obj` without them,
    `optim::Mesh::without_dark_faces`). Returns (parts, parts_without_dark)."""
    label = components(f, len(v))
    zs = [v[np.unique(f[label == k])][:, 2].mean() for k in range(label.max() + 1)]
    order = np.argsort(zs)[::-1]
    parts = [part(v, f, label, k) for k in order]
    if values is None:
        return parts, parts
    keep = values[f].mean(axis=1) >= dark * values.max()
    lit = []
    for k in order:
        sel = (label == k) & keep
        if not sel.any():
            lit.append(None)
            continue
        sub = f[sel]
        used, inv = np.unique(sub, return_inverse=True)
        lit.append((v[used], inv.reshape(-1, 3)))
    return parts, lit
