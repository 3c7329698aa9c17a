//! Lane arithmetic shared by the eight-wide primal passes (`mc3_lanes`, `path_lanes`):
//! plain loops over `[f32; LANES]`, written op for op as the scalar formulas they stand
//! for, which the compiler turns into vector instructions with the same rounding (no
//! SIMD crate, no fused multiply-adds).

use crate::geometry::HiddenTri;
use glam::Vec3;

/// Samples evaluated together.
pub const LANES: usize = 8;

/// One `f32` per lane.
pub type F = [f32; LANES];

/// A lane per sample of `f(k)`.
#[inline(always)]
pub fn lanes(f: impl FnMut(usize) -> f32) -> F {
    std::array::from_fn(f)
}

/// `a · b` per lane: `a0 b0 + a1 b1 + a2 b2`, as [`crate::adjoint::dual::dot`] and glam's
/// `Vec3::dot`.
#[inline(always)]
pub fn dot(a: &[F; 3], b: &[F; 3]) -> F {
    lanes(|k| a[0][k] * b[0][k] + a[1][k] * b[1][k] + a[2][k] * b[2][k])
}

/// `c − v` per lane for a constant `c`.
#[inline(always)]
pub fn from_const(c: Vec3, v: &[F; 3]) -> [F; 3] {
    let c = c.to_array();
    std::array::from_fn(|i| lanes(|k| c[i] - v[i][k]))
}

/// `v − c` per lane for a constant `c`.
#[inline(always)]
pub fn minus_const(v: &[F; 3], c: Vec3) -> [F; 3] {
    let c = c.to_array();
    std::array::from_fn(|i| lanes(|k| v[i][k] - c[i]))
}

/// A constant vector in every lane.
#[inline(always)]
pub fn splat(c: Vec3) -> [F; 3] {
    c.to_array().map(|c| [c; LANES])
}

/// A 3-vector field of the lanes' triangles.
#[inline(always)]
pub fn gather3(tris: &[&HiddenTri; LANES], f: impl Fn(&HiddenTri) -> Vec3) -> [F; 3] {
    let v: [Vec3; LANES] = tris.map(&f);
    std::array::from_fn(|i| lanes(|k| v[k][i]))
}

/// The points at barycentrics `(b1, b2)` of the lanes' triangles and `b0 = 1 − b1 − b2`:
/// `v0 b0 + v1 b1 + v2 b2`, as `HiddenTri::point` and `TriParams::point`.
#[inline(always)]
pub fn points(tris: &[&HiddenTri; LANES], [b1, b2]: [F; 2]) -> ([F; 3], F) {
    let b0 = lanes(|k| 1.0 - b1[k] - b2[k]);
    let (v0, v1, v2) = (
        gather3(tris, |t| t.v[0]),
        gather3(tris, |t| t.v[1]),
        gather3(tris, |t| t.v[2]),
    );
    let x =
        std::array::from_fn(|i| lanes(|k| v0[i][k] * b0[k] + v1[i][k] * b1[k] + v2[i][k] * b2[k]));
    (x, b0)
}

/// The lanes' albedos at barycentrics `(b1, b2)` (`b0 = 1 − b1 − b2` given):
/// `a0 b0 + a1 b1 + a2 b2`, as `HiddenTri::albedo_at` and `TriParams::albedo_at`.
#[inline(always)]
pub fn albedos(tris: &[&HiddenTri; LANES], [b1, b2]: [F; 2], b0: F) -> F {
    lanes(|k| {
        let a = tris[k].albedo;
        a[0] * b0[k] + a[1] * b1[k] + a[2] * b2[k]
    })
}

/// Lane `k`'s vector.
#[inline(always)]
pub fn at(v: &[F; 3], k: usize) -> Vec3 {
    Vec3::new(v[0][k], v[1][k], v[2][k])
}
