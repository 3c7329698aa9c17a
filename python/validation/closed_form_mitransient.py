#!/usr/bin/env python3
"""Closed-form check of mitransient 1.3.1's absolute scale (transient_nlos_path + projector).

Scene: relay wall = Mitsuba `rectangle` scaled to 1.0 m x 0.8 m in the plane z = 0
(normal +z), a 2 cm x 2 cm Lambertian square patch facing the wall at z = 1 m, off
axis; a projector laser of irradiance E0 aimed (lookat) at a wall point x_l; 4x4 scan.
Three-bounce only (filter_bounces = 2 with laser sampling), hidden-geometry sampling on.

For each scan point x_s the time-integrated measurement is compared with

  H(x_s) = pi E0 cos(th_l) / |x_e - x_l|^2 * (rho_w/pi) * Int (rho/pi) G(x_l,x) G(x,x_s) dA(x) * (rho_w/pi)

(G(a,b) = cos_a cos_b / |a-b|^2), integrated over the patch with Gauss-Legendre
quadrature, for `single` (x_l fixed) and `confocal` (x_l = x_s) captures. It also checks
the mean optical path length with account_first_and_last_bounces false/true, and (with
--bsdf) the same scale without hidden-geometry sampling (BSDF sampling, larger patch).

Run: .venv/bin/python python/validation/closed_form_mitransient.py [--spp N] [--seeds K] [--bsdf]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mtutil  # noqa: E402

E0 = 2.0          # projector irradiance
RHO_W = 0.7       # wall albedo
RHO = 0.8         # patch albedo
WALL_HALF = (0.5, 0.4)            # rectangle scale: wall spans [-0.5,0.5] x [-0.4,0.4]
SCAN = (4, 4)                      # (sx, sy)
X_E = np.array([-0.3, 0.25, 0.4])  # laser position
X_L_SINGLE = np.array([0.1, -0.05, 0.0])  # where the laser is aimed (single capture)
SENSOR_ORIGIN = np.array([-0.5, 0.0, 0.25])
PATCH_C = np.array([0.12, -0.08, 1.0])
BIN_W = 0.001  # fine bins so that the OPL convention is checked to ~0.1 mm
RAY_EPS = 1500 * 2.0**-24  # Mitsuba's math::RayEpsilon<float> (spawn_ray origin offset scale)


def scene_dict(capture: str, patch_half: float, hgs: bool, account: bool = False,
               max_depth: int = 4, filter_bounces: int = 2, start_opl: float = 1.5, bins: int = 300):
    mi, _ = mtutil.setup()
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "integrator": {
            "type": "transient_nlos_path",
            "max_depth": max_depth,
            "filter_bounces": filter_bounces,
            "discard_direct_paths": False,
            "nlos_laser_sampling": True,
            "nlos_hidden_geometry_sampling": hgs,
            "nlos_hidden_geometry_sampling_do_rroulette": False,
            "nlos_hidden_geometry_sampling_includes_relay_wall": False,
            "temporal_filter": "box",
            "capture_type": capture,
            "account_first_and_last_bounces": account,
        },
        "laser": {
            "type": "projector",
            "irradiance": {"type": "rgb", "value": [E0, E0, E0]},
            "fov": 0.2,
            "to_world": T().look_at(origin=X_E.tolist(), target=X_L_SINGLE.tolist(), up=[0, 1, 0]),
        },
        "patch": {
            "type": "rectangle",
            # rotate 180 deg about x: local +z normal -> world -z (faces the wall)
            "to_world": T().translate(PATCH_C.tolist()) @ T().rotate([1, 0, 0], 180)
            @ T().scale([patch_half, patch_half, 1]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [RHO] * 3}},
        },
        "relay_wall": {
            "type": "rectangle",
            "to_world": T().scale([WALL_HALF[0], WALL_HALF[1], 1]),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [RHO_W] * 3}},
            "sensor": {
                "type": "nlos_capture_meter",
                "sensor_origin": SENSOR_ORIGIN.tolist(),
                "sampler": {"type": "independent", "sample_count": 1},
                "film": {
                    "type": "transient_hdr_film",
                    "width": SCAN[0], "height": SCAN[1],
                    "temporal_bins": bins, "bin_width_opl": BIN_W, "start_opl": start_opl,
                    "rfilter": {"type": "box"},
                },
            },
        },
    }


def scan_points():
    """Pixel centres of the rectangle's UV: H[iy, ix] <-> local ((2ix+1)/sx-1, (2iy+1)/sy-1)."""
    sx, sy = SCAN
    ix, iy = np.meshgrid(np.arange(sx), np.arange(sy))  # (sy, sx)
    u = (2 * ix + 1) / sx - 1
    v = (2 * iy + 1) / sy - 1
    return np.stack([u * WALL_HALF[0], v * WALL_HALF[1], np.zeros_like(u)], -1)  # (sy, sx, 3)


def closed_form(capture: str, patch_half: float, n_quad: int = 24, account: bool = False):
    """Closed form at each scan point. Returns (H (sy,sx), nodes) where nodes[iy][ix] =
    (weights, opl) of the quadrature nodes (weights sum to H), for binning in time."""
    g, w = np.polynomial.legendre.leggauss(n_quad)
    U, V = np.meshgrid(g, g)
    W = np.outer(w, w).ravel() * patch_half**2  # dA (area element of [-h,h]^2)
    X = np.stack([PATCH_C[0] + patch_half * U.ravel(), PATCH_C[1] - patch_half * V.ravel(),
                  np.full(U.size, PATCH_C[2])], -1)
    n_x = np.array([0.0, 0.0, -1.0])
    n_w = np.array([0.0, 0.0, 1.0])

    def G(a, na, b, nb):
        d = b - a
        r2 = np.sum(d * d, -1)
        r = np.sqrt(r2)
        return np.clip(d @ na / r, 0, None) * np.clip(-(d @ nb) / r, 0, None) / r2, r

    xs_all = scan_points()
    H = np.zeros(xs_all.shape[:2])
    nodes = [[None] * xs_all.shape[1] for _ in range(xs_all.shape[0])]
    for iy in range(xs_all.shape[0]):
        for ix in range(xs_all.shape[1]):
            xs = xs_all[iy, ix]
            xl = X_L_SINGLE if capture == "single" else xs
            de = X_E - xl
            cos_l_in = de @ n_w / np.linalg.norm(de)
            laser = np.pi * E0 * cos_l_in / (de @ de)
            g1, r1 = G(xl, n_w, X, n_x)
            g2, r2 = G(X, n_x, xs, n_w)
            wts = laser * (RHO_W / np.pi) ** 2 * (RHO / np.pi) * g1 * g2 * W
            opl = r1 + r2
            if account:
                opl = opl + np.linalg.norm(de) + np.linalg.norm(xs - SENSOR_ORIGIN)
            H[iy, ix] = wts.sum()
            nodes[iy][ix] = (wts, opl)
    return H, nodes


def predicted_edge_loss(patch_half: float):
    """mitransient's hidden-geometry sampling aims at a point y on the patch but traces the
    ray from x_s + eps*n (Mitsuba spawn_ray offset, eps = (1+max|x_s|)*RayEpsilon) with the
    direction of y - x_s: the hit is displaced by eps*d_xy/d_z, so samples within that distance
    of the patch edge miss. Predicted lost fraction per scan point (uniform-integrand approx.)."""
    xs = scan_points()
    d = PATCH_C[None, None, :] - xs
    eps = (1 + np.abs(xs).max(-1)) * RAY_EPS
    return eps * (np.abs(d[..., 0]) + np.abs(d[..., 1])) / d[..., 2] / (2 * patch_half)


def measure(scene, spp, seeds):
    runs = np.stack([mtutil.render_scene(scene, spp=spp, seed=s).astype(np.float64)
                     for s in range(seeds)])           # (K, sy, sx, T)
    tot = runs.sum(-1)
    return runs.mean(0), tot.mean(0), tot.std(0, ddof=1) / np.sqrt(seeds)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=25000)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--bsdf", action="store_true",
                    help="also check without hidden-geometry sampling (10 cm patch, 4M spp, slower)")
    args = ap.parse_args()
    mi, _ = mtutil.setup()

    rows = []
    cases = [("single", 0.01, True, False), ("confocal", 0.01, True, False),
             ("single", 0.01, True, True), ("confocal", 0.01, True, True),
             ("single", 0.05, True, False), ("confocal", 0.05, True, False)]
    if args.bsdf:
        cases += [("single", 0.05, False, False), ("confocal", 0.05, False, False)]
    for capture, half, hgs, account in cases:
        spp = args.spp if hgs else 1_000_000
        H_cf, nodes = closed_form(capture, half, account=account)
        all_opl = np.concatenate([n[1] for row in nodes for n in row])
        start = np.floor(all_opl.min() / BIN_W) * BIN_W - 20 * BIN_W
        bins = int(np.ceil((all_opl.max() - start) / BIN_W)) + 20
        t0 = time.time()
        scene = mi.load_dict(scene_dict(capture, half, hgs, account, start_opl=start, bins=bins))
        hist, H_mt, se_mt = measure(scene, spp, args.seeds)
        dt = time.time() - t0
        # scan points used by the integrator (ray from sensor_origin to the pixel centre, hit)
        st = np.array(scene.integrator().sensor_targets)     # (3, N) from Dr.Jit
        st = (st.T if st.shape[0] == 3 else st).reshape(SCAN[1], SCAN[0], 3)
        targets_ok = np.allclose(st, scan_points(), atol=1e-6)
        # time: bin the closed form's quadrature nodes the same way; compare mean OPL
        edges = start + BIN_W * np.arange(bins + 1)
        centres = 0.5 * (edges[1:] + edges[:-1])
        dmean = np.zeros(H_cf.shape)
        for iy in range(SCAN[1]):
            for ix in range(SCAN[0]):
                wts, opl = nodes[iy][ix]
                hcf, _ = np.histogram(opl, bins=edges, weights=wts)
                dmean[iy, ix] = (hist[iy, ix] @ centres) / hist[iy, ix].sum() - (hcf @ centres) / hcf.sum()
        ratio = H_mt / H_cf
        loss = predicted_edge_loss(half) if hgs else np.zeros_like(ratio)
        corr = ratio / (1 - loss)
        rel_se = se_mt / H_mt
        name = f"{capture:8s} {2*half*100:>2.0f}cm {'HGS ' if hgs else 'BSDF'} acc={'T' if account else 'F'}"
        print(f"\n== {name}  ({args.seeds} seeds x {spp} spp, {dt:.1f} s); "
              f"integrator scan points == pixel centres: {targets_ok}")
        print("ratio mitransient / closed form, rows = iy (0 = lowest y), cols = ix   "
              "| same, divided by (1 - predicted spawn-offset edge loss)")
        for iy in range(SCAN[1]):
            print("   " + " ".join(f"{ratio[iy, ix]:.4f}" for ix in range(SCAN[0])) + "   | "
                  + " ".join(f"{corr[iy, ix]:.4f}" for ix in range(SCAN[0])))
        tot = H_mt.sum() / H_cf.sum()
        tot_c = H_mt.sum() / (H_cf * (1 - loss)).sum()
        tse = np.sqrt((se_mt**2).sum()) / H_mt.sum()
        print(f"   total ratio {tot:.5f} (edge-corrected {tot_c:.5f}) +- {tse:.1e};  max rel stderr/point "
              f"{rel_se.max():.1e};  mean OPL mitransient - closed form: avg {dmean.mean():+.1e} m, "
              f"max |.| {np.abs(dmean).max():.1e} m (bins {BIN_W} m)")
        rows.append((name, tot, tot_c, np.abs(ratio - 1).max(), np.abs(corr - 1).max(), rel_se.max(),
                     dmean.mean()))
    print("\nsummary: case | total ratio | edge-corrected | max|r-1| | max|r_corr-1| | max rel se | avg dOPL (m)")
    for r in rows:
        print(f"  {r[0]} | {r[1]:.5f} | {r[2]:.5f} | {r[3]:.4f} | {r[4]:.4f} | {r[5]:.1e} | {r[6]:+.1e}")


if __name__ == "__main__":
    main()
