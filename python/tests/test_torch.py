"""umbra.torch: a torch.autograd.Function whose backward is Umbra's adjoint. Needs torch
(installed by ./test.sh unless UMBRA_SKIP_TORCH=1); without it these tests are skipped
with that reason, never silently."""
from __future__ import annotations

import numpy as np
import pytest

import umbra
from conftest import VALIDATION

torch = pytest.importorskip("torch", reason="PyTorch is not installed (UMBRA_SKIP_TORCH=1?)")
import umbra.torch as ut  # noqa: E402

T_XML = VALIDATION / "scenes" / "T.xml"


def small_scene() -> umbra.Scene:
    return umbra.load_scene(T_XML, scan_x=6, scan_y=6, bins=128, capture_type="confocal")


def test_module_imports_and_renders_like_umbra():
    s = small_scene()
    m = ut.TransientModule(s, model="tri3")
    h = m()
    assert isinstance(h, torch.Tensor) and tuple(h.shape) == tuple(s.shape)
    assert np.array_equal(h.detach().numpy(), umbra.render(s, model="tri3"))


def test_backward_matches_finite_differences_tri3():
    """A finite-difference check of gradcheck's strength on the autograd Function
    (central differences on the tri3 render, which is deterministic; float32 output, so
    steps of 0.5 mm rather than gradcheck's 1e-6)."""
    s = small_scene()
    w = torch.from_numpy(np.random.default_rng(0).normal(size=tuple(s.shape))).double()
    v0 = torch.from_numpy(s.vertices().astype(np.float64))
    a0 = torch.tensor(float(s.albedo[0]), dtype=torch.float64)

    def loss(v, a):
        return (ut.render(v, a, s, model="tri3").double() * w).sum()

    v = v0.clone().requires_grad_(True)
    a = a0.clone().requires_grad_(True)
    loss(v, a).backward()
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(8):
        i, k = int(rng.integers(v0.shape[0])), int(rng.integers(3))
        h = 5e-4
        vp, vm = v0.clone(), v0.clone()
        vp[i, k] += h
        vm[i, k] -= h
        fd = float((loss(vp, a0) - loss(vm, a0)) / (2 * h))
        ad = float(v.grad[i, k])
        scale = max(abs(fd), 0.05 * float(v.grad.abs().max()))
        assert abs(ad - fd) < 0.03 * scale, (i, k, ad, fd)
        checked += 1
    fd_a = float((loss(v0, a0 + 0.01) - loss(v0, a0 - 0.01)) / 0.02)
    assert abs(float(a.grad) - fd_a) < 1e-3 * abs(fd_a)
    assert checked == 8


def test_adam_lowers_the_loss():
    s = small_scene()
    moved = s.copy()
    moved.set_vertices(s.vertices() + np.array([0.0, 0.0, 0.01], np.float32))
    target = torch.from_numpy(umbra.render(moved, model="tri3"))
    m = ut.TransientModule(s, model="tri3", fit_albedo=False)
    opt = torch.optim.Adam(m.parameters(), lr=2e-3)
    losses = []
    for _ in range(8):
        opt.zero_grad()
        loss = ((m() - target) ** 2).sum()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0], losses


def test_function_uses_setup_context():
    """The current style of torch.autograd.Function: forward without ctx, setup_context
    separate (needed for torch.func transforms and vmap-free composition)."""
    import inspect

    assert "ctx" not in inspect.signature(ut.RenderFunction.forward).parameters
    assert "setup_context" in vars(ut.RenderFunction)


def test_two_objects_and_albedo_against_finite_differences(tmp_path):
    """Every hidden object's vertices and albedo as parameters: backward equals
    umbra.grad for the same adjoint, and central differences of the loss."""
    from scenes_two import two_object_scene

    s = two_object_scene(tmp_path)
    m = ut.TransientModule(s)  # model from the scene (tri3)
    assert len(m.vertices) == 2 and tuple(m.albedo.shape) == (2,)
    w = torch.from_numpy(np.random.default_rng(3).normal(size=tuple(s.shape)))

    def loss_of(h):
        return (h.double() * w).sum()

    loss_of(m()).backward()
    g = umbra.grad(s, w.float().numpy())
    for k in range(2):
        np.testing.assert_allclose(m.vertices[k].grad.numpy(), g["vertices"][k], rtol=1e-6)
    np.testing.assert_allclose(m.albedo.grad.numpy(), g["albedo"], rtol=1e-6)

    def loss_at(k, i, c, h):
        vs = [p.detach().clone() for p in m.vertices]
        vs[k][i, c] += h
        return float(loss_of(ut.render(vs, m.albedo.detach(), s)))

    rng = np.random.default_rng(4)
    for k in range(2):
        gk = m.vertices[k].grad
        for _ in range(3):
            i, c = int(rng.integers(gk.shape[0])), int(rng.integers(3))
            fd = (loss_at(k, i, c, 3e-4) - loss_at(k, i, c, -3e-4)) / 6e-4
            scale = max(abs(fd), 0.05 * float(gk.abs().max()))
            assert abs(float(gk[i, c]) - fd) < 0.05 * scale, (k, i, c, float(gk[i, c]), fd)
    for k in range(2):
        a = [m.albedo.detach().clone() for _ in range(2)]
        a[0][k] += 0.01
        a[1][k] -= 0.01
        vs = [p.detach() for p in m.vertices]
        fd = (float(loss_of(ut.render(vs, a[0], s))) - float(loss_of(ut.render(vs, a[1], s)))) / 0.02
        assert abs(float(m.albedo.grad[k]) - fd) < 1e-3 * abs(fd), (k, fd)


def test_vertex_albedo_parameters(tmp_path):
    from scenes_two import two_object_scene

    s = two_object_scene(tmp_path)
    m = ut.TransientModule(s, objects=[1], fit_vertex_albedo=True)
    assert m.albedo is None and len(m.vertex_albedo) == 1
    assert np.allclose(m.vertex_albedo[0].detach().numpy(), s.albedo[1])
    w = torch.from_numpy(np.random.default_rng(5).normal(size=tuple(s.shape)))
    (m().double() * w).sum().backward()
    ga = m.vertex_albedo[0].grad
    assert ga.dtype == torch.float64 and ga.shape == (s.vertices(1).shape[0],)
    base = m.vertex_albedo[0].detach().numpy().copy()
    for i in (0, 4, 8):
        vals = []
        for sign in (1, -1):
            c = s.copy()
            a = base.copy()
            a[i] += sign * 0.05
            c.set_vertex_albedo(a, 1)
            vals.append(float((torch.from_numpy(umbra.render(c)).double() * w).sum()))
        fd = (vals[0] - vals[1]) / 0.1
        assert abs(float(ga[i]) - fd) < 1e-3 * abs(fd) + 1e-12, (i, float(ga[i]), fd)
