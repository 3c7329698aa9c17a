//! An independent reference for three-bounce measurements with occlusion: the lit part
//! of every hidden triangle computed exactly by polygon clipping, and the measurement
//! integrated over it by quadrature. Nothing here samples, so finite differences of it
//! are smooth in the vertices (the shadow polygons' corners move continuously) and can
//! use small steps: the reference for the visibility boundary terms (issue 18).
//!
//! For measurement `m`, a fixed adjoint `λ` and the receiver triangle `R`,
//! `J = Σ_m ∫_{R \ ∪ S} F(x) a_m(opl(x)) dA`, with `F = P (ρ_w/π)² (ρ/π) G(x_l,x) G(x,x_s)`,
//! `a_m(τ) = Σ_b λ_{m,b} K_b(τ)` and `S` the shadows on `R`'s plane of every other
//! triangle, cast from `x_l` and from `x_s` (clipped to the part between the wall point
//! and the plane). The union is integrated by inclusion–exclusion over convex polygons,
//! each triangulated and split into `n²` sub-triangles with a degree-5 7-point rule.
//! All in `f64`. Scenes: planar pieces in front of the wall, at most 12 shadows per
//! receiver and measurement.

use glam::{DVec2, DVec3};
use umbra::film::Film;
use umbra::geometry::SceneGeometry;
use umbra::scene::Scene;
use umbra::transport::MeasurementCtx;

pub(super) struct Tri {
    pub(super) v: [DVec3; 3],
    pub(super) n: DVec3,
    pub(super) albedo: [f64; 3],
    pub(super) two_sided: bool,
}

impl Tri {
    /// Albedo at `x` (on the triangle's plane): barycentric blend of the corners.
    pub(super) fn albedo_at(&self, x: DVec3) -> f64 {
        let (v, n) = (&self.v, self.n);
        let area = n.dot((v[1] - v[0]).cross(v[2] - v[0]));
        let b1 = n.dot((x - v[0]).cross(v[2] - v[0])) / area;
        let b2 = n.dot((v[1] - v[0]).cross(x - v[0])) / area;
        self.albedo[0] * (1.0 - b1 - b2) + self.albedo[1] * b1 + self.albedo[2] * b2
    }
}

/// A receiver plane's frame: origin, two in-plane axes, normal.
pub(super) struct Frame {
    pub(super) o: DVec3,
    pub(super) u: DVec3,
    pub(super) w: DVec3,
    pub(super) n: DVec3,
}

impl Frame {
    pub(super) fn of(t: &Tri) -> Frame {
        let u = (t.v[1] - t.v[0]).normalize();
        Frame {
            o: t.v[0],
            u,
            w: t.n.cross(u),
            n: t.n,
        }
    }
    pub(super) fn to2(&self, p: DVec3) -> DVec2 {
        DVec2::new((p - self.o).dot(self.u), (p - self.o).dot(self.w))
    }
    pub(super) fn to3(&self, p: DVec2) -> DVec3 {
        self.o + p.x * self.u + p.y * self.w
    }
}

pub(super) fn triangles(scene: &Scene) -> Vec<Tri> {
    let mut out = Vec::new();
    for o in &scene.objects {
        for (t, idx) in o.mesh.triangles.iter().enumerate() {
            let v = o.mesh.triangle(t).map(|p| p.as_dvec3());
            out.push(Tri {
                v,
                n: (v[1] - v[0]).cross(v[2] - v[0]).normalize(),
                albedo: match &o.mesh.vertex_albedo {
                    Some(a) => idx.map(|i| a[i as usize] as f64),
                    None => [o.albedo as f64; 3],
                },
                two_sided: o.two_sided,
            });
        }
    }
    out
}

/// The shadow of `q` cast from `o` onto the plane of `f`, in the plane's coordinates:
/// the part of `q` strictly between `o` and the plane, projected. Empty if none.
pub(super) fn shadow(f: &Frame, q: &Tri, o: DVec3) -> Vec<DVec2> {
    let side = |p: DVec3| (p - f.o).dot(f.n);
    let s_o = side(o);
    // Keep the part of q in the slab between the plane and the parallel plane through o
    // (only there is a point between o and a point of the plane).
    let height = |p: DVec3| side(p) * s_o.signum();
    let mut kept: Vec<DVec3> = q.v.to_vec();
    for (lo, hi) in [
        (-1e-12, f64::INFINITY),
        (f64::NEG_INFINITY, s_o.abs() * (1.0 - 1e-6)),
    ] {
        let inside = |p: DVec3| (lo..=hi).contains(&height(p));
        let bound = |p: DVec3| if height(p) < lo { lo } else { hi };
        let input = std::mem::take(&mut kept);
        for i in 0..input.len() {
            let (a, b) = (input[i], input[(i + 1) % input.len()]);
            if inside(a) {
                kept.push(a);
            }
            if inside(a) != inside(b) {
                let level = bound(if inside(a) { b } else { a });
                let t = (level - height(a)) / (height(b) - height(a));
                kept.push(a + t * (b - a));
            }
        }
    }
    if kept.len() < 3 || kept.iter().all(|&p| side(p).abs() < 1e-12) {
        return Vec::new();
    }
    kept.iter()
        .map(|&p| {
            let t = s_o / (s_o - side(p));
            f.to2(o + t * (p - o))
        })
        .collect()
}

/// Sutherland–Hodgman: `subject` clipped to the convex polygon `clip` (either winding),
/// without repeated corners (an edge of length ~0 has no direction to clip along).
pub(super) fn clip(subject: &[DVec2], clip: &[DVec2]) -> Vec<DVec2> {
    let out = clip_raw(subject, &dedup(clip));
    let out = dedup(&out);
    if out.len() < 3 {
        return Vec::new();
    }
    out
}

/// `p` without corners within 1e-10 m of the previous one (cyclically).
pub(super) fn dedup(p: &[DVec2]) -> Vec<DVec2> {
    let mut out: Vec<DVec2> = Vec::with_capacity(p.len());
    for &q in p {
        if out.last().is_none_or(|l| l.distance(q) > 1e-10) {
            out.push(q);
        }
    }
    while out.len() > 1 && out[0].distance(out[out.len() - 1]) <= 1e-10 {
        out.pop();
    }
    out
}

fn clip_raw(subject: &[DVec2], clip: &[DVec2]) -> Vec<DVec2> {
    if clip.len() < 3 {
        return Vec::new();
    }
    let orient = area2(clip).signum();
    let mut out = subject.to_vec();
    for i in 0..clip.len() {
        let (a, b) = (clip[i], clip[(i + 1) % clip.len()]);
        let inside = |p: DVec2| orient * (b - a).perp_dot(p - a) >= 0.0;
        let input = std::mem::take(&mut out);
        for j in 0..input.len() {
            let (p, q) = (input[j], input[(j + 1) % input.len()]);
            if inside(p) {
                out.push(p);
            }
            if inside(p) != inside(q) {
                let (dp, dq) = ((b - a).perp_dot(p - a), (b - a).perp_dot(q - a));
                out.push(p + dp / (dp - dq) * (q - p));
            }
        }
        if out.len() < 3 {
            return Vec::new();
        }
    }
    out
}

pub(super) fn area2(p: &[DVec2]) -> f64 {
    (0..p.len())
        .map(|i| p[i].perp_dot(p[(i + 1) % p.len()]))
        .sum()
}

/// Degree-5 rule on the triangle: (barycentric weight, (a, b, b) permutations).
const RULE: [(f64, f64, f64); 3] = [
    (0.225, 1.0 / 3.0, 1.0 / 3.0),
    (
        0.132_394_152_788_506_2,
        0.059_715_871_789_769_8,
        0.470_142_064_105_115_1,
    ),
    (
        0.125_939_180_544_827_1,
        0.797_426_985_353_087_3,
        0.101_286_507_323_456_3,
    ),
];

/// `∫ g dA` over the convex polygon `poly` (plane coordinates), `n²` sub-triangles per
/// fan triangle.
pub(super) fn integrate(poly: &[DVec2], n: usize, g: &mut impl FnMut(DVec2) -> f64) -> f64 {
    let mut sum = 0.0;
    for k in 1..poly.len() - 1 {
        let (a, b, c) = (poly[0], poly[k], poly[k + 1]);
        let area = 0.5 * (b - a).perp_dot(c - a).abs() / (n * n) as f64;
        let p = |i: usize, j: usize| {
            a + (b - a) * (i as f64 / n as f64) + (c - a) * (j as f64 / n as f64)
        };
        let mut sub = |p0: DVec2, p1: DVec2, p2: DVec2| {
            for &(w, x, y) in &RULE {
                let pts: &[(f64, f64, f64)] = if x == y {
                    &[(x, y, 1.0 - x - y)]
                } else {
                    &[(x, y, y), (y, x, y), (y, y, x)]
                };
                for &(l0, l1, l2) in pts {
                    sum += w * area * g(p0 * l0 + p1 * l1 + p2 * l2);
                }
            }
        };
        for i in 0..n {
            for j in 0..n - i {
                sub(p(i, j), p(i + 1, j), p(i, j + 1));
                if i + j + 1 < n {
                    sub(p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                }
            }
        }
    }
    sum
}

/// `a_m(τ)` tabulated finely (spacing a 64th of the kernel's scale) and interpolated
/// linearly: the same function for every evaluation, so finite differences stay smooth.
pub(super) struct Adjoint {
    start: f64,
    step: f64,
    values: Vec<f64>,
}

impl Adjoint {
    pub(super) fn new(film: &Film, lambda: &[f32]) -> Adjoint {
        let scale = match film.kernel {
            umbra::scene::KernelSpec::Gaussian { sigma_opl } => sigma_opl as f64,
            umbra::scene::KernelSpec::Box => film.width,
        };
        let step = scale / 64.0;
        let (start, end) = (film.start - 8.0 * scale, film.end() + 8.0 * scale);
        let values = (0..=((end - start) / step) as usize + 1)
            .map(|i| film.adjoint((start + i as f64 * step) as f32, lambda).0)
            .collect();
        Adjoint {
            start,
            step,
            values,
        }
    }
    pub(super) fn at(&self, tau: f64) -> f64 {
        let x = (tau - self.start) / self.step;
        if x < 0.0 || x >= (self.values.len() - 1) as f64 {
            return 0.0;
        }
        let i = x as usize;
        let f = x - i as f64;
        self.values[i] * (1.0 - f) + self.values[i + 1] * f
    }
}

/// `J = Σ_m ∫ F a_m dA` over the lit parts of the hidden triangles (module docs), with
/// `n²` sub-triangles per quadrature triangle.
pub fn lit_integral(scene: &Scene, lambda: &[f32], n: usize) -> f64 {
    let geom = SceneGeometry::build(scene);
    let film = Film::new(&scene.film);
    let tris = triangles(scene);
    let mut total = 0.0;
    for m in 0..scene.num_measurements() {
        let ctx = MeasurementCtx::new(scene, &geom, &film, m);
        if !ctx.legs_visible {
            continue;
        }
        let adj = Adjoint::new(&film, &lambda[m * film.bins..(m + 1) * film.bins]);
        let (x_l, x_s) = (ctx.x_l.as_dvec3(), ctx.x_s.as_dvec3());
        let n_w = ctx.n_w.as_dvec3();
        let c = ctx.power as f64 * (ctx.f_wall as f64).powi(2);
        let legs = (ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg) as f64;
        let views: Vec<DVec3> = if x_l == x_s {
            vec![x_l]
        } else {
            vec![x_l, x_s]
        };
        for (ri, r) in tris.iter().enumerate() {
            let f = Frame::of(r);
            let base: Vec<DVec2> = r.v.iter().map(|&p| f.to2(p)).collect();
            let shadows: Vec<Vec<DVec2>> = views
                .iter()
                .flat_map(|&o| {
                    tris.iter()
                        .enumerate()
                        .filter(|&(qi, _)| qi != ri)
                        .map(move |(_, q)| (o, q))
                })
                .map(|(o, q)| shadow(&f, q, o))
                .filter(|s| s.len() >= 3 && area2(s).abs() > 1e-18)
                .map(|s| clip(&s, &base))
                // Degenerate (a shadow touching the receiver along an edge) clips nothing.
                .filter(|s| s.len() >= 3 && area2(s).abs() > 1e-9 * area2(&base).abs())
                .collect();
            assert!(
                shadows.len() <= 12,
                "too many shadows for inclusion-exclusion"
            );
            let mut g = |p2: DVec2| {
                let x = f.to3(p2);
                let (dl, ds) = (x_l - x, x_s - x);
                let (cl, cs) = (r.n.dot(dl), r.n.dot(ds));
                let facing = if r.two_sided {
                    cl * cs > 0.0
                } else {
                    cl > 0.0 && cs > 0.0
                };
                let (wl, ws) = (-n_w.dot(dl), -n_w.dot(ds));
                if !facing || wl <= 0.0 || ws <= 0.0 {
                    return 0.0;
                }
                let (rl, rs) = (dl.length(), ds.length());
                let geometry = (cl * wl * cs * ws).abs() / (rl.powi(4) * rs.powi(4));
                let rho = r.albedo_at(x);
                c * rho / std::f64::consts::PI * geometry * adj.at(rl + rs + legs)
            };
            total += integrate(&base, n, &mut g);
            // Inclusion–exclusion over the non-empty intersections of the shadows.
            let k = shadows.len();
            for mask in 1u32..(1 << k) {
                let mut poly = base.clone();
                for (i, s) in shadows.iter().enumerate() {
                    if mask & (1 << i) != 0 {
                        poly = clip(&poly, s);
                        if poly.len() < 3 {
                            break;
                        }
                    }
                }
                if poly.len() < 3 {
                    continue;
                }
                let sign = if mask.count_ones() % 2 == 1 {
                    -1.0
                } else {
                    1.0
                };
                total += sign * integrate(&poly, n, &mut g);
            }
        }
    }
    total
}
