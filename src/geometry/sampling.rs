//! Sampling routines, each returning its sample with the pdf in the measure it was
//! drawn in (pbrt-style records):
//!
//! - [`AreaDistribution`]: a triangle with probability `A_i / A`, then a uniform point on
//!   it; the record carries the triangle's probability `prob`, and `pdf_area = prob / A_i`
//!   (`1 / A` at the mesh it was built for; hidden-geometry sampling, DESIGN §3 rung 2).
//! - [`cosine_hemisphere`]: `pdf_solid_angle = cos θ / π` (BSDF sampling of a Lambertian
//!   surface), by Shirley–Chiu's concentric disk mapping.
//! - [`uniform_disk`]: a uniform point on a disk (a laser spot of finite size).

use crate::adjoint::dual::{self, Real, V3};
use glam::Vec3;

/// The largest f32 below 1.
pub const ONE_MINUS_EPS: f32 = 1.0 - f32::EPSILON / 2.0;

/// Discrete distribution over triangles proportional to area.
///
/// Triangles are laid out along a Morton (Z-order) curve of their centroids before the
/// CDF is built, so consecutive values of the sample's first coordinate pick nearby
/// triangles: stratified samples then stay stratified over the surface, not just over
/// the list of triangles.
#[derive(Clone, Debug, Default)]
pub struct AreaDistribution {
    /// Normalised running sums in sampling order: `cdf[k]` = (A_order[0] + … + A_order[k]) / A.
    cdf: Vec<f32>,
    /// Flat triangle index of each position along the curve.
    order: Vec<u32>,
    /// Probability of each triangle, by flat index (the width of its CDF step).
    prob: Vec<f32>,
    total: f64,
}

/// A sampled triangle and barycentrics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleSample {
    /// Flat triangle index.
    pub tri: u32,
    /// Barycentrics `(b1, b2)`: the point is `(1-b1-b2) v0 + b1 v1 + b2 v2`.
    pub bary: [f32; 2],
    /// Probability of the triangle: the density with respect to area is `prob` over the
    /// triangle's area (its *current* area, so that vertex gradients see the area factor
    /// while the discrete choice stays fixed).
    pub prob: f32,
}

impl AreaDistribution {
    /// A distribution in the given order of triangles.
    pub fn new(areas: &[f32]) -> Self {
        Self::with_order(areas, (0..areas.len() as u32).collect())
    }

    /// A distribution over triangles with `areas` and `centroids`, laid out in Morton
    /// order of the centroids.
    pub fn spatial(areas: &[f32], centroids: &[Vec3]) -> Self {
        let (lo, hi) = centroids.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &c| (lo.min(c), hi.max(c)),
        );
        let extent = (hi - lo).max(Vec3::splat(1e-12));
        let key = |c: Vec3| {
            let q = ((c - lo) / extent * 1023.0).clamp(Vec3::ZERO, Vec3::splat(1023.0));
            morton3(q.x as u32) | (morton3(q.y as u32) << 1) | (morton3(q.z as u32) << 2)
        };
        let mut order: Vec<u32> = (0..areas.len() as u32).collect();
        order.sort_by_cached_key(|&i| (key(centroids[i as usize]), i));
        Self::with_order(areas, order)
    }

    fn with_order(areas: &[f32], order: Vec<u32>) -> Self {
        let mut acc = 0.0f64;
        let mut sums = Vec::with_capacity(order.len());
        for &i in &order {
            acc += areas[i as usize].max(0.0) as f64;
            sums.push(acc);
        }
        let cdf: Vec<f32> = sums.iter().map(|&c| (c / acc) as f32).collect();
        let mut prob = vec![0.0; areas.len()];
        for (k, &i) in order.iter().enumerate() {
            prob[i as usize] = cdf[k] - if k == 0 { 0.0 } else { cdf[k - 1] };
        }
        AreaDistribution {
            cdf,
            order,
            prob,
            total: acc,
        }
    }

    /// Total area `A` (m²).
    pub fn total_area(&self) -> f32 {
        self.total as f32
    }

    pub fn is_empty(&self) -> bool {
        self.cdf.is_empty() || self.total <= 0.0
    }

    /// Area density of any point on the sampled surfaces: `1 / A`.
    /// Probability of picking triangle `tri` (flat index).
    pub fn prob(&self, tri: u32) -> f32 {
        self.prob[tri as usize]
    }

    /// A uniform point on the surfaces from one 2-D sample: `u[0]` picks the triangle and
    /// is then rescaled to [0, 1) within the triangle's share of the CDF, so the pair
    /// `(u[0]', u[1])` that places the point on the triangle keeps the stratification of
    /// `u` over the whole surface.
    #[inline]
    pub fn sample(&self, u: [f32; 2]) -> TriangleSample {
        let i = self
            .cdf
            .partition_point(|&c| c <= u[0])
            .min(self.cdf.len() - 1);
        let lo = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let width = self.cdf[i] - lo;
        let u0 = if width > 0.0 {
            ((u[0] - lo) / width).clamp(0.0, ONE_MINUS_EPS)
        } else {
            0.5
        };
        TriangleSample {
            tri: self.order[i],
            bary: uniform_triangle([u0, u[1]]),
            prob: width,
        }
    }
}

/// [`TriangleSample`]s of `L` samples at once, one lane each.
#[derive(Clone, Copy, Debug)]
pub struct TriangleLanes<const L: usize> {
    pub tri: [u32; L],
    pub b1: [f32; L],
    pub b2: [f32; L],
    pub prob: [f32; L],
}

/// Up to this many triangles, [`AreaDistribution::sample_lanes`] finds each lane's CDF
/// step by counting the steps at or below it (compares in lanes); above, by bisection.
const COUNTED_PICK_MAX: usize = 32;

impl AreaDistribution {
    /// [`AreaDistribution::sample`] of `L` pairs `(u0[k], u1[k])` at once, lane `k` the
    /// same bits as `sample([u0[k], u1[k]])`: the same operations in the same order, with
    /// each `if` as a select, so that they vectorise. The CDF is non-decreasing, so the
    /// number of its steps `≤ u` is `partition_point`'s answer.
    #[inline]
    pub fn sample_lanes<const L: usize>(&self, u0: [f32; L], u1: [f32; L]) -> TriangleLanes<L> {
        let n = self.cdf.len();
        let step: [usize; L] = if n <= COUNTED_PICK_MAX {
            let mut count = [0usize; L];
            for &c in &self.cdf {
                for k in 0..L {
                    count[k] += (c <= u0[k]) as usize;
                }
            }
            count.map(|i| i.min(n - 1))
        } else {
            u0.map(|u| self.cdf.partition_point(|&c| c <= u).min(n - 1))
        };
        let lo: [f32; L] = step.map(|i| if i == 0 { 0.0 } else { self.cdf[i - 1] });
        let width: [f32; L] = std::array::from_fn(|k| self.cdf[step[k]] - lo[k]);
        let u: [f32; L] = std::array::from_fn(|k| {
            let q = (u0[k] - lo[k]) / width[k];
            let q = if q < 0.0 { 0.0 } else { q };
            let q = if q > ONE_MINUS_EPS { ONE_MINUS_EPS } else { q };
            if width[k] > 0.0 {
                q
            } else {
                0.5
            }
        });
        let s = u.map(f32::sqrt);
        TriangleLanes {
            tri: step.map(|i| self.order[i]),
            b1: std::array::from_fn(|k| s[k] * (1.0 - u1[k])),
            b2: std::array::from_fn(|k| s[k] * u1[k]),
            prob: width,
        }
    }
}

/// Spreads the low 10 bits of `x` to every third bit (for 3-D Morton codes).
fn morton3(x: u32) -> u32 {
    let mut x = x & 0x3FF;
    x = (x | (x << 16)) & 0x030000FF;
    x = (x | (x << 8)) & 0x0300F00F;
    x = (x | (x << 4)) & 0x030C30C3;
    (x | (x << 2)) & 0x09249249
}

/// Uniform barycentrics `(b1, b2)` on a triangle (square-root parameterisation).
pub fn uniform_triangle(u: [f32; 2]) -> [f32; 2] {
    let s = u[0].sqrt();
    [s * (1.0 - u[1]), s * u[1]]
}

/// A direction sampled about a normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionSample {
    pub dir: Vec3,
    /// Density with respect to solid angle (1/sr).
    pub pdf_solid_angle: f32,
}

/// Cosine-weighted direction about unit normal `n`.
pub fn cosine_hemisphere(n: Vec3, u: [f32; 2]) -> DirectionSample {
    let (dir, dz) = cosine_dir(n.to_array(), u);
    DirectionSample {
        dir: Vec3::from_array(dir),
        pdf_solid_angle: dz * std::f32::consts::FRAC_1_PI,
    }
}

/// The direction of [`cosine_hemisphere`] for `u` about the unit normal `n`, and its
/// cosine with `n`; generic, so a path's direction follows its vertex's normal in the
/// adjoint pass. The frame is Duff et al. 2017's (as glam's `any_orthonormal_pair`).
pub fn cosine_dir<R: Real>(n: V3<R>, u: [f32; 2]) -> (V3<R>, f32) {
    let [dx, dy] = concentric_disk(u);
    let dz = (1.0 - dx * dx - dy * dy).max(0.0).sqrt();
    (frame_direction(n, [dx, dy, dz]), dz)
}

/// The unit direction with coordinates `local` in the frame about `n` that
/// [`cosine_dir`] uses (Duff et al. 2017: tangent, bitangent, `n`); generic, so a
/// direction held fixed in the frame turns with `n`.
pub fn frame_direction<R: Real>(n: V3<R>, local: [f32; 3]) -> V3<R> {
    let sign: f32 = if n[2].v().is_sign_negative() {
        -1.0
    } else {
        1.0
    };
    let a = R::c(-1.0) / (n[2] + R::c(sign as f64));
    let b = n[0] * n[1] * a;
    let t = [
        R::c(1.0) + (n[0] * n[0] * a).s(sign),
        b.s(sign),
        n[0].s(-sign),
    ];
    let bt = [b, R::c(sign as f64) + n[1] * n[1] * a, -n[1]];
    let [dx, dy, dz] = local;
    let d: V3<R> = std::array::from_fn(|k| t[k].s(dx) + bt[k].s(dy) + n[k].s(dz));
    dual::scale(d, R::c(1.0) / dual::length(d))
}

/// The coordinates of the unit direction `d` in [`frame_direction`]'s frame about `n`.
pub fn frame_coordinates(n: Vec3, d: Vec3) -> [f32; 3] {
    let axes = [0, 1, 2].map(|k| {
        let mut e = [0.0; 3];
        e[k] = 1.0;
        Vec3::from_array(frame_direction(n.to_array(), e))
    });
    axes.map(|a| d.dot(a))
}

/// Density of [`cosine_hemisphere`] for direction `dir` (1/sr).
pub fn cosine_hemisphere_pdf(n: Vec3, dir: Vec3) -> f32 {
    n.dot(dir).max(0.0) * std::f32::consts::FRAC_1_PI
}

/// Uniform point on the unit disk (concentric mapping, low distortion).
pub fn concentric_disk(u: [f32; 2]) -> [f32; 2] {
    let a = 2.0 * u[0] - 1.0;
    let b = 2.0 * u[1] - 1.0;
    if a == 0.0 && b == 0.0 {
        return [0.0, 0.0];
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, std::f32::consts::FRAC_PI_4 * (b / a))
    } else {
        (
            b,
            std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (a / b),
        )
    };
    [r * phi.cos(), r * phi.sin()]
}

/// Uniform point on a disk of `radius` about `center`, in the plane normal to `n`;
/// `pdf_area = 1 / (π r²)`.
pub fn uniform_disk(center: Vec3, n: Vec3, radius: f32, u: [f32; 2]) -> Vec3 {
    let [x, y] = concentric_disk(u);
    let (t, b) = n.any_orthonormal_pair();
    center + radius * (x * t + y * b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Sampler;
    use statrs::distribution::{ChiSquared, ContinuousCDF};

    /// Pearson's chi-square test as Mitsuba's test suite runs it: cells with small
    /// expected counts pooled, then the p-value against the significance level.
    fn chi2_pvalue(observed: &[f64], expected: &[f64]) -> f64 {
        let mut cells: Vec<(f64, f64)> = observed
            .iter()
            .copied()
            .zip(expected.iter().copied())
            .collect();
        cells.sort_by(|a, b| a.1.partial_cmp(&b.1).unwrap());
        let (mut pooled_o, mut pooled_e) = (0.0, 0.0);
        let mut stat = 0.0;
        let mut dof = 0usize;
        for (o, e) in cells {
            if e < 5.0 || pooled_e > 0.0 && pooled_e < 5.0 {
                pooled_o += o;
                pooled_e += e;
                continue;
            }
            stat += (o - e) * (o - e) / e;
            dof += 1;
        }
        if pooled_e > 0.0 {
            stat += (pooled_o - pooled_e) * (pooled_o - pooled_e) / pooled_e;
            dof += 1;
        }
        1.0 - ChiSquared::new((dof - 1) as f64).unwrap().cdf(stat)
    }

    #[test]
    fn chi2_cosine_hemisphere() {
        let n = Vec3::new(0.3, -0.2, 0.9).normalize();
        let (t, b) = n.any_orthonormal_pair();
        let (nt, np) = (10usize, 20usize);
        let samples = 200_000u32;
        let mut obs = vec![0.0; nt * np];
        for i in 0..samples {
            let mut s = Sampler::independent(3, 0, i);
            let d = cosine_hemisphere(n, s.next_2d());
            let ct = d.dir.dot(n).clamp(0.0, 1.0);
            let theta = ct.acos();
            let phi = d
                .dir
                .dot(b)
                .atan2(d.dir.dot(t))
                .rem_euclid(std::f32::consts::TAU);
            let it =
                ((theta / std::f32::consts::FRAC_PI_2) * nt as f32).min(nt as f32 - 1.0) as usize;
            let ip = ((phi / std::f32::consts::TAU) * np as f32).min(np as f32 - 1.0) as usize;
            obs[it * np + ip] += 1.0;
            // The pdf matches the density it claims.
            assert!((d.pdf_solid_angle - cosine_hemisphere_pdf(n, d.dir)).abs() < 1e-4);
        }
        // Expected mass of a (θ, φ) cell under cosθ/π: (sin²θ1 - sin²θ0)/2 · Δφ/π.
        let mut exp = vec![0.0; nt * np];
        for it in 0..nt {
            let t0 = it as f64 / nt as f64 * std::f64::consts::FRAC_PI_2;
            let t1 = (it + 1) as f64 / nt as f64 * std::f64::consts::FRAC_PI_2;
            let m = (t1.sin().powi(2) - t0.sin().powi(2)) / 2.0
                * (std::f64::consts::TAU / np as f64)
                / std::f64::consts::PI;
            for ip in 0..np {
                exp[it * np + ip] = m * samples as f64;
            }
        }
        let p = chi2_pvalue(&obs, &exp);
        assert!(p > 0.01, "cosine hemisphere fails chi-square: p = {p}");
    }

    #[test]
    fn chi2_area_sampling_on_mesh() {
        // An irregular mesh: triangles of very different areas.
        let mesh = crate::geometry::mesh::TriMesh::parse_obj(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 3 0 0\nv 0 0 2\nv 0.1 0.1 0.3\n\
             f 1 2 3\nf 2 4 3\nf 1 3 5\nf 1 2 6\n",
            std::path::Path::new("t.obj"),
        )
        .unwrap();
        let areas: Vec<f32> = (0..mesh.triangles.len()).map(|t| mesh.area(t)).collect();
        let dist = AreaDistribution::new(&areas);
        let total: f32 = areas.iter().sum();
        assert!((dist.total_area() - total).abs() < 1e-5);
        // Cells: triangle x a 4x4 grid over (b1, b2 / (1 - b1)) mapped back, i.e. a
        // partition of each triangle into 16 equal-area sub-triangles would be neater;
        // we use 8 bands of b1 (exact areas: band [a, b] of b1 holds (1-a)² - (1-b)²).
        let bands = 8usize;
        let samples = 200_000u32;
        let mut obs = vec![0.0; areas.len() * bands * 2];
        for i in 0..samples {
            let mut s = Sampler::independent(9, 1, i);
            let ts = dist.sample(s.next_2d());
            let [b1, b2] = ts.bary;
            assert!(b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 + 1e-6);
            let band = ((b1 * bands as f32) as usize).min(bands - 1);
            // Within a band of b1, b2 / (1 - b1) is uniform: split it in two halves.
            let half = if b2 < 0.5 * (1.0 - b1) { 0 } else { 1 };
            obs[(ts.tri as usize * bands + band) * 2 + half] += 1.0;
        }
        let mut exp = vec![0.0; obs.len()];
        for (t, a) in areas.iter().enumerate() {
            for k in 0..bands {
                let (lo, hi) = (k as f64 / bands as f64, (k + 1) as f64 / bands as f64);
                let frac = (1.0 - lo).powi(2) - (1.0 - hi).powi(2);
                for h in 0..2 {
                    exp[(t * bands + k) * 2 + h] =
                        samples as f64 * (*a as f64 / total as f64) * frac * 0.5;
                }
            }
        }
        let p = chi2_pvalue(&obs, &exp);
        assert!(p > 0.01, "area sampling fails chi-square: p = {p}");
    }

    #[test]
    fn lanes_sample_as_the_scalar_sampler() {
        // Few triangles (counted pick) and many (bisection); zero-area triangles give
        // empty CDF steps; u on a step's edge, 0 and the largest f32 below 1.
        for n in [1usize, 4, 7, 32, 33, 500] {
            let areas: Vec<f32> = (0..n)
                .map(|i| {
                    if i % 5 == 3 {
                        0.0
                    } else {
                        0.1 + (i % 7) as f32
                    }
                })
                .collect();
            let d = AreaDistribution::new(&areas);
            let mut s = Sampler::independent(3, n as u64, 0);
            let mut u: Vec<[f32; 2]> = (0..200).map(|_| s.next_2d()).collect();
            u.extend(d.cdf.iter().map(|&c| [c, 0.5]));
            u.extend([[0.0, 0.0], [ONE_MINUS_EPS, ONE_MINUS_EPS]]);
            for chunk in u.chunks_exact(8) {
                let lanes = d.sample_lanes::<8>(
                    std::array::from_fn(|k| chunk[k][0]),
                    std::array::from_fn(|k| chunk[k][1]),
                );
                for (k, &uk) in chunk.iter().enumerate() {
                    let t = d.sample(uk);
                    let l = (lanes.tri[k], [lanes.b1[k], lanes.b2[k]], lanes.prob[k]);
                    assert_eq!((t.tri, t.bary, t.prob), l, "n {n}, u {uk:?}");
                }
            }
        }
    }

    #[test]
    fn chi2_detects_a_wrong_sampler() {
        // The test must be able to fail: a sampler with a sqrt missing is rejected.
        let samples = 50_000u32;
        let bands = 8usize;
        let mut obs = vec![0.0; bands];
        for i in 0..samples {
            let mut s = Sampler::independent(2, 2, i);
            let u = s.next_2d();
            let b1 = u[0] * (1.0 - u[1]); // wrong: not uniform over the triangle
            obs[((b1 * bands as f32) as usize).min(bands - 1)] += 1.0;
        }
        let exp: Vec<f64> = (0..bands)
            .map(|k| {
                let (lo, hi) = (k as f64 / bands as f64, (k + 1) as f64 / bands as f64);
                samples as f64 * ((1.0 - lo).powi(2) - (1.0 - hi).powi(2))
            })
            .collect();
        assert!(chi2_pvalue(&obs, &exp) < 1e-6);
    }
}
