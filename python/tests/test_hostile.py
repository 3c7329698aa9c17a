"""Issue 17 from Python: inputs that crashed the interpreter or the renderer are refused
with UmbraError (tests/bad_input.rs and tests/hostile_input.rs have the CLI side)."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import umbra


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
