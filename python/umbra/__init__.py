"""Umbra: a differentiable transient renderer for non-line-of-sight imaging.

    import umbra
    scene = umbra.load_scene("scene.xml")              # TOML, Mitsuba XML, or a dict
    H = umbra.render(scene, spp=256, model="mc3")       # numpy, mitransient's layout
    g = umbra.grad(scene, dLdH, spp=256, model="mc3")  # {"vertices": (V, 3), "albedo": ...}

Models (the same names as the CLI and scene files): ``tri3`` (noise-free per-triangle
three-bounce), ``mc3`` (Monte Carlo three-bounce), ``path`` (multi-bounce), ``auto``.
Errors are raised as :class:`UmbraError` with Umbra's message; Ctrl-C interrupts a long
render or gradient. ``umbra.torch`` has a ``torch.autograd.Function`` on top.
"""
from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from ._umbra import Scene, UmbraError, capture, default_scene, grad as _grad, mc3_samples
from ._umbra import render as _render, tri3_subtriangles
from ._umbra import load_scene as _load_path, load_scene_xml as _load_xml

__all__ = ["Scene", "UmbraError", "load_scene", "default_scene", "render", "grad", "dict_to_xml",
           "capture", "mc3_samples", "tri3_subtriangles"]


def load_scene(source: "str | os.PathLike | Mapping[str, Any]", base_dir: "str | None" = None,
               **defines: Any) -> Scene:
    """A scene from a TOML or Mitsuba XML file (``defines`` set the XML's ``$name``
    parameters, like Mitsuba's ``-D``), or from a dict in Mitsuba's ``load_dict``
    vocabulary as mitransient uses it (relative file names resolve against
    ``base_dir``, default the current directory)."""
    if isinstance(source, Mapping):
        return _load_xml(dict_to_xml(source), base_dir or os.getcwd(), "<dict>")
    return _load_path(os.fspath(source), [(k, _xml_value(v)) for k, v in defines.items()])


def render(scene: Scene, spp: "int | None" = None, model: "str | None" = None,
           seed: "int | None" = None, threads: "int | None" = None) -> np.ndarray:
    """The scene's transient, float32, in mitransient's layout ``(sy, sx, T)`` (or
    ``(sy, sx, ly, lx, T)`` for exhaustive capture). Unset arguments come from the scene.
    Same seed, same output, whatever the thread count."""
    return _render(scene, spp=spp, model=model, seed=seed, threads=threads)


def grad(scene: Scene, adjoint: np.ndarray, spp: "int | None" = None, model: "str | None" = None,
         seed: "int | None" = None, threads: "int | None" = None) -> dict:
    """``dLoss/dθ`` given ``adjoint = dLoss/dH`` (the render's shape): a dict with
    ``vertices`` ((V, 3) float64, rows in the OBJ's ``v`` order; a list of such arrays if
    the scene has several hidden objects), ``albedo`` (one per object) and
    ``vertex_albedo`` (per object, None without vertex colours). Use the render's seed
    for a Monte Carlo model: the adjoint pass replays its paths."""
    adjoint = np.ascontiguousarray(adjoint, dtype=np.float32)
    return _grad(scene, adjoint, spp=spp, model=model, seed=seed, threads=threads)


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
        tag = _CATEGORY.get(kind)
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
