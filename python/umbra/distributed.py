"""Umbra on a Ray cluster: one render or gradient split over many processes and machines,
data sets of many scenes, many fits at once (issue 21). Ray schedules, moves data and
retries; nothing here is a scheduler of its own.

- :func:`render` splits one render's measurements (scan points; laser points too for
  exhaustive captures) into shards and returns exactly ``umbra.render``'s array, bit for
  bit: each measurement's samples depend on the seed and its index alone, not on where
  it runs. ``out="x.npy"`` (a memory map) or ``out="x.hdf5"`` (y-tal's capture) streams
  the shards into a file as they arrive instead of into one process's memory.
- :func:`grad` splits a gradient into the renderer's fixed chunks of measurements
  (``umbra::adjoint::gradient_chunks``); the chunks' shares are added in chunk order, so
  the result is ``umbra.grad``'s, bit for bit, for any number of workers.
- :func:`render_many` renders a data set, one ``.npy`` (or y-tal ``.hdf5``) per scene and
  a ``manifest.json``; a rerun skips what is complete, a failed scene is reported, not
  fatal; on a shared file system the workers write the files themselves.
- :func:`fit_many` runs several ``umbra.fit`` at once, each in its own output folder with
  its own checkpoint (a rerun resumes them).

What moves over the network: each scene once per machine (``ray.put``: Ray's object
store; each shard unpickles it), each shard's adjoint rows (gradients), and each shard's
result rows or chunk shares back. A worker killed mid-shard is retried by Ray
(``max_retries``); its result is the same bits.

Needs Ray (``pip install './python[ray]'``). Without a running ``ray.init``, the first
call starts a local one (``RAY_ADDRESS`` or ``ray start --head`` to join a cluster).
"""
from __future__ import annotations

import json
import os
import tempfile
import time
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _umbra

# Ray's retries of a shard whose worker died (a killed process, a lost node).
MAX_RETRIES = 3


def _ray():
    try:
        import ray
    except ImportError as e:  # pragma: no cover - the message is the point
        raise ImportError("umbra.distributed needs Ray: pip install './python[ray]' "
                          "(or pip install ray)") from e
    if not ray.is_initialized():
        ray.init(address=os.environ.get("RAY_ADDRESS"), log_to_driver=False)
    return ray


def _workers(ray) -> int:
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def _even(n: int, parts: int) -> List[Tuple[int, int]]:
    parts = max(1, min(parts, n))
    return [(i * n // parts, (i + 1) * n // parts) for i in range(parts)]


def _bar(total: int, desc: str, progress: Union[bool, Callable[[int, int], Any]]):
    """A tqdm bar when tqdm is there and progress is True; a callback's adapter; or None."""
    if callable(progress):
        class _Call:
            def __init__(self):
                self.n = 0

            def update(self, k):
                self.n += k
                progress(self.n, total)

            def close(self):
                pass
        return _Call()
    if not progress:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=desc, unit="shard")


def _shard_error(what: str, shard: int, rows: Tuple[int, int], e: BaseException) -> _umbra.UmbraError:
    return _umbra.UmbraError(f"{what}: shard {shard} (measurements {rows[0]}..{rows[1]}) failed: "
                             f"{_cause(e)}")


def _arrivals(ray, refs: Sequence[Any], bar):
    """Yields ``(i, result, error)`` for each task as it finishes (so big results are
    written and dropped one at a time); closing the generator early cancels the tasks
    still running."""
    index = {r: i for i, r in enumerate(refs)}
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            i = index[done[0]]
            try:
                result = ray.get(done[0])
            except Exception as e:  # Ray wraps the worker's error
                yield i, None, e
            else:
                yield i, result, None
            if bar is not None:
                bar.update(1)
    finally:
        for r in pending:
            ray.cancel(r, force=True)
        if bar is not None:
            bar.close()


def _each(ray, refs: Sequence[Any], take: Callable[[int, Any], None], bar,
          fail: Callable[[int, BaseException], None]) -> None:
    """Hands each result to ``take(i, result)`` as it arrives and each failure to
    ``fail(i, error)``; what either raises cancels the tasks still running."""
    arrivals = _arrivals(ray, refs, bar)
    try:
        for i, result, error in arrivals:
            if error is not None:
                fail(i, error)
            else:
                take(i, result)
    finally:
        arrivals.close()


def _gather(ray, refs: Sequence[Any], what: str, rows: Sequence[Tuple[int, int]],
            take: Callable[[int, Any], None], bar) -> None:
    """:func:`_each` where the first failure is raised, naming ``what`` and the shard."""
    def fail(i: int, e: BaseException) -> None:
        raise _shard_error(what, i, rows[i], e) from e
    _each(ray, refs, take, bar, fail)


def _cause(e: BaseException) -> str:
    cause = getattr(e, "cause", None) or e
    return f"{type(cause).__name__}: {cause}"


def _remote(ray, fn, cpus: int):
    return ray.remote(num_cpus=cpus, max_retries=MAX_RETRIES, retry_exceptions=False)(fn)


def _render_rows(scene, start, stop, options, hook):
    if hook is not None:
        hook(start, stop)
    return _umbra.render_measurements(scene, start, stop, **options)


def _grad_rows(scene, adjoint_rows, chunks, options, hook):
    if hook is not None:
        hook(*chunks)
    return _umbra.grad_chunks(scene, adjoint_rows, chunks[0], chunks[1], **options)


def _options(spp, model, seed, cpus, extra) -> Dict[str, Any]:
    o = {k: v for k, v in dict(spp=spp, model=model, seed=seed).items() if v is not None}
    o.update({k: v for k, v in extra.items() if v is not None})
    o.setdefault("threads", cpus)
    return o


def _atomic_npy(path: str, shape: Sequence[int]):
    """A float32 ``.npy`` memory map at a temporary name beside ``path``, and the call
    that flushes it and moves it into place."""
    d = os.path.dirname(os.path.abspath(path)) or "."
    fd, tmp = tempfile.mkstemp(prefix=".umbra-", suffix=".npy", dir=d)
    os.close(fd)
    mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=tuple(shape))

    def finish():
        mm.flush()
        os.replace(tmp, path)
    return mm, finish, tmp


def _is_hdf5(path: str) -> bool:
    return str(path).lower().endswith((".hdf5", ".h5"))


def render(scene: "_umbra.Scene", *, spp: Optional[int] = None, model: Optional[str] = None,
           seed: Optional[int] = None, shards: Optional[int] = None, out: Optional[str] = None,
           cpus_per_shard: int = 1, progress: Union[bool, Callable[[int, int], Any]] = True,
           _on_shard: Optional[Callable[[int, int], Any]] = None, **options: Any):
    """``umbra.render(scene, spp=..., model=..., seed=..., **options)`` on the Ray cluster,
    the same array bit for bit. ``shards``: how many pieces (default four per CPU of the
    cluster, at most one per measurement); each runs on ``cpus_per_shard`` cores (its
    render threads). ``out``: a file to stream the result into, as the shards arrive,
    instead of gathering it in this process's memory; it is written at a temporary name
    and moved into place when complete:

    - ``x.npy``: a memory map of the render (returned, opened read-only);
    - ``x.hdf5`` / ``x.h5``: y-tal's capture (``tal.io.read_capture`` reads it; ``H`` is
      the render transposed, stored in chunks of one scan row, or one scan point's laser
      grid for exhaustive capture; shards are cut on those chunks); returns the path.

    ``progress``: a tqdm bar (True, when tqdm is installed), a callback
    ``progress(done, total)`` or False."""
    ray = _ray()
    shape = tuple(scene.shape)
    n, bins = int(np.prod(shape[:-1])), shape[-1]
    opts = _options(spp, model, seed, cpus_per_shard, options)
    # The pilots (model = "auto", rr_early_survival = "auto") run here once, not per shard.
    opts.update(_umbra.resolve_pilots(scene, **opts))
    parts = shards or 4 * _workers(ray)
    hdf5 = out is not None and _is_hdf5(out)
    if out is not None and not hdf5 and not str(out).endswith(".npy"):
        raise ValueError(f"out={out!r}: a .npy or a y-tal .hdf5 / .h5 path")
    if hdf5:
        unit = _umbra.ytal_chunk_rows(scene)
        rows = [(a * unit, b * unit) for a, b in _even(n // unit, parts)]
    else:
        rows = _even(n, parts)
    task = _remote(ray, _render_rows, cpus_per_shard)
    scene_ref = ray.put(scene)
    refs = [task.remote(scene_ref, a, b, opts, _on_shard) for a, b in rows]
    bar = _bar(len(rows), "umbra render", progress)
    if hdf5:
        arrivals = _arrivals(ray, refs, bar)

        def blocks():
            for i, block, error in arrivals:
                if error is not None:
                    raise _shard_error("render", i, rows[i], error) from error
                yield rows[i][0], block
        try:
            _umbra.write_ytal_blocks(out, scene, blocks())
        finally:
            arrivals.close()
        return out
    if out is not None:
        mm, finish, tmp = _atomic_npy(out, shape)
        flat = mm.reshape(n, bins)
    else:
        result = np.empty(shape, np.float32)
        flat = result.reshape(n, bins)

    def take(i, block):
        a, b = rows[i]
        flat[a:b] = block
    try:
        _gather(ray, refs, "render", rows, take, bar)
    except BaseException:
        if out is not None:
            del mm, flat
            os.unlink(tmp)
        raise
    if out is None:
        return result
    del flat
    finish()
    return np.load(out, mmap_mode="r")


def grad(scene: "_umbra.Scene", adjoint: Any, *, spp: Optional[int] = None,
         model: Optional[str] = None, seed: Optional[int] = None, shards: Optional[int] = None,
         cpus_per_shard: int = 1, progress: Union[bool, Callable[[int, int], Any]] = True,
         _on_shard: Optional[Callable[[int, int], Any]] = None, **options: Any) -> Dict[str, Any]:
    """``umbra.grad(scene, adjoint, ...)`` on the Ray cluster: the same dict (``loss`` and
    ``render`` None), bit for bit. The gradient's measurements are cut into the
    renderer's fixed chunks (at most 16); ``shards`` (default: one per CPU of the cluster,
    at most one per chunk) get consecutive chunks and only their adjoint rows."""
    ray = _ray()
    shape = tuple(scene.shape)
    adjoint = np.ascontiguousarray(adjoint, dtype=np.float32)
    if adjoint.shape != shape:
        raise ValueError(f"adjoint has shape {adjoint.shape}, the render {shape}")
    n, bins = int(np.prod(shape[:-1])), shape[-1]
    flat = adjoint.reshape(n, bins)
    layout = _umbra.grad_chunk_layout(scene)
    groups = _even(len(layout), shards or _workers(ray))
    rows = [(layout[a][0], layout[b - 1][1]) for a, b in groups]
    opts = _options(spp, model, seed, cpus_per_shard, options)
    opts.update(_umbra.resolve_pilots(scene, **opts))
    task = _remote(ray, _grad_rows, cpus_per_shard)
    scene_ref = ray.put(scene)
    refs = [task.remote(scene_ref, flat[r[0]:r[1]], g, opts, _on_shard)
            for g, r in zip(groups, rows)]
    parts: List[Any] = []
    _gather(ray, refs, "grad", rows, lambda i, p: parts.extend(p),
            _bar(len(refs), "umbra grad", progress))
    out = _umbra.grad_combine(scene, parts, **opts)
    out["loss"], out["render"] = None, None
    return out


def _write_json(path: str, value: Any) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(value, f, indent=1, sort_keys=True)
    os.replace(tmp, path)


def _save(path: str, h: np.ndarray, scene) -> None:
    """``h`` to ``path`` atomically: ``.npy``, or y-tal's capture for ``.hdf5``."""
    if _is_hdf5(path):
        _umbra.save(path, h, scene)
        return
    d, name = os.path.split(path)
    tmp = os.path.join(d, f".{name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            np.save(f, h)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _render_scene(scene, opts, path):
    """Renders one scene of a data set: with ``path`` (a shared folder), the worker writes
    the file and returns only its shape; else the array comes back."""
    t0 = time.perf_counter()
    h = _umbra.render(scene, **opts)
    seconds = time.perf_counter() - t0
    if path is None:
        return h, list(h.shape), seconds
    _save(path, h, scene)
    return None, list(h.shape), seconds


FORMATS = {"npy": ".npy", "hdf5": ".hdf5"}


def render_many(scenes: Union[Mapping[str, Any], Iterable[Tuple[str, Any]]], out_dir: str, *,
                spp: Optional[int] = None, model: Optional[str] = None, seed: Optional[int] = None,
                format: str = "npy", shared_dir: bool = False, cpus_per_scene: int = 1,
                progress: Union[bool, Callable[[int, int], Any]] = True,
                **options: Any) -> Dict[str, Any]:
    """A data set: each ``(name, scene)`` (a ``umbra.Scene`` or a scene file's path)
    rendered with the same settings into ``out_dir/NAME.npy`` (``format="hdf5"``:
    ``NAME.hdf5``, y-tal's capture with the scene's grid and film), and
    ``out_dir/manifest.json`` (per name: file, shape, settings, seconds, or the error),
    rewritten after every scene. A rerun with the same settings skips the scenes already
    done; a scene that fails (a bad file, a render error) is recorded and reported, and
    the rest go on. ``shared_dir=True``: ``out_dir`` is on a file system every worker
    sees (NFS, a cluster's shared disk), so each worker writes its scene's file itself
    and only its shape comes back; by default the renders come back to this process,
    which writes them. Returns the manifest."""
    ray = _ray()
    if format not in FORMATS:
        raise ValueError(f"render_many: format={format!r}: one of {sorted(FORMATS)}")
    items = list(scenes.items() if isinstance(scenes, Mapping) else scenes)
    names = [n for n, _ in items]
    if len(set(names)) != len(names):
        raise ValueError("render_many: scene names must be unique")
    for n in names:
        if not n or os.sep in n or n.startswith("."):
            raise ValueError(f"render_many: scene name {n!r} is not a plain file name")
    os.makedirs(out_dir, exist_ok=True)
    mpath = os.path.join(out_dir, "manifest.json")
    manifest: Dict[str, Any] = {}
    if os.path.exists(mpath):
        with open(mpath, encoding="utf-8") as f:
            manifest = json.load(f)
    opts = _options(spp, model, seed, cpus_per_scene, options)
    settings = {k: v for k, v in opts.items() if k != "threads"}
    settings["format"] = format

    def file_of(name: str) -> str:
        return f"{name}{FORMATS[format]}"

    def done(name):
        e = manifest.get(name, {})
        return (e.get("status") == "done" and e.get("settings") == settings
                and os.path.exists(os.path.join(out_dir, e.get("file", ""))))
    todo = [(n, s) for n, s in items if not done(n)]
    task = _remote(ray, _render_scene, cpus_per_scene)
    refs, which, kept = [], [], {}
    for name, s in todo:
        try:
            sc = s if isinstance(s, _umbra.Scene) else _umbra.load_scene(os.fspath(s))
        except Exception as e:
            manifest[name] = dict(status="failed", error=_cause(e), settings=settings)
            continue
        path = os.path.abspath(os.path.join(out_dir, file_of(name)))
        refs.append(task.remote(sc, opts, path if shared_dir else None))
        which.append(name)
        kept[name] = sc
    _write_json(mpath, manifest)

    def take(i: int, result: Any) -> None:
        name = which[i]
        h, shape, seconds = result
        if h is not None:
            _save(os.path.join(out_dir, file_of(name)), h, kept[name])
        manifest[name] = dict(status="done", file=file_of(name), shape=shape,
                              settings=settings, seconds=seconds)
        _write_json(mpath, manifest)

    def fail(i: int, e: BaseException) -> None:
        manifest[which[i]] = dict(status="failed", error=_cause(e), settings=settings)
        _write_json(mpath, manifest)
    _each(ray, refs, take, _bar(len(refs), "umbra render_many", progress), fail)
    return manifest


def _fit_one(job, output):
    from . import fit
    job = dict(job)
    scene = job.pop("scene")
    if not isinstance(scene, _umbra.Scene):
        scene = _umbra.load_scene(os.fspath(scene))
    measured = job.pop("measured", None)
    resume = os.path.exists(os.path.join(output, "checkpoint"))
    out = fit(scene, measured, output=output, resume=resume, **job)
    keep = ("final_loss", "relative_l2", "scale", "background", "seconds", "init",
            "photon_noise_floor", "chamfer", "undetermined_faces", "unsupported_faces")
    return {k: out.get(k) for k in keep}


def fit_many(jobs: Union[Mapping[str, Mapping[str, Any]], Iterable[Tuple[str, Mapping[str, Any]]]],
             out_root: str, *, cpus_per_fit: int = 1,
             progress: Union[bool, Callable[[int, int], Any]] = True) -> Dict[str, Any]:
    """Several ``umbra.fit`` runs at once: each ``(name, job)`` (``job``: ``scene`` (a
    ``umbra.Scene`` or a path), ``measured`` and any ``umbra.fit`` keyword) fitted into
    ``out_root/NAME`` with its own checkpoint; a rerun resumes each from its checkpoint
    (a finished fit's checkpoint returns it at once). ``out_root`` must be reachable by
    every worker (one machine, or a shared file system). Returns, per name, the fit's
    figures (``final_loss``, ``relative_l2``, ``seconds``, ...) or ``{"error": ...}``;
    a failed fit does not stop the others."""
    ray = _ray()
    items = list(jobs.items() if isinstance(jobs, Mapping) else jobs)
    task = _remote(ray, _fit_one, cpus_per_fit)
    refs = []
    for name, job in items:
        job = dict(job)
        job.setdefault("threads", cpus_per_fit)
        refs.append(task.remote(job, os.path.join(out_root, name)))
    results: Dict[str, Any] = {}

    def take(i: int, result: Any) -> None:
        results[items[i][0]] = result

    def fail(i: int, e: BaseException) -> None:
        results[items[i][0]] = {"error": _cause(e)}
    _each(ray, refs, take, _bar(len(refs), "umbra fit_many", progress), fail)
    return results
