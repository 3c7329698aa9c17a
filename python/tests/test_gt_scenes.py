"""The ground-truth data set of python/studies/gt_scenes.py (issue 20), small: 16 x 16 scan,
the film of the data set (768 bins of 4 mm from OPL 1.2 m), two scenes x both captures:

- two_depths: two objects 0.5 m apart in depth (a plate at 0.7 m, a letter at 1.2 m), the
  widest OPL span of the set, mitransient's hidden-geometry sampling;
- bunny: self-occluding, rendered with BSDF sampling alone (mitransient's HGS over-counts
  it by about 6 %: the check against Umbra would fail with it).

Through the CLI (gt_scenes.main): mitransient renders (two seeds), the XML loads in Umbra
and Umbra's path render has mitransient's total (within 1 % + 3 sigma of both renders' seed
noise), target_poisson.npy holds integer counts whose sum is the stated photon count
(within 5 sigma), and every object's three-bounce OPL window lies inside the film with
light in its own bins; no light before the windows, little after them, ~none in the film's
last bins. Also: mitransient's scan points and laser spot are the ones gt_scenes computes
its windows with, its objects' bounding boxes those of gt.truth_meshes; the Poisson draw.
About 12 s (2026-12-03, 2 cores
shared with another process).

    .venv/bin/python -m pytest -q -s python/tests/test_gt_scenes.py
"""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from conftest import PY_DIR, require_umbra

sys.path.insert(0, str(PY_DIR / "studies"))
import gt_scenes as gt  # noqa: E402

SCAN, SPP, UMBRA_SPP = 16, 8192, 1024
SCENES = ("two_depths", "bunny")


@pytest.fixture(scope="module")
def data(mt, umbra_bin, tmp_path_factory):
    exe = require_umbra(umbra_bin)
    out = tmp_path_factory.mktemp("gt")
    gt.main(["--out", str(out), "--scan", str(SCAN), "--spp", str(SPP),
             "--scenes", ",".join(SCENES), "--captures", "confocal,single",
             "--umbra-spp", str(UMBRA_SPP), "--umbra", exe])
    manifest = json.loads((out / "manifest.json").read_text())
    return out, {(c["scene"], c["capture"]): c for c in manifest["cases"]}


CASES = [(s, c) for s in SCENES for c in gt.CAPTURES]


@pytest.mark.parametrize("scene,capture", CASES)
def test_case(data, scene, capture):
    out, cases = data
    c = cases[(scene, capture)]
    d = out / c["dir"]
    for f in ["scene.xml", "target.npy", "target_seed1.npy", "target_seed2.npy",
              "target_poisson.npy"] + [o["mesh"] for o in gt.SCENES[scene]]:
        assert (d / f).is_file(), f
    H = np.load(d / "target.npy")
    assert H.shape == (SCAN, SCAN, gt.BINS) and H.dtype == np.float32 and np.isfinite(H).all()
    assert c["spp"] == SPP * gt.SPP_FACTOR[scene]
    xml = (d / "scene.xml").read_text()
    assert f'<string name="capture_type" value="{capture}"/>' in xml
    hgs = "true" if gt.HIDDEN_GEOMETRY_SAMPLING[scene] else "false"
    assert f'name="nlos_hidden_geometry_sampling" value="{hgs}"' in xml

    # Umbra reads the XML and renders mitransient's total: a bias of 1 % at most, beyond the
    # seeds' noise (no scan point dark in one renderer only).
    u = c["umbra_check"]
    print(f"\n{scene}-{capture}: mitransient {c['spp']} spp {c['render_seconds']:.1f} s, noise "
          f"{100 * c['noise_peak']:.1f} % at the peaks; umbra/mitransient {u['ratio']:.4f} +- "
          f"{u['ratio_se']:.4f}; bins {c['first_bin']}..{c['last_bin']}; Poisson peak "
          f"{c['poisson_peak_counts']:.0f}")
    assert abs(u["ratio"] - 1) < 0.01 + 3 * u["ratio_se"], u
    assert u["only_umbra"] == 0 and u["only_mitransient"] == 0, u

    # Poisson counts: integers, the stated expected sum.
    P = np.load(d / "target_poisson.npy")
    assert P.dtype == np.float32 and P.shape == H.shape
    assert (P >= 0).all() and (P == np.round(P)).all()
    assert c["photons"] == gt.PHOTONS_PER_POINT * SCAN * SCAN
    assert abs(P.sum() - c["photons"]) < 5 * np.sqrt(c["photons"])
    assert c["poisson_peak_counts"] >= 50

    # Inside the film: every object's three-bounce window, with light in its own bins; the
    # first non-zero bin after the film's start, no light before the windows; after them
    # only multi-bounce light, and nothing of note in the film's last bins (the bunny's
    # multi-bounce tail, paths through the wall, reaches past the end of the film: 0.09 %
    # of the total beyond it, measured).
    end = gt.START_OPL + gt.BINS * gt.BIN_WIDTH
    for o in gt.SCENES[scene]:
        lo, hi = c["object_opl"][o["id"]]
        assert gt.START_OPL + 0.1 < lo < hi < end - 0.1, (o["id"], lo, hi)
        assert c["energy_exclusive"][o["id"]] > 0.01, c["energy_exclusive"]
    assert c["first_bin"] > 0
    assert c["first_opl"] >= c["three_bounce_opl"][0] - 2 * gt.BIN_WIDTH
    assert c["energy_before_windows"] < 1e-4
    assert c["energy_after_windows"] < 0.02      # bunny (BSDF sampling): 0.6 %
    assert c["energy_last_5pc_bins"] < 2e-3     # bunny: 8e-4; the HGS scenes: 0


def test_poisson_expected_count():
    H = np.random.default_rng(3).random((4, 4, 64)).astype(np.float32) * 1e-4
    H[0, 0, :] = 0
    P = gt.poisson(H, 1e5, seed=1)
    assert P.dtype == np.float32 and (P == np.round(P)).all()
    assert abs(P.sum() - 1e5) < 5 * np.sqrt(1e5)
    assert (P[0, 0] == 0).all()
    np.testing.assert_array_equal(P, gt.poisson(H, 1e5, seed=1))
    assert not np.array_equal(P, gt.poisson(H, 1e5, seed=2))


def test_geometry_is_mitransients(mt, tmp_path):
    """mitransient's own scan points are gt.scan_points (the geometry of gt.opl_windows),
    the single capture's laser spot is the wall centre, and the objects are where
    gt.truth_meshes puts them (the scene's bounding box)."""
    import mtutil

    for name in ("two_depths", "tilted_plate"):
        xml = gt.write_scene(str(tmp_path / name), name, "single", scan=8, bins=64)
        scene = mtutil.load_xml(xml)
        mtutil.render_scene(scene, spp=1, seed=0)
        integ = scene.integrator()
        st = np.array(integ.sensor_targets)
        st = st.T if st.shape[0] == 3 else st
        np.testing.assert_allclose(st, gt.scan_points(8).reshape(-1, 3), atol=1e-6)
        np.testing.assert_allclose(np.array(integ.laser_targets).ravel(), gt.LASER_SPOT, atol=1e-6)
        v = np.vstack([v for _, v, _ in gt.truth_meshes(name)])
        hidden = [s for s in scene.shapes() if s.id() != "relay_wall"]
        lo = np.min([np.array(s.bbox().min).ravel() for s in hidden], 0)
        hi = np.max([np.array(s.bbox().max).ravel() for s in hidden], 0)
        np.testing.assert_allclose(lo, v.min(0), atol=1e-5)
        np.testing.assert_allclose(hi, v.max(0), atol=1e-5)
