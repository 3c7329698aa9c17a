"""Writes the plate meshes of the boundary-term study (issue 18; deterministic; numpy only).

    python scenes/meshes/make_plates.py

- plate_bent.obj: the receiver, 0.6 m x 0.5 m (12 x 10 quads, 5 cm), folded along its
  vertical centre line so that each half turns 20 degrees towards the wall: the fold at
  z = 0, the side edges at z = -0.3 sin 20 = -0.103 m (an open book facing -z).
- plate_flat.obj: the same grid, flat (the fit's start).
- occluder.obj: a 0.2 m x 0.16 m plate, 4 x 4 quads.

All at the origin in the xy plane (+y up); front faces point to -z (towards a wall at
z < 0 once translated); the study scenes make them two-sided.
"""
import os

import numpy as np

from make_meshes import write_obj  # the same OBJ writer as the other study meshes


def grid(width, height, nx, ny, fold_deg=0.0):
    u = np.linspace(-width / 2, width / 2, nx + 1)
    v = np.linspace(-height / 2, height / 2, ny + 1)
    uu, vv = np.meshgrid(u, v)  # (ny+1, nx+1)
    a = np.radians(fold_deg)
    x = np.sign(uu) * np.abs(uu) * np.cos(a)
    z = -np.abs(uu) * np.sin(a)
    verts = np.stack([x, vv, z], -1).reshape(-1, 3)
    faces = []
    for j in range(ny):
        for i in range(nx):
            a0 = j * (nx + 1) + i
            b0, c0, d0 = a0 + 1, a0 + nx + 2, a0 + nx + 1
            # Winding (v1 - v0) x (v2 - v0) along -z: front faces towards the wall.
            faces += [(a0, d0, c0), (a0, c0, b0)]
    return verts, np.array(faces)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    src = "(scenes/meshes/make_plates.py)"
    v, f = grid(0.6, 0.5, 12, 10, fold_deg=20.0)
    write_obj(os.path.join(here, "plate_bent.obj"), v, f,
              [f"plate 0.6 x 0.5 m, 12 x 10 quads, folded 20 deg per side along x = 0 {src}"])
    v, f = grid(0.6, 0.5, 12, 10)
    write_obj(os.path.join(here, "plate_flat.obj"), v, f,
              [f"plate 0.6 x 0.5 m, 12 x 10 quads, flat {src}"])
    v, f = grid(0.2, 0.16, 4, 4)
    write_obj(os.path.join(here, "occluder.obj"), v, f,
              [f"occluder plate 0.2 x 0.16 m, 4 x 4 quads {src}"])


if __name__ == "__main__":
    main()
