"""The `umbra` Python package (PyO3 bindings): numpy in and out, errors as exceptions,
reproducibility, the same numbers as the CLI, dict scenes, the GIL released, Ctrl-C."""
from __future__ import annotations

import _thread
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import umbra
from conftest import VALIDATION, require_umbra

import mtutil  # noqa: E402  (python/validation, on the path via conftest)

T_XML = VALIDATION / "scenes" / "T.xml"


def small_scene() -> umbra.Scene:
    return umbra.load_scene(T_XML, scan_x=8, scan_y=8, bins=128, spp=64)


def test_render_layout_and_reproducibility():
    s = small_scene()
    h = umbra.render(s, model="mc3", seed=3)
    assert h.dtype == np.float32 and h.shape == (8, 8, 128) == tuple(s.shape)
    assert np.isfinite(h).all() and h.sum() > 0
    assert np.array_equal(h, umbra.render(s, model="mc3", seed=3, threads=1))
    assert not np.array_equal(h, umbra.render(s, model="mc3", seed=4))


def test_render_and_grad_equal_the_cli(tmp_path: Path, umbra_bin: str):
    exe = require_umbra(umbra_bin)
    defines = ["-D", "scan_x=8", "-D", "scan_y=8", "-D", "bins=128"]
    out = tmp_path / "h.npy"
    subprocess.run([exe, "render", str(T_XML), *defines, "--model", "mc3", "--spp", "64",
                    "--seed", "5", "-o", str(out), "--no-preview", "-q"], check=True)
    s = small_scene()
    h = umbra.render(s, model="mc3", spp=64, seed=5)
    assert np.array_equal(h, np.load(out))
    adj = np.random.default_rng(1).normal(size=h.shape).astype(np.float32)
    np.save(tmp_path / "adj.npy", adj)
    subprocess.run([exe, "grad", str(T_XML), *defines, "--model", "mc3", "--spp", "64", "--seed", "5",
                    "--adjoint", str(tmp_path / "adj.npy"), "-o", str(tmp_path / "g.npz")],
                   check=True, capture_output=True)
    g = umbra.grad(s, adj, model="mc3", spp=64, seed=5)
    cli = np.load(tmp_path / "g.npz")
    assert g["vertices"][0].shape == cli["vertices"].shape == (s.vertices().shape[0], 3)
    assert np.array_equal(g["vertices"][0], cli["vertices"])
    assert np.array_equal(g["albedo"], cli["albedo"])
    # With a target: the CLI's --target and grad(target=...) agree, loss value included.
    target = umbra.render(s, model="mc3", spp=64, seed=9)
    np.save(tmp_path / "target.npy", target)
    for loss in ("l2", "l2-normalized"):
        subprocess.run([exe, "grad", str(T_XML), *defines, "--model", "mc3", "--spp", "64",
                        "--seed", "5", "--target", str(tmp_path / "target.npy"), "--loss", loss,
                        "-o", str(tmp_path / "gt.npz")], check=True, capture_output=True)
        cli = np.load(tmp_path / "gt.npz")
        g = umbra.grad(s, target=target, loss=loss, model="mc3", spp=64, seed=5)
        assert g["loss"] == pytest.approx(float(cli["loss"]), rel=1e-12)
        assert np.array_equal(g["vertices"][0], cli["vertices"])
        assert np.array_equal(g["render"], h)


def test_vertices_and_albedo_round_trip_and_bad_input():
    s = small_scene()
    v = s.vertices()
    assert v.dtype == np.float32 and v.shape[1] == 3
    moved = s.copy()
    moved.set_vertices(v + np.array([0.0, 0.0, 0.01]))
    assert np.allclose(moved.vertices(), v + [0, 0, 0.01], atol=1e-6)
    assert np.array_equal(s.vertices(), v), "copy() must not share vertices"
    moved.set_albedo(0.3)
    assert moved.albedo[0] == pytest.approx(0.3)
    assert s.triangles().shape[1] == 3
    with pytest.raises(umbra.UmbraError, match=r"shape \(2, 3\), expected"):
        s.set_vertices(np.zeros((2, 3)))
    bad = v.astype(np.float64)
    bad[1, 2] = np.nan
    with pytest.raises(umbra.UmbraError, match="non-finite value at row 1"):
        s.set_vertices(bad)
    with pytest.raises(umbra.UmbraError, match="outside"):
        s.set_albedo(1.5)
    with pytest.raises(umbra.UmbraError, match="object 3 does not exist"):
        s.vertices(3)
    with pytest.raises(umbra.UmbraError, match="adjoint has shape"):
        umbra.grad(s, np.zeros((2, 2), np.float32), model="mc3")
    with pytest.raises(umbra.UmbraError, match="target has shape"):
        umbra.grad(s, target=np.zeros((2, 2)), model="mc3")
    with pytest.raises(umbra.UmbraError, match="adjoint: expected an array of real numbers"):
        umbra.grad(s, np.full(tuple(s.shape), "x"), model="mc3")
    with pytest.raises(umbra.UmbraError, match="either adjoint"):
        umbra.grad(s, model="mc3")
    with pytest.raises(umbra.UmbraError, match="loss: unknown loss 'l1'"):
        umbra.grad(s, target=np.zeros(tuple(s.shape)), loss="l1")
    with pytest.raises(umbra.UmbraError, match="vertices of object 0: expected an array of real"):
        s.copy().set_vertices(np.array([["a", "b", "c"]] * v.shape[0]))


def test_errors_name_the_file():
    with pytest.raises(umbra.UmbraError, match="nope.toml"):
        umbra.load_scene("nope.toml")
    with pytest.raises(umbra.UmbraError, match="is not one of"):
        umbra.render(small_scene(), model="bogus")


def _rot_y_then_translate(angle_deg, t):
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = np.cos(a), np.sin(a), -np.sin(a), np.cos(a)
    m[:3, 3] = t
    return m


def test_dict_scene_matches_its_xml():
    """The letter scene of python/validation/scenes/T.xml written as a Mitsuba dict."""
    rgb = lambda v: {"type": "rgb", "value": [v, v, v]}  # noqa: E731
    d = {
        "type": "scene",
        "integrator": {"type": "transient_nlos_path", "max_depth": 3, "filter_bounces": 2,
                       "discard_direct_paths": False, "nlos_laser_sampling": True,
                       "nlos_hidden_geometry_sampling": True,
                       "nlos_hidden_geometry_sampling_do_rroulette": False,
                       "nlos_hidden_geometry_sampling_includes_relay_wall": False,
                       "account_first_and_last_bounces": False, "capture_type": "single",
                       "temporal_filter": "box"},
        "laser": {"type": "projector", "irradiance": rgb(1.0), "fov": 0.2,
                  "to_world": mtutil.lookat([0.4, -0.3, 0.5], [0.1, 0.1, 0.0], [0, 1, 0])},
        "T": {"type": "obj", "filename": "T.obj", "face_normals": True,
              "to_world": _rot_y_then_translate(20.0, [0.05, -0.02, 0.95]),
              "bsdf": {"type": "diffuse", "reflectance": rgb(0.7)}},
        "relay_wall": {"type": "rectangle", "to_world": np.diag([0.5, 0.5, 1.0, 1.0]),
                       "bsdf": {"type": "diffuse", "reflectance": rgb(0.8)},
                       "sensor": {"type": "nlos_capture_meter", "sensor_origin": [-0.5, 0.0, 0.3],
                                  "sampler": {"type": "independent", "sample_count": 64, "seed": 0},
                                  "film": {"type": "transient_hdr_film", "width": 8, "height": 8,
                                           "temporal_bins": 128, "bin_width_opl": 0.006,
                                           "start_opl": 1.6, "rfilter": {"type": "box"}}}},
    }
    from_dict = umbra.load_scene(d, base_dir=str(T_XML.parent))
    from_xml = small_scene()
    assert from_dict.shape == from_xml.shape
    assert np.allclose(from_dict.vertices(), from_xml.vertices(), atol=1e-5)
    a = umbra.render(from_dict, model="mc3", seed=2)
    b = umbra.render(from_xml, model="mc3", seed=2)
    assert np.allclose(a, b, rtol=1e-4, atol=1e-6 * b.max())
    with pytest.raises(umbra.UmbraError, match="unknown plugin type 'teapot'"):
        umbra.load_scene({"type": "scene", "x": {"type": "teapot"}})


def test_gil_is_released_while_rendering():
    """A Python thread keeps running while Umbra renders: renders back to back for 0.6 s
    while a thread ticks every millisecond. With the GIL held during renders it would tick
    about once per render."""
    s = umbra.load_scene(T_XML, scan_x=16, scan_y=16, bins=256)
    ticks = 0
    done = threading.Event()

    def count():
        nonlocal ticks
        while not done.is_set():
            ticks += 1
            time.sleep(0.001)

    t = threading.Thread(target=count)
    t.start()
    start, renders = time.perf_counter(), 0
    while time.perf_counter() - start < 0.6:
        umbra.render(s, model="path", spp=512)
        renders += 1
    elapsed = time.perf_counter() - start
    done.set()
    t.join()
    # Sleeping 1 ms per tick on a loaded 2-core machine: expect well over 100 ticks.
    assert ticks > max(5 * renders, 0.1 * elapsed / 0.001), (ticks, renders, elapsed)


def test_ctrl_c_interrupts_a_long_render():
    s = umbra.load_scene(T_XML, scan_x=32, scan_y=32, bins=256)
    threading.Timer(0.3, _thread.interrupt_main).start()
    start = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        umbra.render(s, model="path", spp=1 << 16)  # minutes, uninterrupted
    assert time.perf_counter() - start < 5.0
