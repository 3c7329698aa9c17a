#!/usr/bin/env python3
"""Numerical probes of mitransient 1.3.1 semantics that Umbra must match (see
notes/mitransient.md). Each probe prints what it measured. Small renders (seconds).

  A. scan-point placement and ordering on a rotated, translated, non-square wall
  B. which filter_bounces selects the three-bounce signal, with laser sampling and with
     plain NEE; what discard_direct_paths removes; what max_depth allows
  C. multi-bounce path space: BSDF sampling vs hidden-geometry sampling (HGS) with and
     without the relay wall (interreflections via the wall are only in some of them)

Run: .venv/bin/python python/validation/mitransient_semantics.py
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mtutil  # noqa: E402

mi, mitr = mtutil.setup()
T = mi.ScalarTransform4f


def rgb(v):
    return {"type": "rgb", "value": [v, v, v]}


def base_scene(integrator: dict, wall_to_world=None, scan=(8, 8), bins=400, start=0.5, bw=0.01,
               laser_fov=0.2, laser_target=(0.0, 0.0, 0.0), hidden=None):
    d = {
        "type": "scene",
        "integrator": {"type": "transient_nlos_path", "temporal_filter": "box", **integrator},
        "laser": {"type": "projector", "irradiance": rgb(1.0), "fov": laser_fov,
                  "to_world": T().look_at(origin=[0.3, 0.2, 0.3], target=list(laser_target),
                                          up=[0, 1, 0])},
        "relay_wall": {
            "type": "rectangle",
            "to_world": wall_to_world if wall_to_world is not None else T().scale([0.5, 0.5, 1]),
            "bsdf": {"type": "diffuse", "reflectance": rgb(0.8)},
            "sensor": {
                "type": "nlos_capture_meter",
                "sensor_origin": [-0.5, 0.0, 0.25],
                "sampler": {"type": "independent", "sample_count": 1},
                "film": {"type": "transient_hdr_film", "width": scan[0], "height": scan[1],
                         "temporal_bins": bins, "bin_width_opl": bw, "start_opl": start,
                         "rfilter": {"type": "box"}},
            },
        },
    }
    if hidden is None:
        # V-shaped bent sheet ("open book", two 30 cm x 40 cm arms at 90 degrees) facing the
        # wall, apex at z ~ 0.906: its arms see each other, so hidden-hidden interreflections
        # exist. The arms meet exactly at the apex: if they crossed, the few mm of arm behind
        # the other arm would be counted twice by mitransient's HGS (see notes).
        a = 0.15 * np.sqrt(0.5)
        hidden = {
            "armA": {"type": "rectangle",
                     "to_world": T().translate([-a, 0.0, 0.8]) @ T().rotate([0, 1, 0], 180 - 45)
                     @ T().scale([0.15, 0.2, 1]),
                     "bsdf": {"type": "diffuse", "reflectance": rgb(0.8)}},
            "armB": {"type": "rectangle",
                     "to_world": T().translate([a, 0.0, 0.8]) @ T().rotate([0, 1, 0], 180 + 45)
                     @ T().scale([0.15, 0.2, 1]),
                     "bsdf": {"type": "diffuse", "reflectance": rgb(0.8)}},
        }
    d.update(hidden)
    return d


def total(scene_d, spp, seeds=2):
    sc = mi.load_dict(scene_d)
    runs = [mtutil.render_scene(sc, spp=spp, seed=s).sum() for s in range(seeds)]
    return float(np.mean(runs)), float(np.std(runs, ddof=1) / np.sqrt(seeds)) if seeds > 1 else 0.0


def probe_scan_points():
    print("== A. scan points (rotated 30 deg about z, translated, 1.0 x 0.6 m wall, 5x3 scan)")
    w2w = T().translate([0.05, -0.02, 0.0]) @ T().rotate([0, 0, 1], 30) @ T().scale([0.5, 0.3, 1])
    d = base_scene({"nlos_laser_sampling": True, "capture_type": "confocal"}, wall_to_world=w2w,
                   scan=(5, 3))
    sc = mi.load_dict(d)
    mtutil.render_scene(sc, spp=1)
    st = np.array(sc.integrator().sensor_targets)
    st = st.T if st.shape[0] == 3 else st
    sx, sy = 5, 3
    M = np.array(w2w.matrix)
    exp = []
    for iy in range(sy):
        for ix in range(sx):
            u, v = (2 * ix + 1) / sx - 1, (2 * iy + 1) / sy - 1
            exp.append((M @ np.array([u, v, 0, 1]))[:3])
    exp = np.array(exp)
    print("   integrator sensor_targets[k] == to_world((2ix+1)/sx-1, (2iy+1)/sy-1, 0) with "
          f"k = ix + iy*sx: {np.allclose(st, exp, atol=1e-5)}  (max err {np.abs(st - exp).max():.1e})")


def probe_depth():
    print("== B. depth semantics (V sheet, 8x8 scan, totals over all bins)")
    spp = 2000
    rows = []
    for ls in (True, False):
        for hgs in (False,):
            for fb in (-1, 1, 2, 3, 4):
                integ = {"nlos_laser_sampling": ls, "nlos_hidden_geometry_sampling": hgs,
                         "filter_bounces": fb, "max_depth": 8}
                # NEE mode needs a projector that lights a wall region, not a point
                fov = 0.2 if ls else 30.0
                t, e = total(base_scene(integ, laser_fov=fov), spp if ls else 20000)
                rows.append((f"laser_sampling={ls!s:5s} filter_bounces={fb:2d} max_depth=8", t, e))
    for ls in (True, False):
        for dd in (False, True):
            integ = {"nlos_laser_sampling": ls, "filter_bounces": -1, "max_depth": 8,
                     "discard_direct_paths": dd}
            t, e = total(base_scene(integ, laser_fov=0.2 if ls else 30.0), spp if ls else 20000)
            rows.append((f"laser_sampling={ls!s:5s} discard_direct_paths={dd!s:5s} max_depth=8", t, e))
    for md in (2, 3, 4, 5):
        integ = {"nlos_laser_sampling": True, "filter_bounces": -1, "max_depth": md}
        t, e = total(base_scene(integ), spp)
        rows.append((f"laser_sampling=True  filter_bounces=-1 max_depth={md}", t, e))
    for name, t, e in rows:
        print(f"   {name:60s} total {t:.4e} +- {e:.1e}")


def probe_path_space():
    print("== C. multi-bounce path space (V sheet, laser sampling, max_depth=-1, rr_depth=5)")
    cases = [
        ("BSDF sampling", {"nlos_hidden_geometry_sampling": False}, 40000),
        ("HGS, no relay wall", {"nlos_hidden_geometry_sampling": True}, 4000),
        ("HGS + relay wall", {"nlos_hidden_geometry_sampling": True,
                              "nlos_hidden_geometry_sampling_includes_relay_wall": True}, 40000),
        ("HGS 50/50 roulette w/ BSDF", {"nlos_hidden_geometry_sampling": True,
                                        "nlos_hidden_geometry_sampling_do_rroulette": True}, 40000),
        ("HGS, no relay wall, 3-bounce only", {"nlos_hidden_geometry_sampling": True,
                                               "filter_bounces": 2}, 4000),
        ("BSDF sampling, 3-bounce only", {"nlos_hidden_geometry_sampling": False,
                                          "filter_bounces": 2}, 40000),
        ("HGS 50/50 roulette, 3-bounce only", {"nlos_hidden_geometry_sampling": True,
                                               "nlos_hidden_geometry_sampling_do_rroulette": True,
                                               "filter_bounces": 2}, 40000),
    ]
    for name, extra, spp in cases:
        integ = {"nlos_laser_sampling": True, "max_depth": -1, **extra}
        t, e = total(base_scene(integ, scan=(4, 4)), spp, seeds=3)
        print(f"   {name:36s} total {t:.5e} +- {e:.1e} ({spp} spp x 3 seeds)")


if __name__ == "__main__":
    which = sys.argv[1:] or ["A", "B", "C"]
    if "A" in which:
        probe_scan_points()
    if "B" in which:
        probe_depth()
    if "C" in which:
        probe_path_space()
