"""Issues 17 and 52 from Python: inputs that crashed the interpreter or the renderer, or
were taken silently, are refused with UmbraError (tests/bad_input.rs and
tests/hostile_input.rs have the CLI side; test_arrays.py has the arrays' memory layouts)."""
from __future__ import annotations

import inspect
import json
import os
import pickle
import subprocess
import sys
import threading

import numpy as np
import pytest

import umbra
from umbra import _umbra
from scenes_two import two_object_scene


def test_deeply_nested_xml_is_an_error_not_a_segfault(tmp_path):
    path = tmp_path / "deep.xml"
    path.write_text('<scene version="3.0.0">' + "<a>" * 40000 + "</a>" * 40000 + "</scene>")
    # In a child interpreter: the old failure was a segfault that would take pytest down.
    code = (
        "import sys, umbra\n"
        "try:\n"
        f"    umbra.load_scene({str(path)!r})\n"
        "except umbra.UmbraError as e:\n"
        "    print(e)\n"
        "    sys.exit(3)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert "elements nested more than 64 deep" in r.stdout


def test_absurd_vertices_are_refused():
    scene = umbra.default_scene()
    v = scene.vertices()
    with pytest.raises(umbra.UmbraError, match="row 0 has -2.5e29, more than 1000000 m from the origin"):
        scene.set_vertices(v.astype(np.float64) * 1e30)
    with pytest.raises(umbra.UmbraError, match="non-finite value at row 0"):
        bad = v.copy()
        bad[0, 0] = np.nan
        scene.set_vertices(bad)
    # The scene is unchanged and still renders.
    assert np.array_equal(scene.vertices(), v)


def test_threads_are_capped():
    scene = umbra.default_scene()
    with pytest.raises(umbra.UmbraError, match="threads: 10000 threads is more than"):
        umbra.render(scene, model="tri3", threads=10000)


def test_a_render_larger_than_the_memory_budget_is_refused(monkeypatch):
    scene = umbra.default_scene()
    monkeypatch.setenv("UMBRA_MAX_MEMORY", "1M")
    with pytest.raises(umbra.UmbraError, match=r"the render would need \d+ bytes .* UMBRA_MAX_MEMORY allows"):
        umbra.render(scene, model="tri3")
    monkeypatch.setenv("UMBRA_MAX_MEMORY", "1G")
    assert umbra.render(scene, model="tri3").shape == tuple(scene.shape)


# --- Issue 52 (second round) ---------------------------------------------------------


@pytest.fixture()
def two(tmp_path) -> umbra.Scene:
    return two_object_scene(tmp_path)


def wire(scene: umbra.Scene) -> dict:
    """The scene's wire format (what pickle sends), as a dict to tamper with."""
    _, (data,) = scene.__reduce__()
    return json.loads(data)


def from_wire(d: dict) -> umbra.Scene:
    return _umbra._scene_from_wire(json.dumps(d).encode())


def _past_the_vertices(m: dict) -> None:
    m["triangles"][3][2] = len(m["positions"]) + 7


def _short_vertex_albedo(m: dict) -> None:
    m["vertex_albedo"] = [0.5] * (len(m["positions"]) - 1)


def _no_triangles(m: dict) -> None:
    m["triangles"] = []


def _only_degenerate(m: dict) -> None:
    m["triangles"] = [[0, 1, 1], [2, 2, 2]]


def _far_vertex(m: dict) -> None:
    m["positions"][2] = [0.1, 1e30, 0.7]


@pytest.mark.parametrize("tamper, field, words", [
    (_past_the_vertices, r"objects\[1\]\.mesh\.triangles", r"triangle 3 of b names vertex 16, "
                                                           r"and the mesh has 9 vertices \(0 to 8\)"),
    (_short_vertex_albedo, r"objects\[1\]\.mesh\.vertex_albedo", "8 values for the 9 vertices of b"),
    (_no_triangles, r"objects\[1\]\.mesh\.triangles", "b has no triangles"),
    (_only_degenerate, r"objects\[1\]\.mesh\.triangles", "b has no non-degenerate triangles"),
    (_far_vertex, r"objects\[1\]\.mesh\.positions", "vertex 2 is at .* more than 1000000 m"),
])
def test_the_wire_format_is_checked_like_a_scene_file(two, tamper, field, words):
    """A face index past the vertices or a short vertex albedo used to panic in the
    renderer; no triangles or only degenerate ones were taken."""
    d = wire(two)
    assert from_wire(d).objects == two.objects  # the untouched bytes read back
    tamper(d["objects"][1]["mesh"])
    with pytest.raises(umbra.UmbraError, match=f"{field}.*{words}"):
        from_wire(d)


def test_the_wire_format_checks_the_retroreflective_falloff(two):
    d = wire(two)
    d["objects"][0]["reflectance"] = {"Retroreflective": {"falloff": 1e30}}
    with pytest.raises(umbra.UmbraError, match=r"objects\[0\]\.reflectance.*falloff = 1000000"):
        from_wire(d)
    # Past float32 (JSON has no NaN or infinity): refused by the reader.
    d["objects"][0]["reflectance"] = {"Retroreflective": {"falloff": 1e39}}
    with pytest.raises(umbra.UmbraError, match="not a scene written by .*number out of range"):
        from_wire(d)


def test_a_pickled_scene_gets_the_checks_of_a_file(two):
    flat = two.copy()
    flat.set_vertices(np.zeros_like(two.vertices(0)), 0)  # every triangle degenerate
    with pytest.raises(umbra.UmbraError, match=r"objects\[0\].*a has no non-degenerate triangles"):
        pickle.loads(pickle.dumps(flat))
    back = pickle.loads(pickle.dumps(two))
    assert np.array_equal(umbra.render(back), umbra.render(two))


def test_set_albedo_refuses_an_object_with_vertex_albedo(two):
    n = two.vertices(1).shape[0]
    two.set_vertex_albedo(np.linspace(0.2, 0.8, n), 1)
    before = umbra.render(two)
    with pytest.raises(umbra.UmbraError, match="object 1 has per-vertex albedo.*set_vertex_albedo"):
        two.set_albedo(0.3, 1)
    assert np.array_equal(umbra.render(two), before)
    # Without the vertex albedo, the object's albedo applies again and can be set.
    two.set_vertex_albedo(None, 1)
    two.set_albedo(0.3, 1)
    assert two.albedo[1] == pytest.approx(0.3)


def test_torch_refuses_two_albedos_for_one_object(two):
    torch = pytest.importorskip("torch")
    import umbra.torch as ut

    v = torch.from_numpy(two.vertices(0).astype(np.float64))
    with pytest.raises(ValueError, match=r"albedo: 2 values for 1 object"):
        ut.render(v, torch.tensor([0.5, 0.6], dtype=torch.float64), two, obj=0)
    with pytest.raises(ValueError, match="objects: object 0 is given twice"):
        ut.TransientModule(two, objects=[0, 0])
    call = ut._Call(two, [("albedo", (1,)), ("vertex_albedo", 1)], {})
    with pytest.raises(ValueError, match="object 1 has two albedos"):
        ut.RenderFunction.apply(call, torch.tensor([0.5]), torch.full((9,), 0.5))
    two.set_vertex_albedo(np.full(9, 0.5), 1)
    with pytest.raises(ValueError, match="object 1 has per-vertex albedo.*fit_vertex_albedo=True"):
        ut.TransientModule(two)


def test_grad_combine_refuses_a_non_finite_share(two):
    adjoint = np.random.default_rng(3).random(tuple(two.shape), dtype=np.float32)
    rows = adjoint.reshape(-1, two.shape[-1])
    layout = _umbra.grad_chunk_layout(two)
    parts = _umbra.grad_chunks(two, rows[layout[0][0]:layout[1][1]], 0, 2, model="tri3")
    parts += _umbra.grad_chunks(two, rows[layout[2][0]:], 2, len(layout), model="tri3")
    whole = _umbra.grad_combine(two, parts, model="tri3")
    assert np.array_equal(whole["vertices"][0], umbra.grad(two, adjoint, model="tri3")["vertices"][0])
    parts[1]["tri_grad"][2, 5] = np.nan
    with pytest.raises(umbra.UmbraError, match=r"chunk 1's tri_grad has NaN at row 2"):
        _umbra.grad_combine(two, parts, model="tri3")
    parts[1]["tri_grad"][2, 5] = 0.0
    parts[2]["vertex_grad"][1][4, 0] = np.inf
    with pytest.raises(umbra.UmbraError, match=r"chunk 2's vertex_grad of object 1 has inf at row 4"):
        _umbra.grad_combine(two, parts, model="tri3")


ACCESSORS = {
    "vertices": lambda s, k: s.vertices(k),
    "triangles": lambda s, k: s.triangles(k),
    "vertex_albedo": lambda s, k: s.vertex_albedo(k),
    "set_vertices": lambda s, k: s.set_vertices(s.vertices(1) + 0.01, k),
    "set_albedo": lambda s, k: s.set_albedo(0.25, k),
    "set_vertex_albedo": lambda s, k: s.set_vertex_albedo(np.full(9, 0.3), k),
}


@pytest.mark.parametrize("name", ACCESSORS)
def test_negative_object_indices_count_from_the_end(two, name):
    f = ACCESSORS[name]
    assert inspect.signature(getattr(umbra.Scene, name)).parameters["object"].default == 0
    a, b = two.copy(), two.copy()
    ra, rb = f(a, -1), f(b, 1)
    if name.startswith("set"):
        ra, rb = umbra.render(a), umbra.render(b)
        assert not np.array_equal(ra, umbra.render(two))
    assert (ra is None and rb is None) or np.array_equal(ra, rb)
    for bad in (-3, 2, 2 ** 70, -(2 ** 70)):
        with pytest.raises(umbra.UmbraError, match=rf"object {bad} does not exist: the scene has 2 "
                                                    r"hidden objects \(0 to 1, or -2 to -1\)"):
            f(two.copy(), bad)


IN_USE = "the scene is in use by a running render, gradient or fit"


def test_changing_a_scene_that_is_being_read_is_a_clear_error(two):
    """An adjoint whose conversion changes the scene (grad holds it meanwhile)."""
    class Sneaky:
        def __array__(self, dtype=None, copy=None):
            two.set_albedo(0.1, 0)
            return np.ones(tuple(two.shape), np.float32)

    with pytest.raises(umbra.UmbraError, match=IN_USE):
        umbra.grad(two, Sneaky(), model="tri3")
    assert two.albedo[0] == pytest.approx(0.7)


def test_changing_a_scene_from_another_thread_while_it_is_written(two, tmp_path):
    started, release = threading.Event(), threading.Event()
    rows = umbra.render(two).reshape(-1, two.shape[-1])
    errors = []

    def blocks():
        started.set()
        release.wait(60)
        yield 0, rows

    def write():
        try:
            _umbra.write_ytal_blocks(tmp_path / "h.hdf5", two, blocks())
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    t = threading.Thread(target=write)
    t.start()
    try:
        assert started.wait(60)
        for change in (lambda: two.set_albedo(0.2, 0), lambda: two.set_vertex_albedo(None, 0),
                       lambda: two.set_vertices(two.vertices(0), 0)):
            with pytest.raises(umbra.UmbraError, match=IN_USE):
                change()
    finally:
        release.set()
        t.join(60)
    assert not errors and (tmp_path / "h.hdf5").is_file()
    two.set_albedo(0.2, 0)  # free again


def test_a_fit_progress_callback_may_change_the_scene(two):
    """fit works on its own copy of the scene: a callback may change the caller's."""
    target = umbra.render(two)
    changed = []

    def progress(d):
        two.set_albedo(0.25, 1)
        changed.append(d["iteration"])

    out = umbra.fit(two, target, init="scene", schedule=[dict(iters=2, solver="adam", lr=0.001)],
                    progress=progress)
    assert len(changed) == 2 and two.albedo[1] == pytest.approx(0.25)
    assert out["render"].shape == target.shape


def _fit_in_thread(scene, target, out, hold):
    """A fit into ``out`` in a new thread whose first progress call waits for ``hold``."""
    started, result = threading.Event(), {}

    def progress(d):
        started.set()
        hold.wait(120)

    def run():
        try:
            result["out"] = umbra.fit(scene, target, output=out, init="scene",
                                      schedule=[dict(iters=2, solver="adam", lr=0.001)],
                                      progress=progress)
        except BaseException as e:  # noqa: BLE001 - reported by the caller
            result["error"] = e
            started.set()

    t = threading.Thread(target=run)
    t.start()
    assert started.wait(120)
    return t, result


def test_two_fits_into_two_folders_from_two_threads(two, tmp_path):
    target = umbra.render(two)
    hold = threading.Event()
    t, first = _fit_in_thread(two.copy(), target, tmp_path / "a", hold)
    try:
        second = umbra.fit(two.copy(), target, output=tmp_path / "b", init="scene",
                           schedule=[dict(iters=2, solver="adam", lr=0.001)])
    finally:
        hold.set()
        t.join(120)
    assert "error" not in first, first.get("error")
    assert first["out"]["final_loss"] == second["final_loss"]


def test_a_second_fit_into_a_folder_in_use_names_the_lock(two, tmp_path):
    target = umbra.render(two)
    hold = threading.Event()
    t, first = _fit_in_thread(two.copy(), target, tmp_path / "fit", hold)
    try:
        with pytest.raises(umbra.UmbraError, match="lock"):
            umbra.fit(two.copy(), target, output=tmp_path / "fit", init="scene",
                      schedule=[dict(iters=2, solver="adam", lr=0.001)])
    finally:
        hold.set()
        t.join(120)
    assert "error" not in first, first.get("error")
    assert (tmp_path / "fit" / "summary.toml").is_file()


def test_an_absurd_jitter_is_refused_not_an_abort(tmp_path):
    # In a child interpreter: the old failure aborted the process (12.5 TB allocation).
    code = (
        "import sys, umbra\n"
        f"sys.path.insert(0, {os.path.dirname(__file__)!r})\n"
        "from pathlib import Path\n"
        "from scenes_two import two_object_scene\n"
        f"s = two_object_scene(Path({str(tmp_path)!r}))\n"
        "try:\n"
        "    umbra.fit(s, umbra.render(s), jitter=1e10, iters=1)\n"
        "except umbra.UmbraError as e:\n"
        "    print(e)\n"
        "    sys.exit(3)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 3, (r.returncode, r.stderr[-2000:])
    assert "jitter" in r.stdout


def test_a_render_of_nothing_warns_with_its_cause(tmp_path):
    # The film ends long before any return: the render was silently zero.
    (tmp_path / "sq.obj").write_text(
        "v -0.2 -0.2 0.8\nv 0.2 -0.2 0.8\nv 0.2 0.2 0.8\nv -0.2 0.2 0.8\nf 1 4 3 2\n")
    (tmp_path / "s.toml").write_text(
        'capture_type = "confocal"\n[wall]\nsize = [1.0, 1.0]\n[laser]\norigin = [0.0, 0.0, 1.0]\n'
        'power = 1.0\n[scan]\nresolution = [4, 4]\n[film]\ntemporal_bins = 64\nbin_width_opl = 0.001\n'
        '[[objects]]\nfile = "sq.obj"\n')
    s = umbra.load_scene(str(tmp_path / "s.toml"))
    with pytest.warns(UserWarning, match="zero everywhere: the film .* ends at 0.0640 m of OPL, before the earliest return"):
        h = umbra.render(s, model="tri3")
    assert not h.any()
    with pytest.warns(UserWarning, match="zero everywhere, so the gradient is too"):
        umbra.grad(s, target=np.ones_like(h), model="tri3")
