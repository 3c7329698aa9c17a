"""`umbra.fit`'s fitted surface seen from the wall: ``albedo`` and ``depth``, (ny, nx)
float32 per scan point in the measurement's scan order, NaN where no surface, equal to
the fit folder's albedo.npy and depth.npy."""
from __future__ import annotations

from pathlib import Path

import numpy as np

import umbra
from scenes_two import two_object_scene


def test_fit_returns_the_albedo_and_depth_seen_from_the_wall(tmp_path: Path):
    # Two small quads (albedo 0.7 at depth about 0.7 m, 0.5 at about 0.9 m) in front of a
    # 6 x 6 scan over 0.8 m: most scan points see neither.
    s = two_object_scene(tmp_path)
    target = umbra.render(s)
    out = umbra.fit(s, target, output=tmp_path / "fit", init="scene", known_scale=True,
                    background="none", schedule=[dict(iters=2, solver="adam", lr=0.001)])
    ny, nx = target.shape[:2]
    albedo, depth = out["albedo"], out["depth"]
    for a in (albedo, depth):
        assert isinstance(a, np.ndarray) and a.dtype == np.float32 and a.shape == (ny, nx)
    hit = np.isfinite(depth)
    assert (np.isfinite(albedo) == hit).all()
    assert 0 < hit.sum() < ny * nx
    assert ((albedo[hit] >= 0) & (albedo[hit] <= 1)).all()
    assert ((depth[hit] > 0.55) & (depth[hit] < 1.05)).all()
    # Scan order [iy, ix] (x = -0.333 + 0.1333 ix, y likewise): the quad at x -0.23 to
    # -0.07, y -0.03 to 0.13, 0.7 m out is in front of [3, 1] only; the scan's corners
    # see nothing.
    assert abs(depth[3, 1] - 0.7) < 0.05, depth
    assert np.isnan(depth[0, 0]) and np.isnan(depth[ny - 1, nx - 1])
    # The same arrays as the files.
    for name, a in (("albedo", albedo), ("depth", depth)):
        f = np.load(tmp_path / "fit" / f"{name}.npy")
        assert f.dtype == np.float32 and f.shape == (ny, nx)
        np.testing.assert_array_equal(f, a)
    names = {Path(f).name for f in out["files"]}
    assert {"albedo.npy", "depth.npy", "albedo.png", "reconstruction.png"} <= names
    # No capture model (background "none"): no floor per scan point.
    assert out["floor"] is None and "floor.npy" not in names


def test_fit_returns_the_capture_models_floor_per_scan_point(tmp_path: Path):
    # Poisson counts of the two quads with a floor that jumps between scan columns (as the
    # Stanford captures' does): the capture model (background "per-point") fits one floor
    # per scan point, returned as ``floor`` (ny, nx) and written as floor.npy.
    s = two_object_scene(tmp_path, scan=8)
    h = np.asarray(umbra.render(s))
    ny, nx, _ = h.shape
    truth = np.tile([0.5, 2.0, 0.8, 1.4], nx // 4)[None, :].repeat(ny, 0)
    counts = np.random.default_rng(3).poisson(h / h.max() * 200 + truth[..., None])
    out = umbra.fit(s, counts.astype(np.float32), output=tmp_path / "fit", init="scene",
                    background="per-point", iters=4)
    floor = out["floor"]
    assert isinstance(floor, np.ndarray) and floor.shape == (ny, nx)
    # ~150 bins of 0.5-2 counts a point: each floor within a few tenths, each column's
    # mean over its 8 points within 0.15.
    assert np.abs(floor - truth).max() < 0.5, np.round(floor, 2)
    assert np.abs(floor.mean(axis=0) - truth[0]).max() < 0.15, np.round(floor.mean(axis=0), 2)
    f = np.load(tmp_path / "fit" / "floor.npy")
    assert f.dtype == np.float32 and f.shape == (ny, nx)
    np.testing.assert_allclose(f, floor, rtol=1e-6)
    assert abs(out["nuisance"]["floor_mean"] - floor.mean()) < 1e-9 * floor.mean()
