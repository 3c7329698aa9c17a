//! An independent reference for four-bounce measurements with occlusion: two hidden
//! vertices, every visibility found exactly by polygon clipping, the rest by quadrature.
//! The counterpart of [`super::exact_shadows`] for `path` with `filter_bounces = 4`:
//! nothing samples, so finite differences of it are smooth in the vertices and can use
//! small steps.
//!
//! For measurement `m` and a fixed adjoint `λ` (`a_m` as in `exact_shadows`),
//!
//! `J4 = Σ_m ∫∫ C (ρ1/π) G(x_s,y1) V(x_s,y1) G(y1,y2) V(y1,y2) (ρ2/π) G(y2,x_l) V(y2,x_l)
//!       a_m(opl) dA(y2) dA(y1)`,
//!
//! `C = P (ρ_w/π)²`, `G(a,b) = |cos_a| |cos_b| / |a-b|²`, `opl = |x_s-y1| + |y1-y2| +
//! |y2-x_l|` plus the visible legs if counted. `y1` sees `x_s` and `y2`, `y2` sees `y1`
//! and `x_l`, each on one side of a two-sided surface (the front of a one-sided one).
//!
//! Outer quadrature: `y1` over the part of each hidden triangle lit from `x_s`. Inner, for
//! each `y1`: `y2` over every triangle not coplanar with `y1`'s, cut to the side of
//! `y1`'s plane that `x_s` is on, minus the shadows of every other triangle cast from
//! `y1` and from `x_l`. A lit part is the triangle minus the union of the shadows, as
//! signed convex polygons (inclusion–exclusion over the shadows' non-empty
//! intersections), each integrated like `exact_shadows` does (`n²` sub-triangles per fan
//! triangle, a degree-5 rule). The inner integrand is smooth (no two non-coplanar
//! triangles of the scene it is used on touch). The outer one, the inner integral as a
//! function of `y1`, is continuous with kinks: where `y1` crosses another triangle's
//! plane (the facing at `y2` flips; that triangle's shadow from `y1` turns edge-on) the
//! outer polygons are cut, so those kinks stay on polygon edges as the vertices move; the
//! kinks left (a shadow's corner crossing a receiver's edge, where the inner integral is
//! still `C¹`) converge with the outer order. With `x_l = x_s` (confocal) the integrand
//! is symmetric in `(y1, y2)` and each pair of triangles is integrated once, doubled.
//! All in `f64`; measurements in parallel, summed in order (deterministic).

use super::exact_shadows::{area2, clip, dedup, integrate, shadow, triangles, Adjoint, Frame, Tri};
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::f64::consts::PI;
use umbra::film::Film;
use umbra::geometry::SceneGeometry;
use umbra::scene::Scene;
use umbra::transport::MeasurementCtx;

/// `poly ∩ {q : a·q + b ≥ 0}` (empty if less than a triangle is left).
fn cut(poly: &[DVec2], a: DVec2, b: f64) -> Vec<DVec2> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (hp, hq) = (a.dot(p) + b, a.dot(q) + b);
        if hp >= 0.0 {
            out.push(p);
        }
        if (hp >= 0.0) != (hq >= 0.0) {
            out.push(p + hp / (hp - hq) * (q - p));
        }
    }
    let out = dedup(&out);
    if out.len() < 3 {
        return Vec::new();
    }
    out
}

/// `base` minus the union of the convex `shadows`, as signed convex polygons: the
/// inclusion–exclusion sum over the shadows' non-empty intersections (subsets in index
/// order, a subset's supersets skipped once it is empty).
fn signed_pieces(base: Vec<DVec2>, shadows: &[Vec<DVec2>]) -> Vec<(f64, Vec<DVec2>)> {
    fn add(
        poly: &[DVec2],
        sign: f64,
        shadows: &[Vec<DVec2>],
        min_area: f64,
        out: &mut Vec<(f64, Vec<DVec2>)>,
    ) {
        for (k, s) in shadows.iter().enumerate() {
            let p = clip(poly, s);
            if p.len() >= 3 && area2(&p).abs() > min_area {
                add(&p, -sign, &shadows[k + 1..], min_area, out);
                out.push((-sign, p));
            }
        }
    }
    let min_area = 1e-12 * area2(&base).abs();
    let mut out = Vec::new();
    add(&base, 1.0, shadows, min_area, &mut out);
    out.push((1.0, base));
    out
}

/// Whether two triangles lie in one plane (to the `f32` rounding of the vertices): no
/// transport between them.
fn coplanar(a: &Tri, b: &Tri) -> bool {
    a.n.cross(b.n).length() < 1e-6 && b.v.iter().all(|&p| a.n.dot(p - a.v[0]).abs() < 1e-6)
}

/// `G(a, b)` for the surface point `b` with normal `n_b` and the wall point `a`.
fn g_wall(n_w: DVec3, a: DVec3, b: DVec3, n_b: DVec3) -> f64 {
    let d = a - b;
    let cw = n_w.dot(b - a);
    if cw <= 0.0 {
        return 0.0;
    }
    (n_b.dot(d) * cw).abs() / d.length_squared().powi(2)
}

/// One measurement's geometry and adjoint.
struct Measurement<'a> {
    tris: &'a [Tri],
    frames: &'a [Frame],
    bases: &'a [Vec<DVec2>],
    x_l: DVec3,
    x_s: DVec3,
    n_w: DVec3,
    /// `P (ρ_w/π)²`, and the visible legs' OPL.
    c: f64,
    legs: f64,
    adj: Adjoint,
    /// Per receiver, the shadows of the other triangles cast from `x_l`.
    from_laser: Vec<Vec<Vec<DVec2>>>,
}

impl Measurement<'_> {
    /// The shadows on triangle `j` cast from `o` by every triangle but `j` and `skip`,
    /// clipped to `j`.
    fn shadows_on(&self, j: usize, o: DVec3, skip: usize) -> Vec<Vec<DVec2>> {
        let (f, base) = (&self.frames[j], &self.bases[j]);
        (0..self.tris.len())
            .filter(|&k| k != j && k != skip)
            .map(|k| shadow(f, &self.tris[k], o))
            .filter(|s| s.len() >= 3 && area2(s).abs() > 1e-18)
            .map(|s| clip(&s, base))
            .filter(|s| s.len() >= 3 && area2(s).abs() > 1e-12 * area2(base).abs())
            .collect()
    }

    /// `∫ (ρ2/π) G(y1,y2) V(y1,y2) G(y2,x_l) V(y2,x_l) a(tau + |y1-y2| + |y2-x_l|) dA(y2)`
    /// for `y1` on triangle `i`, `side` the sign of `x_s` over `i`'s plane.
    fn inner(&self, i: usize, y1: DVec3, side: f64, tau: f64, n: usize) -> f64 {
        let r1 = &self.tris[i];
        let mut sum = 0.0;
        for (j, r2) in self.tris.iter().enumerate() {
            // Confocal: each pair of triangles once (`four_bounce` doubles it).
            if j == i || coplanar(r1, r2) || (self.x_l == self.x_s && j < i) {
                continue;
            }
            // At y2, y1 and x_l on one side (constant over the plane).
            let (a, b) = (r2.n.dot(y1 - r2.v[0]), r2.n.dot(self.x_l - r2.v[0]));
            let facing = if r2.two_sided {
                a * b > 0.0
            } else {
                a > 0.0 && b > 0.0
            };
            if !facing {
                continue;
            }
            // At y1, y2 on x_s's side of the plane.
            let f = &self.frames[j];
            let lin = side * DVec2::new(r1.n.dot(f.u), r1.n.dot(f.w));
            let base = cut(&self.bases[j], lin, side * r1.n.dot(f.o - y1));
            if base.is_empty() {
                continue;
            }
            let mut shadows = self.shadows_on(j, y1, i);
            shadows.extend(self.from_laser[j].iter().cloned());
            let mut g = |p: DVec2| {
                let y2 = f.to3(p);
                let d = y2 - y1;
                let r2sq = d.length_squared();
                let g12 = (r1.n.dot(d) * r2.n.dot(d)).abs() / (r2sq * r2sq);
                let g2l = g_wall(self.n_w, self.x_l, y2, r2.n);
                let opl = tau + r2sq.sqrt() + (self.x_l - y2).length();
                r2.albedo_at(y2) / PI * g12 * g2l * self.adj.at(opl)
            };
            for (sign, piece) in signed_pieces(base, &shadows) {
                sum += sign * integrate(&piece, n, &mut g);
            }
        }
        sum
    }

    /// The measurement's `J4` term, `n_outer` and `n_inner` the quadrature orders.
    fn four_bounce(&self, n_outer: usize, n_inner: usize) -> f64 {
        let mut total = 0.0;
        for (i, r1) in self.tris.iter().enumerate() {
            let s = r1.n.dot(self.x_s - r1.v[0]);
            if !(if r1.two_sided { s != 0.0 } else { s > 0.0 }) {
                continue;
            }
            let f = &self.frames[i];
            let mut g = |p: DVec2| {
                let y1 = f.to3(p);
                let g1s = g_wall(self.n_w, self.x_s, y1, r1.n);
                if g1s == 0.0 {
                    return 0.0;
                }
                let tau = self.legs + (self.x_s - y1).length();
                let inner = self.inner(i, y1, s.signum(), tau, n_inner);
                self.c * r1.albedo_at(y1) / PI * g1s * inner
            };
            let shadows = self.shadows_on(i, self.x_s, i);
            let mut pieces = signed_pieces(self.bases[i].clone(), &shadows);
            // The inner integral has a kink where y1 crosses another triangle's plane
            // (its facing there flips; its shadow from y1 turns edge-on): cut there, so
            // the kinks lie on piece edges whatever the vertices do.
            for (j, r2) in self.tris.iter().enumerate() {
                let lin = DVec2::new(r2.n.dot(f.u), r2.n.dot(f.w));
                if j == i || lin.length() < 1e-9 {
                    continue;
                }
                let off = r2.n.dot(f.o - r2.v[0]);
                pieces = pieces
                    .into_iter()
                    .flat_map(|(s, p)| [(s, cut(&p, lin, off)), (s, cut(&p, -lin, -off))])
                    .filter(|(_, p)| !p.is_empty())
                    .collect();
            }
            for (sign, piece) in pieces {
                total += sign * integrate(&piece, n_outer, &mut g);
            }
        }
        if self.x_l == self.x_s {
            2.0 * total
        } else {
            total
        }
    }

    /// The three-bounce term with this module's shadows, signed pieces and factors
    /// (`exact_shadows::lit_integral`'s `J`: a check of the parts shared with it).
    fn three_bounce(&self, n: usize) -> f64 {
        let mut total = 0.0;
        for (i, r) in self.tris.iter().enumerate() {
            let f = &self.frames[i];
            let mut g = |p: DVec2| {
                let x = f.to3(p);
                let (cl, cs) = (r.n.dot(self.x_l - x), r.n.dot(self.x_s - x));
                let facing = if r.two_sided {
                    cl * cs > 0.0
                } else {
                    cl > 0.0 && cs > 0.0
                };
                if !facing {
                    return 0.0;
                }
                let geometry =
                    g_wall(self.n_w, self.x_l, x, r.n) * g_wall(self.n_w, self.x_s, x, r.n);
                let opl = self.legs + (self.x_l - x).length() + (self.x_s - x).length();
                self.c * r.albedo_at(x) / PI * geometry * self.adj.at(opl)
            };
            let mut shadows = self.from_laser[i].clone();
            if self.x_s != self.x_l {
                shadows.extend(self.shadows_on(i, self.x_s, i));
            }
            for (sign, piece) in signed_pieces(self.bases[i].clone(), &shadows) {
                total += sign * integrate(&piece, n, &mut g);
            }
        }
        total
    }
}

/// `Σ_m` of `term` over the scene's measurements (in parallel, summed in order).
fn over_measurements(
    scene: &Scene,
    lambda: &[f32],
    term: impl Fn(&Measurement) -> f64 + Sync,
) -> f64 {
    let geom = SceneGeometry::build(scene);
    let film = Film::new(&scene.film);
    let tris = triangles(scene);
    let frames: Vec<Frame> = tris.iter().map(Frame::of).collect();
    let bases: Vec<Vec<DVec2>> = tris
        .iter()
        .zip(&frames)
        .map(|(t, f)| t.v.iter().map(|&p| f.to2(p)).collect())
        .collect();
    let per: Vec<f64> = (0..scene.num_measurements())
        .into_par_iter()
        .map(|m| {
            let ctx = MeasurementCtx::new(scene, &geom, &film, m);
            if !ctx.legs_visible {
                return 0.0;
            }
            let mut me = Measurement {
                tris: &tris,
                frames: &frames,
                bases: &bases,
                x_l: ctx.x_l.as_dvec3(),
                x_s: ctx.x_s.as_dvec3(),
                n_w: ctx.n_w.as_dvec3(),
                c: ctx.power as f64 * (ctx.f_wall as f64).powi(2),
                legs: (ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg) as f64,
                adj: Adjoint::new(&film, &lambda[m * film.bins..(m + 1) * film.bins]),
                from_laser: Vec::new(),
            };
            me.from_laser = (0..tris.len())
                .map(|j| me.shadows_on(j, me.x_l, j))
                .collect();
            term(&me)
        })
        .collect();
    per.iter().sum()
}

/// `J4 = Σ_m ⟨λ_m, H_m⟩` of the four-bounce transport (module docs), `n_outer²` and
/// `n_inner²` sub-triangles per fan triangle of the `y1` and `y2` pieces.
pub fn interreflection_integral(
    scene: &Scene,
    lambda: &[f32],
    n_outer: usize,
    n_inner: usize,
) -> f64 {
    over_measurements(scene, lambda, |m| m.four_bounce(n_outer, n_inner))
}

/// The three-bounce `J` of `exact_shadows::lit_integral`, computed with this module's
/// parts (for comparison).
pub fn three_bounce_integral(scene: &Scene, lambda: &[f32], n: usize) -> f64 {
    over_measurements(scene, lambda, |m| m.three_bounce(n))
}
