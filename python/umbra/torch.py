"""PyTorch autograd on top of Umbra: the forward pass renders, the backward pass calls
Umbra's adjoint (path replay for the Monte Carlo models, the exact derivative for
``tri3``), so ``loss.backward()`` and any ``torch.optim`` optimiser work on the hidden
mesh's vertex positions and albedo.

    import torch, umbra, umbra.torch as ut
    scene = umbra.load_scene("scene.toml")
    model = ut.TransientModule(scene, model="tri3")
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    loss = ((model() - target) ** 2).sum(); loss.backward(); opt.step()

torch is optional: this module imports without it, and using it then raises ImportError.
Renders are float32 on the CPU; gradients come back in the parameters' dtype and device.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

import umbra

try:
    import torch
except ImportError:  # pragma: no cover - exercised where torch is absent
    torch = None


def _need_torch():
    if torch is None:
        raise ImportError("umbra.torch needs PyTorch: pip install torch")


def _scene_at(scene, vertices, albedo, obj):
    s = scene.copy()
    s.set_vertices(vertices.detach().to("cpu", torch.float64).numpy(), obj)
    if albedo is not None:
        s.set_albedo(float(albedo.detach().clamp(0.0, 1.0)), obj)
    return s


if torch is not None:

    class RenderFunction(torch.autograd.Function):
        """``H = render(scene with vertices, albedo)`` for hidden object ``obj``;
        backward: Umbra's adjoint with the same seed (the same paths)."""

        @staticmethod
        def forward(ctx, vertices, albedo, scene, obj, opts):
            s = _scene_at(scene, vertices, albedo, obj)
            h = umbra.render(s, **opts)
            ctx.scene, ctx.obj, ctx.opts = s, obj, opts
            ctx.meta = (vertices.dtype, vertices.device, albedo is not None)
            return torch.from_numpy(h).to(vertices.device)

        @staticmethod
        def backward(ctx, grad_h):
            dtype, device, has_albedo = ctx.meta
            adjoint = grad_h.detach().to("cpu", torch.float32).contiguous().numpy()
            g = umbra.grad(ctx.scene, adjoint, **ctx.opts)
            v = g["vertices"] if isinstance(g["vertices"], np.ndarray) else g["vertices"][ctx.obj]
            d_vertices = torch.from_numpy(np.asarray(v)).to(device, dtype)
            d_albedo = None
            if has_albedo:
                d_albedo = torch.tensor(float(g["albedo"][ctx.obj]), dtype=dtype, device=device)
            return d_vertices, d_albedo, None, None, None

    class TransientModule(torch.nn.Module):
        """The transient of ``scene`` as a differentiable function of hidden object
        ``obj``'s vertices (and albedo, unless ``fit_albedo=False``), both
        ``torch.nn.Parameter``s initialised from the scene."""

        def __init__(self, scene, model: Optional[str] = None, spp: Optional[int] = None,
                     seed: Optional[int] = None, obj: int = 0, fit_albedo: bool = True,
                     threads: Optional[int] = None):
            super().__init__()
            self.scene, self.obj = scene, obj
            self.opts = dict(model=model, spp=spp, seed=seed, threads=threads)
            self.vertices = torch.nn.Parameter(torch.from_numpy(scene.vertices(obj).astype(np.float64)))
            self.albedo = (torch.nn.Parameter(torch.tensor(float(scene.albedo[obj]), dtype=torch.float64))
                           if fit_albedo else None)

        def forward(self):
            return RenderFunction.apply(self.vertices, self.albedo, self.scene, self.obj, self.opts)

else:  # pragma: no cover

    class RenderFunction:  # type: ignore[no-redef]
        @staticmethod
        def apply(*_args, **_kwargs):
            _need_torch()

    class TransientModule:  # type: ignore[no-redef]
        def __init__(self, *_args, **_kwargs):
            _need_torch()


def render(vertices, albedo, scene, obj: int = 0, **opts):
    """Functional form: ``H`` for ``vertices`` (and ``albedo``, or None) of object ``obj``."""
    _need_torch()
    return RenderFunction.apply(vertices, albedo, scene, obj,
                                {k: opts.get(k) for k in ("model", "spp", "seed", "threads")})
