"""`umbra render -o X.hdf5` writes y-tal's capture format: y-tal 0.20.0's own reader
(`tal.io.read_capture`) opens it, and its `H` is the `.npy` render transposed (2, 1, 0)
((T, Sx, Sy) against Umbra's (sy, sx, T)), with the scene's grid, film and capture type.

y-tal pins numpy < 2, so it lives in its own venv, `.venv-ytal` (test.sh creates it, or
UMBRA_YTAL_PYTHON names another interpreter). A missing venv FAILS these tests."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import VALIDATION, require_umbra, require_ytal
from ytal_reader import read_with_ytal

T_XML = VALIDATION / "scenes" / "T.xml"

def render(exe: str, out: Path, capture: str, scan_x: int, scan_y: int) -> None:
    subprocess.run(
        [exe, "render", str(T_XML), "-D", f"capture_type={capture}", "-D", f"scan_x={scan_x}",
         "-D", f"scan_y={scan_y}", "-D", "bins=96", "-D", "bin_width=0.012",
         "--model", "tri3", "-o", str(out), "--no-preview", "-q"],
        check=True, capture_output=True)


@pytest.mark.parametrize("capture", ["single", "confocal"])
def test_ytal_reads_umbras_hdf5(tmp_path: Path, umbra_bin: str, capture: str):
    exe = require_umbra(umbra_bin)
    python = require_ytal()
    sx, sy = 6, 4          # not square, so a swapped axis shows
    render(exe, tmp_path / "h.npy", capture, sx, sy)
    render(exe, tmp_path / "h.hdf5", capture, sx, sy)
    npy = np.load(tmp_path / "h.npy")
    assert npy.shape == (sy, sx, 96) and npy.sum() > 0

    meta, H, sensor, laser = read_with_ytal(python, tmp_path / "h.hdf5", tmp_path)
    assert meta["tal_version"] == "0.20.0"
    assert meta["keys"] == sorted([
        "H", "H_format", "sensor_xyz", "sensor_grid_xyz", "sensor_grid_normals",
        "sensor_grid_format", "laser_xyz", "laser_grid_xyz", "laser_grid_normals",
        "laser_grid_format", "volume_format", "delta_t", "t_start",
        "t_accounts_first_and_last_bounces", "scene_info"])
    assert meta["H_format"] == "T_Sx_Sy" and meta["H_dtype"] == "float32"
    assert meta["sensor_grid_format"] == meta["laser_grid_format"] == "X_Y_3"
    assert H.shape == (96, sx, sy)
    assert np.array_equal(H, npy.transpose(2, 1, 0))
    assert meta["is_confocal"] == (capture == "confocal")
    assert meta["delta_t"] == 0.012 and meta["t_start"] == 1.6
    assert meta["t_accounts_first_and_last_bounces"] is False
    assert meta["scene_info"]["capture_type"] == capture

    # sensor_grid_xyz is indexed [x, y] at pixel centres on the wall z = 0: x grows along
    # the first index, y along the second.
    assert sensor.shape == (sx, sy, 3)
    assert np.allclose(sensor[..., 2], 0.0)
    assert np.all(np.diff(sensor[..., 0], axis=0) > 0) and np.allclose(np.diff(sensor[..., 0], axis=1), 0)
    assert np.all(np.diff(sensor[..., 1], axis=1) > 0) and np.allclose(np.diff(sensor[..., 1], axis=0), 0)
    if capture == "single":
        assert laser.shape == (1, 1, 3)
        assert np.allclose(laser[0, 0], [0.1, 0.1, 0.0], atol=1e-5)   # T.xml's laser spot
    else:
        assert np.array_equal(laser, sensor)


# T.xml is single/confocal only: the exhaustive capture is a TOML scene, a quad 1 m out.
EXHAUSTIVE_TOML = """
capture_type = "exhaustive"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.0, -0.5, 1.5]
irradiance = 1.0
[detector]
origin = [0.0, -0.5, 1.5]
[scan]
resolution = [3, 2]
size = [1.0, 1.0]
[film]
temporal_bins = 96
bin_width_opl = 0.012
start_opl = 1.6
[[objects]]
file = "quad.obj"
transform = { translate = [0.0, 0.0, 1.0] }
[render]
model = "tri3"
"""
QUAD_OBJ = "v -0.2 -0.2 0\nv 0.2 -0.2 0\nv 0.2 0.2 0\nv -0.2 0.2 0\nf 1 3 2\nf 1 4 3\n"


def test_ytal_reads_an_exhaustive_capture(tmp_path: Path, umbra_bin: str):
    exe = require_umbra(umbra_bin)
    python = require_ytal()
    sx, sy = 3, 2
    (tmp_path / "quad.obj").write_text(QUAD_OBJ)
    scene = tmp_path / "exhaustive.toml"
    scene.write_text(EXHAUSTIVE_TOML)
    for out in ["h.npy", "h.h5"]:
        subprocess.run([exe, "render", str(scene), "-o", str(tmp_path / out), "--no-preview", "-q"],
                       check=True, capture_output=True)
    npy = np.load(tmp_path / "h.npy")
    assert npy.shape == (sy, sx, sy, sx, 96) and npy.sum() > 0
    meta, H, sensor, laser = read_with_ytal(python, tmp_path / "h.h5", tmp_path)
    assert meta["H_format"] == "T_Lx_Ly_Sx_Sy"
    # (sy, sx, ly, lx, T) -> (T, Lx, Ly, Sx, Sy)
    assert H.shape == (96, sx, sy, sx, sy)
    assert np.array_equal(H, npy.transpose(4, 3, 2, 1, 0))
    assert np.array_equal(laser, sensor) and sensor.shape == (sx, sy, 3)
