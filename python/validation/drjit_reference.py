#!/usr/bin/env python3
"""An independent Dr.Jit implementation of Umbra's three-bounce estimators (DESIGN §6,
check 2): the `tri3` model and the `mc3` Monte Carlo estimator, differentiated by Dr.Jit's
reverse-mode AD (variant `llvm_ad_mono`), to compare with `umbra.render` / `umbra.grad`.

Written from the equations (DESIGN §2-4; the module docs of src/transport/tri3.rs,
tri3_kernel.rs, mc3.rs, src/film/mod.rs, pulse.rs), not from Umbra's code. What it takes
from Umbra is only the *input*: the capture (`umbra.capture`: wall points, power, legs,
film), the mesh (`scene.vertices`, `scene.triangles`, `scene.albedo`), and the random or
discrete choices (`umbra.mc3_samples`: triangle, barycentrics, triangle probability,
laser-spot point, visibility flag per sample; `umbra.tri3_subtriangles`: each
sub-triangle's parent and corner barycentrics). So both sides evaluate exactly the same
estimator, and their derivatives must agree to float precision.

The equations, with `P` the power delivered to the laser spot, `f_w = ρ_w/π`, `n_w` the wall
normal, and for a hidden point `x` on a triangle of unit normal `n` and albedo `ρ`:

    G(a, b)  = cos θ_a cos θ_b / |a − b|²
    w(x)     = P f_w² (ρ/π) G(x_l, x) G(x, x_s)
    τ(x)     = |x_l − x| + |x − x_s| + legs
    valid    : n·(x_l − x) > 0 and n·(x_s − x) > 0 (one-sided; two-sided: same sign),
               n_w·(x − x_l) > 0 and n_w·(x − x_s) > 0 (in front of the wall)

- mc3: a sample on triangle t (probability p_t, barycentrics (b1, b2), point
  x = (1 − b1 − b2) v0 + b1 v1 + b2 v2, area A_t = |(v1 − v0) × (v2 − v0)|/2 of the *current*
  vertices) contributes `w(x) A_t / p_t / spp` (zero unless valid, visible and
  start − 6.5σ ≤ τ < end + 6.5σ) at OPL τ(x), splatted through the Gaussian:
  bin b gets `½ [erf((e_{b+1} − τ)/(σ√2)) − erf((e_b − τ)/(σ√2))]`.
- tri3: for each (measurement, sub-triangle) the corner OPLs τ_i and corner weights w_i
  (zero at a corner behind the wall; zero for the whole sub-triangle unless it faces both
  wall points), the sub-triangle's area A; all τ_i are shifted by
  `0.75 (τ(c) − mean τ_i)` (c the centroid). The pulse is the linear weight over the
  triangle pushed through the linear OPL: with t0 ≤ t1 ≤ t2 sorted (weights moved along),
  Δ1 = t1 − t0, Δ2 = t2 − t0, Δ3 = t2 − t1, the weighted area below t is
      W(t) = A a b (3 w0 + a (w1 − w0) + b (w2 − w0))/3,          a = (t−t0)/Δ1, b = (t−t0)/Δ2
           = W_tot − A c d (3 w2 + c (w1 − w2) + d (w0 − w2))/3, c = (t2−t)/Δ3, d = (t2−t)/Δ2
  on [t0, t1] and [t1, t2] (W_tot = A (w0 + w1 + w2)/3; the area of the corner triangle cut
  off by the level line, times the mean of the linear weight at its corners).
  * box bins: bin b gets `W(e_{b+1}) − W(e_b)` (exact).
  * Gaussian bins: bin b gets `∫ W'(t) κ_b(t) dt`, κ_b the point splat above. Here this is
    *not* Umbra's closed form (Gaussian moments) but composite Gauss-Legendre quadrature
    of the exact piecewise-quadratic pulse density: with u ∈ [0, 1], λ = Δ1/Δ2,
    μ = Δ3/Δ2, the density in u is `A λ u (2 w0 + u (w1 − w0) + u λ (w2 − w0))` at
    t = t0 + u Δ1 (first piece) and `A μ u (2 w2 + u (w1 − w2) + u μ (w0 − w2))` at
    t = t2 − u Δ3 (second piece); each node is splatted as a point. The integrand is a
    quadratic times an analytic function of width σ, so segments ≤ σ/2 with 6 nodes make
    the quadrature error negligible (measured by `quadrature_check`).

Precision: `precision="float32"` (the default: Dr.Jit's `Float` of llvm_ad_mono, Umbra's
render precision) or `"float64"`. The parameters (vertex positions, albedos) are Float64
leaves cast to the working type after their gather, and the transient and the loss are
accumulated in Float64, so sums over many samples do not add rounding of their own.

The scenes, metrics and the table of docs/GRADIENTS.md are in drjit_cases.py
(`.venv/bin/python python/validation/drjit_cases.py`); the test is
python/tests/test_vs_drjit.py.
"""
from __future__ import annotations

import glob
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SCENES = HERE / "scenes"

GAUSS_CUTOFF = 6.5        # Umbra's Gaussian truncation (src/film/mod.rs), in σ

_DR = None


def setup(threads: int | None = None):
    """Imports Dr.Jit through Mitsuba with variant llvm_ad_mono (LLVM 19, as mtutil) and
    returns the `drjit` module."""
    global _DR
    if _DR is None:
        if not os.environ.get("DRJIT_LIBLLVM_PATH"):
            cands = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*"))
            if cands:
                os.environ["DRJIT_LIBLLVM_PATH"] = cands[0]
        import mitsuba as mi

        mi.set_variant("llvm_ad_mono")
        import drjit as dr

        _DR = dr
    if threads is not None:
        _DR.set_thread_count(threads)
    return _DR


class _Types:
    """Dr.Jit array types for one working precision."""

    def __init__(self, precision: str):
        setup()
        import drjit.llvm.ad as ad

        self.ad = ad
        if precision == "float32":
            self.F, self.V3, self.np = ad.Float, ad.Array3f, np.float32
        elif precision == "float64":
            self.F, self.V3, self.np = ad.Float64, ad.Array3f64, np.float64
        else:
            raise ValueError(f"precision {precision!r}: float32 or float64")
        self.F64, self.V364 = ad.Float64, ad.Array3f64
        self.U, self.I, self.B = ad.UInt32, ad.Int32, ad.Bool

    def f(self, a):
        return self.F(np.ascontiguousarray(a, dtype=self.np).ravel())

    def v3(self, a):
        a = np.asarray(a, dtype=self.np).reshape(-1, 3)
        return self.V3(self.f(a[:, 0]), self.f(a[:, 1]), self.f(a[:, 2]))


@dataclass
class Result:
    """What both sides produce: the transient (the render's shape, float64), the loss
    L = Σ δH·H, and dL/dθ (vertex gradients per object, (V, 3); albedo per object)."""
    H: np.ndarray
    loss: float
    vertices: list
    albedo: np.ndarray
    seconds: float = 0.0


# --------------------------------------------------------------------------------------
# Inputs taken from Umbra (data only)

class _Problem:
    """The scene as data: capture, flat triangle list, parameters as Float64 AD leaves."""

    def __init__(self, scene, types: _Types):
        import umbra

        dr = setup()
        self.t = t = types
        self.scene = scene
        cap = umbra.capture(scene)
        self.cap = cap
        self.shape = tuple(scene.shape)
        if len(self.shape) != 3:
            raise NotImplementedError("single and confocal capture only (sy, sx, T)")
        self.M = self.shape[0] * self.shape[1]
        self.T = int(cap["bins"])
        assert self.T == self.shape[2]
        self.start = float(cap["start"])
        self.width = float(cap["width"])
        self.kernel = cap["kernel"]
        self.sigma = float(cap["sigma"])

        n_obj = len(scene.objects)
        verts, tris, tri_obj, offs = [], [], [], [0]
        for o in range(n_obj):
            if scene.vertex_albedo(o) is not None:
                raise NotImplementedError("per-vertex albedo is not modelled here")
            v = np.asarray(scene.vertices(o), dtype=np.float32)
            f = np.asarray(scene.triangles(o), dtype=np.int64)
            verts.append(v)
            tris.append(f + offs[-1])
            tri_obj.append(np.full(len(f), o))
            offs.append(offs[-1] + len(v))
        self.V = np.concatenate(verts)
        self.F = np.concatenate(tris)
        self.tri_obj = np.concatenate(tri_obj)
        self.offsets = offs
        # the flat triangle order and corner values of umbra.capture are ours too
        if not np.array_equal(self.V[self.F], np.asarray(cap["triangles"], dtype=np.float32)):
            raise AssertionError("umbra.capture's triangles are not vertices[triangles] in object order")
        self.albedo0 = np.asarray(scene.albedo, dtype=np.float64)
        if not np.allclose(np.asarray(cap["albedo"]), self.albedo0[self.tri_obj][:, None]):
            raise AssertionError("umbra.capture's corner albedos are not the object albedos")
        self.two_sided_np = np.asarray(cap["two_sided"], dtype=bool)

        # parameters: Float64 leaves (gradients accumulate in double)
        self.pos = t.F64(self.V.astype(np.float64).ravel())
        self.alb = t.F64(self.albedo0)
        dr.enable_grad(self.pos)
        dr.enable_grad(self.alb)

        self.tri_v = t.U(self.F.astype(np.uint32).ravel())
        self.tri_obj_u = t.U(self.tri_obj.astype(np.uint32))
        self.two_sided = t.B(self.two_sided_np)
        self.x_s = t.v3(cap["x_s"])
        self.x_l = t.v3(cap["x_l"])
        self.power = t.f(cap["power"])
        self.legs = t.f(cap["legs"])
        self.n_w = t.V3(*[float(c) for c in cap["n_w"]])
        self.f_wall = float(cap["f_wall"])

    # gathers ---------------------------------------------------------------------------
    def corners(self, tri):
        dr, t = setup(), self.t
        out = []
        for k in range(3):
            vid = dr.gather(t.U, self.tri_v, tri * 3 + k)
            out.append(t.V3(dr.gather(t.V364, self.pos, vid)))
        return out

    def rho(self, tri):
        dr, t = setup(), self.t
        return t.F(dr.gather(t.F64, self.alb, dr.gather(t.U, self.tri_obj_u, tri)))

    def per_measurement(self, m):
        dr, t = setup(), self.t
        return (dr.gather(t.V3, self.x_s, m), dr.gather(t.F, self.power, m),
                dr.gather(t.F, self.legs, m))

    def point_terms(self, x, n, x_l, x_s, two_sided):
        """G(x_l, x) G(x, x_s) (with |cos| at x), OPL without legs, facing and wall-front."""
        dr = setup()
        dl, ds = x_l - x, x_s - x
        rl2, rs2 = dr.squared_norm(dl), dr.squared_norm(ds)
        rl, rs = dr.sqrt(rl2), dr.sqrt(rs2)
        cos_l = dr.dot(n, dl) / rl              # at x, towards x_l
        cos_s = dr.dot(n, ds) / rs
        cos_wl = -dr.dot(self.n_w, dl) / rl     # at the wall: n_w·(x − x_l)/r_l
        cos_ws = -dr.dot(self.n_w, ds) / rs
        facing = dr.select(two_sided, cos_l * cos_s > 0, (cos_l > 0) & (cos_s > 0))
        front = (cos_wl > 0) & (cos_ws > 0)
        gg = dr.abs(cos_l * cos_s) * cos_wl * cos_ws / (rl2 * rs2)
        return gg, rl + rs, facing, front

    # results ---------------------------------------------------------------------------
    def finish(self, H64, loss64, t0) -> Result:
        dr = setup()
        dr.backward(loss64)
        g_pos = np.array(dr.grad(self.pos), dtype=np.float64).reshape(-1, 3)
        g_alb = np.array(dr.grad(self.alb), dtype=np.float64)
        verts = [g_pos[a:b] for a, b in zip(self.offsets[:-1], self.offsets[1:])]
        H = np.array(H64, dtype=np.float64).reshape(self.shape)
        return Result(H=H, loss=float(loss64[0]), vertices=verts, albedo=g_alb,
                      seconds=time.perf_counter() - t0)


# --------------------------------------------------------------------------------------
# Splats

def _splat_points(pb: _Problem, m, u, w, adj):
    """Point splats through the Gaussian kernel: contributions (m, u, w), u = (τ − start) /
    width the OPL in bins from the film's start, -> (H, L) in Float64. Bins within
    GAUSS_CUTOFF σ of τ (the mass beyond is < 1e-10). Time is kept in bins from `start`,
    where the bin edges are exact integers (absolute OPLs of ~2 m would put a systematic
    rounding of ~1e-7 m, 1e-5 of a bin, on every edge in float32)."""
    dr, t = setup(), pb.t
    sig = pb.sigma / pb.width                      # σ in bins
    T = pb.T
    K = int(math.ceil(2 * GAUSS_CUTOFF * sig)) + 2
    n = dr.width(u)
    b0 = t.I(dr.floor(dr.detach(u) - GAUSS_CUTOFF * sig))
    j = dr.arange(t.U, n * K)
    item, k = j // K, j % K
    b = dr.gather(t.I, b0, item) + t.I(k)
    inb = (b >= 0) & (b < T)
    bf = t.F(b)
    u_j = dr.gather(t.F, u, item)
    s = 1.0 / (sig * math.sqrt(2.0))
    kb = 0.5 * (dr.erf((bf + 1 - u_j) * s) - dr.erf((bf - u_j) * s))
    c = dr.select(inb, dr.gather(t.F, w, item) * kb, 0)
    idx = dr.gather(t.U, m, item) * T + t.U(dr.select(inb, b, 0))
    return _accumulate(pb, idx, c, inb, adj)


def _accumulate(pb: _Problem, idx, c, active, adj):
    dr, t = setup(), pb.t
    H = dr.zeros(t.F64, pb.M * pb.T)
    c64 = t.F64(c)
    dr.scatter_reduce(dr.ReduceOp.Add, H, dr.detach(c64), idx, active)
    dH = dr.gather(t.F, t.f(adj), idx, active)
    loss = dr.sum(t.F64(dH * c))
    return H, loss


# --------------------------------------------------------------------------------------
# mc3

def mc3(scene, adjoint, spp: int, seed: int, precision: str = "float32",
        hold_area: bool = False) -> Result:
    """The mc3 estimator on Umbra's own samples (`umbra.mc3_samples`), Gaussian kernel.
    `hold_area` (for the test's sensitivity check only) holds the area factor A_t of the
    pdf constant, as an implementation that forgot it would."""
    import umbra

    dr = setup()
    t0 = time.perf_counter()
    t = _Types(precision)
    pb = _Problem(scene, t)
    if pb.kernel != "gaussian":
        raise NotImplementedError("mc3 reference: Gaussian kernel only (box has no time derivative)")
    smp = umbra.mc3_samples(scene, spp, seed)
    N = pb.M * spp
    spot_moves = not np.array_equal(np.asarray(smp["x_l"]),
                                    np.broadcast_to(np.asarray(pb.cap["x_l"])[:, None], smp["x_l"].shape))
    if spot_moves and np.any(np.asarray(pb.cap["legs"]) != 0):
        raise NotImplementedError("a finite laser spot with account_first_and_last_bounces: "
                                  "the laser leg would depend on the sampled spot point")
    m = dr.arange(t.U, N) // spp
    tri = t.U(np.asarray(smp["tri"], dtype=np.uint32).ravel())
    bary = np.asarray(smp["bary"], dtype=np.float32).reshape(N, 2)
    b1, b2 = t.f(bary[:, 0]), t.f(bary[:, 1])
    prob = t.f(smp["prob"])
    x_l = t.v3(smp["x_l"])
    vis = t.B(np.asarray(smp["visible"], dtype=bool).ravel())

    v0, v1, v2 = pb.corners(tri)
    x = v0 * (1 - b1 - b2) + v1 * b1 + v2 * b2
    cr = dr.cross(v1 - v0, v2 - v0)
    crn = dr.norm(cr)
    area = 0.5 * crn
    if hold_area:
        area = dr.detach(area)
    n = cr / crn
    x_s, P, legs = pb.per_measurement(m)
    gg, opl, facing, front = pb.point_terms(x, n, x_l, x_s, dr.gather(t.B, pb.two_sided, tri))
    u = (opl + legs - pb.start) / pb.width          # OPL in bins from the film's start
    cut = GAUSS_CUTOFF * pb.sigma / pb.width
    valid = vis & facing & front & (u >= -cut) & (u < pb.T + cut)
    w = P * (pb.f_wall * pb.f_wall / math.pi) * pb.rho(tri) * gg * area / prob / spp
    w = dr.select(valid, w, 0)
    H, loss = _splat_points(pb, m, u, w, adjoint)
    return pb.finish(H, loss, t0)


# --------------------------------------------------------------------------------------
# tri3

def _sort3(dr, p0, p1, p2):
    """Sorts three (time, weight) pairs by time: a compare-exchange network."""

    def cx(p, q):
        (tp, wp), (tq, wq) = p, q
        sw = tq < tp
        return ((dr.select(sw, tq, tp), dr.select(sw, wq, wp)),
                (dr.select(sw, tp, tq), dr.select(sw, wp, wq)))

    p0, p1 = cx(p0, p1)
    p1, p2 = cx(p1, p2)
    p0, p1 = cx(p0, p1)
    return p0, p1, p2


def _safe(dr, d):
    return dr.select(d > 0, d, 1)


def _pulse_cdf(dr, x, t0, t1, t2, w0, w1, w2, A):
    """W(x): the weighted area of the (linear-OPL, linear-weight) triangle with τ ≤ x."""
    d1, d2, d3 = t1 - t0, t2 - t0, t2 - t1
    wtot = A * (w0 + w1 + w2) / 3
    s = x - t0
    a, b = s / _safe(dr, d1), s / _safe(dr, d2)
    W1 = A * a * b * (3 * w0 + a * (w1 - w0) + b * (w2 - w0)) / 3
    r = t2 - x
    c, d = r / _safe(dr, d3), r / _safe(dr, d2)
    W2 = wtot - A * c * d * (3 * w2 + c * (w1 - w2) + d * (w0 - w2)) / 3
    return dr.select(x <= t0, 0, dr.select(x >= t2, wtot, dr.select(x < t1, W1, W2)))


def _tri3_pairs(pb: _Problem, sub, S):
    """Per (measurement, sub-triangle) pair: measurement index, sorted corner OPLs (shifted,
    in bins from the film's start) and weights, sub-triangle area."""
    dr, t = setup(), pb.t
    N = pb.M * S
    i = dr.arange(t.U, N)
    m, s = i // S, i % S
    parent = dr.gather(t.U, t.U(np.asarray(sub["parent"], dtype=np.uint32)), s)
    cb = np.asarray(sub["corner_bary"], dtype=np.float32).reshape(S, 6)
    cbs = [dr.gather(t.F, t.f(cb[:, k]), s) for k in range(6)]
    V0, V1, V2 = pb.corners(parent)
    v = [V0 * (1 - cbs[2 * k] - cbs[2 * k + 1]) + V1 * cbs[2 * k] + V2 * cbs[2 * k + 1]
         for k in range(3)]
    cr = dr.cross(v[1] - v[0], v[2] - v[0])
    crn = dr.norm(cr)
    area = 0.5 * crn
    n = cr / crn
    x_s, P, legs = pb.per_measurement(m)
    x_l = dr.gather(t.V3, pb.x_l, m)
    two = dr.gather(t.B, pb.two_sided, parent)
    scale = P * (pb.f_wall * pb.f_wall / math.pi) * pb.rho(parent)
    taus, ws, facing_all = [], [], None
    for k in range(3):
        gg, opl, facing, front = pb.point_terms(v[k], n, x_l, x_s, two)
        taus.append(opl)
        ws.append(dr.select(front, scale * gg, 0))
        facing_all = facing if facing_all is None else facing_all & facing
    c = (v[0] + v[1] + v[2]) / 3
    tau_c = dr.norm(x_l - c) + dr.norm(c - x_s)
    shift = 0.75 * (tau_c - (taus[0] + taus[1] + taus[2]) / 3) + legs
    ws = [dr.select(facing_all, w, 0) for w in ws]
    taus = [(tk + shift - pb.start) / pb.width for tk in taus]   # in bins from the start
    (t0, w0), (t1, w1), (t2, w2) = _sort3(dr, *zip(taus, ws))
    return m, (t0, t1, t2), (w0, w1, w2), area


def _gauss_legendre_unit(n_nodes: int, segments: int):
    """Composite Gauss-Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n_nodes)
    u = np.concatenate([(g + (x + 1) / 2) / segments for g in range(segments)])
    wt = np.concatenate([w / (2 * segments)] * segments)
    return u, wt


def tri3(scene, adjoint, subdivision: float | None = None, precision: str = "float32",
         nodes: int = 6, segments_per_sigma: float = 2.0,
         emulate_dropped_pieces: float | None = None) -> Result:
    """The tri3 model on Umbra's sub-triangles (`umbra.tri3_subtriangles`), box or Gaussian
    kernel. The scene's tri3 visibility must be `none` (no shadow rays here).

    `emulate_dropped_pieces` (m; diagnostic only, Gaussian kernel): reproduce what Umbra's
    src/film/pulse.rs does with a pulse piece [t0, t1] or [t1, t2] narrower than this
    (1e-7 min(σ, bin width) there): the piece is dropped while the by-parts boundary term
    `W_tot Φ((x − t2)/σ)` is kept. Integrating by parts back, that is the other piece plus
    point masses: +W_tot at t2 and −W(t1) at t1 (upper piece dropped), +W(t1) at t1 (lower
    piece dropped). See docs/GRADIENTS.md ("Against an independent Dr.Jit implementation")."""
    import umbra

    dr = setup()
    t0_ = time.perf_counter()
    t = _Types(precision)
    pb = _Problem(scene, t)
    sub = umbra.tri3_subtriangles(scene, subdivision)
    S = len(sub["parent"])
    m, (t0, t1, t2), (w0, w1, w2), A = _tri3_pairs(pb, sub, S)
    dr.eval(m, t0, t1, t2, w0, w1, w2, A)
    T = pb.T
    if pb.kernel == "box":
        # every bin overlapping [t0, t2] (times in bins: bin b is [b, b + 1))
        b_lo = np.floor(np.array(dr.detach(t0), dtype=np.float64))
        b_hi = np.floor(np.array(dr.detach(t2), dtype=np.float64))
        K = int(np.max(b_hi - b_lo)) + 2
        n = dr.width(t0)
        b0 = t.I(dr.floor(dr.detach(t0)))
        j = dr.arange(t.U, n * K)
        item, k = j // K, j % K
        b = dr.gather(t.I, b0, item) + t.I(k)
        inb = (b >= 0) & (b < T)
        bf = t.F(b)
        g = [dr.gather(t.F, a, item) for a in (t0, t1, t2, w0, w1, w2, A)]
        W_hi = _pulse_cdf(dr, bf + 1, *g)
        W_lo = _pulse_cdf(dr, bf, *g)
        c = dr.select(inb, W_hi - W_lo, 0)
        idx = dr.gather(t.U, m, item) * T + t.U(dr.select(inb, b, 0))
        H, loss = _accumulate(pb, idx, c, inb, adjoint)
        return pb.finish(H, loss, t0_)
    # Gaussian: quadrature of the pulse density, each node splatted as a point
    span = np.array(dr.detach(t2 - t0), dtype=np.float64) * pb.width
    segments = max(1, int(math.ceil(span.max() * segments_per_sigma / pb.sigma)))
    u_np, wq_np = _gauss_legendre_unit(nodes, segments)
    Q = len(u_np)
    n = dr.width(t0)
    d2 = t2 - t0
    degenerate = ~(d2 > 0)
    lam = dr.select(degenerate, 0.5, (t1 - t0) / _safe(dr, d2))
    mu = dr.select(degenerate, 0.5, (t2 - t1) / _safe(dr, d2))
    no = dr.zeros(t.B, n)
    drop_lo, drop_hi = no, no
    if emulate_dropped_pieces is not None:
        thr = emulate_dropped_pieces / pb.width
        drop_lo, drop_hi = (t1 - t0) < thr, (t2 - t1) < thr
    j = dr.arange(t.U, n * 2 * Q)
    item, q = j // (2 * Q), j % (2 * Q)
    second = q >= Q
    qq = dr.select(second, q - Q, q)
    u = dr.gather(t.F, t.f(u_np), qq)
    wq = dr.gather(t.F, t.f(wq_np), qq)
    tt0, tt1, tt2, ww0, ww1, ww2, AA, ll, mm_ = [
        dr.gather(t.F, a, item) for a in (t0, t1, t2, w0, w1, w2, A, lam, mu)]
    mass1 = ll * u * (2 * ww0 + u * (ww1 - ww0) + u * ll * (ww2 - ww0))
    mass2 = mm_ * u * (2 * ww2 + u * (ww1 - ww2) + u * mm_ * (ww0 - ww2))
    mass1 = dr.select(dr.gather(t.B, drop_lo, item), 0, mass1)
    mass2 = dr.select(dr.gather(t.B, drop_hi, item), 0, mass2)
    tau = dr.select(second, tt2 - u * (tt2 - tt1), tt0 + u * (tt1 - tt0))
    wnode = AA * wq * dr.select(second, mass2, mass1)
    mm = dr.gather(t.U, m, item)
    if emulate_dropped_pieces is not None:
        wtot = A * (w0 + w1 + w2) / 3
        W_t1 = A * lam * (3 * w0 + (w1 - w0) + lam * (w2 - w0)) / 3     # W(t1), exact
        mm = dr.concat([mm, m, m, m])
        tau = dr.concat([tau, t2, t1, t1])
        wnode = dr.concat([wnode, dr.select(drop_hi, wtot, 0), dr.select(drop_hi, -W_t1, 0),
                           dr.select(drop_lo & ~drop_hi, W_t1, 0)])
    H, loss = _splat_points(pb, mm, tau, wnode, adjoint)
    return pb.finish(H, loss, t0_)
