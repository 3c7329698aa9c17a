"""`umbra fit` on data made by mitransient 1.3.1 (box bins, mitransient's own scale): the
small version of python/studies/fit_mitransient.py, for CI (about half a minute).

The letter T turned 30 degrees, 1 m from the wall; confocal 12 x 12 scan, 128 bins of 16 mm;
mitransient target at 8192 spp (2 seeds; relative L2 noise about 4.5 %). The fit starts from
a plane with a short schedule (30 Adam, 30 Adam with albedo after remeshing, 20 L-BFGS).
Measured over 5 target seeds: Chamfer (seen) 94 mm for the plane -> 24-34 mm, relative L2
0.735 -> 0.23-0.35. Also: `umbra render` agrees with mitransient on the same XML, and the
fit does not depend on the target's absolute scale.

    UMBRA_BIN=$PWD/target/release/umbra .venv/bin/python -m pytest -q -s python/tests/test_fit_mitransient.py
"""
from __future__ import annotations

import sys

import numpy as np

from conftest import PY_DIR, require_umbra

sys.path.insert(0, str(PY_DIR / "studies"))
import fit_mitransient as fm  # noqa: E402

SCAN, BINS, BIN_WIDTH, SPP = 12, 128, 0.016, 8192
FIRST = """checkpoint_every = 100
[[stage]]
iters = {}
lr = 0.01
large_steps = 20.0
time_downsample = 2
"""
SHORT = FIRST.format(30) + """[[stage]]
iters = 30
lr = 0.004
large_steps = 20.0
fit_albedo = true
remesh_factor = 0.5
[[stage]]
iters = 20
solver = "lbfgs"
large_steps = 20.0
fit_albedo = true
"""


def schedule(tmp_path, name, text):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return str(path)


def loss_history(out):
    rows = np.genfromtxt(f"{out}/loss.csv", delimiter=",", names=True)
    return rows["data_loss"], rows["scale"]


def test_fit_mitransient_letter(mt, umbra_bin, tmp_path):
    exe = require_umbra(umbra_bin)
    xml = fm.write_scene(str(tmp_path), SCAN, BINS, BIN_WIDTH, spp=SPP // 2)
    H, H1, H2, _ = fm.render_mitransient(xml, SPP, str(tmp_path))
    target = str(tmp_path / "target.npy")
    assert H.shape == (SCAN, SCAN, BINS) and np.isfinite(H).all()
    noise = fm.noise(H1, H2)
    assert noise["l2"] < 0.08, noise

    # Umbra reads the same XML at the same scale (laser and SPAD unshadowed: no zeros).
    U = [fm.umbra_render(xml, 1024, s, str(tmp_path / f"u{s}.npy"), umbra=exe) for s in (1, 2)]
    chk = fm.compare(H1, H2, *U)
    assert abs(chk["ratio"] - 1) < 0.01 + 3 * chk["ratio_se"], chk
    assert chk["only_umbra"] == 0 and chk["only_mitransient"] == 0, chk
    assert chk["l2"] < 1.5 * chk["l2_noise"], chk

    # The initial plane (a 0-iteration fit) against the fit.
    plane = fm.run_fit(xml, target, str(tmp_path / "plane"), umbra=exe,
                       config=schedule(tmp_path, "zero", FIRST.format(0)))
    fit = fm.run_fit(xml, target, str(tmp_path / "fit"), umbra=exe,
                     config=schedule(tmp_path, "short", SHORT))
    c0, c1 = plane["chamfer"]["seen_mm"], fit["chamfer"]["seen_mm"]
    print(f"\nmitransient target noise {noise['l2']:.3f}; umbra/mitransient {chk['ratio']:.4f}; "
          f"Chamfer {c0:.1f} -> {c1:.1f} mm; relative L2 {plane['relative_l2']:.3f} -> "
          f"{fit['relative_l2']:.3f}; fit {fit['wall_seconds']:.1f} s")
    assert c1 < 0.5 * c0, (c0, c1)
    assert fit["relative_l2"] < 0.6 * plane["relative_l2"], (plane["relative_l2"], fit["relative_l2"])
    v = np.array([line.split()[1:4] for line in open(tmp_path / "fit" / "mesh.obj")
                  if line.startswith("v ")], dtype=float)
    assert len(v) > 0 and np.isfinite(v).all()
    assert fit["faces"] > 0

    # Its own scale: a target 1000x brighter gives the same losses and a 1000x scale
    # (a few iterations: rounding differences grow chaotically in a long fit).
    np.save(tmp_path / "target_x1000.npy", H * np.float32(1000))
    few = schedule(tmp_path, "few", FIRST.format(3))
    fm.run_fit(xml, target, str(tmp_path / "few"), umbra=exe, config=few)
    fm.run_fit(xml, str(tmp_path / "target_x1000.npy"), str(tmp_path / "few_x1000"),
               umbra=exe, config=few)
    (l1, s1), (l2, s2) = loss_history(tmp_path / "few"), loss_history(tmp_path / "few_x1000")
    np.testing.assert_allclose(l2, l1, rtol=1e-5)
    np.testing.assert_allclose(s2, 1000 * s1, rtol=1e-5)
