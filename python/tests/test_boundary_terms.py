"""The `boundary_terms` option (issue 18) through Python: on by default, reported in the
grad result and the scene's options, off on request, the same numbers as the CLI, and
passed through the torch module. Their accuracy is checked in tests/gradient_bias.rs
(exact reference) and test_boundary_mitsuba.py (Mitsuba 3's projective sampling)."""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

import umbra
from conftest import require_umbra

PLATE = "v -0.15 -0.15 0.9\nv 0.15 -0.15 0.9\nv 0.15 0.15 0.9\nv -0.15 0.15 0.9\nf 1 4 3 2\n"
OCCLUDER = "v -0.02 -0.05 0.6\nv 0.08 -0.05 0.6\nv 0.08 0.05 0.6\nv -0.02 0.05 0.6\nf 1 4 3 2\n"
TOML = """
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.3, -0.4, 1.0]
[scan]
resolution = [4, 4]
size = [0.9, 0.9]
[film]
temporal_bins = 200
bin_width_opl = 0.01
start_opl = 0.9
kernel = "gaussian"
sigma_opl = 0.012
[[objects]]
file = "plate.obj"
albedo = 0.7
two_sided = true
[[objects]]
file = "occ.obj"
albedo = 0.7
two_sided = true
[render]
model = "mc3"
spp = 512
"""


def occluded_scene(tmp: Path) -> Path:
    (tmp / "plate.obj").write_text(PLATE)
    (tmp / "occ.obj").write_text(OCCLUDER)
    (tmp / "scene.toml").write_text(TOML)
    return tmp / "scene.toml"


def test_on_by_default_off_on_request_and_equal_to_the_cli(tmp_path: Path, umbra_bin: str):
    path = occluded_scene(tmp_path)
    s = umbra.load_scene(path)
    assert s.options["boundary_terms"] is True
    adjoint = np.ones(tuple(s.shape), np.float32)
    on = umbra.grad(s, adjoint)
    off = umbra.grad(s, adjoint, boundary_terms=False)
    assert on["boundary_terms"] is True and off["boundary_terms"] is False
    np.testing.assert_array_equal(umbra.grad(s, adjoint, boundary_terms=True)["vertices"][1],
                                  on["vertices"][1])
    # The occluder's in-plane motion moves its shadow on the plate: the boundary terms
    # change its gradient by far more than the Monte Carlo noise.
    d = np.abs(on["vertices"][1][:, :2] - off["vertices"][1][:, :2]).max()
    assert d > 0.1 * np.abs(on["vertices"][1][:, :2]).max()
    # Albedo gradients have no boundary term.
    np.testing.assert_allclose(on["albedo"], off["albedo"], rtol=1e-12)
    # The CLI, with and without, writes the same numbers.
    exe = require_umbra(umbra_bin)
    np.save(tmp_path / "adj.npy", adjoint)
    for flag, ref in (("true", on), ("false", off)):
        out = tmp_path / f"g_{flag}.npz"
        subprocess.run([exe, "grad", str(path), "--adjoint", str(tmp_path / "adj.npy"),
                        "-o", str(out), "--boundary-terms", flag], check=True,
                       capture_output=True)
        with np.load(out) as z:
            key = [k for k in z.files if "vert" in k and k.endswith("1")]
            assert key, z.files
            np.testing.assert_allclose(z[key[0]], ref["vertices"][1], rtol=1e-6,
                                       atol=1e-9 * np.abs(ref["vertices"][1]).max())


def test_torch_module_takes_the_option(tmp_path: Path):
    torch = pytest.importorskip("torch")
    from umbra.torch import TransientModule
    s = umbra.load_scene(occluded_scene(tmp_path))
    grads = {}
    for flag in (True, False):
        m = TransientModule(s, boundary_terms=flag, fit_albedo=False)
        m().sum().backward()
        grads[flag] = m.vertices[1].grad.numpy().copy()
        ref = umbra.grad(s, np.ones(tuple(s.shape), np.float32), boundary_terms=flag)
        np.testing.assert_allclose(grads[flag], ref["vertices"][1], rtol=1e-6,
                                   atol=1e-9 * np.abs(ref["vertices"][1]).max())
    assert not np.allclose(grads[True], grads[False])
    del torch
