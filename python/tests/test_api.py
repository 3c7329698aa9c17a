"""The Python API beyond the basics of test_package.py: every CLI option as a keyword,
grad's types and its target/loss form, several hidden objects, `umbra.fit`, `umbra.save`, and the
package's typing (version, py.typed, stubs)."""
from __future__ import annotations

import ast
import inspect
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import umbra
from conftest import PY_DIR, VALIDATION, require_umbra
from scenes_two import two_object_scene

T_XML = VALIDATION / "scenes" / "T.xml"


def small_scene() -> umbra.Scene:
    return umbra.load_scene(T_XML, scan_x=6, scan_y=6, bins=128, spp=32)


def test_every_cli_render_option_is_a_keyword(umbra_bin: str):
    """The option names are `umbra render --help`'s flags, and render and grad take each."""
    exe = require_umbra(umbra_bin)
    help_text = subprocess.run([exe, "render", "--help"], capture_output=True, text=True,
                               check=True).stdout
    for name in umbra.option_names():
        assert f"--{name.replace('_', '-')}" in help_text, name
        for f in (umbra.render, umbra.grad):
            assert name in inspect.signature(f).parameters, (f.__name__, name)
    # ... and every flag of `umbra render` that is not about files or the terminal is one.
    flags = set(re.findall(r"--([a-z][a-z-]*)", help_text))
    not_options = {"output", "define", "no-preview", "quiet", "help", "version"}
    assert flags - not_options == {n.replace("_", "-") for n in umbra.option_names()}
    assert set(umbra.default_scene().options) | {"threads"} == set(umbra.option_names())


def test_options_override_the_scene_and_equal_the_cli(tmp_path: Path, umbra_bin: str):
    exe = require_umbra(umbra_bin)
    s = small_scene()
    opts = s.options
    assert opts["spp"] == 32 and opts["max_depth"] == 3
    # Unset options come from the scene: passing the scene's own values changes nothing.
    base = umbra.render(s, model="path")
    assert np.array_equal(base, umbra.render(s, model="path", spp=opts["spp"], seed=opts["seed"],
                                             max_depth=opts["max_depth"],
                                             laser_sampling=opts["laser_sampling"]))
    # The core's own checks reach Python as UmbraError (here: a point laser spot can only
    # be reached by laser sampling).
    with pytest.raises(umbra.UmbraError, match="laser sampling off"):
        umbra.render(s, model="path", laser_sampling=False)
    # All bounces kept (the file keeps only three): max_depth then matters where longer
    # paths exist. With the file's techniques (laser + hidden-geometry sampling, the wall
    # not sampled) the planar letter has none: a path cannot leave it for the wall, so
    # max_depth is compared with BSDF sampling on (letter -> wall -> letter paths). Those
    # are 3.6 m or longer (four times the letter's gap to the wall): the film must reach
    # them (512 bins of 6 mm from 1.6 m: to 4.67 m), else they are not even traced.
    allb = umbra.load_scene(T_XML, scan_x=6, scan_y=6, bins=512, spp=32, filter_bounces=-1)
    base1 = umbra.render(allb, model="path", seed=1)
    with_bsdf = dict(bsdf_sampling=True)
    base_bsdf = umbra.render(allb, model="path", seed=1, **with_bsdf)
    cases = [(dict(max_depth=-1, spp=8, **with_bsdf), base_bsdf),
             (dict(max_depth=6, **with_bsdf), base_bsdf),
             (with_bsdf, base1),
             (dict(hidden_geometry_sampling=False, bsdf_sampling=True), base1)]
    for kw, other in cases:
        h = umbra.render(allb, model="path", seed=1, **kw)
        assert not np.array_equal(h, other), kw
        flags = [f"--{k.replace('_', '-')}={str(v).lower()}" for k, v in kw.items()]
        out = tmp_path / "h.npy"
        subprocess.run([exe, "render", str(T_XML), "-D", "scan_x=6", "-D", "scan_y=6", "-D",
                        "bins=512", "-D", "spp=32", "-D", "filter_bounces=-1", "--model", "path",
                        "--seed", "1", *flags,
                        "-o", str(out), "--no-preview", "-q"], check=True, capture_output=True)
        assert np.array_equal(h, np.load(out)), kw
    # The tri3 options reach the renderer: a coarser subdivision renders differently.
    a = umbra.render(s, model="tri3", subdivision=0.15)
    b = umbra.render(s, model="tri3", subdivision=5.0)
    assert not np.array_equal(a, b)
    # The scene itself is untouched by per-call options.
    assert s.options == opts


def test_bad_options_name_the_argument():
    s = small_scene()
    with pytest.raises(umbra.UmbraError, match="model: 'bogus' is not one of"):
        umbra.render(s, model="bogus")
    with pytest.raises(umbra.UmbraError, match="visibility: 'maybe'"):
        umbra.render(s, visibility="maybe")
    with pytest.raises(umbra.UmbraError, match="^spp: "):
        umbra.render(s, spp=-3)
    with pytest.raises(umbra.UmbraError, match="^spp: "):
        umbra.render(s, spp="many")
    with pytest.raises(umbra.UmbraError, match="max_depth: must be -1 or >= 3 bounces, got 2"):
        umbra.grad(s, np.zeros(tuple(s.shape), np.float32), max_depth=2)
    with pytest.raises(umbra.UmbraError, match="^laser_sampling: "):
        umbra.render(s, laser_sampling="yes")
    with pytest.raises(umbra.UmbraError, match="unknown option 'colour'"):
        umbra._umbra.render(s, colour=1)


def test_grad_types_and_target_form(tmp_path: Path):
    s = two_object_scene(tmp_path)
    assert len(s.objects) == 2
    target = umbra.render(s)
    s.set_vertices(s.vertices(1) + [0.0, 0.0, 0.01], 1)
    h = umbra.render(s)
    g = umbra.grad(s, target=target)
    # The loss is the L2 of numpy's own difference, and the adjoint form gives the same.
    assert g["loss"] == pytest.approx(float(((h.astype(np.float64) - target) ** 2).sum()), rel=1e-6)
    assert np.array_equal(g["render"], h)
    ga = umbra.grad(s, 2 * (h - target))
    assert ga["loss"] is None and ga["render"] is None
    for k in range(2):
        np.testing.assert_allclose(ga["vertices"][k], g["vertices"][k], rtol=1e-5,
                                   atol=1e-6 * np.abs(g["vertices"][k]).max())
    # Types: lists per object, float64 everywhere.
    assert isinstance(g["vertices"], list) and len(g["vertices"]) == 2
    for k in range(2):
        assert g["vertices"][k].dtype == np.float64
        assert g["vertices"][k].shape == s.vertices(k).shape
    assert g["albedo"].dtype == np.float64 and g["albedo"].shape == (2,)
    assert g["vertex_albedo"] == [None, None]
    # A single-object scene: the same types.
    g1 = umbra.grad(small_scene(), np.ones(tuple(small_scene().shape), np.float32), model="tri3")
    assert isinstance(g1["vertices"], list) and len(g1["vertices"]) == 1
    # Object 1's vertices move the loss; object 0 sits where the target has it but sees
    # the same residual: check object 1's gradient against central differences.
    rng = np.random.default_rng(0)
    v1 = s.vertices(1).astype(np.float64)
    for _ in range(4):
        i, c = int(rng.integers(v1.shape[0])), int(rng.integers(3))
        hstep = 2e-4
        losses = []
        for sign in (1, -1):
            m = s.copy()
            vv = v1.copy()
            vv[i, c] += sign * hstep
            m.set_vertices(vv, 1)
            losses.append(((umbra.render(m).astype(np.float64) - target) ** 2).sum())
        fd = (losses[0] - losses[1]) / (2 * hstep)
        ad = g["vertices"][1][i, c]
        scale = max(abs(fd), 0.05 * np.abs(g["vertices"][1]).max())
        assert abs(ad - fd) < 0.05 * scale, (i, c, ad, fd)


def test_vertex_albedo_gradient_matches_finite_differences(tmp_path: Path):
    s = two_object_scene(tmp_path)
    n = s.vertices(0).shape[0]
    s.set_vertex_albedo(np.linspace(0.3, 0.8, n), 0)
    assert s.vertex_albedo(0).dtype == np.float32
    w = np.random.default_rng(2).normal(size=tuple(s.shape)).astype(np.float32)
    g = umbra.grad(s, w)
    assert g["vertex_albedo"][0].dtype == np.float64 and g["vertex_albedo"][1] is None
    a0 = s.vertex_albedo(0).astype(np.float64)
    for i in (0, n // 2, n - 1):
        vals = []
        for sign in (1, -1):
            m = s.copy()
            a = a0.copy()
            a[i] += sign * 0.05
            m.set_vertex_albedo(a, 0)
            vals.append(float((umbra.render(m).astype(np.float64) * w).sum()))
        fd = (vals[0] - vals[1]) / 0.1
        assert abs(g["vertex_albedo"][0][i] - fd) < 1e-3 * max(abs(fd), 1e-12) + 1e-9, (i, fd)
    with pytest.raises(umbra.UmbraError, match=r"vertex albedo of object 0: shape \(2,\)"):
        s.set_vertex_albedo([0.5, 0.5], 0)
    with pytest.raises(umbra.UmbraError, match="outside"):
        s.set_vertex_albedo(np.full(n, 2.0), 0)


def test_scene_geometry_cache_follows_edits():
    """A render after set_vertices / set_albedo sees the change (the cached acceleration
    structure is dropped), and equals a fresh scene's render."""
    s = small_scene()
    umbra.render(s, model="tri3")
    v = s.vertices() + np.array([0.0, 0.0, 0.05], np.float32)
    s.set_vertices(v)
    s.set_albedo(0.3)
    fresh = small_scene()
    fresh.set_vertices(v)
    fresh.set_albedo(0.3)
    assert np.array_equal(umbra.render(s, model="tri3"), umbra.render(fresh, model="tri3"))


def test_save_writes_each_format_atomically_and_checks_the_shape(tmp_path: Path):
    s = small_scene()
    h = umbra.render(s, model="tri3")
    umbra.save(tmp_path / "h.npy", h, s)
    assert np.array_equal(np.load(tmp_path / "h.npy"), h)
    umbra.save(str(tmp_path / "h.hdf5"), h, s)
    assert (tmp_path / "h.hdf5").read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    umbra.save(tmp_path / "h.exr", h.astype(np.float64), s)  # converted once
    assert (tmp_path / "h.exr").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.exr", "h.hdf5", "h.npy"]
    with pytest.raises(umbra.UmbraError, match=r"transient has shape \(6, 6\), the render \(6, 6, 128\)"):
        umbra.save(tmp_path / "x.npy", h[..., 0], s)
    with pytest.raises(umbra.UmbraError, match=r"x\.txt: unknown output format"):
        umbra.save(tmp_path / "x.txt", h, s)
    assert not (tmp_path / "x.npy").exists()


def test_version_typing_and_stubs():
    pkg = Path(umbra.__file__).parent
    assert (pkg / "py.typed").is_file() and (pkg / "_umbra.pyi").is_file()
    pyproject = (PY_DIR / "pyproject.toml").read_text()
    assert f'version = "{umbra.__version__}"' in pyproject
    tree = ast.parse((pkg / "_umbra.pyi").read_text())
    stubbed = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    public = {n for n in dir(umbra._umbra) if not n.startswith("_")}
    assert public <= stubbed | {"__version__"}, public - stubbed
    scene_cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Scene")
    methods = {n.name for n in scene_cls.body if isinstance(n, ast.FunctionDef)}
    assert {n for n in dir(umbra.Scene) if not n.startswith("_")} <= methods
    for f in tree.body:
        if isinstance(f, ast.FunctionDef):
            assert ast.get_docstring(f), f.name
    # Keyword sets of the stubs are the binding's.
    assert [a.arg for a in next(f for f in tree.body if getattr(f, "name", "") == "render")
            .args.kwonlyargs] == umbra.option_names()


def test_mypy_accepts_a_script_using_the_api(tmp_path: Path):
    mypy = shutil.which("mypy") or (Path(sys.executable).parent / "mypy")
    if not Path(mypy).exists():
        pytest.skip("mypy is not installed")
    script = tmp_path / "use.py"
    script.write_text(
        "import numpy as np\nimport umbra\n"
        "s: umbra.Scene = umbra.default_scene()\n"
        "h: np.ndarray = umbra.render(s, model='tri3', spp=4, max_depth=3)\n"
        "g = umbra.grad(s, target=h, loss='l2')\n"
        "v: np.ndarray = s.vertices(0)\n"
        "s.set_vertices(v, 0)\n"
        "print(umbra.__version__, g['loss'], s.options['spp'])\n")
    r = subprocess.run([str(mypy), "--strict", str(script)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    bad = tmp_path / "bad.py"
    bad.write_text("import umbra\numbra.render(umbra.default_scene(), spp='many')\n")
    r = subprocess.run([str(mypy), str(bad)], capture_output=True, text=True)
    assert r.returncode != 0 and "spp" in r.stdout, r.stdout


def test_fit_runs_the_cli_fit_on_a_tiny_scene(tmp_path: Path):
    """umbra.fit on a known answer: a target rendered from the scene's quads, fitted from
    the scene's mesh moved 2 cm; the loss falls, the result has the documented types, and
    the output directory has the CLI's files."""
    s = two_object_scene(tmp_path)
    target = umbra.render(s)
    moved = s.copy()
    for k in range(2):
        moved.set_vertices(s.vertices(k) + np.array([0, 0, 0.02], np.float32), k)
    seen = []
    start = time.perf_counter()
    out = umbra.fit(moved, target, output=tmp_path / "fit", init="scene", truth=False,
                    known_scale=True, background="none",
                    schedule=[dict(iters=12, solver="adam", lr=0.004, large_steps=0.0)],
                    progress=seen.append)
    assert time.perf_counter() - start < 60
    hist = out["history"]
    assert len(seen) == len(hist["loss"]) == 12
    assert [d["iteration"] for d in seen] == list(hist["iteration"])
    assert hist["data_loss"][-1] < 0.5 * hist["data_loss"][0], hist["data_loss"]
    assert out["vertices"].dtype == np.float64 and out["vertices"].shape[1] == 3
    assert out["triangles"].dtype == np.uint32 and out["triangles"].max() < len(out["vertices"])
    assert out["render"].shape == out["measured"].shape == tuple(s.shape)
    assert out["render"].dtype == np.float32
    # The final render is the fitted mesh's: its loss is the one reported.
    r, m = out["render"].astype(np.float64), out["measured"].astype(np.float64)
    assert ((r - m) ** 2).sum() / (m ** 2).sum() == pytest.approx(out["final_loss"], rel=1e-3)
    # A render is not photon counts: no noise model, nothing left out for noise.
    assert out["face_determination"] is None and out["undetermined_faces"] == 0
    # Photon counts: each face of the full mesh has its determination (0 where dark or
    # unsupported); mesh.obj's faces are among the ones at 1 or more.
    counts = np.round(target / target.max() * 200.0).astype(np.float32)
    c = umbra.fit(moved, counts, init="scene", schedule=[dict(iters=2, solver="adam", lr=0.004)])
    det = c["face_determination"]
    assert det.dtype == np.float64 and det.shape == (len(c["full_mesh"]["triangles"]),)
    assert not np.isnan(det).any() and (det >= 0).all()
    assert len(c["triangles"]) <= int((det >= 1).sum())
    assert isinstance(c["undetermined_faces"], int) and c["undetermined_faces"] >= 0
    names = {Path(f).name for f in out["files"]}
    assert {"mesh.obj", "loss.csv", "loss.png", "transients.png"} <= names
    assert (tmp_path / "fit" / "summary.toml").is_file()


def test_fit_with_truth_reports_chamfer_and_errors_name_arguments(tmp_path: Path):
    s = two_object_scene(tmp_path)
    out = umbra.fit(s, None, init="scene", target_spp=64, iters=2,
                    schedule=[dict(iters=2, solver="adam", lr=0.001)])
    assert out["chamfer"] is not None and out["chamfer"]["whole_mm"] >= 0
    assert out["files"] == []
    with pytest.raises(umbra.UmbraError, match="jitter and irf"):
        umbra.fit(s, umbra.render(s), jitter=0.01, irf="direct", iters=1)
    with pytest.raises(umbra.UmbraError, match="measured has shape"):
        umbra.fit(s, np.zeros((3, 3)), iters=1)
    with pytest.raises(umbra.UmbraError, match="bin: 0,1 is not TIME,SCAN"):
        umbra.fit(s, umbra.render(s), bin=(0, 1), iters=1)
    with pytest.raises(umbra.UmbraError, match="init: 'cube'"):
        umbra.fit(s, umbra.render(s), init="cube", iters=1)


def test_ctrl_c_interrupts_a_fit(tmp_path: Path):
    import _thread
    import threading

    s = two_object_scene(tmp_path)
    threading.Timer(1.0, _thread.interrupt_main).start()
    start = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        umbra.fit(s, umbra.render(s), init="plane", iters=100000, output=tmp_path / "f")
    assert time.perf_counter() - start < 20
