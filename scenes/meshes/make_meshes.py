"""Writes the procedural meshes of the recovery studies (deterministic; numpy only).

    python scenes/meshes/make_meshes.py

- sphere.obj: an icosphere (level 3, 1280 triangles) of radius 0.15 m at the origin.
- bunny_like.obj: a bunny-like blob, 5120 triangles, about 0.45 m long and 0.4 m tall:
  an ellipsoid body, a head, two ears, smoothly joined (a smooth minimum of ellipsoid
  distance estimates), meshed by projecting a level-4 icosphere onto the surface along
  rays from an interior point (the outermost crossing). It has what the studies need
  from the Stanford bunny: concave folds (neck, between the ears), thin parts (ears)
  and self-occlusion, with no external download. Faces point outwards; origin near the
  body's centre, +y up, the head towards +x.
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                "python", "validation"))
from icosphere import icosphere  # noqa: E402


def ellipsoid(p, centre, radii, angle_z=0.0):
    """Distance estimate to an ellipsoid rotated by angle_z (radians) about z."""
    q = p - centre
    c, s = np.cos(-angle_z), np.sin(-angle_z)
    q = np.stack([c * q[..., 0] - s * q[..., 1], s * q[..., 0] + c * q[..., 1], q[..., 2]], -1)
    return (np.linalg.norm(q / radii, axis=-1) - 1.0) * min(radii)


def smin(a, b, k=0.03):
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0, 1)
    return b * (1 - h) + a * h - k * h * (1 - h)


def bunny_sdf(p):
    d = ellipsoid(p, np.array([0.0, 0.0, 0.0]), np.array([0.17, 0.13, 0.13]))
    d = smin(d, ellipsoid(p, np.array([0.15, 0.10, 0.0]), np.array([0.085, 0.075, 0.075])))
    for z in (-0.05, 0.05):
        d = smin(d, ellipsoid(p, np.array([0.12, 0.24, z]), np.array([0.035, 0.1, 0.025]), 0.2), 0.02)
    d = smin(d, ellipsoid(p, np.array([-0.17, 0.02, 0.0]), np.array([0.04, 0.04, 0.04])), 0.02)
    return d


def project(dirs, centre, sdf, r_max=0.5):
    """Outermost crossing of sdf = 0 along centre + r * dir."""
    out = np.empty(len(dirs))
    rs = np.linspace(r_max, 0.0, 2001)
    for i, d in enumerate(dirs):
        vals = sdf(centre + rs[:, None] * d)
        k = np.argmax(vals < 0)  # first inside point from outside
        lo, hi = rs[k], rs[k - 1]  # lo inside, hi outside
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if sdf(centre + mid * d) < 0:
                lo = mid
            else:
                hi = mid
        out[i] = 0.5 * (lo + hi)
    return out


def write_obj(path, v, f, header):
    with open(path, "w") as fh:
        fh.write("".join(f"# {line}\n" for line in header))
        fh.writelines(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    v, f = icosphere(3)
    write_obj(os.path.join(here, "sphere.obj"), 0.15 * v, f,
              ["icosphere level 3, radius 0.15 m (scenes/meshes/make_meshes.py)"])
    v, f = icosphere(4)
    centre = np.array([0.07, 0.06, 0.0])
    r = project(v, centre, bunny_sdf)
    write_obj(os.path.join(here, "bunny_like.obj"), centre + r[:, None] * v, f,
              ["bunny-like blob: body, head, two ears (scenes/meshes/make_meshes.py)"])


if __name__ == "__main__":
    main()
