"""y-tal 0.20.0's own scene XMLs rendered by mitransient 1.3.1 (as y-tal drives it) and by
the Umbra CLI, compared per scan point.

Fixtures: scenes/ytal/{confocal,exhaustive}/render/nlos_scene.xml, written by
`tal render -r` from the YAML next to them, run in scenes/ytal/<kind>/ (so the mesh is
`../meshes/plate.obj`, relative to that working directory, as y-tal writes it). A 24 cm
plate tilted 15 deg at 0.6 m, 1 x 1 m wall, 4 x 4 scan, 64 bins of 2 cm; three-bounce
(nlos_laser_sampling + filter_bounces 2) with hidden-geometry sampling.

mitransient side: exactly what y-tal's `tal/render/mitsuba3_transient_nlos.py` does per
laser point: load the XML (from y-tal's working directory), then
`mitransient.nlos.focus_emitter_at_relay_wall_pixel(Point2f(x, y), relay_wall, laser)`
with y-tal's laser_lookat (film pixel units), and render.
- confocal: 1x1 film + original_film_*: one render per scan point (4 x 4 renders).
- exhaustive: y-tal's single-capture XML aimed at one laser point, (3, 0) of its 4 x 4
  laser grid: lookat (3.5, 0.5).
Umbra side: `umbra render render/nlos_scene.xml` run in the same folder (confocal: the
whole 4 x 4 capture in one run; exhaustive: `-D laser_lookat_x=3.5 -D laser_lookat_y=0.5`,
and the whole grid with `-D scan_type=exhaustive -D laser_width=4 -D laser_height=4`, sliced
at that laser point).

Statistics: K independent seeds per renderer. Per scan point, the time-summed signal's
mean difference against its standard error (per-point variances across seeds, both
sides): |z| <= Z_MAX. With K = 6 seeds per side the variance estimates have ~10 degrees
of freedom (Welch); P(|t_10| > 5) = 5e-4, so over 16 points a false failure has ~1 %
probability. Totals: |U/M - 1| <= 1 % + 3 sigma (as test_vs_mitransient.py), and the
relative L2 over all bins <= 1.5 x its no-bias expectation (its compare()).
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, SELF_CHECK, require_umbra
from test_vs_mitransient import L2_FACTOR, TOTAL_TOL, compare, report

YTAL = REPO / "scenes" / "ytal"
K = 6            # seeds per renderer
SPP = 1000       # samples per scan point and render, both renderers
Z_MAX = 5.0
T = 64


def _mt_confocal(mt, seed: int) -> np.ndarray:
    """y-tal's confocal loop: one 1x1 render per scan point, laser aimed at it."""
    import mtutil

    mi, mitr = mt
    scene = mtutil.load_xml(Path("render/nlos_scene.xml"))
    wall = [s for s in scene.shapes() if s.id() == "relay_wall"][0]
    laser = [e for e in scene.emitters() if e.id() == "laser"][0]
    H = np.zeros((4, 4, T), np.float32)
    for y in range(4):
        for x in range(4):
            # y-tal: laser_lookat = (i + 0.5) / laser_width * sensor_width
            mitr.nlos.focus_emitter_at_relay_wall_pixel(mi.Point2f(x + 0.5, y + 0.5), wall, laser)
            h = mtutil.render_scene(scene, spp=SPP, seed=seed * 16 + y * 4 + x)
            assert h.shape == (1, 1, T), h.shape
            H[y, x] = h[0, 0]
    return H


def _mt_exhaustive_point(mt, seed: int) -> np.ndarray:
    import mtutil

    mi, mitr = mt
    scene = mtutil.load_xml(Path("render/nlos_scene.xml"))
    wall = [s for s in scene.shapes() if s.id() == "relay_wall"][0]
    laser = [e for e in scene.emitters() if e.id() == "laser"][0]
    mitr.nlos.focus_emitter_at_relay_wall_pixel(mi.Point2f(3.5, 0.5), wall, laser)
    return mtutil.render_scene(scene, spp=SPP, seed=seed)


def _umbra(umbra_bin: str, seed: int, out: Path, defines=()) -> np.ndarray:
    cmd = [umbra_bin, "render", "render/nlos_scene.xml", "-o", str(out), "--spp", str(SPP),
           "--seed", str(seed), "--no-preview", "-q"]
    for d in defines:
        cmd += ["-D", d]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return np.load(out)


def _check(case: str, M: np.ndarray, U: np.ndarray) -> None:
    res = compare(M, U, SPP, SPP)
    print("\n" + report(f"ytal-{case}", res))
    Pm, Pu = M.astype(np.float64).sum(-1), U.astype(np.float64).sum(-1)   # (K, sy, sx)
    se = np.sqrt(Pm.var(0, ddof=1) / len(Pm) + Pu.var(0, ddof=1) / len(Pu))
    diff = Pu.mean(0) - Pm.mean(0)
    z = diff / se
    ratio = Pu.mean(0) / Pm.mean(0)
    print(f"per scan point: umbra/mitransient {ratio.min():.4f} .. {ratio.max():.4f}, "
          f"|z| max {np.abs(z).max():.2f}, relative stderr {np.median(se / Pm.mean(0)):.4f} (median)")
    assert np.all(Pm.mean(0) > 0), "mitransient renders no light at some scan point"
    assert np.abs(z).max() <= Z_MAX, (z, ratio)
    tm, tu = res["tot_m"], res["tot_u"]
    sd = np.hypot(res["se_m"], res["se_u"])
    assert abs(tu - tm) <= TOTAL_TOL * tm + 3 * sd, (tu, tm, sd)
    for label, k, _, _, meas, exp, _, _ in res["rows"]:
        if k == K:
            assert meas <= L2_FACTOR * exp, (label, meas, exp)


@pytest.fixture
def umbra(umbra_bin):
    if umbra_bin == SELF_CHECK:
        pytest.skip("compares y-tal's XML in Umbra with mitransient; no self-check mode")
    return str(Path(require_umbra(umbra_bin)).resolve())


def test_ytal_confocal_xml(mt, umbra, tmp_path, monkeypatch):
    monkeypatch.chdir(YTAL / "confocal")     # where y-tal ran: ../meshes/plate.obj
    M = np.stack([_mt_confocal(mt, s) for s in range(K)])
    U = np.stack([_umbra(umbra, 100 + s, tmp_path / f"u{s}.npy") for s in range(K)])
    assert U.shape == M.shape == (K, 4, 4, T)
    _check("confocal", M, U)


def test_ytal_exhaustive_xml_one_laser_point(mt, umbra, tmp_path, monkeypatch):
    monkeypatch.chdir(YTAL / "exhaustive")
    M = np.stack([_mt_exhaustive_point(mt, s) for s in range(K)])
    aim = ("laser_lookat_x=3.5", "laser_lookat_y=0.5")
    U = np.stack([_umbra(umbra, 100 + s, tmp_path / f"u{s}.npy", aim) for s in range(K)])
    assert U.shape == M.shape == (K, 4, 4, T)
    _check("exhaustive-L3-0", M, U)
    # y-tal's whole laser grid in one Umbra run (-D scan_type=exhaustive): its laser point
    # (lx 3, ly 0) of the (sy, sx, ly, lx, T) capture against the same mitransient renders.
    full = ("scan_type=exhaustive", "laser_width=4", "laser_height=4")
    E = np.stack([_umbra(umbra, 200 + s, tmp_path / f"e{s}.npy", full) for s in range(K)])
    assert E.shape == (K, 4, 4, 4, 4, T)
    _check("exhaustive-grid-L3-0", M, E[:, :, :, 0, 3, :])
