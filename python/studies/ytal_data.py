"""The data side of ytal_recon.py: the voxel grid, the capture's type and wall axes, re-timing
H to start at OPL 0 of the hidden path, binning it in time, putting the scan grid in ascending
order, and resampling a volume onto our voxels (notes/ytal-recon.md, "Grids and time
conventions"). Runs in .venv-ytal (imports y-tal's enums lazily)."""
from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np


class ReconError(Exception):
    """A reason the reconstruction cannot run (reported, exit status 2)."""


def read_grid(path: str | Path) -> dict:
    try:
        g = json.loads(Path(path).read_text())
        lo = np.asarray(g["min"], dtype=np.float64)
        hi = np.asarray(g["max"], dtype=np.float64)
        dims = np.asarray(g["dims"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ReconError(f"cannot read grid {path}: {e}") from None
    if lo.shape != (3,) or hi.shape != (3,) or dims.shape != (3,):
        raise ReconError(f"grid {path}: min, max and dims must have 3 entries each")
    if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)) or not np.all(hi > lo):
        raise ReconError(f"grid {path}: need finite min < max on every axis, got {lo} .. {hi}")
    if not np.all(dims == np.round(dims)) or not np.all(dims >= 1):
        raise ReconError(f"grid {path}: dims must be positive integers, got {g['dims']}")
    return {"min": lo, "max": hi, "dims": dims.astype(int)}


def grid_axes(grid: dict) -> list[np.ndarray]:
    """Voxel-centre coordinates along x, y, z."""
    lo, hi, n = grid["min"], grid["max"], grid["dims"]
    return [lo[a] + (np.arange(n[a]) + 0.5) * (hi[a] - lo[a]) / n[a] for a in range(3)]


def volume_xyz(xs, ys, zs) -> np.ndarray:
    """(nx, ny, nz, 3): y-tal's VolumeFormat.X_Y_Z_3."""
    return np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1)


def capture_type(data) -> str:
    from tal.enums import HFormat
    if data.H_format in (HFormat.T_Lx_Ly_Sx_Sy, HFormat.T_Li_Si):
        return "exhaustive"
    if data.H_format not in (HFormat.T_Sx_Sy, HFormat.T_Si):
        return f"unsupported H_format {data.H_format.name}"
    if data.is_confocal():
        return "confocal"
    if np.asarray(data.laser_grid_xyz).size == 3:
        return "single"
    return "custom (laser paired to sensor, not confocal)"


def wall_axes(data, method: str):
    """x of the sensor grid's first index and y of its second, for a regular axis-aligned
    X_Y_3 sensor grid on the wall z = 0 (as Umbra writes it). Else a ReconError."""
    from tal.enums import GridFormat
    g = np.asarray(data.sensor_grid_xyz, dtype=np.float64)
    if data.sensor_grid_format != GridFormat.X_Y_3 or g.ndim != 3 or min(g.shape[:2]) < 2:
        raise ReconError(f"{method} needs an X_Y_3 sensor grid of at least 2 x 2 points, "
                         f"got shape {g.shape} ({data.sensor_grid_format.name})")
    xs, ys = g[:, 0, 0], g[0, :, 1]
    tol = 1e-6 * max(1.0, np.abs(g).max())
    regular = (np.allclose(g[..., 0], xs[:, None], atol=tol)
               and np.allclose(g[..., 1], ys[None, :], atol=tol)
               and np.allclose(g[..., 2], 0.0, atol=tol)
               and np.allclose(np.diff(xs), xs[1] - xs[0], atol=tol)
               and np.allclose(np.diff(ys), ys[1] - ys[0], atol=tol)
               and xs[1] > xs[0] and ys[1] > ys[0])
    if not regular:
        raise ReconError(f"{method} needs the sensor grid to be a regular grid on the wall "
                         "z = 0 with x growing along its first index and y along its second")
    return xs, ys


def retime(data, notes: list, max_opl: float | None = None, centre: bool = False,
           delay: float = 0.0, parity: str | None = None) -> None:
    """Rewrite data.H in place so that its time axis starts at OPL 0 of the hidden path
    (first and last legs excluded), t_start = 0: y-tal's fk and pf ignore t_start and the
    first/last legs, and pf_dev crashes on them. New bin k holds OPL [k, k + 1) * delta_t;
    with centre, new sample k is the old histogram read at OPL k * delta_t with each old bin's
    value at the middle of its interval (for methods that take sample k at t = k * delta_t).
    Exact (a pure shift by whole bins) when t_start and the legs are whole bins and not
    centre; linear interpolation between bins otherwise (a half-bin shift averages two
    neighbouring bins: no phase error, a cos(pi f delta_t) low-pass). delay: a further
    delay in bins (to undo a filter's lead); parity "even" or "odd": append an empty bin if
    need be to give H that parity of bins."""
    from tal.enums import HFormat
    dt, t0 = float(data.delta_t), float(data.t_start or 0.0)
    H = np.asarray(data.H)
    nt = H.shape[0]
    legs = 0.0
    if data.t_accounts_first_and_last_bounces:
        if data.H_format != HFormat.T_Sx_Sy:
            raise ReconError("re-timing data whose time includes the first and last legs is "
                             "implemented for H_format T_Sx_Sy only")
        lg = np.asarray(data.laser_grid_xyz, dtype=np.float64)
        sg = np.asarray(data.sensor_grid_xyz, dtype=np.float64)
        d4 = np.linalg.norm(sg - np.asarray(data.sensor_xyz, dtype=np.float64), axis=-1)
        d1 = np.linalg.norm(lg - np.asarray(data.laser_xyz, dtype=np.float64), axis=-1)
        legs = d1 + d4 if lg.shape == sg.shape else d1.reshape(()) + d4   # (Sx, Sy)
    legs = np.asarray(legs, dtype=np.float64)
    shift = (t0 - legs) / dt + (0.5 if centre else 0.0) + delay   # new index of old bin 0
    end = float(np.max(shift)) + nt
    if max_opl is not None:
        end = min(end, max_opl / dt)
    nt_new = int(math.ceil(end - 1e-9))
    if nt_new <= 0:
        raise ReconError("no bins left after re-timing (t_start or --fk-max-opl too small)")
    whole = np.allclose(shift, np.round(shift), atol=1e-4)
    if np.all(shift == shift.flat[0]) and whole and shift.flat[0] >= 0:
        s = int(round(float(shift.flat[0])))
        out = np.zeros((nt_new,) + H.shape[1:], dtype=H.dtype)
        n = max(0, min(nt, nt_new - s))
        out[s:s + n] = H[:n]
        how = f"padded {s} empty bins in front (t_start = {t0:g} = {t0 / dt:g} bins"
        if centre:
            how += ", plus half a bin for each bin's value at the middle of its interval"
        if delay:
            how += f", plus {delay:g} bin for pf_dev's filter lead"
        how += ")"
    else:
        # new bin k <- old fractional index k - shift (per column), linear in between
        k = np.arange(nt_new, dtype=np.float64).reshape((-1,) + (1,) * (H.ndim - 1))
        src = k - shift
        i0 = np.floor(src).astype(np.int64)
        f = (src - i0).astype(np.float32)
        def take(i):
            ok = (i >= 0) & (i < nt)
            v = np.take_along_axis(H, np.broadcast_to(np.clip(i, 0, nt - 1), (nt_new,) + H.shape[1:]), axis=0)
            return np.where(ok, v, 0)
        out = ((1 - f) * take(i0) + f * take(i0 + 1)).astype(H.dtype)
        how = ("shifted each column by t_start - (laser->spot + point->sensor)"
               if data.t_accounts_first_and_last_bounces
               else f"shifted by t_start = {t0:g} ({t0 / dt:g} bins)")
        if centre:
            how += " plus half a bin (each bin's value at the middle of its interval)"
        if delay:
            how += f" plus {delay:g} bin (pf_dev's filter lead)"
        how += ", linear interpolation between bins"
    if nt_new < np.max(shift) + nt:
        how += f"; cut at OPL {nt_new * dt:g}"
    if parity is not None and nt_new % 2 != (parity == "odd"):
        out = np.concatenate([out, np.zeros((1,) + out.shape[1:], dtype=out.dtype)])
        nt_new += 1
        how += f"; one empty bin appended (an {parity} number of bins)"
    data.H = out
    data.t_start = 0.0
    data.t_accounts_first_and_last_bounces = False
    notes.append(f"H re-timed to start at OPL 0 of the hidden path: {how}; "
                 f"{nt} -> {nt_new} bins")


def resample(vol: np.ndarray, src_axes, dst_axes, clamp_lateral: bool) -> np.ndarray:
    """Trilinear interpolation of vol (on the regular ascending src_axes x, y, z) at the points
    dst_axes (x, y, z). Outside the source grid: 0, except that with clamp_lateral the outer
    half spacing around the x, y samples (the scan points' pixels) takes the edge values."""
    from scipy.interpolate import RegularGridInterpolator
    ax = [np.asarray(a, dtype=np.float64) for a in src_axes]
    v = vol
    if clamp_lateral:
        for a in (0, 1):
            h = 0.5 * (ax[a][1] - ax[a][0]) if len(ax[a]) > 1 else 0.5
            ax[a] = np.concatenate([[ax[a][0] - h], ax[a], [ax[a][-1] + h]])
            v = np.concatenate([np.take(v, [0], axis=a), v, np.take(v, [-1], axis=a)], axis=a)
    for a in range(3):
        if len(ax[a]) == 1:   # a single sample: duplicate it a hair apart
            ax[a] = np.array([ax[a][0] - 1e-9, ax[a][0] + 1e-9])
            v = np.concatenate([v, v], axis=a)
    interp = RegularGridInterpolator(ax, v, method="linear", bounds_error=False, fill_value=0.0)
    pts = volume_xyz(*dst_axes)
    return interp(pts.reshape(-1, 3)).reshape(pts.shape[:-1])


def ascending(data, notes):
    """A copy of `data` whose sensor (and laser) grid runs with +x along its first index
    and +y along its second, H flipped to match (the LCT captures' grid runs down y)."""
    from tal.enums import HFormat
    g = np.asarray(data.sensor_grid_xyz, dtype=np.float64)
    if g.ndim != 3 or min(g.shape[:2]) < 2 or data.H_format != HFormat.T_Sx_Sy:
        return data
    d = copy.copy(data)
    d.H = np.asarray(d.H)
    first = g[1, 0] - g[0, 0]
    if abs(first[1]) > abs(first[0]):   # the first index runs along y: transpose
        g = np.swapaxes(g, 0, 1)
        d.H = np.swapaxes(d.H, 1, 2)
        notes.append("sensor grid transposed (its first index ran along y), H to match")
    for axis, comp in ((0, 0), (1, 1)):
        step = np.take(g, 1, axis=axis)[..., comp] - np.take(g, 0, axis=axis)[..., comp]
        if np.all(step < 0):
            g = np.flip(g, axis=axis)
            d.H = np.flip(d.H, axis=axis + 1)
            notes.append(f"sensor grid reversed along its {'first' if axis == 0 else 'second'} "
                         f"index (its {'xy'[comp]} decreased), H flipped to match")
    d.sensor_grid_xyz = np.ascontiguousarray(g)
    d.laser_grid_xyz = np.ascontiguousarray(g.copy())
    d.H = np.ascontiguousarray(d.H)
    return d


def time_bin(data, k: int, notes: list) -> None:
    """Sum every k consecutive bins of data.H (time first, already re-timed to start at OPL 0)
    into one, delta_t *= k; the last bin is padded with empty bins to a multiple of k. Each
    new bin is exactly the OPL interval [j k dt, (j + 1) k dt): no interpolation."""
    if k <= 1:
        return
    H = np.asarray(data.H)
    nt = H.shape[0]
    n = -(-nt // k)
    pad = n * k - nt
    if pad:
        H = np.concatenate([H, np.zeros((pad,) + H.shape[1:], dtype=H.dtype)])
    data.H = H.reshape((n, k) + H.shape[1:]).sum(axis=1)
    data.delta_t = float(data.delta_t) * k
    notes.append(f"H summed over {k} bins ({nt} -> {n} bins of {data.delta_t:g} m OPL"
                 + (f", {pad} empty bins appended" if pad else "") + ")")

