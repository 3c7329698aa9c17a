"""One gate for every entry point (tests/gate.rs has the library and CLI side): Python's
render, grad, fit and umbra.torch refuse exactly what the CLI refuses, with the CLI's very
message, and accept what it accepts."""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

import umbra
from conftest import require_umbra

SQUARE = "v -0.1 -0.13 0.6\nv 0.2 -0.13 0.6\nv 0.2 0.17 0.6\nv -0.1 0.17 0.6\nf 1 4 3 2\n"


def scene_toml(capture="confocal", spot=0.0, reflectance="lambertian", render=()) -> str:
    return "\n".join([
        f'capture_type = "{capture}"', "[wall]", "size = [2.0, 2.0]",
        "[laser]", "origin = [0.3, -0.4, 1.0]", f"spot_radius = {spot}",
        "[scan]", "resolution = [4, 4]", "size = [1.0, 1.0]",
        "[film]", "temporal_bins = 120", "bin_width_opl = 0.01", "start_opl = 0.8",
        'kernel = "gaussian"', "sigma_opl = 0.012",
        "[[objects]]", 'file = "sq.obj"', "albedo = 0.8", f'reflectance = "{reflectance}"',
        "[render]", "spp = 8", *render, ""])


# (name, scene, model, render refused?, gradient refused?)
CASES = [
    ("mc3 + retroreflective", scene_toml(reflectance="retroreflective"), "mc3", True, True),
    ("retroreflective single", scene_toml("single", reflectance="retroreflective"), "tri3", True, True),
    ("tri3 + finite spot", scene_toml(spot=0.01), "tri3", True, True),
    ("path, no way off the wall",
     scene_toml(render=["bsdf_sampling = false", "hidden_geometry_sampling = false"]), "path", True, True),
    ("path gradients + finite spot, no laser sampling",
     scene_toml(spot=0.01, render=["laser_sampling = false"]), "path", False, True),
    ("path gradients + finite spot", scene_toml(spot=0.01), "path", False, False),
    ("tri3 retroreflective confocal", scene_toml(reflectance="retroreflective"), "tri3", False, False),
]


def write_scene(tmp: Path, toml: str):
    (tmp / "sq.obj").write_text(SQUARE)
    path = tmp / "scene.toml"
    path.write_text(toml)
    return path, umbra.load_scene(path)


def cli_error(exe: str, args: list, cwd: Path):
    r = subprocess.run([exe, *args], capture_output=True, text=True, cwd=cwd)
    if r.returncode == 0:
        return None
    last = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert last, r.stderr
    return last[-1][len("error: "):]


def py_error(f):
    try:
        f()
    except umbra.UmbraError as e:
        return str(e)
    return None


@pytest.mark.parametrize("name,toml,model,render_refused,grad_refused", CASES, ids=[c[0] for c in CASES])
def test_python_refuses_what_the_cli_refuses(tmp_path, umbra_bin, name, toml, model,
                                             render_refused, grad_refused):
    exe = require_umbra(umbra_bin)
    path, scene = write_scene(tmp_path, toml)
    adj = np.ones(scene.shape, np.float32)
    np.save(tmp_path / "adj.npy", adj)

    cli_render = cli_error(exe, ["render", str(path), "--model", model, "-q", "--no-preview",
                                 "-o", "h.npy"], tmp_path)
    cli_grad = cli_error(exe, ["grad", str(path), "--model", model, "--adjoint", "adj.npy",
                               "-o", "g.npz"], tmp_path)
    assert (cli_render is not None) == render_refused, cli_render
    assert (cli_grad is not None) == grad_refused, cli_grad

    assert py_error(lambda: umbra.render(scene, model=model)) == cli_render
    assert py_error(lambda: umbra.grad(scene, adj, model=model)) == cli_grad
    # grad with a target renders first: the render's refusal, else the gradient's.
    assert py_error(lambda: umbra.grad(scene, target=adj, model=model)) == (cli_render or cli_grad)


@pytest.mark.parametrize("name,toml,model,render_refused,grad_refused",
                         [c for c in CASES if c[3] or c[4]], ids=[c[0] for c in CASES if c[3] or c[4]])
def test_fit_and_torch_refuse_with_the_same_message(tmp_path, umbra_bin, name, toml, model,
                                                    render_refused, grad_refused):
    exe = require_umbra(umbra_bin)
    path, scene = write_scene(tmp_path, toml)
    measured = (1.0 + np.arange(np.prod(scene.shape)) % 7).astype(np.float32).reshape(scene.shape)
    np.save(tmp_path / "m.npy", measured)
    expected = cli_error(exe, ["render", str(path), "--model", model, "-q", "--no-preview",
                               "-o", "h.npy"], tmp_path) or \
        cli_error(exe, ["grad", str(path), "--model", model, "--adjoint", "m.npy", "-o", "g.npz"],
                  tmp_path)
    # The fit replaces the scene's objects by its own mesh, "fit", which inherits the
    # first object's reflectance: the refusal names that object.
    fit_expected = expected.replace("objects[0] (sq)", "objects[0] (fit)")
    cli_fit = cli_error(exe, ["fit", str(path), "--model", model, "--measured", "m.npy",
                              "--iters", "1", "-q", "-o", "fitcli"], tmp_path)
    assert cli_fit is not None and fit_expected in cli_fit, cli_fit
    py_fit = py_error(lambda: umbra.fit(scene, measured, output=str(tmp_path / "fitpy"), model=model,
                                        iters=1))
    assert py_fit is not None and fit_expected in py_fit, py_fit
    torch = pytest.importorskip("torch", reason="PyTorch not installed (UMBRA_SKIP_TORCH=1)")
    from umbra.torch import TransientModule

    module = TransientModule(scene, model=model)
    with pytest.raises(umbra.UmbraError) as e:
        out = module()
        out.sum().backward()
    assert str(e.value) == expected


def test_retro_falloff_is_checked_and_used(tmp_path):
    """The retroreflector's angular falloff: a scene's `retro_falloff` dims the render by
    cos^m of the entrance angle, and `umbra.fit(retro_falloff=...)` is checked by the same
    gate as `umbra fit --retro-falloff`, with the Python name."""
    retro = scene_toml(reflectance="retroreflective")
    _, ideal = write_scene(tmp_path, retro)
    steep = retro.replace('reflectance = "retroreflective"',
                          'reflectance = "retroreflective"\nretro_falloff = 4')
    _, dimmed = write_scene(tmp_path, steep)
    h0, h4 = umbra.render(ideal, model="tri3"), umbra.render(dimmed, model="tri3")
    ratio = h4.sum() / h0.sum()
    # The square is turned away from every scan point by some degrees, not more than 40.
    assert 0.34 < ratio < 1.0, ratio
    measured = h0 * 1e3
    e = py_error(lambda: umbra.fit(ideal, measured, retro_falloff=20.0, iters=1))
    assert e is not None and "retro_falloff = 20: the angular falloff exponent is a number from 0 to 16" in e, e
    _, lambertian = write_scene(tmp_path, scene_toml())
    e = py_error(lambda: umbra.fit(lambertian, measured, retro_falloff=2.0, iters=1))
    assert e is not None and "retro_falloff = 2 is for a retroreflective surface" in e, e
    fits = [umbra.fit(ideal, measured, retro_falloff=m, iters=2) for m in (0.0, 4.0)]
    assert all(np.isfinite(f["final_loss"]) for f in fits)
    assert fits[0]["final_loss"] != fits[1]["final_loss"]
