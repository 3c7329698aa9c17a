"""Helpers to run mitransient 1.3.1 (Mitsuba 3.9.1, llvm_ad_mono) from the validation
scripts and tests.

Import this module before anything imports mitsuba: `setup()` sets
DRJIT_LIBLLVM_PATH (LLVM 19), the variant and the thread count, then imports
mitransient.
"""
from __future__ import annotations

import glob
import os

_MI = None


def lookat(origin, target, up=(0.0, 1.0, 0.0)):
    """A Mitsuba `to_world` 4x4 matrix (numpy) for an emitter at `origin` looking at
    `target` (Mitsuba's look-at convention: +z forward, +x left)."""
    import numpy as np

    o, t, u = (np.asarray(x, float) for x in (origin, target, up))
    d = (t - o) / np.linalg.norm(t - o)
    left = np.cross(u, d)
    left /= np.linalg.norm(left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(d, left), d, o
    return m



def rgb(v):
    """A Mitsuba `rgb` spectrum of grey `v`."""
    return {"type": "rgb", "value": [v, v, v]}


def nlos_integrator(capture="confocal", hidden_geometry_sampling=True):
    """mitransient's `transient_nlos_path` as the studies run it: up to 6 bounces, laser
    sampling, hidden-geometry sampling as asked (without the relay wall or its roulette),
    rectified (`account_first_and_last_bounces` off), box temporal filter."""
    return {
        "type": "transient_nlos_path", "capture_type": capture,
        "max_depth": 6, "filter_bounces": -1, "discard_direct_paths": False,
        "nlos_laser_sampling": True, "nlos_hidden_geometry_sampling": bool(hidden_geometry_sampling),
        "nlos_hidden_geometry_sampling_do_rroulette": False,
        "nlos_hidden_geometry_sampling_includes_relay_wall": False,
        "account_first_and_last_bounces": False, "temporal_filter": "box"}


def projector(laser, target):
    """The laser: a unit-irradiance `projector` of 0.2 degrees at `laser` aimed at `target`
    (single capture: where its +z axis meets the wall is the laser spot; confocal: only its
    position matters)."""
    return {"type": "projector", "irradiance": rgb(1.0), "fov": 0.2,
            "to_world": lookat(laser, target)}


def relay_wall(half, albedo, laser, scan, bins, bin_width, start_opl, spp):
    """The relay wall: a `2 half` square at z = 0 facing +z, diffuse of `albedo`, carrying
    an `nlos_capture_meter` at `laser` with a `scan x scan` box-filtered transient film of
    `bins` bins of `bin_width` (OPL, m) from `start_opl`, `spp` independent samples."""
    import numpy as np

    return {
        "type": "rectangle", "to_world": np.diag([half, half, 1.0, 1.0]),
        "bsdf": {"type": "diffuse", "reflectance": rgb(albedo)},
        "sensor": {"type": "nlos_capture_meter", "sensor_origin": laser,
                   "sampler": {"type": "independent", "sample_count": int(spp), "seed": 0},
                   "film": {"type": "transient_hdr_film", "width": scan, "height": scan,
                            "temporal_bins": bins, "bin_width_opl": bin_width,
                            "start_opl": start_opl, "rfilter": {"type": "box"}}}}

def find_libllvm() -> str:
    """Path of an LLVM >= 19 shared library for Dr.Jit (LLVM 14 is too old, 15/16 crash)."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    cands = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*")) + sorted(
        glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM-19*.so*")
    )
    if not cands:
        raise RuntimeError(
            "No LLVM 19 found: apt-get install -y libllvm19 and set DRJIT_LIBLLVM_PATH"
        )
    return cands[0]


def setup(threads: int = 2):
    """Returns (mi, mitr) with variant llvm_ad_mono and `threads` worker threads."""
    global _MI
    if _MI is not None:
        return _MI
    os.environ["DRJIT_LIBLLVM_PATH"] = find_libllvm()
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono")
    dr.set_thread_count(threads)
    mi.set_log_level(mi.LogLevel.Error)
    import mitransient as mitr

    _MI = (mi, mitr)
    return _MI


def to_numpy(transient) -> "np.ndarray":
    """mitransient's transient tensor (sy, sx, T, 1) in llvm_ad_mono -> float32 (sy, sx, T).
    Exhaustive captures give (sy, sx, ly, lx, T, 1) -> (sy, sx, ly, lx, T) (square grids only:
    see notes/mitransient.md)."""
    import numpy as np

    a = np.array(transient, dtype=np.float32)
    assert a.shape[-1] == 1, a.shape
    return a[..., 0]


def render_scene(scene, spp: int, seed: int = 0):
    """Render a loaded scene; returns float32 (sy, sx, T)."""
    mi, _ = setup()
    steady, transient = mi.render(scene, spp=spp, seed=seed)
    return to_numpy(transient)


def load_xml(path: str, **params):
    """mi.load_file with <default> overrides (values converted to str)."""
    mi, _ = setup()
    return mi.load_file(str(path), **{k: str(v) for k, v in params.items()})


def render_xml(path: str, spp: int, seed: int = 0, **params):
    return render_scene(load_xml(path, **params), spp=spp, seed=seed)
