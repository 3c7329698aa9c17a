"""Issue 52, item 1: numpy arrays reach Umbra by their shape and strides, never by their
memory. Every entry point that takes or saves an array gives, for a Fortran-order, a
transposed, a negative-stride or a strided array, what it gives for
``np.ascontiguousarray`` of it (a Fortran-order array used to be read as if it were in C
order: another gradient, another loss, a scrambled file)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator, Tuple

import numpy as np
import pytest

import umbra
from umbra import _umbra
from scenes_two import two_object_scene


def layouts(a: np.ndarray) -> Iterator[Tuple[str, np.ndarray]]:
    """``a``'s values in other memory layouts (each equal to ``a`` element by element)."""
    yield "fortran", np.asfortranarray(a)
    # y-tal's H is (T, Sx, Sy): its .T is Fortran-contiguous, a view.
    yield "transposed", np.ascontiguousarray(a.transpose()).transpose()
    yield "negative", np.ascontiguousarray(a[::-1])[::-1]
    yield "strided", np.repeat(a, 2, axis=-1)[..., ::2]
    yield "fortran float64", np.asfortranarray(a, dtype=np.float64)
    yield "big-endian", np.asfortranarray(a, dtype=">f4")
    unaligned = np.ndarray(a.shape, a.dtype, buffer=bytearray(a.nbytes + 1), offset=1)
    unaligned[...] = a
    yield "unaligned", unaligned


def check_layouts(a: np.ndarray) -> None:
    """The fixture itself: each layout holds ``a``'s values and the Fortran ones really are
    not C-contiguous (else the tests below could not fail)."""
    for name, v in layouts(a):
        assert np.array_equal(v, a), name
    assert not np.asfortranarray(a).flags.c_contiguous
    assert not dict(layouts(a))["unaligned"].flags.aligned


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> umbra.Scene:
    return two_object_scene(tmp_path_factory.mktemp("two"))


@pytest.fixture(scope="module")
def values(scene) -> np.ndarray:
    """Values of the render's shape with no symmetry, so that any scrambling shows."""
    rng = np.random.default_rng(52)
    a = rng.random(tuple(scene.shape), dtype=np.float32)
    check_layouts(a)
    return a


def same_gradient(g: dict, ref: dict, what: str) -> None:
    assert g["loss"] == ref["loss"], what
    for k, (x, y) in enumerate(zip(g["vertices"], ref["vertices"])):
        assert np.array_equal(x, y), (what, k)
    assert np.array_equal(g["albedo"], ref["albedo"]), what


@pytest.mark.parametrize("arg", ["adjoint", "target"])
def test_grad_reads_arrays_by_their_strides(scene, values, arg):
    ref = umbra.grad(scene, model="tri3", **{arg: values})
    # The input matters: a plain transpose of the values is another gradient.
    other = umbra.grad(scene, model="tri3", **{arg: np.ascontiguousarray(values[::-1])})
    assert not np.array_equal(other["vertices"][0], ref["vertices"][0])
    for name, v in layouts(values):
        same_gradient(umbra.grad(scene, model="tri3", **{arg: v}), ref, f"{arg} {name}")


def test_ytal_layout_target_gives_the_loss_of_its_values(scene, values):
    """``target = H_ytal.T`` (y-tal's H is (T, Sx, Sy)): the loss of the values it holds."""
    target = umbra.render(scene, model="tri3") * (1 + 0.5 * values)
    h_ytal = np.ascontiguousarray(target.transpose())
    g = umbra.grad(scene, model="tri3", target=h_ytal.T)
    h = g["render"].astype(np.float64)
    assert g["loss"] == pytest.approx(((h - target.astype(np.float64)) ** 2).sum(), rel=1e-5)


@pytest.mark.parametrize("ext", [".npy", ".hdf5", ".exr"])
def test_save_writes_arrays_by_their_strides(scene, values, tmp_path: Path, ext):
    ref = tmp_path / f"ref{ext}"
    umbra.save(ref, values, scene)
    if ext == ".npy":
        assert np.array_equal(np.load(ref), values)
    for name, v in layouts(values):
        path = tmp_path / f"{name.replace(' ', '_')}{ext}"
        umbra.save(path, v, scene)
        if ext == ".hdf5":
            h5py = pytest.importorskip("h5py")
            with h5py.File(ref, "r") as a, h5py.File(path, "r") as b:
                assert np.array_equal(a["H"][()], b["H"][()]), name
        else:
            assert path.read_bytes() == ref.read_bytes(), name


def test_ytal_blocks_and_gradient_chunks_read_rows_by_their_strides(scene, values, tmp_path):
    n, bins = int(np.prod(values.shape[:-1])), values.shape[-1]
    rows = values.reshape(n, bins)
    ref = tmp_path / "ref.hdf5"
    _umbra.write_ytal_blocks(ref, scene, [(0, rows)])
    layout = _umbra.grad_chunk_layout(scene)
    start, stop = layout[0]
    ref_parts = _umbra.grad_chunks(scene, rows[start:stop], 0, 1, model="tri3")
    h5py = pytest.importorskip("h5py")
    for name, v in layouts(rows):
        path = tmp_path / f"{name.replace(' ', '_')}.hdf5"
        _umbra.write_ytal_blocks(path, scene, [(0, v)])
        with h5py.File(ref, "r") as a, h5py.File(path, "r") as b:
            assert np.array_equal(a["H"][()], b["H"][()]), name
        parts = _umbra.grad_chunks(scene, v[start:stop], 0, 1, model="tri3")
        assert np.array_equal(parts[0]["tri_grad"], ref_parts[0]["tri_grad"]), name


def test_scene_setters_read_arrays_by_their_strides(scene):
    v = scene.vertices(1).astype(np.float64) + np.array([0.0, 0.0, 0.01])
    a = np.linspace(0.2, 0.9, len(v))
    ref = scene.copy()
    ref.set_vertices(v, 1)
    ref.set_vertex_albedo(a, 1)
    for (name, vv), (_, aa) in zip(layouts(v), layouts(a)):
        s = scene.copy()
        s.set_vertices(vv, 1)
        s.set_vertex_albedo(aa, 1)
        assert np.array_equal(s.vertices(1), ref.vertices(1)), name
        assert np.array_equal(s.vertex_albedo(1), ref.vertex_albedo(1)), name


def fit_measured(scene, measured):
    return umbra.fit(scene, measured, init="scene", known_scale=True, background="none",
                     schedule=[dict(iters=1, solver="adam", lr=0.001)])


def test_fit_reads_the_measurement_by_its_strides(scene, values, tmp_path: Path):
    measured = umbra.render(scene) * (1 + 0.5 * values)
    ref = fit_measured(scene, measured)
    assert np.array_equal(ref["measured"], measured)
    for name, v in list(layouts(measured))[:3]:
        out = fit_measured(scene, v)
        assert np.array_equal(out["measured"], measured), name
        assert out["final_loss"] == ref["final_loss"], name


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fortran_order_npy_files_are_read_in_their_order(scene, values, tmp_path, dtype):
    """A .npy file with ``fortran_order: True`` (np.save of a Fortran array) is read by the
    Rust side (src/io) as the array it holds."""
    measured = umbra.render(scene) * (1 + 0.5 * values)
    path = tmp_path / "f.npy"
    np.save(path, np.asfortranarray(measured, dtype=dtype))
    assert b"'fortran_order': True" in path.read_bytes()[:128]
    out = fit_measured(scene, path)
    assert np.array_equal(out["measured"], measured.astype(dtype).astype(np.float32))


def test_torch_adjoint_of_a_transposed_tensor(scene, values):
    torch = pytest.importorskip("torch")
    import umbra.torch as ut

    m = ut.TransientModule(scene, model="tri3")
    w = torch.from_numpy(np.ascontiguousarray(values.transpose())).permute(2, 1, 0)
    assert not w.is_contiguous()
    (m() * w).sum().backward()
    ref = umbra.grad(scene, values, model="tri3")
    for k in range(2):
        assert np.allclose(m.vertices[k].grad.numpy(), ref["vertices"][k], rtol=1e-6, atol=0)
