"""umbra.distributed on a local Ray cluster started here (two worker processes): a render
and a gradient split into shards give umbra.render's and umbra.grad's bits for single,
confocal and exhaustive capture; a worker killed mid-render (by its PID) is retried and
the array is unchanged; render_many resumes; fit_many fits each job into its folder.
UMBRA_SKIP_RAY=1 skips these tests (the test command installs Ray otherwise)."""
from __future__ import annotations

import functools
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

if os.environ.get("UMBRA_SKIP_RAY") == "1":
    pytest.skip("UMBRA_SKIP_RAY=1: the Ray tests are skipped", allow_module_level=True)

import ray  # noqa: E402  (installed by ./test.sh)

import umbra  # noqa: E402
import umbra.distributed as ud  # noqa: E402
from conftest import require_ytal  # noqa: E402
from scenes_two import two_object_scene  # noqa: E402
from ytal_reader import read_with_ytal  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def cluster():
    # The workers cannot import this file: its hook goes to them by value.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a.view(np.uint8), b.view(np.uint8)))


@pytest.mark.parametrize("capture", ["single", "confocal", "exhaustive"])
def test_render_and_grad_equal_the_local_ones_bit_for_bit(tmp_path: Path, capture: str):
    s = two_object_scene(tmp_path, capture, scan=4)
    for model, spp in [("tri3", None), ("path", 24)]:
        local = umbra.render(s, model=model, spp=spp, seed=3)
        assert local.max() > 0
        far = ud.render(s, model=model, spp=spp, seed=3, shards=5, progress=False)
        assert same_bits(local, far), f"{capture} {model}: render differs"
        adj = (np.random.default_rng(1).standard_normal(local.shape) * 1e-3).astype(np.float32)
        g = umbra.grad(s, adjoint=adj, model=model, spp=spp, seed=3)
        gd = ud.grad(s, adj, model=model, spp=spp, seed=3, shards=3, progress=False)
        for k in range(2):
            assert np.abs(g["vertices"][k]).max() > 0
            assert same_bits(g["vertices"][k], gd["vertices"][k]), f"{capture} {model}: vertex grad"
        assert same_bits(g["albedo"], gd["albedo"])
        assert gd["boundary_terms"] == g["boundary_terms"]


def test_the_pilots_run_once_and_every_shard_plays_their_choice(tmp_path: Path):
    # From 1024 spp path's roulette pilot runs (transport::roulette): umbra.distributed
    # runs it once (_umbra.resolve_pilots) and hands its survival to the shards.
    from umbra import _umbra
    s = two_object_scene(tmp_path, "confocal", scan=4)
    picked = _umbra.resolve_pilots(s, model="path", spp=1024, seed=3)
    assert set(picked) == {"rr_early_survival"}, picked
    q = picked["rr_early_survival"]
    assert 0.2 <= q <= 1.0
    assert _umbra.resolve_pilots(s, model="path", spp=1024, seed=3, rr_early_survival=0.5) == {}
    assert _umbra.resolve_pilots(s, model="tri3") == {}
    auto = _umbra.resolve_pilots(s, model="auto", spp=1024, seed=3)
    assert auto["model"] in ("tri3", "mc3", "path"), auto
    local = umbra.render(s, model="path", spp=1024, seed=3)
    assert same_bits(local, umbra.render(s, model="path", spp=1024, seed=3, rr_early_survival=q))
    far = ud.render(s, model="path", spp=1024, seed=3, shards=3, progress=False)
    assert same_bits(local, far)
    adj = (np.random.default_rng(2).standard_normal(local.shape) * 1e-3).astype(np.float32)
    g = umbra.grad(s, adjoint=adj, model="path", spp=1024, seed=3)
    gd = ud.grad(s, adj, model="path", spp=1024, seed=3, shards=2, progress=False)
    for k in range(2):
        assert same_bits(g["vertices"][k], gd["vertices"][k])


def test_a_render_streams_into_an_npy_file(tmp_path: Path):
    s = two_object_scene(tmp_path, "exhaustive", scan=4)
    out = tmp_path / "h.npy"
    seen = []
    m = ud.render(s, model="tri3", out=str(out), shards=6, progress=lambda d, t: seen.append((d, t)))
    assert isinstance(m, np.memmap) and same_bits(np.asarray(m), umbra.render(s, model="tri3"))
    assert seen[-1] == (6, 6) and [d for d, _ in seen] == list(range(1, 7))
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".umbra-")] == []
    with pytest.raises(ValueError, match=r"\.npy"):
        ud.render(s, model="tri3", out=str(tmp_path / "h.exr"))


def _fail_from_row_four(start: int, stop: int) -> None:  # runs in a Ray worker
    if start >= 4:
        raise RuntimeError("a shard's own failure")


@pytest.mark.parametrize("capture", ["confocal", "exhaustive"])
def test_a_render_streams_into_a_ytal_capture_that_ytal_reads(tmp_path: Path, capture: str):
    python = require_ytal()
    s = two_object_scene(tmp_path, capture, scan=4)
    local = umbra.render(s, model="path", spp=8, seed=2)
    out = tmp_path / "h.hdf5"
    assert ud.render(s, model="path", spp=8, seed=2, shards=3, out=str(out), progress=False) == str(out)
    meta, H, _, _ = read_with_ytal(python, out, tmp_path)
    assert meta["H_format"] == ("T_Lx_Ly_Sx_Sy" if capture == "exhaustive" else "T_Sx_Sy")
    axes = tuple(range(local.ndim))[::-1]
    assert same_bits(H, np.ascontiguousarray(local.transpose(axes))), f"{capture}: y-tal's H differs"
    # A failing shard: its error, and no file nor temporary left.
    out2 = tmp_path / "bad.h5"
    with pytest.raises(umbra.UmbraError, match=r"render: shard \d+ \(measurements \d+\.\.\d+\)"):
        ud.render(s, model="tri3", out=str(out2), progress=False, _on_shard=_fail_from_row_four)
    assert not out2.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".bad.h5")]


def _pause_first(flag_dir: str, start: int, stop: int) -> None:  # runs in a Ray worker
    """A shard hook: writes its worker's PID, then waits, until the test has killed one."""
    if not os.path.exists(os.path.join(flag_dir, "killed")):
        Path(flag_dir, f"pid-{start}-{os.getpid()}").write_text("")
        time.sleep(5)


def test_a_worker_killed_mid_render_is_retried_and_the_array_is_unchanged(tmp_path: Path):
    s = two_object_scene(tmp_path, "confocal", scan=6)
    local = umbra.render(s, model="path", spp=64, seed=5)
    flags = tmp_path / "flags"
    flags.mkdir()
    killed = []

    def killer():
        deadline = time.time() + 60
        while time.time() < deadline and not killed:
            for p in flags.glob("pid-*"):
                pid = int(p.name.split("-")[2])
                (flags / "killed").write_text(str(pid))
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.05)
    t = threading.Thread(target=killer)
    t.start()
    far = ud.render(s, model="path", spp=64, seed=5, shards=4, progress=False,
                    _on_shard=functools.partial(_pause_first, str(flags)))
    t.join()
    assert killed, "no shard started"
    with pytest.raises(ProcessLookupError):
        os.kill(killed[0], 0)  # the worker is gone
    assert same_bits(local, far)


def test_render_many_skips_what_is_done_and_reports_a_failure(tmp_path: Path):
    scenes = {n: two_object_scene(tmp_path / n, "confocal", scan=3) for n in "abc"
              if (tmp_path / n).mkdir() is None}
    out = tmp_path / "set"
    first = ud.render_many({"a": scenes["a"], "b": scenes["b"], "bad": tmp_path / "missing.toml"},
                           str(out), model="tri3", progress=False)
    assert first["a"]["status"] == first["b"]["status"] == "done"
    assert first["bad"]["status"] == "failed" and "missing.toml" in first["bad"]["error"]
    stamp = (out / "a.npy").stat().st_mtime_ns
    # An interrupted run's manifest may name a file that never got written: done again.
    manifest = json.loads((out / "manifest.json").read_text())
    (out / "b.npy").unlink()
    second = ud.render_many(scenes, str(out), model="tri3", progress=False)
    assert (out / "a.npy").stat().st_mtime_ns == stamp, "a finished scene was rendered again"
    for n in "abc":
        assert second[n]["status"] == "done"
        assert same_bits(np.load(out / f"{n}.npy"), umbra.render(scenes[n], model="tri3"))
    assert manifest["a"] == second["a"]
    # Other settings are another data set: nothing is skipped.
    third = ud.render_many({"a": scenes["a"]}, str(out), model="tri3", spp=2, progress=False)
    assert (out / "a.npy").stat().st_mtime_ns != stamp and third["a"]["settings"]["spp"] == 2


def test_render_many_writes_ytal_captures_from_the_workers(tmp_path: Path):
    python = require_ytal()
    scenes = {n: two_object_scene(tmp_path / n, "confocal", scan=3) for n in "ab"
              if (tmp_path / n).mkdir() is None}
    out = tmp_path / "set"
    m = ud.render_many(scenes, str(out), model="tri3", format="hdf5", shared_dir=True,
                       progress=False)
    for n in "ab":
        assert m[n]["status"] == "done" and m[n]["file"] == f"{n}.hdf5"
        assert m[n]["settings"]["format"] == "hdf5"
        _, H, _, _ = read_with_ytal(python, out / f"{n}.hdf5", tmp_path)
        assert same_bits(H, np.ascontiguousarray(umbra.render(scenes[n], model="tri3").transpose(2, 1, 0)))
    assert sorted(p.name for p in out.iterdir()) == ["a.hdf5", "b.hdf5", "manifest.json"]
    # The .npy data set in the same folder is another one: rendered, not skipped.
    again = ud.render_many(scenes, str(out), model="tri3", shared_dir=True, progress=False)
    assert again["a"]["file"] == "a.npy" and (out / "a.npy").is_file()
    with pytest.raises(ValueError, match="format='exr'"):
        ud.render_many(scenes, str(out), format="exr", progress=False)


def test_fit_many_fits_each_job_into_its_folder_and_resumes(tmp_path: Path):
    s = two_object_scene(tmp_path, "confocal", scan=4)
    target = umbra.render(s)
    moved = s.copy()
    moved.set_vertices(s.vertices(0) + np.array([0, 0, 0.02], np.float32), 0)
    job = dict(scene=moved, measured=target, init="scene", known_scale=True, background="none",
               schedule=[dict(iters=3, solver="adam", lr=0.004, large_steps=0.0)])
    jobs = {"one": job, "two": dict(job, schedule=[dict(iters=4, solver="adam", lr=0.002)]),
            "broken": dict(job, init="cube")}
    r = ud.fit_many(jobs, str(tmp_path / "fits"), progress=False)
    assert r["one"]["relative_l2"] < 1 and r["two"]["relative_l2"] < 1
    assert "init" in r["broken"]["error"]
    for n in ("one", "two"):
        assert (tmp_path / "fits" / n / "mesh.obj").is_file()
        assert (tmp_path / "fits" / n / "checkpoint").is_dir()
    again = ud.fit_many({"one": job}, str(tmp_path / "fits"), progress=False)
    assert again["one"]["final_loss"] == r["one"]["final_loss"]


def test_errors_name_the_shard_and_the_argument(tmp_path: Path):
    s = two_object_scene(tmp_path, "confocal", scan=3)
    # Options are checked once, before any shard runs (with the pilots, resolve_pilots).
    with pytest.raises(umbra.UmbraError, match=r"model: 'bogus' is not one of"):
        ud.render(s, model="bogus", progress=False)
    with pytest.raises(umbra.UmbraError,
                       match=r"render: shard \d+ \(measurements [4-9]\.\.\d+\) failed: .*a shard's own failure"):
        ud.render(s, model="tri3", shards=3, progress=False, _on_shard=_fail_from_row_four)
    with pytest.raises(ValueError, match=r"adjoint has shape \(2, 2\)"):
        ud.grad(s, np.zeros((2, 2)), progress=False)
