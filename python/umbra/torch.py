"""PyTorch autograd on top of Umbra: the forward pass renders, the backward pass calls
Umbra's adjoint (path replay for the Monte Carlo models, the exact derivative for
``tri3``), so ``loss.backward()`` and any ``torch.optim`` optimiser work on the hidden
meshes' vertex positions, their albedo and their per-vertex albedo.

    import torch, umbra, umbra.torch as ut
    scene = umbra.load_scene("scene.toml")
    model = ut.TransientModule(scene, model="tri3")       # every hidden object
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    loss = ((model() - target) ** 2).sum(); loss.backward(); opt.step()

torch is optional: this module imports without it, and using it then raises ImportError.
Renders are float32 on the CPU; gradients come back in the parameters' dtype and device.
Albedos are clamped to [0, 1] when rendering; their gradient passes the clamp unchanged.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

import umbra

try:
    import torch
except ImportError:  # pragma: no cover - exercised where torch is absent
    torch = None


def _need_torch() -> None:
    if torch is None:
        raise ImportError("umbra.torch needs PyTorch: pip install torch")


def _numpy(t: "torch.Tensor") -> np.ndarray:
    return t.detach().to("cpu", torch.float64).numpy()


class _Call:
    """One differentiable render: the scene, which parameter each tensor is, the options.

    ``kinds[i]`` says what tensor ``i`` of the call holds: ``("vertices", k)`` a
    ``(V_k, 3)`` tensor of object k, ``("albedo", ks)`` a ``(len(ks),)`` tensor of the
    objects ``ks``, ``("vertex_albedo", k)`` a ``(V_k,)`` tensor. The forward pass keeps
    the scene it rendered (``rendered``) for the backward pass, which so reuses its
    geometry."""

    def __init__(self, scene: umbra.Scene, kinds: List[Tuple[str, Any]], opts: Dict[str, Any]):
        self.scene, self.kinds, self.opts = scene, kinds, opts
        self.rendered: Optional[umbra.Scene] = None

    def check(self, tensors: Sequence["torch.Tensor"]) -> None:
        """Refuses a call that would set one parameter twice or drop values: an object in
        two tensors of one kind, an albedo and a vertex albedo for one object, an albedo
        tensor with another count of values than its objects."""
        n = len(self.scene.objects)
        seen: Dict[Tuple[str, int], str] = {}
        for (kind, which), t in zip(self.kinds, tensors):
            objects = list(which) if kind == "albedo" else [which]
            if kind == "albedo" and t.numel() != len(objects):
                raise ValueError(f"albedo: {t.numel()} values for {len(objects)} object(s) "
                                 f"{objects}: one albedo per object")
            for k in objects:
                slot = ("vertices" if kind == "vertices" else "albedo", k + n if k < 0 else k)
                if slot in seen:
                    what = "two vertex tensors" if kind == "vertices" else "two albedos"
                    raise ValueError(f"object {k} has {what} ({seen[slot]} and {kind}): "
                                     "give each parameter once")
                seen[slot] = kind

    def scene_at(self, tensors: Sequence["torch.Tensor"]) -> umbra.Scene:
        self.check(tensors)
        s = self.scene.copy()
        for (kind, which), t in zip(self.kinds, tensors):
            if kind == "vertices":
                s.set_vertices(_numpy(t), which)
            elif kind == "albedo":
                for k, a in zip(which, _numpy(t).reshape(-1)):
                    s.set_albedo(float(np.clip(a, 0.0, 1.0)), k)
            else:
                s.set_vertex_albedo(np.clip(_numpy(t), 0.0, 1.0), which)
        return s


if torch is not None:

    class RenderFunction(torch.autograd.Function):
        """``H = render(scene with the parameters)``: ``apply(call, *tensors)`` with a
        :class:`_Call` saying what each tensor is; backward: Umbra's adjoint with the same
        options and seed (the same paths)."""

        @staticmethod
        def forward(call: _Call, *tensors: "torch.Tensor") -> "torch.Tensor":
            s = call.scene_at(tensors)
            call.rendered = s
            device = tensors[0].device if tensors else torch.device("cpu")
            return torch.from_numpy(umbra.render(s, **call.opts)).to(device)

        @staticmethod
        def setup_context(ctx: Any, inputs: Tuple[Any, ...], output: "torch.Tensor") -> None:
            call, *tensors = inputs
            ctx.call = call
            ctx.meta = [(t.dtype, t.device) for t in tensors]

        @staticmethod
        def backward(ctx: Any, grad_h: "torch.Tensor") -> Tuple[Optional["torch.Tensor"], ...]:
            call: _Call = ctx.call
            if not any(ctx.needs_input_grad[1:]):
                return (None,) * (1 + len(call.kinds))
            adjoint = grad_h.detach().to("cpu", torch.float32).contiguous().numpy()
            g = umbra.grad(call.rendered, adjoint, **call.opts)
            out: List[Optional[torch.Tensor]] = [None]
            for (kind, which), (dtype, device), needed in zip(call.kinds, ctx.meta,
                                                              ctx.needs_input_grad[1:]):
                if not needed:
                    out.append(None)
                    continue
                if kind == "vertices":
                    d = g["vertices"][which]
                elif kind == "albedo":
                    d = g["albedo"][list(which)]
                else:
                    d = g["vertex_albedo"][which]
                    if d is None:
                        d = np.zeros(call.rendered.vertices(which).shape[0])
                out.append(torch.from_numpy(np.asarray(d)).to(device, dtype))
            return tuple(out)

    class TransientModule(torch.nn.Module):
        """The transient of ``scene`` as a differentiable function of its hidden objects'
        parameters, all ``torch.nn.Parameter``s (float64) initialised from the scene:

        - ``vertices``: a ``ParameterList`` with one ``(V_k, 3)`` tensor per fitted object
          (``objects``, default every hidden object; ``obj=k`` is ``objects=[k]``);
        - ``albedo``: a ``(K,)`` tensor, one per fitted object (``fit_albedo=True`` and
          ``fit_vertex_albedo=False``; refused for an object with per-vertex albedo, which
          takes the place of its albedo), else None;
        - ``vertex_albedo``: with ``fit_vertex_albedo=True``, a ``ParameterList`` with one
          ``(V_k,)`` tensor per fitted object (the mesh's vertex colours, or its albedo
          where it has none), else None.

        ``options`` are :func:`umbra.render`'s (``model``, ``spp``, ``seed``,
        ``max_depth``, ``visibility``, ...), used by the forward and the backward pass."""

        def __init__(self, scene: umbra.Scene, model: Optional[str] = None,
                     spp: Optional[int] = None, seed: Optional[int] = None,
                     obj: Optional[int] = None, fit_albedo: bool = True,
                     threads: Optional[int] = None, *, objects: Optional[Sequence[int]] = None,
                     fit_vertex_albedo: bool = False, **options: Any):
            super().__init__()
            if obj is not None and objects is not None:
                raise ValueError("give obj or objects, not both")
            self.scene = scene
            self.objects = ([obj] if obj is not None else
                            list(objects) if objects is not None else
                            list(range(len(scene.objects))))
            if not self.objects:
                raise ValueError("the scene has no hidden object to differentiate")
            n = len(scene.objects)
            for k in self.objects:
                if not 0 <= k < n:
                    raise ValueError(f"objects: object {k} does not exist: the scene has {n}")
            twice = [k for i, k in enumerate(self.objects) if k in self.objects[:i]]
            if twice:
                raise ValueError(f"objects: object {twice[0]} is given twice")
            coloured = [k for k in self.objects if scene.vertex_albedo(k) is not None]
            if fit_albedo and not fit_vertex_albedo and coloured:
                raise ValueError(f"object {coloured[0]} has per-vertex albedo, which takes the "
                                 "place of its albedo: fit it with fit_vertex_albedo=True, or "
                                 "pass fit_albedo=False")
            self.opts = dict(model=model, spp=spp, seed=seed, threads=threads, **options)
            unknown = set(self.opts) - set(umbra.option_names())
            if unknown:
                raise ValueError(f"unknown option(s) {sorted(unknown)}: the options are "
                                 f"{umbra.option_names()}")
            f64 = torch.float64
            self.vertices = torch.nn.ParameterList(
                [torch.nn.Parameter(torch.from_numpy(scene.vertices(k).astype(np.float64)))
                 for k in self.objects])
            self.albedo = None
            self.vertex_albedo = None
            if fit_vertex_albedo:
                init = [scene.vertex_albedo(k) for k in self.objects]
                init = [a.astype(np.float64) if a is not None else
                        np.full(scene.vertices(k).shape[0], scene.albedo[k], np.float64)
                        for a, k in zip(init, self.objects)]
                self.vertex_albedo = torch.nn.ParameterList(
                    [torch.nn.Parameter(torch.from_numpy(a)) for a in init])
            elif fit_albedo:
                self.albedo = torch.nn.Parameter(
                    torch.tensor([scene.albedo[k] for k in self.objects], dtype=f64))

        def forward(self) -> "torch.Tensor":
            kinds: List[Tuple[str, Any]] = [("vertices", k) for k in self.objects]
            tensors: List[torch.Tensor] = list(self.vertices)
            if self.albedo is not None:
                kinds.append(("albedo", tuple(self.objects)))
                tensors.append(self.albedo)
            if self.vertex_albedo is not None:
                kinds += [("vertex_albedo", k) for k in self.objects]
                tensors += list(self.vertex_albedo)
            return RenderFunction.apply(_Call(self.scene, kinds, self.opts), *tensors)

else:  # pragma: no cover

    class RenderFunction:  # type: ignore[no-redef]
        @staticmethod
        def apply(*_args: Any, **_kwargs: Any) -> Any:
            _need_torch()

    class TransientModule:  # type: ignore[no-redef]
        def __init__(self, *_args: Any, **_kwargs: Any):
            _need_torch()


def render(vertices: Union["torch.Tensor", Sequence["torch.Tensor"]],
           albedo: Optional["torch.Tensor"], scene: umbra.Scene, obj: int = 0,
           **options: Any) -> "torch.Tensor":
    """Functional form: ``H`` for ``vertices`` and ``albedo`` (or None). Either one
    object's: ``vertices`` a ``(V, 3)`` tensor of object ``obj`` and ``albedo`` a scalar;
    or every object's: ``vertices`` a sequence with one tensor per hidden object and
    ``albedo`` a ``(K,)`` tensor. ``options`` are :func:`umbra.render`'s."""
    _need_torch()
    if isinstance(vertices, torch.Tensor):
        objects, tensors = [obj], [vertices]
    else:
        objects, tensors = list(range(len(vertices))), list(vertices)
    kinds: List[Tuple[str, Any]] = [("vertices", k) for k in objects]
    if albedo is not None:
        kinds.append(("albedo", tuple(objects)))
        tensors.append(albedo.reshape(-1))
    return RenderFunction.apply(_Call(scene, kinds, dict(options)), *tensors)
