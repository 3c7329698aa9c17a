"""Ground-truth NLOS data rendered by mitransient 1.3.1, with known meshes (issue 20).

For comparing classical reconstructions (backprojection, LCT, f-k, phasor fields) with
Umbra's mesh fit on data Umbra did not make. Five hidden scenes (SCENES), each about 1 m
from a 1.6 m x 1.6 m relay wall (Mitsuba `rectangle` `relay_wall`: z = 0, normal +z, up
+y; albedo 0.8), hidden objects diffuse with albedo 0.9, front faces towards the wall:

  letter        letter_t.obj (0.5 m T) turned 30 deg about +y, centre (0, 0, 1.0)
  sphere        sphere.obj scaled to radius 0.25 m, centre (0, 0, 1.0)
  bunny         bunny_like.obj scaled 1.075 (0.5 m tall), turned 20 deg about +y, its
                bounding box centred on (0, 0, 1.0)
  two_depths    plate_flat.obj scaled to 0.3 m x 0.3 m, facing the wall, centre
                (-0.3, 0.15, 0.7); letter_t.obj scaled to 0.4 m, facing the wall, centre
                (0.3, -0.1, 1.2)
  tilted_plate  plate_flat.obj scaled to 0.4 m x 0.4 m, tilted 35 deg about +x (its top
                edge away from the wall), centre (0, 0, 0.9)

Captures: "confocal" (laser spot = scan point) and "single" (mitransient's non-confocal
capture: one laser spot at the wall centre (0, 0, 0), the scan grid as sensor points).
Laser and SPAD at (0, -0.5, 0.8), below the objects' line of sight (see fit_mitransient.py:
nothing blocks their lines to the wall). Scan: scan x scan points (pixel centres) over the
whole wall. Film (one for every scene and capture, so that the cases are comparable):
768 bins of 4 mm from OPL 1.2 m (to 4.272 m; OPL without the laser -> x_l and x_s -> SPAD
legs, account_first_and_last_bounces = false). The three-bounce signal of all scenes spans
OPL 1.40 m (two_depths' plate, confocal) to 3.92 m (two_depths' letter, confocal, from the
far wall corner); 512 bins of 4 mm (2.048 m) cannot hold that span. transient_nlos_path up
to 6 bounces, laser sampling, box bins, mitransient's own scale; hidden-geometry sampling
except for the bunny (HIDDEN_GEOMETRY_SAMPLING: mitransient's HGS over-counts
self-occluding objects by ~6 %; BSDF sampling alone there, at 4x the spp).

Per case the CLI writes OUT/SCENE-CAPTURE/: scene.xml and its meshes (the XML loads in
mitransient and in `umbra`), target.npy (the "noise-free" target: mean of two mitransient
seeds of spp/2, spp = --spp x SPP_FACTOR[scene]; (sy, sx, T) float32), target_seed1.npy,
target_seed2.npy, target_poisson.npy (Poisson counts, float32), and OUT/manifest.json over
all cases (placements and to_world matrices, film, spp, render seconds, photons, the noise
of target.npy from the two seeds, the first and last non-zero bins against the geometric
three-bounce OPL windows, Umbra's path render of the same XML against mitransient's total).

Photons: by default PHOTONS_PER_POINT = 2000 expected counts per scan point on average
(2.05e6 at 32 x 32; --photons sets the total): the brightest bin of a case then holds
107-1059 counts, the 99th percentile of the non-zero bins 67-175 (table below), i.e. a
Poisson SNR of about 10-30 at the peaks and a few counts in the tails. The Monte Carlo
noise left in target.npy (2.7-7.5 % at the peak bins) is below that Poisson noise (8-12 %
at the 99th-percentile bins) but not negligible for the bunny and the sphere.

    .venv/bin/python python/studies/gt_scenes.py --out out/gt [--scan 32] [--spp 65536]
        [--scenes letter,sphere,...] [--captures confocal,single] [--photons N]
        [--umbra-spp 1024] [--no-umbra] [--bins 768 --bin-width 0.004 --start-opl 1.2]

Measured 2026-12-03 (32 x 32, defaults; 2 mitransient threads while another 2-thread
process shared the 2 cores, so about 1.3x slower than alone: fit_mitransient.py's 65536
spp letter took 19 s alone, 25 s here). Noise of target.npy: relative RMS at the peak bins /
relative L2. Umbra: `umbra render --model path`, 1024 spp in two seeds, total against
mitransient's with its standard error. Poisson: the brightest bin / 99th percentile of the
non-zero bins, 2.05e6 photons.

  case                    spp   seconds  noise %     bins      umbra / mitransient  Poisson
  letter confocal        65536    25    2.9 / 3.2  137..607   1.0003 +- 0.0001      364 / 143
  letter single          65536    29    2.9 / 3.2  147..446   1.0005 +- 0.0000      163 /  95
  sphere confocal       131072    49    4.9 / 4.9   75..440   0.9996 +- 0.0007      288 / 164
  sphere single         131072    51    4.8 / 4.8   75..304   1.0001 +- 0.0006      175 / 111
  bunny confocal (BSDF) 262144    50    7.4 / 8.2  127..767   0.9987 +- 0.0028      333 / 175
  bunny single (BSDF)   262144    56    7.5 / 8.5  129..767   1.0001 +- 0.0031      270 / 133
  two_depths confocal    65536    25    2.9 / 3.0   49..679   0.9986 +- 0.0002     1059 / 166
  two_depths single      65536    23    2.7 / 2.8   54..514   0.9966 +- 0.0001      511 / 147
  tilted_plate confocal  65536    33    4.1 / 4.1   92..544   0.9999 +- 0.0001      190 / 109
  tilted_plate single    65536    27    3.7 / 3.8   96..383   1.0001 +- 0.0001      107 /  67

The first non-zero bin of every case is within a bin of its three-bounce minimum (the
film starts 0.2 m of OPL earlier), the last at or before the three-bounce maximum, except
the bunny's: its multi-bounce tail (self-inter-reflection and, with BSDF sampling, paths
through the wall; 0.4-0.6 % of its light after the three-bounce windows) runs past the end
of the film, with 0.07 % of the total in the last 5 % of the bins and 0.09 % beyond the end
(measured at 16 x 16). two_depths: Umbra is 0.14 % / 0.34 % below mitransient, the same
HGS over-count where rays cross the near plate and then the far letter (both front-facing).

Importable: sys.path.insert(0, "python/studies"); import gt_scenes as gt;
gt.write_scene(dest, "bunny", "confocal"), gt.render(xml, spp, dest), gt.poisson(H, n, seed),
gt.truth_meshes("bunny") (world-space vertices and faces of the known meshes).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "python", "validation"))
sys.path.insert(0, HERE)
import mtutil  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before Mitsuba loads)
import fit_mitransient as fm  # noqa: E402  (render_mitransient, noise, umbra_render, compare)

MESHES = os.path.join(ROOT, "scenes", "meshes")
UMBRA = fm.UMBRA

WALL_HALF = 0.8                  # the relay wall: 1.6 m x 1.6 m, z = 0, normal +z
WALL_ALBEDO = 0.8
ALBEDO = 0.9                     # every hidden object
LASER = (0.0, -0.5, 0.8)         # laser and SPAD
LASER_SPOT = (0.0, 0.0, 0.0)     # single capture: the laser aims at the wall centre
SCAN, BINS, BIN_WIDTH, START_OPL = 32, 768, 0.004, 1.2
SPP = 65536                      # mitransient, both seeds together (times SPP_FACTOR)
UMBRA_SPP = 1024                 # Umbra's check render, both seeds together
PHOTONS_PER_POINT = 2000
CAPTURES = ("confocal", "single")


def _obj(ident, mesh, scale=1.0, rotate=(), translate=(0.0, 0.0, 0.0)):
    """One hidden object: to_world = translate @ rotations (in order) @ scale."""
    return {"id": ident, "mesh": mesh,
            "scale": [float(x) for x in np.broadcast_to(np.asarray(scale, float), 3)],
            "rotate": [[a, float(d)] for a, d in rotate],
            "translate": [float(x) for x in translate]}


def _rotation(axis, degrees):
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(4)
    m[i, i] = m[j, j] = c
    m[i, j], m[j, i] = -s, s
    return m


def to_world(obj):
    """The object's 4x4 to_world (numpy)."""
    m = np.diag(list(obj["scale"]) + [1.0])
    for axis, deg in obj["rotate"]:
        m = _rotation(axis, deg) @ m
    t = np.eye(4)
    t[:3, 3] = obj["translate"]
    return t @ m


def _read_obj(path):
    v, f = [], []
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                v.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(x.split("/")[0]) for x in line.split()[1:]]
                f += [[idx[0] - 1, idx[k] - 1, idx[k + 1] - 1] for k in range(1, len(idx) - 1)]
    return np.array(v), np.array(f, dtype=np.int64)


def _world(v, m):
    return v @ m[:3, :3].T + m[:3, 3]


def _bunny():
    # bunny_like.obj spans y -0.13..0.335 (0.465 m): scaled 1.075 it is 0.5 m tall. Centre
    # the turned, scaled mesh's bounding box on (0, 0, 1).
    o = _obj("bunny", "bunny_like.obj", 1.075, [("y", 20.0)])
    v = _world(_read_obj(os.path.join(MESHES, o["mesh"]))[0], to_world(o))
    centre = (v.min(0) + v.max(0)) / 2
    return _obj("bunny", "bunny_like.obj", 1.075, [("y", 20.0)], np.array([0, 0, 1.0]) - centre)


# name -> hidden objects. Meshes from scenes/meshes/ (front faces along -z in object space:
# towards the wall).
SCENES = {
    "letter": [_obj("letter_t", "letter_t.obj", 1.0, [("y", 30.0)], (0.0, 0.0, 1.0))],
    "sphere": [_obj("sphere", "sphere.obj", 0.25 / 0.15, (), (0.0, 0.0, 1.0))],
    "bunny": [_bunny()],
    "two_depths": [
        _obj("plate_near", "plate_flat.obj", (0.3 / 0.6, 0.3 / 0.5, 1.0), (), (-0.3, 0.15, 0.7)),
        _obj("letter_far", "letter_t.obj", (0.8, 0.8, 1.0), (), (0.3, -0.1, 1.2))],
    "tilted_plate": [_obj("plate", "plate_flat.obj", (0.4 / 0.6, 0.4 / 0.5, 1.0),
                          [("x", 35.0)], (0.0, 0.0, 0.9))],
}


# mitransient's hidden-geometry sampling counts a direction once per front-facing hidden
# surface it crosses (notes/mitransient.md, path space 7): unbiased for convex objects, planar
# letters and plates, biased for the self-occluding bunny (measured at 16 x 16: HGS total
# 1.055x / 1.063x that of mitransient's own BSDF sampling and of Umbra, confocal / single).
# So the bunny is rendered with BSDF sampling alone (unbiased; at 16 x 16 about 5x the
# variance per sample, 2.5x cheaper samples), at 4x the spp; the sphere (HGS wastes its
# back half) at 2x.
HIDDEN_GEOMETRY_SAMPLING = {name: name != "bunny" for name in SCENES}
SPP_FACTOR = {name: {"bunny": 4, "sphere": 2}.get(name, 1) for name in SCENES}


def truth_meshes(name):
    """[(id, world vertices (V, 3), faces (F, 3))] of the scene's known meshes."""
    out = []
    for o in SCENES[name]:
        v, f = _read_obj(os.path.join(MESHES, o["mesh"]))
        out.append((o["id"], _world(v, to_world(o)), f))
    return out


def scan_points(scan):
    """(scan, scan, 3) scan points x_s[iy, ix] (mitransient: pixel centres of the wall)."""
    c = ((np.arange(scan) + 0.5) / scan * 2 - 1) * WALL_HALF
    xx, yy = np.meshgrid(c, c)
    return np.stack([xx, yy, np.zeros_like(xx)], -1)


def opl_windows(name, capture, scan, points=8000, seed=0):
    """Three-bounce OPL bounds per object and scan point, (n_objects, scan, scan, 2): min and
    max of |x_l - x| + |x - x_s| over points x of the object (its vertices and about
    `points` random points on its triangles) that face both x_l and x_s (visibility
    ignored: an envelope of the signal; inf / -inf where no point qualifies)."""
    rng = np.random.default_rng(seed)
    xs = scan_points(scan).reshape(-1, 3)
    out = []
    for _, v, f in truth_meshes(name):
        tri = v[f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        k = max(1, points // len(f))
        b = np.concatenate([np.broadcast_to(np.eye(3), (len(f), 3, 3)),
                            rng.dirichlet([1.0, 1.0, 1.0], size=(len(f), k))], 1)
        p = np.einsum("fkj,fjd->fkd", b, tri).reshape(-1, 3)
        nn = np.repeat(n, k + 3, axis=0)
        lo = np.full(len(xs), np.inf)
        hi = np.full(len(xs), -np.inf)
        for i in range(0, len(xs), 32):
            s = xs[i:i + 32, None]                               # (S, 1, 3)
            xl = s if capture == "confocal" else np.asarray(LASER_SPOT, float)[None, None]
            ds, dl = s - p[None], xl - p[None]
            front = ((ds * nn).sum(-1) > 0) & ((dl * nn).sum(-1) > 0)
            opl = np.linalg.norm(ds, axis=-1) + np.linalg.norm(dl, axis=-1)
            lo[i:i + 32] = np.where(front, opl, np.inf).min(-1)
            hi[i:i + 32] = np.where(front, opl, -np.inf).max(-1)
        out.append(np.stack([lo, hi], -1).reshape(scan, scan, 2))
    return np.array(out)


_rgb = mtutil.rgb


def scene_dict(name, capture, scan=SCAN, bins=BINS, bin_width=BIN_WIDTH, start_opl=START_OPL,
               spp=SPP // 2, hgs=None):
    """The case as a Mitsuba load_dict-style dict (the vocabulary of umbra.dict_to_xml).
    hgs: mitransient's hidden-geometry sampling (default HIDDEN_GEOMETRY_SAMPLING[name])."""
    hgs = HIDDEN_GEOMETRY_SAMPLING[name] if hgs is None else bool(hgs)
    if capture not in CAPTURES:
        raise ValueError(f"capture {capture!r}: one of {CAPTURES}")
    laser = [float(x) for x in LASER]
    target = [0.0, 0.0, 0.0] if capture == "confocal" else [float(x) for x in LASER_SPOT]
    scene = {"type": "scene", "integrator": mtutil.nlos_integrator(capture, hgs),
             "laser": mtutil.projector(laser, target)}
    for o in SCENES[name]:
        scene[o["id"]] = {"type": "obj", "filename": o["mesh"], "face_normals": True,
                          "to_world": to_world(o),
                          "bsdf": {"type": "diffuse", "reflectance": _rgb(ALBEDO)}}
    scene["relay_wall"] = mtutil.relay_wall(WALL_HALF, WALL_ALBEDO, laser, scan, bins, bin_width,
                                            start_opl, spp)
    return scene


def dict_to_xml(scene):
    import umbra
    return umbra.dict_to_xml(scene)


def write_scene(dest, name, capture, scan=SCAN, bins=BINS, bin_width=BIN_WIDTH,
                start_opl=START_OPL, spp=SPP // 2, hgs=None):
    """Writes dest/scene.xml (and the meshes it names beside it); returns the XML's path.
    spp: the XML's sample count (the renders here override it)."""
    scene = scene_dict(name, capture, scan, bins, bin_width, start_opl, spp, hgs)
    os.makedirs(dest, exist_ok=True)
    for o in SCENES[name]:
        shutil.copyfile(os.path.join(MESHES, o["mesh"]), os.path.join(dest, o["mesh"]))
    path = os.path.join(dest, "scene.xml")
    with open(path, "w") as f:
        f.write(dict_to_xml(scene))
    return path


def render(xml, spp, dest, seeds=(1, 2), threads=2):
    """mitransient: two renders of spp/2 (seeds), their mean saved as dest/target.npy and
    both as target_seed1/2.npy; returns (mean, render 1, render 2, seconds)."""
    return fm.render_mitransient(xml, spp, dest, threads=threads, seeds=seeds)


def poisson(H, photons, seed):
    """Photon counts: H scaled so that its sum is `photons` expected counts, then Poisson
    draws (numpy default_rng(seed)); float32, integer values."""
    H = np.asarray(H, dtype=np.float64)
    lam = np.clip(H, 0.0, None) * (photons / H.sum())
    return np.random.default_rng(seed).poisson(lam).astype(np.float32)


def signal_span(H, start_opl=START_OPL, bin_width=BIN_WIDTH):
    """First and last bins with any non-zero value (over all scan points), and their OPL
    (the first bin's start, the last bin's end)."""
    nz = np.flatnonzero((np.asarray(H) != 0).any(axis=tuple(range(H.ndim - 1))))
    first, last = int(nz[0]), int(nz[-1])
    return {"first_bin": first, "last_bin": last,
            "first_opl": start_opl + first * bin_width,
            "last_opl": start_opl + (last + 1) * bin_width}


def window_energy(H, windows, start_opl=START_OPL, bin_width=BIN_WIDTH, margin=0.02):
    """Where H's light is against the objects' three-bounce windows (opl_windows), widened
    by `margin` m of OPL, per scan point; fractions of H's total:
    early: before every window (no path can arrive earlier: ~0 up to sampling of the
    windows); late: outside the windows otherwise (multi-bounce light: self-inter-
    reflection, with BSDF sampling also paths through the wall); exclusive[k]: in the bins
    of object k's window that no other object's window covers (> 0: that object is seen)."""
    T = H.shape[-1]
    t = start_opl + (np.arange(T) + 0.5) * bin_width
    inside = (t >= windows[..., :1] - margin) & (t <= windows[..., 1:] + margin)  # (n, sy, sx, T)
    early = t < windows[..., :1].min(0) - margin                                  # (sy, sx, T)
    total = H.astype(np.float64).sum()
    out = {"early": float(H[early].sum() / total),
           "late": float(H[~inside.any(0) & ~early].sum() / total), "exclusive": []}
    for k in range(len(windows)):
        only = inside[k] & ~np.delete(inside, k, 0).any(0)
        out["exclusive"].append(float(H[only].sum() / total))
    return out


def case_dir(out, name, capture):
    return os.path.join(out, f"{name}-{capture}")


def run_case(out, name, capture, scan=SCAN, spp=SPP, bins=BINS, bin_width=BIN_WIDTH,
             start_opl=START_OPL, photons=None, poisson_seed=0, umbra_spp=UMBRA_SPP,
             umbra=UMBRA, threads=2, log=print):
    """Writes, renders and checks one case; returns its manifest entry. spp: the base
    mitransient spp (times SPP_FACTOR[name], in two seeds)."""
    dest = case_dir(out, name, capture)
    spp = int(spp * SPP_FACTOR[name])
    xml = write_scene(dest, name, capture, scan, bins, bin_width, start_opl, spp // 2)
    H, H1, H2, seconds = render(xml, spp, dest, threads=threads)
    n = fm.noise(H1, H2)
    photons = int(photons if photons else PHOTONS_PER_POINT * scan * scan)
    P = poisson(H, photons, poisson_seed)
    np.save(os.path.join(dest, "target_poisson.npy"), P)
    span = signal_span(H, start_opl, bin_width)
    win = opl_windows(name, capture, scan)
    energy = window_energy(H, win, start_opl, bin_width)
    entry = {
        "scene": name, "capture": capture, "dir": os.path.relpath(dest, out),
        "objects": [{**o, "to_world": to_world(o).tolist()} for o in SCENES[name]],
        "scan": scan, "wall_size_m": 2 * WALL_HALF, "bins": bins, "bin_width_opl": bin_width,
        "start_opl": start_opl, "end_opl": start_opl + bins * bin_width,
        "laser_origin": list(LASER),
        "laser_spot": "scan point" if capture == "confocal" else list(LASER_SPOT),
        "hidden_geometry_sampling": HIDDEN_GEOMETRY_SAMPLING[name],
        "spp": spp, "seeds": [1, 2], "render_seconds": round(seconds, 2),
        "noise_peak": float(n["peak"]), "noise_l2": float(n["l2"]),
        "total": float(H.astype(np.float64).sum()),
        "photons": photons, "poisson_seed": poisson_seed,
        "poisson_peak_counts": float(P.max()),
        "poisson_p99_counts": float(np.percentile(P[P > 0], 99)),
        **span,
        "three_bounce_opl": [float(win[..., 0].min()), float(win[..., 1].max())],
        "object_opl": {o["id"]: [float(w[..., 0].min()), float(w[..., 1].max())]
                       for o, w in zip(SCENES[name], win)},
        "energy_before_windows": energy["early"],
        "energy_after_windows": energy["late"],
        "energy_last_5pc_bins": float(H[..., int(0.95 * bins):].sum() / H.sum()),
        "energy_exclusive": dict(zip([o["id"] for o in SCENES[name]], energy["exclusive"])),
    }
    log(f"{name}-{capture}: {spp} spp in {seconds:.1f} s, noise {100 * n['peak']:.2f} % at the "
        f"peaks, L2 {100 * n['l2']:.2f} %; signal bins {span['first_bin']}..{span['last_bin']} "
        f"of {bins} (OPL {span['first_opl']:.3f}..{span['last_opl']:.3f}, three-bounce "
        f"{entry['three_bounce_opl'][0]:.3f}..{entry['three_bounce_opl'][1]:.3f}); Poisson "
        f"{photons} photons, peak {P.max():.0f} counts")
    if umbra_spp:
        t0 = time.time()
        U = [fm.umbra_render(xml, max(umbra_spp // 2, 1), s,
                             os.path.join(dest, f"umbra_seed{s}.npy"), umbra=umbra)
             for s in (1, 2)]
        chk = fm.compare(H1, H2, *U)
        entry["umbra_check"] = {"spp": umbra_spp, "seconds": round(time.time() - t0, 2),
                                **{k: float(v) for k, v in chk.items()}}
        for s in (1, 2):
            os.remove(os.path.join(dest, f"umbra_seed{s}.npy"))
        log("  umbra path / mitransient: total {ratio:.4f} +- {ratio_se:.4f}, relative L2 "
            "{l2:.4f} (noise alone {l2_noise:.4f})".format(**chk))
    return entry


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "gt"))
    ap.add_argument("--scan", type=int, default=SCAN)
    ap.add_argument("--spp", type=int, default=SPP, help="mitransient spp (two seeds of spp/2)")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--captures", default=",".join(CAPTURES))
    ap.add_argument("--bins", type=int, default=BINS)
    ap.add_argument("--bin-width", type=float, default=BIN_WIDTH)
    ap.add_argument("--start-opl", type=float, default=START_OPL)
    ap.add_argument("--photons", type=float, default=0,
                    help=f"expected counts in all (default {PHOTONS_PER_POINT} x scan points)")
    ap.add_argument("--poisson-seed", type=int, default=0)
    ap.add_argument("--umbra-spp", type=int, default=UMBRA_SPP,
                    help="Umbra path check render (two seeds); 0 or --no-umbra skips it")
    ap.add_argument("--no-umbra", action="store_true")
    ap.add_argument("--umbra", default=UMBRA, help="the Umbra CLI (default $UMBRA_BIN or "
                    "target/release/umbra)")
    ap.add_argument("--threads", type=int, default=2, help="mitransient threads")
    a = ap.parse_args(argv)
    scenes = [s for s in a.scenes.split(",") if s]
    captures = [c for c in a.captures.split(",") if c]
    for s in scenes:
        if s not in SCENES:
            ap.error(f"unknown scene {s!r}: {', '.join(SCENES)}")
    for c in captures:
        if c not in CAPTURES:
            ap.error(f"unknown capture {c!r}: {', '.join(CAPTURES)}")
    os.makedirs(a.out, exist_ok=True)
    mitsuba, mitransient = mtutil.setup(a.threads)
    import drjit
    cases = []
    for name in scenes:
        for capture in captures:
            cases.append(run_case(a.out, name, capture, a.scan, a.spp, a.bins, a.bin_width,
                                  a.start_opl, a.photons, a.poisson_seed,
                                  0 if a.no_umbra else a.umbra_spp, umbra=a.umbra,
                                  threads=a.threads,
                                  log=lambda s: print(s, flush=True)))
            manifest = {
                "generator": "python/studies/gt_scenes.py",
                "renderer": {"mitransient": mitransient.__version__, "mitsuba": mitsuba.__version__,
                             "drjit": drjit.__version__, "variant": "llvm_ad_mono",
                             "integrator": "transient_nlos_path", "max_depth": 6,
                             "threads": a.threads, "machine": platform.machine()},
                "layout": "(sy, sx, T) float32; iy = wall y, ix = wall x; x_s at pixel centres",
                "albedo": ALBEDO, "wall_albedo": WALL_ALBEDO,
                "photons_per_point_default": PHOTONS_PER_POINT,
                "noise": "noise_peak / noise_l2: relative RMS of target.npy (mean of the two "
                         "seeds) over bins >= half their scan point's peak / relative L2, "
                         "from the seeds' difference (fit_mitransient.noise)",
                "cases": cases,
            }
            with open(os.path.join(a.out, "manifest.json"), "w") as f:
                json.dump(manifest, f, indent=1)
    print(f"wrote {os.path.join(a.out, 'manifest.json')} ({len(cases)} cases)")


if __name__ == "__main__":
    main()
