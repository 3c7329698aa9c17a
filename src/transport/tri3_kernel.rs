//! The `tri3` inner loop, eight sub-triangles per step: a structure of arrays with one
//! lane per triangle, written branch-free so the compiler emits one AVX2 instruction per
//! operation for all eight (build with `target-cpu=x86-64-v3`, as `.cargo/config.toml`
//! does).
//!
//! For one measurement (laser spot `x_l`, sensor point `x_s`, wall normal `n_w`) and a
//! triangle on the plane `n·x = d` with corners `v_i`:
//!
//! - corner OPL, in bins: `τ_i = (|x_l − v_i| + |v_i − x_s| + legs − start) / width`;
//! - corner weight (the integrand of the `tri3` module doc at `v_i`):
//!   `w_i = (ρ_i/π) cos θ_l cos θ_s cos θ_wall,l cos θ_wall,s / (r_l² r_s²)`. On the plane,
//!   `r_l cos θ_l = n·x_l − d =: p_l` is the same for every corner (likewise `p_s`), and
//!   `r_l cos θ_wall,l = −n_w·(x_l − v_i) =: c_l`, so
//!   `w_i = (ρ_i/π) |p_l p_s| c_l c_s / (r_l² r_s²)²`, with `w_i = 0` where the corner is
//!   behind the wall (`c_l ≤ 0` or `c_s ≤ 0`) and for a triangle that does not face both
//!   wall points (`p_l, p_s > 0`, or `p_l p_s > 0` if two-sided); for a retroreflective
//!   triangle (confocal) the return leg's `|p_s| c_s / r_s⁴` is 1 (per m²);
//! - the curvature shift of the pulse: `0.75 (τ(c) − mean τ_i)`, `c` the centroid;
//! - the pulse constants of [`BoxPulse`].

use crate::film::{BoxPulse, Film, PulseLanes, LANES};
use glam::Vec3;

/// Triangles per block: the film's splat width, one AVX2 register of `f32`.
pub const W: usize = LANES;

type Lanes = [f32; W];

/// Eight sub-triangles, one per lane. Padding lanes repeat a real triangle with zero
/// area and albedo, so they compute finite numbers and are never live.
#[derive(Clone, Copy, Debug, Default)]
pub struct TriBlock {
    /// Corner positions, `p[corner][axis][lane]` (m).
    pub p: [[Lanes; 3]; 3],
    /// Unit normal.
    pub n: [Lanes; 3],
    /// Plane offset `n·v` (m).
    pub plane: Lanes,
    /// Area (m²).
    pub area: Lanes,
    /// `ρ/π` at each corner (1/sr).
    pub brdf: [Lanes; 3],
    /// 1 where the triangle reflects on both sides, else 0.
    pub two_sided: Lanes,
    /// 1 where the triangle is retroreflective (confocal only), else 0.
    pub retro: Lanes,
}

/// The measurement's constants, in the units the lanes use.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub x_l: Vec3,
    pub x_s: Vec3,
    pub n_w: Vec3,
    /// `legs − start` (m): added to the hidden-path length to get OPL from the film's start.
    pub offset: f32,
    /// 1 / bin width (1/m).
    pub inv_width: f32,
    /// Pulses entirely outside `[lo, hi)` (bins) cannot reach the film.
    pub lo: f32,
    pub hi: f32,
}

impl Frame {
    pub fn confocal(&self) -> bool {
        self.x_l == self.x_s
    }

    /// OPL in bins from the film's start of a point at distances `r_l`, `r_s`.
    #[inline(always)]
    fn bins(&self, r_l: f32, r_s: f32) -> f32 {
        (r_l + r_s + self.offset) * self.inv_width
    }
}

/// Eight pulses: the box splat's lanes, and the corner weights and areas that the
/// Gaussian splat (`f64`, one pulse at a time) reads besides.
#[derive(Clone, Copy, Debug, Default)]
pub struct PulseBlock {
    pub lanes: PulseLanes,
    /// Corner weights, in the order of `lanes.t`.
    pub w: [Lanes; 3],
    pub area: Lanes,
    /// `order[s][lane]`: which corner is in sorted slot `s` (as `f32`).
    pub order: [Lanes; 3],
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0].mul_add(b[0], a[1].mul_add(b[1], a[2] * b[2]))
}

#[inline(always)]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// A corner's legs to the wall points: `d = x − v`, `r²`, `r`, and the wall cosine term
/// `c = −n_w·d` (module doc), for the laser spot and the sensor point.
#[derive(Clone, Copy)]
struct Legs {
    d_l: [f32; 3],
    r2_l: f32,
    r_l: f32,
    c_l: f32,
    d_s: [f32; 3],
    r2_s: f32,
    r_s: f32,
    c_s: f32,
}

impl Legs {
    /// `CONFOCAL` (`x_l == x_s`) skips the second distance.
    #[inline(always)]
    fn new<const CONFOCAL: bool>(f: &Frame, v: [f32; 3]) -> Legs {
        let (x_l, x_s, n_w) = (f.x_l.to_array(), f.x_s.to_array(), f.n_w.to_array());
        let d_l = sub(x_l, v);
        let r2_l = dot(d_l, d_l);
        let (r_l, c_l) = (r2_l.sqrt(), -dot(n_w, d_l));
        if CONFOCAL {
            return Legs {
                d_l,
                r2_l,
                r_l,
                c_l,
                d_s: d_l,
                r2_s: r2_l,
                r_s: r_l,
                c_s: c_l,
            };
        }
        let d_s = sub(x_s, v);
        let r2_s = dot(d_s, d_s);
        Legs {
            d_l,
            r2_l,
            r_l,
            c_l,
            d_s,
            r2_s,
            r_s: r2_s.sqrt(),
            c_s: -dot(n_w, d_s),
        }
    }

    /// In front of the wall at both wall points.
    #[inline(always)]
    fn front(&self) -> bool {
        (self.c_l > 0.0) & (self.c_s > 0.0)
    }

    /// The corner weight without `ρ/π` and the plane factor:
    /// `c_l c_s / (r_l² r_s²)²`, or `c_l / r_l⁴` for a retroreflective triangle (the return
    /// leg's `c_s / r_s⁴` is 1, and its `p_s` below); 0 behind the wall.
    #[inline(always)]
    fn weight(&self, retro: bool) -> f32 {
        let back_leg = if retro {
            1.0
        } else {
            self.c_s / (self.r2_s * self.r2_s)
        };
        if self.front() {
            self.c_l * back_leg / (self.r2_l * self.r2_l)
        } else {
            0.0
        }
    }
}

/// The plane terms of lane `j`: `p_l = n·x_l − d`, `p_s`, and the factor `|p_l p_s|`
/// (`|p_l|` retroreflective), 0 unless the triangle faces both wall points.
#[derive(Clone, Copy)]
struct Plane {
    p_l: f32,
    p_s: f32,
    factor: f32,
}

impl TriBlock {
    #[inline(always)]
    fn corner(&self, i: usize, j: usize) -> [f32; 3] {
        [self.p[i][0][j], self.p[i][1][j], self.p[i][2][j]]
    }

    #[inline(always)]
    fn plane<const CONFOCAL: bool>(&self, f: &Frame, j: usize) -> Plane {
        let n = [self.n[0][j], self.n[1][j], self.n[2][j]];
        let p_l = dot(n, f.x_l.to_array()) - self.plane[j];
        let p_s = if CONFOCAL {
            p_l
        } else {
            dot(n, f.x_s.to_array()) - self.plane[j]
        };
        let prod = p_l * p_s;
        let facing = if self.two_sided[j] > 0.0 {
            prod > 0.0
        } else {
            (p_l > 0.0) & (p_s > 0.0)
        };
        let factor = if self.retro[j] > 0.0 {
            p_l.abs()
        } else {
            prod.abs()
        };
        Plane {
            p_l,
            p_s,
            factor: if facing { factor } else { 0.0 },
        }
    }

    /// The centroid's OPL in bins, and its legs.
    #[inline(always)]
    fn centroid<const CONFOCAL: bool>(&self, f: &Frame, j: usize) -> (f32, Legs) {
        let (a, b, c) = (self.corner(0, j), self.corner(1, j), self.corner(2, j));
        let centroid = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) * (1.0 / 3.0));
        let legs = Legs::new::<CONFOCAL>(f, centroid);
        (f.bins(legs.r_l, legs.r_s), legs)
    }

    /// The eight pulses of this block for one measurement. `CONFOCAL` (`x_l == x_s`)
    /// skips the second distance.
    #[inline]
    #[allow(clippy::needless_range_loop)] // lanes and axes by index, as the equations
    pub fn pulses<const CONFOCAL: bool>(&self, f: &Frame, out: &mut PulseBlock) {
        for j in 0..W {
            let retro = self.retro[j] > 0.0;
            let mut tau = [0.0f32; 3];
            let mut vw = [0.0f32; 3];
            for i in 0..3 {
                let legs = Legs::new::<CONFOCAL>(f, self.corner(i, j));
                tau[i] = f.bins(legs.r_l, legs.r_s);
                vw[i] = self.brdf[i][j] * legs.weight(retro);
            }
            let g = self.plane::<CONFOCAL>(f, j).factor;
            let w = vw.map(|v| g * v);
            // Curvature shift: the pulse's mean moves to (1/12) Σ τ_i + (3/4) τ(c).
            let tau_c = self.centroid::<CONFOCAL>(f, j).0;
            let shift = 0.75 * (tau_c - (tau[0] + tau[1] + tau[2]) * (1.0 / 3.0));
            let (p, order) = BoxPulse::new_ordered(tau.map(|t| t + shift), w, self.area[j]);
            let live = (w[0] + w[1] + w[2] > 0.0) & (p.t[2] >= f.lo) & (p.t[0] < f.hi);
            out.lanes.set(j, &p, live);
            for i in 0..3 {
                out.w[i][j] = p.w[i];
                out.order[i][j] = order[i];
            }
            out.area[j] = self.area[j];
        }
    }

    /// The reverse of [`TriBlock::pulses`]: given, per lane, `g = ∂L/∂(τ_0, τ_1, τ_2, w_0,
    /// w_1, w_2, A)` of its pulse (corner order, `τ` in bins with the shift), adds `∂L/∂`
    /// of the sub-triangle's own corners, corner `ρ/π`, normal, plane offset and area into
    /// `acc` (the latter three are chained to the corners once per gradient,
    /// `tri3_adjoint`). The chain rule of the module doc's equations, written out:
    ///
    /// - shift: `S = Σ g_τi`, `∂L/∂τ'_i = g_τi − S/4`, `∂L/∂τ(c) = 3S/4`;
    /// - `∂τ'_i/∂v_i = −(d_l/r_l + d_s/r_s)/width` (likewise the centroid, `1/3` per corner);
    /// - `w_i = G (ρ_i/π) k_i` with `k_i` the legs' weight: `∂k_i/∂v_i = k_i (n_w/c_l +
    ///   4 d_l/r_l² + n_w/c_s + 4 d_s/r_s²)` (retroreflective: the first two);
    /// - `G = |p_l p_s|`: `∂G/∂p_l = sgn(p_l p_s) p_s`; `∂p/∂n = x`, `∂p/∂d = −1`.
    #[allow(clippy::needless_range_loop)] // lanes and axes by index, as the equations
    pub fn reverse<const CONFOCAL: bool>(&self, f: &Frame, g: &[[f32; W]; 7], acc: &mut BlockGrad) {
        let (x_l, x_s, n_w) = (f.x_l.to_array(), f.x_s.to_array(), f.n_w.to_array());
        for j in 0..W {
            let gl: [f32; 7] = std::array::from_fn(|k| g[k][j]);
            if gl.iter().all(|&v| v == 0.0) {
                continue;
            }
            let retro = self.retro[j] > 0.0;
            let plane = self.plane::<CONFOCAL>(f, j);
            let sum = gl[0] + gl[1] + gl[2];
            let mut g_factor = 0.0f32;
            let mut g_v = [[0.0f32; 3]; 3];
            for (i, g_v) in g_v.iter_mut().enumerate() {
                let legs = Legs::new::<CONFOCAL>(f, self.corner(i, j));
                let g_tau = (gl[i] - 0.25 * sum) * f.inv_width;
                let (u_l, u_s) = (1.0 / legs.r_l, 1.0 / legs.r_s);
                for k in 0..3 {
                    g_v[k] = -(legs.d_l[k] * u_l + legs.d_s[k] * u_s) * g_tau;
                }
                let k_i = legs.weight(retro);
                let g_w = gl[3 + i];
                g_factor += g_w * self.brdf[i][j] * k_i;
                let g_k = g_w * plane.factor;
                if g_k != 0.0 && k_i != 0.0 {
                    acc.brdf[i][j] += f64::from(g_k * k_i);
                    let g_kk = g_k * self.brdf[i][j] * k_i;
                    let (a_l, b_l) = (1.0 / legs.c_l, 4.0 / legs.r2_l);
                    let (a_s, b_s) = if retro {
                        (0.0, 0.0)
                    } else {
                        (1.0 / legs.c_s, 4.0 / legs.r2_s)
                    };
                    for k in 0..3 {
                        g_v[k] +=
                            g_kk * (n_w[k] * (a_l + a_s) + legs.d_l[k] * b_l + legs.d_s[k] * b_s);
                    }
                }
            }
            // The centroid's OPL, a third per corner.
            let (_, c) = self.centroid::<CONFOCAL>(f, j);
            let g_c = 0.75 * sum * f.inv_width * (1.0 / 3.0);
            let (u_l, u_s) = (1.0 / c.r_l, 1.0 / c.r_s);
            for g_v in &mut g_v {
                for k in 0..3 {
                    g_v[k] -= (c.d_l[k] * u_l + c.d_s[k] * u_s) * g_c;
                }
            }
            for (i, g_v) in g_v.iter().enumerate() {
                for k in 0..3 {
                    acc.corner[i][k][j] += f64::from(g_v[k]);
                }
            }
            // The plane factor G.
            if plane.factor != 0.0 && g_factor != 0.0 {
                let (g_pl, g_ps) = if retro {
                    (g_factor * plane.p_l.signum(), 0.0)
                } else {
                    let sgn = (plane.p_l * plane.p_s).signum();
                    (g_factor * sgn * plane.p_s, g_factor * sgn * plane.p_l)
                };
                for k in 0..3 {
                    acc.normal[k][j] += f64::from(g_pl * x_l[k] + g_ps * x_s[k]);
                }
                acc.plane[j] -= f64::from(g_pl + g_ps);
            }
            acc.area[j] += f64::from(gl[6]);
        }
    }
}

/// `∂L/∂` of each lane's sub-triangle's own quantities, over a gradient's measurements
/// (`f64`: each is a sum over all of them).
#[derive(Clone, Copy, Debug, Default)]
pub struct BlockGrad {
    /// `corner[i][axis][lane]`.
    pub corner: [[[f64; W]; 3]; 3],
    /// Corner `ρ/π`.
    pub brdf: [[f64; W]; 3],
    pub normal: [[f64; W]; 3],
    /// The plane offset `n·v` (m).
    pub plane: [f64; W],
    pub area: [f64; W],
}

/// An order of the triangles with centroids `centroid` such that each run of [`W`] is a
/// compact cluster: the box splat walks the union of a block's OPL ranges (its window)
/// for all eight lanes at once, so neighbours in space make short windows. Recursive
/// splits at the median of the longest axis, at a multiple of `W`; deterministic.
/// (On the wavy-sheet benchmark the mean window falls from 13.8 bins in mesh order to
/// 9.0, against 4.3 for the longest single pulse of a block: `examples/tri3_windows.rs`.)
pub fn block_order(centroid: &[Vec3]) -> Vec<usize> {
    fn split(idx: &mut [usize], c: &[Vec3]) {
        if idx.len() <= W {
            return;
        }
        let (lo, hi) = idx.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &k| (lo.min(c[k]), hi.max(c[k])),
        );
        let axis = (hi - lo).max_position();
        let mid = idx.len().div_ceil(W) / 2 * W;
        idx.select_nth_unstable_by(mid, |&a, &b| c[a][axis].total_cmp(&c[b][axis]));
        let (left, right) = idx.split_at_mut(mid);
        split(left, c);
        split(right, c);
    }
    let mut idx: Vec<usize> = (0..centroid.len()).collect();
    split(&mut idx, centroid);
    idx
}

/// Packs sub-triangles into blocks of [`W`].
#[allow(clippy::too_many_arguments)]
pub fn pack(
    corners: impl ExactSizeIterator<Item = ([Vec3; 3], [f32; 3])>,
    normal: &[Vec3],
    plane: &[f32],
    area: &[f32],
    two_sided: &[bool],
    retro: &[bool],
) -> Vec<TriBlock> {
    let count = corners.len();
    let mut blocks = vec![TriBlock::default(); count.div_ceil(W)];
    let mut last = None;
    for (k, (v, brdf)) in corners.enumerate() {
        put(
            &mut blocks[k / W],
            k % W,
            v,
            brdf,
            normal[k],
            plane[k],
            area[k],
            two_sided[k],
            retro[k],
        );
        last = Some((v, normal[k], plane[k]));
    }
    if let Some((v, n, d)) = last {
        for k in count..blocks.len() * W {
            put(
                &mut blocks[k / W],
                k % W,
                v,
                [0.0; 3],
                n,
                d,
                0.0,
                false,
                false,
            );
        }
    }
    blocks
}

#[allow(clippy::too_many_arguments)]
fn put(
    b: &mut TriBlock,
    j: usize,
    v: [Vec3; 3],
    brdf: [f32; 3],
    n: Vec3,
    plane: f32,
    area: f32,
    two_sided: bool,
    retro: bool,
) {
    for i in 0..3 {
        for (axis, x) in v[i].to_array().into_iter().enumerate() {
            b.p[i][axis][j] = x;
        }
        b.brdf[i][j] = brdf[i];
        b.n[i][j] = n[i];
    }
    b.plane[j] = plane;
    b.retro[j] = if retro { 1.0 } else { 0.0 };
    b.area[j] = area;
    b.two_sided[j] = if two_sided { 1.0 } else { 0.0 };
}

/// The measurement's frame for the film `film`.
pub fn frame(ctx: &super::MeasurementCtx, film: &Film) -> Frame {
    let inv_width = (1.0 / film.width) as f32;
    let start = film.start as f32;
    Frame {
        x_l: ctx.x_l,
        x_s: ctx.x_s,
        n_w: ctx.n_w,
        offset: ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg - start,
        inv_width,
        lo: (ctx.opl_min - start) * inv_width,
        hi: (ctx.opl_max - start) * inv_width,
    }
}
