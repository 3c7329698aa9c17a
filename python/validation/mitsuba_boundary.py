#!/usr/bin/env python3
"""Umbra's vertex gradients with visibility boundary terms against Mitsuba 3's projective
sampling (`direct_projective`, llvm_ad_mono), and against an exact polygon reference: the
cases and the three sides of python/tests/test_boundary_mitsuba.py. As a script it prints
the table with more seeds: `python python/validation/mitsuba_boundary.py [K_MI] [K_U]`.
Setup, derivation, numbers and the reference's limits: notes/boundary-mitsuba.md.

The measured quantity is the steady-state (time-integrated) three-bounce signal of one
measurement, laser spot x_l -> hidden point x -> sensor point x_s (both on the wall z = 0,
normal +z), as DESIGN §2 writes it:

    I = P (rho_w/pi)^2 ∫ (rho/pi) G(x_l, x) V(x_l, x) V(x, x_s) G(x, x_s) dA(x).

Umbra: a `single` capture with a 1 x 1 scan at x_s, laser `power` P at `target` x_l (disk
spot of radius R_SPOT), a Gaussian kernel, a film covering every OPL; I = the render summed
over bins, dI/dθ = the vertex gradient of `umbra.grad` for an adjoint of ones, dotted with a
direction field over the vertices (with and without `boundary_terms`).

Mitsuba (no wall geometry): a pinhole `perspective` camera at the wall point `o` looking
along the wall normal, and a disk area emitter of radius R_SPOT at the other wall point
`o2`, facing +z, of radiance P rho_w / (pi^2 R_SPOT^2) (the lit spot's radiance: power
rho_w P leaves a Lambertian disk of area pi R^2). A box-filtered pixel p holds the mean
radiance arriving at `o` over the pixel's square on the image plane at unit distance; the
wall's irradiance at `o` is ∫ L cos(theta) d(omega) with d(omega) = cos^3(theta) du dv, and
the wall sends (rho_w/pi) of it toward the detector, so

    I = (rho_w/pi) sum_p W_p img_p,   W_p = ∫_pixel (1 + u^2 + v^2)^-2 du dv

(in closed form, `pixel_weights`). Hidden-to-`o` visibility is then Mitsuba's primary
visibility, whose boundary term projective sampling estimates (`sppp`). Shadows seen from
the emitter `o2` would be indirect discontinuities, which this reference leaves off
(`sppi = 0`): each case is built so that `o2` casts no shadow on any surface
(`check_case`). By reciprocity one Mitsuba configuration serves two Umbra captures:
(x_s, x_l) = (o, o2), "sensor-shadow" (Umbra's boundary term from the sensor point), and
(x_l, x_s) = (o, o2), "laser-shadow" (from the laser spot).

Found while setting this up (notes/boundary-mitsuba.md):
- Mitsuba's primary-silhouette foreground turns the shading normal of a face that looks
  away from the camera to grazing, even under a `twosided` BSDF: every face the camera
  sees must be wound to face it (here: toward the wall), or the boundary term is wrong
  (the occluder's translation came out +2.98e-3 for an exact -2.93e-4).
- The boundary derivative is splatted into the pixel of the silhouette point and weighted
  there by the pixel's mean W_p: a first-order error when an edge runs along a pixel
  column (0.5-1 % at 128 px). The camera is rolled by ROLL degrees so that no edge of these
  axis-aligned scenes does; the results then agree from 64 to 256 px.
"""
from __future__ import annotations

import glob
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

RHO_WALL = 0.8
POWER = 1.0
R_SPOT = 0.005          # laser spot radius (Umbra spot_radius, Mitsuba's emitter disk)
SIGMA = 0.004           # Umbra's Gaussian kernel (m of OPL); boundary nodes every SIGMA/4
BIN = 0.004
START_OPL = 0.6
BINS = 600              # film [0.6, 3.0] m of OPL: every path of these scenes, +- 100 sigma
FOV = 90.0              # Mitsuba camera (degrees along x, square image)
RES = 256               # Mitsuba image side (pixels)
ROLL = 17.0             # camera roll about its axis (degrees): no edge runs along a pixel row


# --------------------------------------------------------------------------------------
# Cases

@dataclass
class Obj:
    name: str
    V: np.ndarray            # (V, 3) float64, metres
    F: np.ndarray            # (T, 3) int
    albedo: float


@dataclass
class Case:
    name: str
    objects: list
    o: tuple                 # the wall point whose shadows fall on the hidden surfaces
    o2: tuple                # the other wall point: casts no shadow on any surface
    # direction name -> {object index: (V, 3) direction field}
    directions: dict = field(default_factory=dict)


def quad(x0, x1, y0, y1, z):
    """A rectangle in a plane z = const, two triangles wound to face the wall (-z)."""
    V = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return V, np.array([[0, 2, 1], [0, 3, 2]])


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def occluder_case() -> Case:
    """A 0.6 m plate at z = 1 shadowed by a 0.14 m plate at z = 0.5. Seen from
    o = (0.3, 0, 0) the small plate's shadow lies inside the big plate (x in [-0.04, 0.24]);
    seen from o2 = (-0.3, 0, 0) it falls at x in [0.56, 0.84], off the big plate.
    Directions: a translation of the small plate, and one of its corners moved alone."""
    Vr, Fr = quad(-0.3, 0.3, -0.3, 0.3, 1.0)
    Vo, Fo = quad(0.13, 0.27, -0.04, 0.10, 0.5)
    objs = [Obj("receiver", Vr, Fr, 0.7), Obj("occluder", Vo, Fo, 0.5)]
    vtx = np.zeros_like(Vo)
    vtx[2] = _unit([0.3, 1.0, -0.4])          # the corner (0.27, 0.10, 0.5)
    return Case("occluder", objs, (0.3, 0.0, 0.0), (-0.3, 0.0, 0.0), {
        "translate": {1: np.tile(_unit([0.6, -0.3, 0.74]), (len(Vo), 1))},
        "vertex": {1: vtx},
    })


def step_case() -> Case:
    """A two-step shape, one open mesh: a near plate (x in [-0.3, 0], z = 0.7), a riser
    (x = 0, z in [0.7, 1]) and a far plate (x in [0, 0.3], z = 1), y in [-0.3, 0.3]. Seen
    from o = (-0.25, 0, 0) the near plate's convex crease (0, y, 0.7) shadows the far plate
    for x in [0, 0.107] and hides the riser; from o2 = (0.25, 0, 0) everything is in view
    (the riser's front, the concave crease) and nothing is shadowed. Directions: a rigid
    translation, and the crease vertex (0, 0.3, 0.7) moved alone along +x (in the near
    plate's plane: the shadow's edge moves, no visible face turns)."""
    ys = (-0.3, 0.3)
    prof = [(-0.3, 0.7), (0.0, 0.7), (0.0, 1.0), (0.3, 1.0)]
    V = np.array([[x, y, z] for (x, z) in prof for y in ys], float)   # vertex 2k + (y>0)
    F = []
    for k in range(3):
        a, b, c, d = 2 * k, 2 * k + 2, 2 * k + 3, 2 * k + 1
        F += [[a, c, b], [a, d, c]]       # plates face the wall (-z), the riser +x
    objs = [Obj("step", V, np.array(F), 0.6)]
    vtx = np.zeros_like(V)
    vtx[3] = [1.0, 0.0, 0.0]
    return Case("step", objs, (-0.25, 0.0, 0.0), (0.25, 0.0, 0.0), {
        "translate": {0: np.tile(_unit([1.0, 0.2, -0.3]), (len(V), 1))},
        "crease-vertex": {0: vtx},
    })


CASES = {c.name: c for c in (occluder_case(), step_case())}
LABELINGS = ("sensor-shadow", "laser-shadow")


def moved(case: Case, direction: str, h: float) -> list:
    """Every object's vertices moved by h along `direction`."""
    d = case.directions[direction]
    return [o.V + h * d[i] if i in d else o.V for i, o in enumerate(case.objects)]


def _triangles(V: list, case: Case) -> np.ndarray:
    return np.concatenate([V[i][o.F] for i, o in enumerate(case.objects)])   # (T, 3, 3)


def occluded(P: np.ndarray, target, tris: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """Whether the segment from each point P (N, 3) to `target` crosses a triangle
    (Möller-Trumbore, open segment)."""
    target = np.asarray(target, float)
    d = target - P                                            # (N, 3), segment = t in (0, 1)
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]  # (T, 3)
    pv = np.cross(d[:, None, :], e2[None])                    # (N, T, 3)
    det = np.einsum("tk,ntk->nt", e1, pv)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1 / np.where(ok, det, 1), 0)
    s = P[:, None, :] - tris[None, :, 0]
    u = np.einsum("ntk,ntk->nt", s, pv) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("nk,ntk->nt", d, q) * inv
    t = np.einsum("tk,ntk->nt", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > eps) & (t < 1 - eps)
    return hit.any(axis=1)


def check_case(case: Case, n: int = 12) -> None:
    """The assumptions of the Mitsuba reference, on points inside every triangle: (1) no
    surface point is hidden from o2 (o2 casts no shadow: the indirect discontinuities Mitsuba
    is not asked for carry no derivative); (2) every face seen from the camera point o faces
    it (Mitsuba's silhouette foreground is wrong on faces seen from behind)."""
    tris = _triangles([o.V for o in case.objects], case)
    g = [(i / n, j / n) for i in range(1, n) for j in range(1, n - i)]
    B = np.array([[1 - a - b, a, b] for a, b in g])
    for k, T in enumerate(tris):
        P = B @ T
        nrm = np.cross(T[1] - T[0], T[2] - T[0])
        assert not occluded(P, case.o2, tris).any(), f"{case.name}: triangle {k} shadowed from o2"
        seen = ~occluded(P, case.o, tris)
        facing = (np.asarray(case.o) - P) @ nrm > 0
        assert np.all(facing[seen]), f"{case.name}: triangle {k} seen from behind by the camera"


# --------------------------------------------------------------------------------------
# Exact reference: polygon visibility, high-order quadrature, central differences

_A1, _B1 = (6 - math.sqrt(15)) / 21, (9 + 2 * math.sqrt(15)) / 21
_A2, _B2 = (6 + math.sqrt(15)) / 21, (9 - 2 * math.sqrt(15)) / 21
_W1, _W2 = (155 - math.sqrt(15)) / 1200, (155 + math.sqrt(15)) / 1200
_RADON = np.array([[1 / 3, 1 / 3, 1 / 3], [_A1, _A1, _B1], [_A1, _B1, _A1], [_B1, _A1, _A1],
                   [_A2, _A2, _B2], [_A2, _B2, _A2], [_B2, _A2, _A2]])
_RADON_W = np.array([9 / 40, _W1, _W1, _W1, _W2, _W2, _W2])


def _quadrature(n: int = 24):
    """Radon's degree-5 rule on each of n^2 sub-triangles: barycentrics (Q, 3), weights."""
    corners = []
    p = lambda i, j: (i / n, j / n, 1 - (i + j) / n)          # noqa: E731
    for i in range(n):
        for j in range(n - i):
            corners.append([p(i, j), p(i + 1, j), p(i, j + 1)])
            if i + j < n - 1:
                corners.append([p(i + 1, j), p(i + 1, j + 1), p(i, j + 1)])
    C = np.array(corners)
    Q = np.einsum("qk,skc->sqc", _RADON, C).reshape(-1, 3)
    return Q, np.tile(_RADON_W, len(C)) / len(C)


_QB, _QW = _quadrature()


def integrand(x, n, xl, xs, rho):
    """P (rho_w/pi)^2 (rho/pi) G(x_l, x) G(x, x_s) at points x (N, 3), unit normals n
    (two-sided: |cos|), point spot."""
    dl, ds = xl - x, xs - x
    rl, rs = np.linalg.norm(dl, axis=1), np.linalg.norm(ds, axis=1)
    dl, ds = dl / rl[:, None], ds / rs[:, None]
    gl = np.abs(np.sum(n * dl, 1)) * -dl[:, 2] / rl ** 2
    gs = np.abs(np.sum(n * ds, 1)) * -ds[:, 2] / rs ** 2
    return POWER * (RHO_WALL / math.pi) ** 2 * rho / math.pi * gl * gs


def _tri(P, xl, xs, rho) -> float:
    n = np.cross(P[1] - P[0], P[2] - P[0])
    a = np.linalg.norm(n)
    X = _QB @ P
    return 0.5 * a * float(np.sum(_QW * integrand(X, np.tile(n / a, (len(X), 1)), xl, xs, rho)))


def _poly(poly, xl, xs, rho) -> float:
    """A convex planar polygon, fanned."""
    return sum(_tri(np.array([poly[0], poly[k], poly[k + 1]]), xl, xs, rho)
               for k in range(1, len(poly) - 1))


def _project(o, p, q0, nrm):
    """The point of the plane (q0, nrm) on the ray from o through p."""
    d = p - o
    return o + (np.dot(q0 - o, nrm) / np.dot(d, nrm)) * d


def _clip_unit_square(poly):
    """Sutherland-Hodgman: a convex polygon of 2-D points clipped to [0, 1]^2."""
    for axis, val, keep in ((0, 0.0, 1), (0, 1.0, -1), (1, 0.0, 1), (1, 1.0, -1)):
        out = []
        for k in range(len(poly)):
            a, b = poly[k], poly[(k + 1) % len(poly)]
            ia, ib = keep * (a[axis] - val) >= 0, keep * (b[axis] - val) >= 0
            if ia:
                out.append(a)
            if ia != ib:
                out.append(a + (val - a[axis]) / (b[axis] - a[axis]) * (b - a))
        poly = out
    return poly


def exact_value(case: Case, V: list) -> float:
    """I for vertex positions V (one array per object), the visibility of these two cases
    written out: nothing is shadowed from o2 (check_case), and from o
    - occluder: the whole small plate, and the big plate minus the small plate's two
      triangles projected onto it from o (inside it, check below);
    - step: both plates' triangles, minus the near plate's quad projected from o onto the
      far plate's plane, clipped to the far plate; the riser is hidden."""
    xs, xl = np.asarray(case.o, float), np.asarray(case.o2, float)   # symmetric in the two
    total = 0.0
    if case.name == "occluder":
        rec, occ = case.objects
        Vr, Vo = V
        for t in occ.F:
            total += _tri(Vo[t], xl, xs, occ.albedo)
        for t in rec.F:
            total += _tri(Vr[t], xl, xs, rec.albedo)
        nr = np.cross(Vr[1] - Vr[0], Vr[3] - Vr[0])
        for t in occ.F:
            S = np.array([_project(xs, Vo[k], Vr[0], nr) for k in t])
            assert np.all(np.abs(S[:, :2]) < 0.3), "the shadow must lie inside the receiver"
            total -= _tri(S, xl, xs, rec.albedo)
    elif case.name == "step":
        (ob,) = case.objects
        P = V[0]
        for t in np.concatenate([ob.F[:2], ob.F[4:]]):            # near and far plates
            total += _tri(P[t], xl, xs, ob.albedo)
        q0, eu, ev = P[4], P[6] - P[4], P[5] - P[4]               # far plate's corner, sides
        nf = np.cross(eu, ev)
        shadow = [_project(xs, P[k], q0, nf) for k in (0, 2, 3, 1)]
        local = [np.array([np.dot(s - q0, eu) / np.dot(eu, eu), np.dot(s - q0, ev) / np.dot(ev, ev)])
                 for s in shadow]
        cl = _clip_unit_square(local)
        if len(cl) >= 3:
            total -= _poly([q0 + c[0] * eu + c[1] * ev for c in cl], xl, xs, ob.albedo)
    else:
        raise ValueError(case.name)
    return total


def exact(case: Case, direction: str, h: float = 1e-5) -> tuple:
    """(I, dI/dθ) by central differences of exact_value (its quadrature points move with the
    geometry, so the difference quotient is smooth; h = 1e-5 and 2e-5 agree to 1e-8)."""
    base = exact_value(case, [o.V for o in case.objects])
    d = (exact_value(case, moved(case, direction, h))
         - exact_value(case, moved(case, direction, -h))) / (2 * h)
    return base, d


# --------------------------------------------------------------------------------------
# Umbra

def umbra_toml(case: Case, labeling: str, files: list) -> str:
    if labeling == "sensor-shadow":
        x_s, x_l = case.o, case.o2
    elif labeling == "laser-shadow":
        x_l, x_s = case.o, case.o2
    else:
        raise ValueError(labeling)
    v = lambda p: "[" + ", ".join(f"{c:.9g}" for c in p) + "]"   # noqa: E731
    objs = "".join(
        f'\n[[objects]]\nfile = "{f}"\nname = "{o.name}"\nalbedo = {o.albedo}\ntwo_sided = true\n'
        for o, f in zip(case.objects, files))
    return f"""# {case.name}, {labeling}: tests/test_boundary_mitsuba.py
capture_type = "single"
[wall]
size = [2.0, 2.0]
albedo = {RHO_WALL}
[laser]
origin = [0.0, -2.0, 1.5]
target = {v(x_l)}
power = {POWER}
spot_radius = {R_SPOT}
[scan]
resolution = [1, 1]
center = {v(x_s)}
size = [0.01, 0.01]
[film]
temporal_bins = {BINS}
bin_width_opl = {BIN}
start_opl = {START_OPL}
kernel = "gaussian"
sigma_opl = {SIGMA}
[render]
model = "mc3"
visible_legs = false
{objs}"""


def umbra_scene(case: Case, labeling: str, workdir: str):
    import umbra

    d = Path(workdir) / f"{case.name}-{labeling}"
    d.mkdir(parents=True, exist_ok=True)
    files = []
    for o in case.objects:
        f = d / f"{o.name}.obj"
        with open(f, "w") as fh:
            fh.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in o.V)
            fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in o.F)
        files.append(f.name)
    (d / "scene.toml").write_text(umbra_toml(case, labeling, files))
    scene = umbra.load_scene(str(d / "scene.toml"))
    for i, o in enumerate(case.objects):     # rows in the OBJ's order
        assert np.allclose(scene.vertices(i), o.V, atol=1e-6)
    return scene


@dataclass
class UmbraRun:
    primal: float
    deriv: dict                  # direction -> dI/dθ with boundary terms
    interior: dict               # direction -> without
    seconds: float


def umbra_run(case: Case, labeling: str, workdir: str, spp: int, seed: int,
              threads=None) -> UmbraRun:
    import umbra

    t0 = time.time()
    scene = umbra_scene(case, labeling, workdir)
    H = umbra.render(scene, spp=spp, seed=seed, model="mc3", threads=threads)
    assert H.shape == (1, 1, BINS)
    # the film must hold every path: the first and last bins stay empty
    assert H[..., :8].max() == 0 and H[..., -8:].max() == 0
    ones = np.ones(H.shape, np.float32)
    out = {}
    for bt in (True, False):
        g = umbra.grad(scene, adjoint=ones, model="mc3", spp=spp, seed=seed, threads=threads,
                       boundary_terms=bt)
        assert g["boundary_terms"] == bt
        out[bt] = {k: float(sum(np.sum(g["vertices"][i] * d) for i, d in dirs.items()))
                   for k, dirs in case.directions.items()}
    return UmbraRun(float(H.sum(dtype=np.float64)), out[True], out[False], time.time() - t0)


# --------------------------------------------------------------------------------------
# Mitsuba

_MI = None


def setup(threads: int = 2):
    """(mi, dr) in llvm_ad_mono with LLVM 19."""
    global _MI
    if _MI is not None:
        return _MI
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        c = sorted(glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*"))
        if not c:
            raise RuntimeError("no LLVM 19 (apt-get install libllvm19; DRJIT_LIBLLVM_PATH)")
        os.environ["DRJIT_LIBLLVM_PATH"] = c[0]
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono")
    dr.set_thread_count(threads)
    mi.set_log_level(mi.LogLevel.Error)
    _MI = (mi, dr)
    return _MI


def _F(u, v):
    """An antiderivative of (1 + u^2 + v^2)^-2 in u and v (d^2F/du dv = the integrand)."""
    a, b = np.sqrt(1 + u * u), np.sqrt(1 + v * v)
    return 0.5 * (u / a * np.arctan(v / a) + v / b * np.arctan(u / b))


def pixel_weights(res: int = RES, fov_deg: float = FOV) -> np.ndarray:
    """W_p = ∫ cos^4(theta) du dv over each pixel's square on the image plane at unit
    distance, (res, res). Symmetric under flips and transposition, so the image's
    orientation does not matter; their sum is the irradiance a uniform unit radiance over
    the field of view gives (pi for the whole hemisphere)."""
    h = math.tan(math.radians(fov_deg) / 2)
    e = np.linspace(-h, h, res + 1)
    Fe = _F(e[None, :], e[:, None])
    return Fe[1:, 1:] - Fe[1:, :-1] - Fe[:-1, 1:] + Fe[:-1, :-1]


def _mesh(mi, o: Obj):
    """A mesh in the given vertex and face order, flat normals, two-sided diffuse."""
    props = mi.Properties()
    props["face_normals"] = True
    props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": {
        "type": "diffuse", "reflectance": {"type": "uniform", "value": o.albedo}}})
    m = mi.Mesh(o.name, len(o.V), len(o.F), props=props, has_vertex_normals=False,
                has_vertex_texcoords=False)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.asarray(o.V, np.float32).ravel())
    p["faces"] = mi.UInt32(np.asarray(o.F, np.uint32).ravel())
    p.update()
    return m


class MitsubaCase:
    """One case's Mitsuba scene: camera at case.o, emitter disk at case.o2."""

    def __init__(self, case: Case, spp: int, res: int = RES):
        mi, dr = setup()
        T = mi.ScalarTransform4f
        o, o2 = case.o, case.o2
        roll = math.radians(ROLL)
        self.case, self.spp, self.res = case, spp, res
        self.W = pixel_weights(res) * (RHO_WALL / math.pi)
        d = {
            "type": "scene",
            "integrator": {"type": "direct_projective", "sppc": spp, "sppp": spp, "sppi": 0},
            "sensor": {
                "type": "perspective", "fov": FOV, "fov_axis": "x", "near_clip": 1e-3,
                "to_world": T().look_at(origin=list(o), target=[o[0], o[1], 1.0],
                                        up=[math.sin(roll), math.cos(roll), 0.0]),
                "film": {"type": "hdrfilm", "width": res, "height": res,
                         "pixel_format": "luminance", "rfilter": {"type": "box"},
                         "sample_border": False},
                "sampler": {"type": "independent", "sample_count": spp},
            },
            "spot": {
                "type": "disk",
                "to_world": T().translate(list(o2)) @ T().scale([R_SPOT, R_SPOT, 1.0]),
                "emitter": {"type": "area", "radiance": {
                    "type": "uniform", "value": POWER * RHO_WALL / (math.pi * R_SPOT) ** 2}},
            },
        }
        for ob in case.objects:
            d[ob.name] = _mesh(mi, ob)
        self.scene = mi.load_dict(d)
        self.params = mi.traverse(self.scene)
        for ob in case.objects:
            got = np.array(self.params[f"{ob.name}.vertex_positions"]).reshape(-1, 3)
            assert np.allclose(got, ob.V, atol=1e-6), "Mitsuba reordered the vertices"

    def primal(self, seed: int) -> float:
        mi, dr = setup()
        with dr.suspend_grad():
            img = mi.render(self.scene, spp=self.spp, seed=seed)
        return float(np.sum(self.W * np.array(img, np.float64)[..., 0]))

    def deriv(self, direction: str, seed: int) -> float:
        """dI/dθ along `direction` in forward mode: θ offsets the vertices of every object
        the direction moves; as Mitsuba's own tests of the projective integrators, θ's
        tangent is pushed into the positions, the edges cut, then render_forward."""
        mi, dr = setup()
        case, params = self.case, self.params
        theta = mi.Float(0.0)
        dr.enable_grad(theta)
        moving = case.directions[direction]
        for i, dv in moving.items():
            ob = case.objects[i]
            params[f"{ob.name}.vertex_positions"] = (
                mi.Float(np.asarray(ob.V, np.float32).ravel())
                + theta * mi.Float(np.asarray(dv, np.float32).ravel()))
        params.update()
        dr.forward(theta, dr.ADFlag.ClearEdges)
        g = self.scene.integrator().render_forward(self.scene, params=theta, seed=seed,
                                                   spp=self.spp)
        out = float(np.sum(self.W * np.array(g, np.float64)[..., 0]))
        for i in moving:
            ob = case.objects[i]
            params[f"{ob.name}.vertex_positions"] = mi.Float(np.asarray(ob.V, np.float32).ravel())
        params.update()
        return out


# --------------------------------------------------------------------------------------
# All of it

def mean_err(x) -> tuple:
    """Mean and its standard error over seeds."""
    x = np.asarray(x, float)
    return float(x.mean()), float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else math.inf


def run(k_mi: int, spp_mi: int, k_u: int, spp_u: int, workdir: str, log=print,
        seed0: int = 0) -> dict:
    """Everything the test compares: per case, Mitsuba's primal and derivatives (k_mi
    seeds from seed0), the exact values, and per labeling Umbra's (k_u seeds from
    1000 + seed0)."""
    out = {}
    for case in CASES.values():
        t0 = time.time()
        check_case(case)
        mc = MitsubaCase(case, spp_mi)
        mp = [mc.primal(seed0 + s) for s in range(k_mi)]
        md = {d: [mc.deriv(d, seed0 + s) for s in range(k_mi)] for d in case.directions}
        t_mi = time.time() - t0
        ex = {d: exact(case, d) for d in case.directions}
        um = {}
        t1 = time.time()
        for lab in LABELINGS:
            rs = [umbra_run(case, lab, workdir, spp_u, 1000 + seed0 + s) for s in range(k_u)]
            um[lab] = {"primal": mean_err([r.primal for r in rs]),
                       "deriv": {d: mean_err([r.deriv[d] for r in rs]) for d in case.directions},
                       "interior": {d: mean_err([r.interior[d] for r in rs])
                                    for d in case.directions}}
        t_u = time.time() - t1
        out[case.name] = {"mitsuba": {"primal": mean_err(mp),
                                      "deriv": {d: mean_err(v) for d, v in md.items()}},
                          "exact": {"primal": next(iter(ex.values()))[0],
                                    "deriv": {d: v[1] for d, v in ex.items()}},
                          "umbra": um, "seconds": {"mitsuba": t_mi, "umbra": t_u}}
        log(f"{case.name}: Mitsuba {t_mi:.1f} s ({k_mi} seeds x {spp_mi} spp at {RES}^2), "
            f"Umbra {t_u:.1f} s ({len(LABELINGS)} captures x {k_u} seeds x {spp_u} spp)")
    return out


def table(res: dict) -> str:
    rows = ["| case | direction | capture | Umbra (boundary) | Umbra interior-only | "
            "Mitsuba projective | exact | Umbra/Mitsuba - 1 | primal U/M - 1 |",
            "|---|---|---|---|---|---|---|---|---|"]
    for cname, r in res.items():
        m, ex = r["mitsuba"], r["exact"]
        for d, (md, me) in m["deriv"].items():
            for lab, u in r["umbra"].items():
                ud, ue = u["deriv"][d]
                ui, _ = u["interior"][d]
                rows.append(
                    f"| {cname} | {d} | {lab} | {ud:.5e} ± {ue:.1e} | {ui:.5e} | "
                    f"{md:.5e} ± {me:.1e} | {ex['deriv'][d]:.5e} | {100 * (ud / md - 1):+.2f} % | "
                    f"{u['primal'][0] / m['primal'][0] - 1:+.1e} |")
    rows.append("")
    rows.append("primal I: " + "; ".join(
        f"{c}: Mitsuba {r['mitsuba']['primal'][0]:.6e} ± {r['mitsuba']['primal'][1]:.1e}, "
        f"exact {r['exact']['primal']:.6e}, Umbra "
        + ", ".join(f"{lab} {u['primal'][0]:.6e} ± {u['primal'][1]:.1e}"
                    for lab, u in r["umbra"].items())
        for c, r in res.items()))
    return "\n".join(rows)


if __name__ == "__main__":
    k_mi = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    k_u = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    setup(int(os.environ.get("UMBRA_TEST_THREADS", "2")))
    with tempfile.TemporaryDirectory() as wd:
        t0 = time.time()
        res = run(k_mi, 16, k_u, 1 << 18, wd)
        print(table(res))
        print(f"total {time.time() - t0:.1f} s")
