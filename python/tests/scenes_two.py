"""A small scene with two hidden objects (two tilted quads at different depths, each
subdivided into 8 triangles), confocal 6 x 6, Gaussian film kernel: smooth in the
vertices, for gradient checks of several objects."""
from __future__ import annotations

from pathlib import Path

import umbra


def _quad_obj(path: Path, cx: float, cy: float, z: float, half: float, tilt: float) -> None:
    # A 3 x 3 grid of vertices, tilted about x by `tilt` (z changes with y).
    lines = []
    for j in range(3):
        for i in range(3):
            x = cx + half * (i - 1)
            y = cy + half * (j - 1)
            lines.append(f"v {x} {y} {z + tilt * (j - 1)}")
    for j in range(2):
        for i in range(2):
            a = 1 + j * 3 + i
            lines.append(f"f {a} {a + 1} {a + 4}")
            lines.append(f"f {a} {a + 4} {a + 3}")
    path.write_text("\n".join(lines) + "\n")


def two_object_scene(tmp: Path, capture: str = "confocal", scan: int = 6) -> umbra.Scene:
    """The two quads; ``capture`` confocal, single or exhaustive on a ``scan x scan`` grid."""
    _quad_obj(tmp / "a.obj", -0.15, 0.05, 0.7, 0.08, 0.03)
    _quad_obj(tmp / "b.obj", 0.18, -0.1, 0.9, 0.1, -0.04)
    (tmp / "two.toml").write_text("""
capture_type = "CAPTURE"
[wall]
center = [0.0, 0.0, 0.0]
size = [1.2, 1.2]
albedo = 0.8
[laser]
origin = [0.0, -0.4, 1.2]
irradiance = 1.0
[detector]
origin = [0.0, -0.4, 1.2]
[scan]
resolution = [SCAN, SCAN]
size = [0.8, 0.8]
[film]
temporal_bins = 160
bin_width_opl = 0.01
start_opl = 1.0
kernel = "gaussian"
sigma_opl = 0.015
[[objects]]
file = "a.obj"
albedo = 0.7
two_sided = true
[[objects]]
file = "b.obj"
albedo = 0.5
two_sided = true
[render]
model = "tri3"
spp = 16
seed = 0
""".replace("CAPTURE", capture).replace("SCAN", str(scan)))
    return umbra.load_scene(str(tmp / "two.toml"))
