"""Umbra: a differentiable transient renderer for non-line-of-sight imaging.

    import umbra
    scene = umbra.load_scene("scene.xml")              # TOML, Mitsuba XML, or a dict
    H = umbra.render(scene, spp=256, model="mc3")       # numpy float32, mitransient's layout
    g = umbra.grad(scene, target=M, spp=256, model="mc3")   # or adjoint=dLoss/dH
    g["loss"], g["vertices"][0], g["albedo"]           # one (V_k, 3) array per object
    fit = umbra.fit(scene, M, init="plane")             # the fitting of `umbra fit`
    umbra.save("H.hdf5", H, scene)                      # y-tal's capture (or .npy, .exr)

Models (the same names as the CLI and scene files): ``tri3`` (noise-free per-triangle
three-bounce), ``mc3`` (Monte Carlo three-bounce), ``path`` (multi-bounce), ``auto``.
Every option of ``umbra render`` is a keyword of :func:`render` and :func:`grad`; an
option left at None takes the scene's value (``scene.options`` lists them).
Errors are raised as :class:`UmbraError` with Umbra's message; Ctrl-C interrupts a long
render, gradient or fit. ``umbra.torch`` has a ``torch.autograd.Function`` on top.
"""
from __future__ import annotations

import os
import tempfile
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from ._umbra import Scene, UmbraError, capture, default_scene, mc3_samples, tri3_subtriangles
from ._umbra import __version__, option_names, save
from ._umbra import fit as _fit, grad as _grad, render as _render
from ._umbra import load_scene as _load_path, load_scene_xml as _load_xml

__all__ = ["Scene", "UmbraError", "load_scene", "default_scene", "render", "grad", "fit",
           "dict_to_xml", "option_names", "save", "capture", "mc3_samples", "tri3_subtriangles",
           "__version__"]

PathLike = Union[str, "os.PathLike[str]"]


def load_scene(source: Union[PathLike, Mapping[str, Any]], base_dir: Optional[str] = None,
               **defines: Any) -> Scene:
    """A scene from a TOML or Mitsuba XML file (``defines`` set the XML's ``$name``
    parameters, like Mitsuba's ``-D``), or from a dict in Mitsuba's ``load_dict``
    vocabulary as mitransient uses it (relative file names resolve against
    ``base_dir``, default the current directory)."""
    if isinstance(source, Mapping):
        return _load_xml(dict_to_xml(source), base_dir or os.getcwd(), "<dict>")
    return _load_path(os.fspath(source), [(k, _xml_value(v)) for k, v in defines.items()])


def render(scene: Scene, spp: Optional[int] = None, model: Optional[str] = None,
           seed: Optional[int] = None, threads: Optional[int] = None, *,
           max_depth: Optional[int] = None, laser_sampling: Optional[bool] = None,
           hidden_geometry_sampling: Optional[bool] = None,
           bsdf_sampling: Optional[bool] = None, visibility: Optional[str] = None,
           subdivision: Optional[float] = None, max_error: Optional[float] = None,
           visible_legs: Optional[bool] = None,
           boundary_terms: Optional[bool] = None,
           rr_early_survival: Union[str, float, None] = None) -> np.ndarray:
    """The scene's transient: a new float32 array in mitransient's layout ``(sy, sx, T)``
    (``(sy, sx, ly, lx, T)`` for exhaustive capture). Same seed, same output, whatever
    the thread count.

    Options (None: the scene's value, see ``scene.options``), as ``umbra render``'s flags:
    ``model`` tri3 | mc3 | path | auto; ``spp`` samples per measurement; ``seed``;
    ``threads`` worker threads (default all cores); ``max_depth`` longest path in
    bounces, laser spot and sensor point included (3 = one hidden bounce, -1 unbounded);
    ``laser_sampling``, ``hidden_geometry_sampling``, ``bsdf_sampling`` the path
    model's techniques; ``visibility`` (tri3) none | centroid | subtriangle;
    ``subdivision`` (tri3) the sub-triangle threshold; ``max_error`` (auto) the relative
    error the chosen model may leave; ``visible_legs`` test the laser -> laser spot and
    sensor point -> detector lines for occlusion by hidden objects (default True, as
    mitransient: a blocked measurement records 0); False when you know they are clear;
    ``boundary_terms`` is :func:`grad`'s (a render is the same with or without it);
    ``rr_early_survival`` (path) the probability a path goes on past each vertex before
    the scene's ``rr_bounces`` (Russian roulette from the first hidden vertex): "auto"
    (the default) lets a pilot pick it per render, 1.0 plays none.
    Render, grad, fit and the CLI refuse the same combinations with the same message."""
    return _render(scene, spp=spp, model=model, seed=seed, threads=threads,
                   max_depth=max_depth, laser_sampling=laser_sampling,
                   hidden_geometry_sampling=hidden_geometry_sampling,
                   bsdf_sampling=bsdf_sampling, visibility=visibility,
                   subdivision=subdivision, max_error=max_error, visible_legs=visible_legs,
                   boundary_terms=boundary_terms, rr_early_survival=rr_early_survival)


def grad(scene: Scene, adjoint: Optional[npt.ArrayLike] = None, spp: Optional[int] = None,
         model: Optional[str] = None, seed: Optional[int] = None,
         threads: Optional[int] = None, *, target: Optional[npt.ArrayLike] = None,
         loss: str = "l2", max_depth: Optional[int] = None,
         laser_sampling: Optional[bool] = None, hidden_geometry_sampling: Optional[bool] = None,
         bsdf_sampling: Optional[bool] = None, visibility: Optional[str] = None,
         subdivision: Optional[float] = None, max_error: Optional[float] = None,
         visible_legs: Optional[bool] = None,
         boundary_terms: Optional[bool] = None,
         rr_early_survival: Union[str, float, None] = None) -> Dict[str, Any]:
    """``dLoss/dθ`` for the scene's hidden objects, given either

    - ``adjoint = dLoss/dH`` (the render's shape) for a loss of your own, or
    - ``target`` (the render's shape, e.g. a measurement) and ``loss``: ``"l2"``
      (``Σ (H - target)²``) or ``"l2-normalized"`` (per scan point, each transient over
      its norm: insensitive to each point's scale); the scene is rendered first.

    Returns a dict; every gradient array is float64 (H and adjoints are float32):

    - ``vertices``: a list with one ``(V_k, 3)`` array per hidden object (also for a
      single object: ``g["vertices"][0]``), rows in the OBJ's ``v`` order;
    - ``albedo``: ``(K,)``, one value per object (0 for an object with vertex albedo);
    - ``vertex_albedo``: a list with, per object, a ``(V_k,)`` array, or None for an
      object without per-vertex albedo;
    - ``loss``: the loss value (float) with ``target``, None with ``adjoint``;
    - ``render``: with ``target``, the float32 render the loss was computed on, else None;
    - ``truncated_paths``: path contributions whose gradient was cut short (``path``);
    - ``boundary_terms``: whether the visibility boundary terms were added.

    Options are :func:`render`'s, and ``boundary_terms`` (default True, the scene's
    ``render.boundary_terms``): add the part of the vertex gradients carried by shadows
    moving across hidden surfaces (one hidden object occluding another, self-occluding
    silhouettes; docs/GRADIENTS.md). False gives the interior derivative alone, biased by
    12-36 % where something occludes, and faster. Use the render's seed for a Monte Carlo model: the
    adjoint pass replays its paths. Inputs of another dtype than float32 are converted
    once; a C-contiguous float32 array is read in place. Arrays of any memory order
    (Fortran, transposed, negative strides) are read by their shape and strides."""
    return _grad(scene, adjoint, target, loss, spp=spp, model=model, seed=seed,
                 threads=threads, max_depth=max_depth, laser_sampling=laser_sampling,
                 hidden_geometry_sampling=hidden_geometry_sampling,
                 bsdf_sampling=bsdf_sampling, visibility=visibility,
                 subdivision=subdivision, max_error=max_error, visible_legs=visible_legs,
                 boundary_terms=boundary_terms, rr_early_survival=rr_early_survival)


def _schedule_toml(stages: Sequence[Mapping[str, Any]]) -> str:
    out = []
    for st in stages:
        out.append("[[stage]]")
        for k, v in st.items():
            if isinstance(v, bool):
                out.append(f"{k} = {'true' if v else 'false'}")
            elif isinstance(v, (int, np.integer)):
                out.append(f"{k} = {int(v)}")
            elif isinstance(v, (float, np.floating)):
                out.append(f"{k} = {float(v)!r}")
            elif isinstance(v, str):
                out.append(f'{k} = "{v}"')
            else:
                raise UmbraError(f"schedule: stage value {k} = {v!r} is not a number, bool or string")
    return "\n".join(out) + "\n"


def fit(scene: Scene, measured: Union[None, PathLike, npt.ArrayLike] = None, *,
        output: Optional[PathLike] = None, init: Optional[str] = None,
        schedule: Union[None, PathLike, Sequence[Mapping[str, Any]]] = None,
        iters: Optional[int] = None, resume: bool = False, model: str = "tri3", spp: int = 16,
        known_scale: bool = False, background: Optional[str] = None,
        jitter: Optional[float] = None, irf: Optional[str] = None,
        time_offset: Optional[float] = None, reflectance: Optional[str] = None,
        retro_falloff: Optional[float] = None, ignore_before: Optional[float] = None, truth: bool = False,
        bin: Optional[Tuple[int, int]] = None, target_spp: int = 4096,
        threads: Optional[int] = None,
        progress: Optional[Callable[[Dict[str, Any]], Any]] = None,
        boundary_terms: Optional[bool] = None) -> Dict[str, Any]:
    """Fits a hidden triangle mesh to a measurement by the code of ``umbra fit`` (same
    schedule, same defaults; ``umbra fit --help`` describes each option).

    ``measured``: an array in the scene's output layout, a file (``.npy``, y-tal
    ``.hdf5``, Stanford LCT ``.mat``), or None for a demonstration: the scene's hidden
    objects rendered with ``path`` at ``target_spp`` as the target, and the fit compared
    with them. ``truth=True`` compares with the scene's hidden objects for a given
    measurement too. ``schedule``: a schedule TOML file, or a list of stage dicts
    (``iters``, ``solver``, ``lr``, ``large_steps``, ``laplacian``, ``fit_albedo``,
    ``time_downsample``, ``scan_downsample``, ``model``, ``spp``, ...); ``iters`` scales
    its stages to that total. ``output``: a directory for mesh.obj, loss.csv/png,
    transients.png, albedo.npy, depth.npy, albedo.png, reconstruction.png, summary.toml
    and the checkpoint (default: a
    temporary directory, removed afterwards). ``progress(d)`` is called after every
    iteration with ``d = {"iteration", "stage", "loss", "data_loss", "smoothness"}``; an
    exception it raises stops the fit and propagates. Ctrl-C stops it at the end of the
    iteration (KeyboardInterrupt; ``resume=True`` continues from the checkpoint).
    ``boundary_terms``: the visibility boundary terms in the fit's gradients (default: the
    scene's ``render.boundary_terms``, True; see :func:`grad`). ``init``: ``plane``,
    ``sphere``, ``scene``, ``backprojection``, ``lct`` (confocal) or ``auto`` (fits from a
    plane, a sphere and a reconstruction's depth map, the LCT's for confocal captures, the
    backprojection's otherwise; keeps the lowest loss, a later start of the three within
    1 % of it winning); default (None) ``lct`` for a Stanford ``.mat`` capture, ``plane``
    otherwise. ``retro_falloff``: a retroreflective surface's angular falloff
    exponent ``m`` (its return scaled by ``cos^m`` of the entrance angle; 0 to 16, default
    the scene object's ``retro_falloff``, else 0).

    Returns a dict: ``vertices`` (N, 3) float64 and ``triangles`` (F, 3) uint32, the
    fitted surface (faces fitted dark, faces no measurement lights and sees, and faces
    whose signal is within the noise, dropped, as mesh.obj; ``unsupported_faces`` and
    ``undetermined_faces`` count the latter two); ``full_mesh`` (every face, with
    ``vertex_albedo``); ``face_determination`` (F_all,) float64 per face of
    ``full_mesh``: its cluster's signal-to-noise over the photon noise its parameters
    could absorb (below 1: undetermined; 0: not tested, dark or unsupported), or None
    when the measurement is not photon counts (nothing is left out for noise then); ``history`` (numpy arrays ``iteration``, ``stage``, ``loss``
    (total), ``data_loss``, ``smoothness``); ``final_loss`` (``‖sH + b − M‖² / ‖M‖²`` at
    full resolution) and ``relative_l2``; ``scale``, ``background``, ``time_offset``;
    ``render`` (the fitted transient ``sH + b``, float32, the measurement's layout) and
    ``measured`` (the measurement as fitted); ``albedo`` and ``depth`` (ny, nx) float32,
    the fitted surface seen from the wall as albedo.npy and depth.npy: for each scan
    point ``[iy, ix]`` (the measurement's scan order, ``measured[iy, ix]``), the albedo
    and the depth from the wall (m) of the first face along the wall normal, NaN where
    there is none; ``chamfer`` (mm, with a truth) or None;
    ``photon_noise_floor``; ``nuisance`` (with the capture model: its gain, floor and tail
    coefficients by name, ``gain_1`` the scale, else None); ``floor`` (ny, nx) float64, the
    capture model's floor per scan point in counts per bin of the measurement as fitted
    (floor.npy), or None; ``rejected_steps``; ``seconds``;
    ``files``; ``init`` (the
    start used, ``auto: NAME`` for ``auto``) and ``starts`` (``auto``:
    each start's final loss)."""
    toml_text = None
    if schedule is not None:
        if isinstance(schedule, (str, os.PathLike)):
            with open(schedule, encoding="utf-8") as f:
                toml_text = f.read()
        else:
            toml_text = _schedule_toml(schedule)
    kw: Dict[str, Any] = dict(init=init, schedule=toml_text, iters=iters, resume=resume, model=model, spp=spp,
              known_scale=known_scale, background=background, jitter=jitter, irf=irf,
              time_offset=time_offset, reflectance=reflectance, retro_falloff=retro_falloff,
              ignore_before=ignore_before,
              truth=truth, bin=bin, target_spp=target_spp, threads=threads, progress=progress,
              boundary_terms=boundary_terms)
    if output is not None:
        return _fit(scene, measured, os.fspath(output), **kw)
    with tempfile.TemporaryDirectory(prefix="umbra-fit-") as tmp:
        out = _fit(scene, measured, tmp, **kw)
    out["files"] = []
    return out


# --- Mitsuba dicts -> Mitsuba XML ---------------------------------------------------

# Which XML element a plugin `type` is (the Mitsuba/mitransient plugins Umbra reads).
_CATEGORY = {
    "transient_nlos_path": "integrator", "transient_path": "integrator", "path": "integrator",
    "projector": "emitter", "area": "emitter",
    "obj": "shape", "ply": "shape", "rectangle": "shape", "sphere": "shape", "cube": "shape",
    "diffuse": "bsdf", "twosided": "bsdf",
    "nlos_capture_meter": "sensor",
    "transient_hdr_film": "film",
    "box": "rfilter", "gaussian": "rfilter",
    "independent": "sampler", "stratified": "sampler", "multijitter": "sampler",
}


def _xml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def _matrix(v: Any) -> "np.ndarray | None":
    m = getattr(v, "matrix", v)
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return a if a.shape == (4, 4) else None


def _element(name: "str | None", v: Any, indent: str) -> str:
    attr = f' name="{name}"' if name is not None else ""
    if isinstance(v, Mapping):
        kind = v.get("type")
        if kind in ("rgb", "spectrum"):
            value = v.get("value", 0.0)
            text = ", ".join(str(float(x)) for x in np.atleast_1d(value))
            return f'{indent}<{kind}{attr} value="{text}"/>\n'
        tag = _CATEGORY.get(str(kind))
        if tag is None:
            raise UmbraError(f"dict scene: unknown plugin type {kind!r} (under {name!r})")
        ident = f' id="{name}"' if name is not None and tag in ("shape", "emitter") else ""
        body = "".join(_element(k, x, indent + "    ") for k, x in v.items() if k != "type")
        return f'{indent}<{tag} type="{kind}"{ident}>\n{body}{indent}</{tag}>\n'
    if isinstance(v, bool):
        return f'{indent}<boolean{attr} value="{_xml_value(v)}"/>\n'
    if isinstance(v, (int, np.integer)):
        return f'{indent}<integer{attr} value="{int(v)}"/>\n'
    if isinstance(v, (float, np.floating)):
        return f'{indent}<float{attr} value="{float(v)!r}"/>\n'
    if isinstance(v, str):
        return f'{indent}<string{attr} value="{v}"/>\n'
    m = _matrix(v)
    if m is not None:
        values = " ".join(repr(float(x)) for x in m.ravel())
        return f'{indent}<transform{attr}>\n{indent}    <matrix value="{values}"/>\n{indent}</transform>\n'
    a = np.asarray(v, dtype=np.float64) if not isinstance(v, str) else None
    if a is not None and a.shape == (3,):
        x, y, z = (repr(float(c)) for c in a)
        return f'{indent}<point{attr} x="{x}" y="{y}" z="{z}"/>\n'
    raise UmbraError(f"dict scene: cannot express {name!r} = {v!r} in Mitsuba XML")


def dict_to_xml(scene: Mapping[str, Any]) -> str:
    """Mitsuba XML text for a scene dict in ``mi.load_dict``'s vocabulary: plugins as
    dicts with a ``type``; ``to_world`` as a 4x4 matrix (numpy, nested lists, or a
    Mitsuba transform); points as 3-sequences; ``{'type': 'rgb', 'value': ...}``."""
    if scene.get("type") != "scene":
        raise UmbraError("dict scene: the top level needs 'type': 'scene'")
    body = "".join(_element(k, v, "    ") for k, v in scene.items() if k != "type")
    return f'<scene version="3.0.0">\n{body}</scene>\n'
