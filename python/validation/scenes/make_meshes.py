#!/usr/bin/env python3
"""Writes the hidden meshes of the cross-validation scenes (run from anywhere):

- T.obj: a planar letter "T", 30 cm x 30 cm, two quads (4 triangles), in the local plane
  z = 0, front face (winding normal) towards -z, i.e. towards the relay wall once placed at
  z > 0 by the scene's to_world.
- arc.obj: a non-planar "bent sheet": a 120-degree arc of a cylinder of radius 25 cm (axis
  along y through the local origin), 30 cm tall, 6 x 2 quads (24 triangles), concave side
  (front faces) towards -z. Its facets see each other (interreflections) but a ray from the
  wall crosses at most one front face, so mitransient's hidden-geometry sampling is unbiased
  on it (see notes/mitransient.md).

Front faces: normal = (v1 - v0) x (v2 - v0) for a face "f v0 v1 v2". Mitsuba's diffuse
BSDF is one-sided, so back faces are black (but still occlude).
"""
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def write_obj(path, V, F, comment):
    with open(path, "w") as f:
        f.write(f"# {comment}\n")
        for v in V:
            f.write(f"v {v[0]:.6f} {v[1]:.6f} {v[2]:.6f}\n")
        for t in F:
            f.write(f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")


def orient(V, F, want):
    """Reorder each triangle so that its winding normal has a positive dot with want(centroid)."""
    out = []
    for a, b, c in F:
        n = np.cross(V[b] - V[a], V[c] - V[a])
        if n @ want((V[a] + V[b] + V[c]) / 3) < 0:
            b, c = c, b
        out.append((a, b, c))
    return out


def quad(i0, i1, i2, i3):
    return [(i0, i1, i2), (i0, i2, i3)]


def letter_t():
    V, F = [], []
    for x0, x1, y0, y1 in [(-0.15, 0.15, 0.07, 0.15), (-0.04, 0.04, -0.15, 0.07)]:
        k = len(V)
        V += [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)]
        F += quad(k, k + 1, k + 2, k + 3)
    V = np.array(V, float)
    return V, orient(V, F, lambda c: np.array([0, 0, -1.0]))


def arc(R=0.25, span_deg=120, nseg=6, height=0.3, nrows=2):
    phis = np.radians(np.linspace(-span_deg / 2, span_deg / 2, nseg + 1))
    ys = np.linspace(-height / 2, height / 2, nrows + 1)
    V = np.array([(R * np.sin(p), y, R * np.cos(p)) for y in ys for p in phis])
    F = []
    for r in range(nrows):
        for s in range(nseg):
            i = r * (nseg + 1) + s
            F += quad(i, i + 1, i + nseg + 2, i + nseg + 1)
    # front faces towards the cylinder axis (concave side, towards -z)
    return V, orient(V, F, lambda c: -np.array([c[0], 0.0, c[2]]))


if __name__ == "__main__":
    V, F = letter_t()
    write_obj(os.path.join(HERE, "T.obj"), V, F,
              "letter T, 30 cm, plane z=0, front faces -z (written by make_meshes.py)")
    V, F = arc()
    write_obj(os.path.join(HERE, "arc.obj"), V, F,
              "120-degree cylinder arc, R=0.25 m, 0.3 m tall, concave/front side -z (make_meshes.py)")
    print("wrote T.obj, arc.obj")
