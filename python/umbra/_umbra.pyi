"""Type stubs of ``umbra._umbra``, the compiled part of the ``umbra`` package (PyO3).

Arrays are numpy arrays in mitransient's layout: renders ``(sy, sx, T)`` or
``(sy, sx, ly, lx, T)`` float32; gradients float64. The user-facing wrappers (with
explicit keyword arguments) are in ``umbra/__init__.py``.
"""
from __future__ import annotations

import os
from typing import Any, Callable, Dict, Iterable, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

class UmbraError(Exception):
    """An error reported by Umbra (bad scene, bad input, unsupported setting)."""

class Scene:
    """A loaded scene: capture setup, hidden meshes (vertices and albedos readable and
    settable from numpy), film and render settings. A scene caches its hidden geometry's
    acceleration structure until a mesh or an albedo changes. ``object`` indexes the
    hidden objects as Python indexes a list (negative: from the end); an index out of
    range is an ``UmbraError`` naming the range. Arrays are read by their shape and
    strides (any memory order). A scene cannot be changed while a render, gradient or
    fit reads it (``UmbraError``; ``fit`` reads its own copy)."""

    @property
    def shape(self) -> List[int]:
        """Shape of a render: ``(sy, sx, T)`` or ``(sy, sx, ly, lx, T)``."""
    @property
    def objects(self) -> List[str]:
        """Names of the hidden objects, in scene order."""
    @property
    def warnings(self) -> List[str]:
        """Warnings raised while loading (unsupported-but-harmless settings)."""
    @property
    def options(self) -> Dict[str, Any]:
        """The scene's render settings: the values ``render`` and ``grad`` use for
        options left unset (keys as ``option_names()``)."""
    @property
    def albedo(self) -> List[float]:
        """Albedo of every hidden object (an object with per-vertex albedo uses that
        instead)."""
    def vertices(self, object: int = 0) -> npt.NDArray[np.float32]:
        """Vertex positions of hidden object ``object``: a new ``(V, 3)`` float32 array
        (world space, m; rows in the OBJ's ``v`` order)."""
    def set_vertices(self, vertices: npt.ArrayLike, object: int = 0) -> None:
        """Replaces the vertex positions of object ``object`` with a ``(V, 3)`` array
        (same V, any real dtype, finite)."""
    def triangles(self, object: int = 0) -> npt.NDArray[np.uint32]:
        """Triangles of object ``object``: a ``(T, 3)`` uint32 array of vertex rows."""
    def set_albedo(self, value: float, object: int = 0) -> None:
        """Sets the albedo of object ``object`` (in [0, 1]). Refused for an object with
        per-vertex albedo, which takes the place of its albedo: change that with
        ``set_vertex_albedo``, or remove it with ``set_vertex_albedo(None, object)``."""
    def vertex_albedo(self, object: int = 0) -> Optional[npt.NDArray[np.float32]]:
        """Per-vertex albedo of object ``object``: a new ``(V,)`` float32 array, or
        None."""
    def set_vertex_albedo(self, values: Optional[npt.ArrayLike], object: int = 0) -> None:
        """Sets the per-vertex albedo of object ``object`` (``(V,)`` values in [0, 1]);
        None removes it."""
    def copy(self) -> Scene:
        """A copy of the scene (to perturb without touching the original)."""
    def __reduce__(self) -> Tuple[Callable[[bytes], Scene], Tuple[bytes]]:
        """Pickling: the whole scene, meshes included, as bytes (``umbra.distributed``)."""

def load_scene(path: str, defines: Optional[Sequence[Tuple[str, str]]] = None) -> Scene:
    """Loads a scene file: Umbra TOML or Mitsuba XML, with ``defines`` for the XML's
    ``$name`` parameters."""

def load_scene_xml(text: str, base_dir: str = ".", origin: str = "<dict>") -> Scene:
    """Parses Mitsuba XML text (``base_dir`` resolves relative file names; ``origin``
    names the source in error messages)."""

def default_scene() -> Scene:
    """The built-in default scene (a letter T, confocal 32 x 32)."""

def option_names() -> List[str]:
    """The keyword options of ``render`` and ``grad``, as ``umbra render`` has them."""

def render(
    scene: Scene,
    *,
    model: Optional[str] = None,
    visibility: Optional[str] = None,
    subdivision: Optional[float] = None,
    max_error: Optional[float] = None,
    spp: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_depth: Optional[int] = None,
    laser_sampling: Optional[bool] = None,
    hidden_geometry_sampling: Optional[bool] = None,
    bsdf_sampling: Optional[bool] = None,
    visible_legs: Optional[bool] = None,
    boundary_terms: Optional[bool] = None,
    rr_early_survival: Union[str, float, None] = None,
) -> npt.NDArray[np.float32]:
    """The scene's transient (float32, mitransient's layout); options left at None take
    the scene's value."""

def grad(
    scene: Scene,
    adjoint: Optional[npt.ArrayLike] = None,
    target: Optional[npt.ArrayLike] = None,
    loss: str = "l2",
    *,
    model: Optional[str] = None,
    visibility: Optional[str] = None,
    subdivision: Optional[float] = None,
    max_error: Optional[float] = None,
    spp: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    max_depth: Optional[int] = None,
    laser_sampling: Optional[bool] = None,
    hidden_geometry_sampling: Optional[bool] = None,
    bsdf_sampling: Optional[bool] = None,
    visible_legs: Optional[bool] = None,
    boundary_terms: Optional[bool] = None,
    rr_early_survival: Union[str, float, None] = None,
) -> Dict[str, Any]:
    """``dLoss/dθ`` for ``adjoint`` (dLoss/dH) or for ``loss`` ("l2" or
    "l2-normalized") against ``target``: a dict with ``vertices`` (list of ``(V_k, 3)``
    float64), ``albedo`` (``(K,)`` float64), ``vertex_albedo`` (list of ``(V_k,)``
    float64 or None), ``loss`` (float or None), ``render`` (float32 or None) and
    ``truncated_paths`` (int)."""

def fit(
    scene: Scene,
    measured: Union[None, str, os.PathLike[str], npt.ArrayLike],
    output: Union[str, os.PathLike[str]],
    *,
    init: Optional[str] = None,
    schedule: Optional[str] = None,
    iters: Optional[int] = None,
    resume: bool = False,
    model: str = "tri3",
    spp: int = 16,
    known_scale: bool = False,
    background: Optional[str] = None,
    jitter: Optional[float] = None,
    irf: Optional[str] = None,
    time_offset: Optional[float] = None,
    reflectance: Optional[str] = None,
    ignore_before: Optional[float] = None,
    truth: bool = False,
    bin: Optional[Tuple[int, int]] = None,
    target_spp: int = 4096,
    threads: Optional[int] = None,
    progress: Optional[Callable[[Dict[str, Any]], Any]] = None,
    boundary_terms: Optional[bool] = None,
) -> Dict[str, Any]:
    """The fit of ``umbra fit`` (``schedule`` as TOML text); see ``umbra.fit``."""

def capture(scene: Scene) -> Dict[str, Any]:
    """The capture as the estimators see it (laser spots, sensor points, powers, legs,
    wall normal and BRDF, flat hidden triangles, film), for independent
    implementations."""

def mc3_samples(scene: Scene, spp: int, seed: int = 0) -> Dict[str, npt.NDArray[Any]]:
    """The random choices of ``mc3`` for ``spp`` samples of every measurement:
    ``tri``, ``bary``, ``prob``, ``x_l``, ``visible``."""

def tri3_subtriangles(scene: Scene, subdivision: Optional[float] = None) -> Dict[str, npt.NDArray[Any]]:
    """The sub-triangles ``tri3`` renders with: ``parent`` (S,) and ``corner_bary``
    (S, 3, 2)."""


# The pieces of a render and a gradient that umbra.distributed sends to Ray workers.
def _scene_from_wire(bytes: bytes) -> Scene:
    """A scene from ``Scene.__reduce__``'s bytes (pickle's reader), checked like a scene file."""
def save(path: Union[str, "os.PathLike[str]"], transient: npt.ArrayLike, scene: Scene) -> None:
    """Writes a render of ``scene`` to ``path``: ``.npy``, ``.exr`` or y-tal ``.hdf5``
    (by the extension, as ``umbra render -o``), atomically."""
def ytal_chunk_rows(scene: Scene) -> int:
    """Rows per HDF5 chunk of a y-tal capture's ``H`` (blocks cut on multiples fill whole chunks)."""
def write_ytal_blocks(path: Union[str, "os.PathLike[str]"], scene: Scene,
                      blocks: Iterable[Tuple[int, npt.ArrayLike]]) -> None:
    """A y-tal capture of ``scene`` from ``(first_row, rows)`` blocks in any order."""
def render_measurements(scene: Scene, start: int, stop: int, **options: Any) -> np.ndarray:
    """Rows ``start..stop`` of the render (measurements in order), ``(stop - start, T)``."""
def resolve_pilots(scene: Scene, **options: Any) -> Dict[str, Any]:
    """What the pilots pick for these options (``model``, ``rr_early_survival``, each only
    where it was ``"auto"``), as options for the shards of one render or gradient."""
def grad_chunk_layout(scene: Scene) -> List[Tuple[int, int]]:
    """The gradient's chunks as measurement ranges, in chunk order."""
def grad_chunks(scene: Scene, adjoint_rows: npt.ArrayLike, start: int, stop: int,
                **options: Any) -> List[Dict[str, Any]]:
    """The shares of gradient chunks ``start..stop`` for their adjoint rows."""
def grad_combine(scene: Scene, parts: Sequence[Dict[str, Any]], **options: Any) -> Dict[str, Any]:
    """The gradient from every chunk's share, added in chunk order; a share with a
    non-finite value is refused, naming its chunk."""
