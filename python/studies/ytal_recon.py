"""Run y-tal 0.20.0's classical NLOS reconstructions on a capture and write the volume on a
voxel grid we choose (issue 20: baselines on the same data as Umbra's fit).

    .venv-ytal/bin/python python/studies/ytal_recon.py CAPTURE.hdf5 GRID.json METHOD OUT.npy \
        [--json TIMING.json] [method options]

CAPTURE.hdf5  a y-tal capture (`umbra render ... -o X.hdf5` writes one).
GRID.json     {"min": [x, y, z], "max": [x, y, z], "dims": [nx, ny, nz]} in y-tal's world
              frame (relay wall centred at the origin in the plane z = 0, normal +z toward
              the hidden scene, up +y). Voxel (ix, iy, iz) has its centre at
              min + (i + 0.5) * (max - min) / dims on each axis.
METHOD        bp      backprojection (tal.reconstruct.bp), any capture type;
              fbp     filtered backprojection (tal.reconstruct.fbp: phasor-field band-pass
                      filter on H, then bp), any capture type;
              fk      f-k migration (tal.reconstruct.fk), confocal only;
              pf      phasor fields with RSD propagation (tal.reconstruct.pf), confocal or
                      single;
              pf_dev  phasor fields (tal.reconstruct.pf_dev), single or exhaustive only.
OUT.npy       float32 (ny, nx, nz), depth fastest: the reconstruction at the voxel centres,
              |.| for complex results (fbp, pf, pf_dev), as is for real ones (bp, fk).

y-tal 0.20.0 needs help on some paths; everything done is listed under "workarounds" in
TIMING.json (notes/ytal-recon.md has the details):
- fk ignores t_start and t_accounts_first_and_last_bounces, and reconstructs on its own grid
  (x, y of the scan points, depth k * delta_t / 2 for sample k of a time axis starting at
  OPL 0): H is first re-timed so that bin k starts at OPL k * delta_t of the hidden path, fk
  gets a copy of the sensor grid centred at x = y = 0 (it reads the aperture's half width
  from the last point's x), and its volume is resampled trilinearly onto ours. fk has no
  anti-aliasing: on bins much finer than the scan pitch, a tilted surface's arrivals alias
  laterally and it lands beside itself (0.5 m off for a letter turned 30 degrees, 4 mm bins,
  5 cm pitch), so H is summed over bins to at least half the pitch (--fk-time-bin).
- pf pads H by t_start but then reconstructs from the unpadded data, ignores
  t_accounts_first_and_last_bounces, imports pyfftw (which it never uses and y-tal does not
  install), and only its planar (convolution) path works: the volume must have the sensor
  grid's x, y (its point-by-point RSD path crashes for confocal data and sums the wrong axes
  for single captures). So H is re-timed, a stand-in pyfftw module is installed if the real one
  is missing, and pf reconstructs on the sensor grid's x, y at our depths; the result is
  resampled bilinearly onto our x, y (exact when they coincide).
- pf_dev crashes unless `nt` is passed (it reads `nt` instead of its own `nt_`), crashes when
  t_start != 0 or the first/last legs are in H without compensate_invsq (`invsq_14` is the int
  1), and its convolution path crashes on volumes of several depths: so nt is passed, H is
  re-timed, and it is called once per depth slice when the grid's x, y spacing is the sensor
  grid's (its convolution path), else once on the whole volume with
  try_optimize_convolutions=False (point by point: slow, ~45 s for 32 x 32 x 80 voxels and
  256 scan points; --pf-dev-lateral sensor evaluates on the scan points' x, y and resamples).
- bp and fbp handle t_start and the first/last legs themselves. fbp's filter (filter_H) leads
  by half a bin when H has an even number of bins: one empty bin is appended to make it odd
  (--keep-filter-shift leaves it).
- Time of a bin: Umbra's (and mitransient's) bin b holds OPL [t_start + b dt, t_start +
  (b+1) dt). bp indexes bins that way (floor); fk, pf and pf_dev take sample b at
  t_start + b dt, which puts depths dt/4 short in confocal captures. By default
  (--bin-time centre) their input is read at the middle of each bin (fk: its output depths
  are (k + 0.5) dt / 2; pf, pf_dev: H delayed by half a bin).

Errors (wrong capture type for a method, bad grid, ...) exit with status 2 and a message
naming the method and the reason.
"""
from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
import types
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ytal_data import (ReconError, ascending, capture_type, grid_axes, read_grid,  # noqa: E402
                       resample, retime, time_bin, volume_xyz, wall_axes)

METHODS = ("bp", "fbp", "fk", "pf", "pf_dev")
SUPPORTED = {   # capture types each method accepts
    "bp": ("confocal", "single", "exhaustive"),
    "fbp": ("confocal", "single", "exhaustive"),
    "fk": ("confocal",),
    "pf": ("confocal", "single"),
    "pf_dev": ("single", "exhaustive"),
}
CAMERA_SYSTEMS = ("DIRECT_LIGHT", "TRANSIENT_T0")


def ensure_pyfftw(notes: list) -> None:
    """tal.reconstruct.pf.propagator imports pyfftw and never uses it; y-tal 0.20.0 does not
    depend on it. Install a stand-in if it is missing."""
    try:
        import pyfftw  # noqa: F401
    except ImportError:
        m = types.ModuleType("pyfftw")
        m.interfaces = types.ModuleType("pyfftw.interfaces")
        m.interfaces.numpy_fft = types.ModuleType("pyfftw.interfaces.numpy_fft")
        sys.modules.update({"pyfftw": m, "pyfftw.interfaces": m.interfaces,
                            "pyfftw.interfaces.numpy_fft": m.interfaces.numpy_fft})
        notes.append("pyfftw not installed: a stand-in module was put in sys.modules "
                     "(tal.reconstruct.pf imports it but never calls it)")


# --------------------------------------------------------------------------- methods

def camera(name: str):
    from tal.enums import CameraSystem
    return CameraSystem[name]


def default_wavelength(data) -> float:
    """2 x the largest spacing of neighbouring scan points (the shortest phasor-field
    wavelength the wall's sampling carries without aliasing)."""
    from tal.enums import GridFormat
    g = np.asarray(data.sensor_grid_xyz, dtype=np.float64)
    if data.sensor_grid_format == GridFormat.X_Y_3 and g.ndim == 3:
        steps = []
        if g.shape[0] > 1:
            steps.append(np.linalg.norm(g[1, 0] - g[0, 0]))
        if g.shape[1] > 1:
            steps.append(np.linalg.norm(g[0, 1] - g[0, 0]))
        if steps:
            return 2.0 * float(max(steps))
    p = g.reshape(-1, 3)
    if len(p) > 1:
        d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(len(p)) * 1e9
        return 2.0 * float(d.min(axis=1).max())
    raise ReconError("cannot infer a wavelength from a single scan point: pass --wl-mean")


def run_bp(data, axes, args, opts, notes):
    import tal
    V = volume_xyz(*axes)
    opts.update(camera_system=args.camera_system, compensate_invsq=args.compensate_invsq)
    t = time.perf_counter()
    R = tal.reconstruct.bp.solve(data, volume_xyz=V, camera_system=camera(args.camera_system),
                                 compensate_invsq=args.compensate_invsq, progress=False)
    return R, time.perf_counter() - t


def run_fbp(data, axes, args, opts, notes):
    import tal
    V = volume_xyz(*axes)
    wl = args.wl_mean or default_wavelength(data)
    sigma = args.wl_sigma or wl / math.sqrt(2)
    if data.H.shape[0] % 2 == 0 and not args.keep_filter_shift:
        # filter_H's kernel (np.fft.ifftshift of a Gaussian centred at (n - 1) / 2, n of the
        # parity of T) is centred half a bin early when n is even, on time when it is odd:
        # the filtered H would lead by half a bin. One empty bin at the end makes T odd.
        H = np.asarray(data.H)
        data.H = np.concatenate([H, np.zeros((1,) + H.shape[1:], dtype=H.dtype)])
        notes.append(f"fbp: one empty bin appended to H ({H.shape[0]} -> {H.shape[0] + 1} "
                     "bins): filter_H's kernel leads by half a bin on an even number")
    opts.update(camera_system=args.camera_system, compensate_invsq=args.compensate_invsq,
                wl_mean=wl, wl_sigma=sigma, border=args.border,
                keep_filter_shift=args.keep_filter_shift)
    t = time.perf_counter()
    R = tal.reconstruct.fbp.solve(data, wl_mean=wl, wl_sigma=sigma, border=args.border,
                                  volume_xyz=V, camera_system=camera(args.camera_system),
                                  compensate_invsq=args.compensate_invsq, progress=False)
    return R, time.perf_counter() - t


def run_pf_dev(data, axes, args, opts, notes):
    import tal
    wl = args.wl_mean or default_wavelength(data)
    sigma = args.wl_sigma or wl / math.sqrt(2)
    xs, ys, zs = axes
    if args.pf_dev_lateral == "sensor":
        xs, ys = wall_axes(data, "pf_dev")
    # pf_dev's kernel (np.fft.fftshift of a Gaussian centred at (nf - 1) / 2, nf of the parity
    # of T) is centred half a bin early for an even number of bins, a whole bin for an odd
    # one: choose the parity that keeps the re-timing a whole number of bins, and delay H by
    # the lead to undo it.
    centre = args.bin_time == "centre"
    if args.keep_filter_shift:
        retime(data, notes, centre=centre)
    else:
        retime(data, notes, centre=centre, delay=0.5 if centre else 1.0,
               parity="even" if centre else "odd")
    # Its convolution path (fast) runs one depth at a time and needs the volume's x, y spacing
    # to be the sensor grid's; else the point-by-point path on the whole volume.
    try:
        sx, sy = wall_axes(data, "pf_dev")
        conv = (len(xs) > 1 and len(ys) > 1 and np.isclose(xs[1] - xs[0], sx[1] - sx[0])
                and np.isclose(ys[1] - ys[0], sy[1] - sy[0]))
    except ReconError:
        conv = False
    common = dict(wl_mean=wl, wl_sigma=sigma, border="zero",
                  camera_system=camera(args.camera_system),
                  compensate_invsq=args.compensate_invsq, progress=False, nt=data.H.shape[0])
    opts.update(camera_system=args.camera_system, compensate_invsq=args.compensate_invsq,
                bin_time=args.bin_time, keep_filter_shift=args.keep_filter_shift,
                wl_mean=wl, wl_sigma=sigma, border="zero", nt=int(data.H.shape[0]),
                lateral=args.pf_dev_lateral,
                path="one depth slice per call, convolutions" if conv
                else "whole volume, point by point (try_optimize_convolutions=False)")
    t = time.perf_counter()
    if conv:
        R = np.stack([tal.reconstruct.pf_dev.solve(
            data, volume_xyz=volume_xyz(xs, ys, [z])[:, :, 0, :],
            try_optimize_convolutions=True, **common) for z in zs], axis=-1)
        notes.append("pf_dev: nt passed explicitly (0.20.0 crashes without it); called once "
                     "per depth slice (its convolution path crashes on volumes of several "
                     "depths)")
    else:
        R = tal.reconstruct.pf_dev.solve(data, volume_xyz=volume_xyz(xs, ys, zs),
                                         try_optimize_convolutions=False, **common)
        notes.append("pf_dev: nt passed explicitly (0.20.0 crashes without it) and "
                     "try_optimize_convolutions=False (its convolution path crashes on volumes "
                     "of several depths, and needs the sensor grid's spacing)")
    secs = time.perf_counter() - t
    R = np.asarray(R).reshape(len(xs), len(ys), len(zs))
    if args.pf_dev_lateral == "sensor":
        R = resample(np.abs(R), (xs, ys, zs), axes, clamp_lateral=True)
        notes.append("pf_dev reconstructed on the sensor grid's x, y, resampled bilinearly "
                     "onto ours (--pf-dev-lateral sensor)")
    return R, secs


def run_pf(data, axes, args, opts, notes):
    import tal
    ensure_pyfftw(notes)
    sx, sy = wall_axes(data, "pf")
    wl = args.wl_mean or default_wavelength(data)
    retime(data, notes, centre=args.bin_time == "centre")
    # pf's planar RSD path needs the volume's x, y to be the sensor grid's.
    V = volume_xyz(sx, sy, axes[2])
    same = (len(sx) == len(axes[0]) and len(sy) == len(axes[1])
            and np.allclose(sx, axes[0], atol=1e-6) and np.allclose(sy, axes[1], atol=1e-6))
    if not same:
        notes.append(f"pf reconstructed on the sensor grid's x, y ({len(sx)} x {len(sy)}) at "
                     "our depths, then resampled bilinearly onto our x, y")
    opts.update(bin_time=args.bin_time)
    opts.update(camera_system=args.camera_system, c_wavelength=wl, wave_cycles=args.cycles,
                volume="sensor grid x, y at the grid's depths")
    t = time.perf_counter()
    R = tal.reconstruct.pf.solve(data, wl, args.cycles, camera_system=camera(args.camera_system),
                                 volume=V)
    secs = time.perf_counter() - t
    R = np.asarray(R)
    if R.shape != V.shape[:-1]:
        raise ReconError(f"pf returned shape {R.shape}, expected {V.shape[:-1]}")
    if not same:
        R = resample(np.abs(R), (sx, sy, axes[2]), axes, clamp_lateral=True)
    return R, secs


FK_BIN_PER_PITCH = 0.5   # fk's OPL bin, at least this many scan pitches (--fk-time-bin auto)


def fk_time_bin(choice: str, pitch: float, dt: float) -> int:
    """How many bins fk's input is summed over. f-k migration is a Fourier method: the
    arrival from a surface tilted by theta changes by about 2 sin(theta) pitch of OPL from one
    scan point to the next, and where that exceeds a bin, it aliases laterally: the migrated
    surface lands where the data are brightest, beside the surface (a letter turned 30
    degrees lands 0.5 m off at 4 mm bins and 5 cm pitch; a surface facing the wall is
    unharmed). y-tal's fk has no anti-aliasing of its own. "auto" sums bins to at least
    FK_BIN_PER_PITCH of the pitch, alias-free up to theta = 14.5 degrees and, past that,
    degrading gradually (notes/ytal-recon.md has the sweep); an integer is used as it is
    (1: fk on the capture's own bins)."""
    if choice == "auto":
        return max(1, int(math.ceil(FK_BIN_PER_PITCH * pitch / dt - 1e-6)))
    try:
        k = int(choice)
    except ValueError:
        k = 0
    if k < 1:
        raise ReconError(f"--fk-time-bin must be auto or a positive integer, got {choice!r}")
    return k


def run_fk(data, axes, args, opts, notes):
    import tal
    data = ascending(data, notes)
    sx, sy = wall_axes(data, "fk")
    nx, ny = len(sx), len(sy)
    if nx != ny:
        raise ReconError(f"fk needs a square scan grid (y-tal uses Sx for both axes), got "
                         f"{nx} x {ny}")
    px, py = sx[1] - sx[0], sy[1] - sy[0]
    if not np.isclose(px, py, rtol=1e-4):
        raise ReconError(f"fk needs equal scan spacing in x and y, got {px:g} and {py:g}")
    retime(data, notes, max_opl=args.fk_max_opl)
    k = fk_time_bin(args.fk_time_bin, px, float(data.delta_t))
    time_bin(data, k, notes)
    offset = 0.5 if args.bin_time == "centre" else 0.0   # sample k's time: (k + offset) * dt
    M, N = data.H.shape[0], nx
    gb = 8 * M * N * N * 100 / 2**30
    if gb > args.fk_max_gb:
        raise ReconError(f"fk would need about {gb:.1f} GiB for {M} bins x {N} x {N} "
                         f"(limit --fk-max-gb {args.fk_max_gb:g}); cut the time axis with "
                         "--fk-max-opl")
    # y-tal's fk takes the aperture's half width as sensor_grid_xyz[-1, -1, 0], which is
    # only meaningful for a grid centred at x = 0: hand it a centred copy of the grid.
    d = copy.copy(data)
    cx, cy = 0.5 * (sx[0] + sx[-1]), 0.5 * (sy[0] + sy[-1])
    centred = np.asarray(data.sensor_grid_xyz, dtype=np.float64) - [cx, cy, 0.0]
    if args.fk_width == "aperture":
        # make sensor_grid_xyz[-1, -1, 0] the true half width N * pitch / 2
        centred = centred * (N / (N - 1))
    d.sensor_grid_xyz = centred
    d.laser_grid_xyz = centred.copy()
    if not (abs(cx) < 1e-6 and abs(cy) < 1e-6):
        notes.append(f"fk given a copy of the sensor grid centred at x = y = 0 (it was centred "
                     f"at {cx:g}, {cy:g}; fk reads the aperture half width from its last x)")
    opts.update(bin_time=args.bin_time, fk_width=args.fk_width, fk_max_opl=args.fk_max_opl,
                fk_time_bin=k,
                half_width_used=float(d.sensor_grid_xyz[-1, -1, 0]),
                depth_of_sample_k=f"(k + {offset:g}) * delta_t / 2")
    t = time.perf_counter()
    R = np.asarray(tal.reconstruct.fk.solve(d))        # (T, Sx, Sy)
    secs = time.perf_counter() - t
    if R.shape != (M, N, N):
        raise ReconError(f"fk returned shape {R.shape}, expected {(M, N, N)}")
    zs = (np.arange(M) + offset) * float(data.delta_t) / 2.0
    notes.append(f"fk's volume ({N} x {N} x {M}, depth (k + {offset:g}) * "
                 f"{float(data.delta_t) / 2:g} m) resampled trilinearly onto the grid")
    return resample(np.moveaxis(R, 0, -1), (sx, sy, zs), axes, clamp_lateral=True), secs


RUNNERS = {"bp": run_bp, "fbp": run_fbp, "fk": run_fk, "pf": run_pf, "pf_dev": run_pf_dev}


# --------------------------------------------------------------------------- main

def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("capture", help="y-tal HDF5 capture")
    p.add_argument("grid", help='GRID.json: {"min": [x,y,z], "max": [x,y,z], "dims": [nx,ny,nz]}')
    p.add_argument("method", choices=METHODS)
    p.add_argument("out", help="OUT.npy: float32 (ny, nx, nz)")
    p.add_argument("--json", dest="timing", help="write timing, version and options here")
    p.add_argument("--camera-system", choices=CAMERA_SYSTEMS, default="DIRECT_LIGHT",
                   help="y-tal CameraSystem for bp, fbp, pf, pf_dev (default DIRECT_LIGHT: "
                        "the confocal virtual camera at t = 0, which accounts for the "
                        "laser-spot leg; TRANSIENT_T0 drops it)")
    p.add_argument("--compensate-invsq", action="store_true",
                   help="bp, fbp, pf_dev: compensate the 1/d^2 falloffs")
    p.add_argument("--wl-mean", type=float, default=None,
                   help="fbp, pf_dev: central wavelength of the phasor-field filter; pf: its "
                        "c_wavelength (m, default 2 x the scan spacing)")
    p.add_argument("--wl-sigma", type=float, default=None,
                   help="fbp, pf_dev: the filter's standard deviation (m, default "
                        "wl_mean / sqrt(2), y-tal's own default)")
    p.add_argument("--border", choices=("zero", "edge", "erase"), default="zero",
                   help="fbp: border handling of the temporal filter (default zero)")
    p.add_argument("--cycles", type=float, default=4.0,
                   help="pf: wave_cycles of the virtual pulse (default 4, as y-tal's examples)")
    p.add_argument("--fk-width", choices=("ytal", "aperture"), default="ytal",
                   help="fk: aperture half width in the Stolt mapping: y-tal's own (the last "
                        "scan point's x, (N-1)/2 spacings) or the aperture's (N/2 spacings)")
    p.add_argument("--bin-time", choices=("centre", "start"), default="centre",
                   help="fk, pf, pf_dev: the time of bin b: the middle of its OPL interval "
                        "[t_start + b dt, t_start + (b+1) dt) (centre, default: Umbra's and "
                        "mitransient's histograms are intervals) or its start (y-tal's own "
                        "reading in fk, pf and pf_dev, which puts depths dt/4 short in "
                        "confocal captures). bp and fbp index bins as intervals (floor) "
                        "either way")
    p.add_argument("--pf-dev-lateral", choices=("grid", "sensor"), default="grid",
                   help="pf_dev: evaluate at our voxels (grid, default) or on the sensor "
                        "grid's x, y resampled bilinearly onto ours (sensor: fast, since it "
                        "allows pf_dev's convolution path)")
    p.add_argument("--fk-time-bin", default="auto",
                   help="fk: sum this many bins before migrating (auto, default: bins of at "
                        "least half the scan pitch in OPL, against lateral aliasing)")
    p.add_argument("--fk-max-opl", type=float, default=None,
                   help="fk: drop bins past this OPL (m) before migrating (memory)")
    p.add_argument("--fk-max-gb", type=float, default=8.0,
                   help="fk: refuse to run past this estimated memory (GiB, default 8)")
    p.add_argument("--keep-filter-shift", action="store_true",
                   help="fbp, pf_dev: leave y-tal's filter kernels as they are (fbp's leads by "
                        "half a bin on an even number of bins, pf_dev's by half a bin or one)")
    p.add_argument("--cpu-processes", type=int, default=1,
                   help="y-tal's tal.set_resources(cpu_processes=...) (default 1)")
    p.add_argument("--downscale", type=int, default=None,
                   help="bp, fbp, pf_dev: y-tal's tal.set_resources(downscale=...): process the "
                        "data in this many chunks to save memory (not passed to pf, where "
                        "it would downsample the scan grid)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    method = args.method
    try:
        import tal
        import tal.log
        from tal.io import read_capture
    except ImportError as e:
        print(f"ytal_recon: {method}: cannot import y-tal ({e}); run this with the "
              ".venv-ytal interpreter", file=sys.stderr)
        return 2
    tal.log._log_level = tal.log.LogLevel.WARNING    # (tal.set_log_level writes ~/.tal.conf)
    warnings.filterwarnings("ignore", message="Detected confocal capture")   # pf, harmless
    try:
        grid = read_grid(args.grid)
        axes = grid_axes(grid)
        try:
            data = read_capture(args.capture)
        except Exception as e:   # noqa: BLE001 - h5py / y-tal raise many kinds
            raise ReconError(f"cannot read capture {args.capture}: {type(e).__name__}: {e}")
        kind = capture_type(data)
        if kind not in SUPPORTED[method]:
            raise ReconError(f"{method} does not support {kind} captures in y-tal 0.20.0 "
                             f"(it supports: {', '.join(SUPPORTED[method])})")
        info = {
            "capture_type": kind,
            "H_shape": list(np.shape(data.H)),
            "delta_t": float(data.delta_t),
            "t_start": float(data.t_start or 0.0),
            "t_accounts_first_and_last_bounces": bool(data.t_accounts_first_and_last_bounces),
        }
        resources = dict(cpu_processes=args.cpu_processes,
                         downscale=None if method == "pf" else args.downscale)
        tal.set_resources(**resources)
        opts, notes = dict(resources), []
        t0 = time.perf_counter()
        R, secs_ytal = RUNNERS[method](data, axes, args, opts, notes)
        R = np.asarray(R)
        vol = np.abs(R) if np.iscomplexobj(R) else R
        want = tuple(int(n) for n in grid["dims"])
        if vol.shape != want:
            if vol.size == np.prod(want):
                vol = vol.reshape(want)
            else:
                raise ReconError(f"y-tal returned shape {R.shape} for a {want} grid")
        out = np.ascontiguousarray(vol.transpose(1, 0, 2), dtype=np.float32)  # (ny, nx, nz)
        secs = time.perf_counter() - t0
        if not np.all(np.isfinite(out)):
            raise ReconError("the reconstruction has non-finite values")
    except ReconError as e:
        print(f"ytal_recon: {method}: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # noqa: BLE001 - a y-tal crash: name the method
        import traceback
        traceback.print_exc()
        print(f"ytal_recon: {method}: y-tal failed: {type(e).__name__}: {e}", file=sys.stderr)
        return 2
    np.save(args.out, out)
    if args.timing:
        report = {
            "method": method,
            "ytal_function": f"tal.reconstruct.{method}.solve",
            "tal_version": tal.__version__,
            "seconds": secs,
            "seconds_ytal_call": secs_ytal,
            "grid": {"min": grid["min"].tolist(), "max": grid["max"].tolist(),
                     "dims": grid["dims"].tolist()},
            "output": {"shape": list(out.shape), "layout": "(ny, nx, nz)",
                       "value": "abs" if np.iscomplexobj(R) else "real",
                       "max": float(out.max()) if out.size else 0.0},
            "capture": info,
            "options": opts,
            "workarounds": notes,
        }
        Path(args.timing).write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
