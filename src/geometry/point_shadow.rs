//! Which hidden triangles see a fixed point (a point laser spot `l` on the relay wall)
//! past every other hidden triangle: shadow-ray culling for next-event estimation to the
//! spot, exact up to the self-intersection offset, like [`super::blockers`].
//!
//! A segment from a point `a` of triangle `t` to `l` lies in the tetrahedron
//! `T = conv(t₀, t₁, t₂, l)`. Another triangle `u` cannot meet it beyond the offset `eps`
//! when one of these planes separates them (heights in `f64`, `τ = eps / 4`):
//! - `t`'s plane: every corner of `u` at most `τ` above it on `l`'s side (the set
//!   `B(t, ±)` of [`super::blockers`] leaves `u` out for the same reason);
//! - a side face of `T`, through an edge of `t` and `l`: `u` more than `τ` outside;
//! - `u`'s plane: all of `T` more than `τ` on one side, or, for a neighbour that touches
//!   `t` (a shared edge or corner), `t` no more than `τ` behind it and `l` in front by
//!   more than half the longest distance `d` from `t`'s corners to `l`. Then a point at
//!   distance `s ≥ eps` from `a` along the segment is at height at least
//!   `−τ + (eps / d)(d / 2) = eps / 4` above `u`'s plane: it does not reach `u`.
//!
//! When every other triangle is separated, the shadow ray from `t` to `l` need only test
//! the wall. The planes are a subset of the separating-axis test (no edge–edge axes), so
//! the answer is conservative: a triangle it cannot clear is traced as before.

use glam::{DVec3, Vec3};

/// Most triangles the bit set holds.
pub const MAX_TRIANGLES: usize = 64;

/// Bit `t` set: no hidden triangle other than `t` can block a segment from a point of
/// triangle `t` to `l` (`tris[t]` its corners, `tau` the coplanarity tolerance, m). Empty
/// for more than [`MAX_TRIANGLES`] triangles.
pub fn clear_toward(tris: &[[Vec3; 3]], l: Vec3, tau: f32) -> u64 {
    if tris.len() > MAX_TRIANGLES {
        return 0;
    }
    let tau = tau as f64;
    let l = l.as_dvec3();
    let corners: Vec<[DVec3; 3]> = tris.iter().map(|t| t.map(|c| c.as_dvec3())).collect();
    let mut clear = 0u64;
    for (t, tc) in corners.iter().enumerate() {
        let others = corners.iter().enumerate().filter(|&(u, _)| u != t);
        if sees(tc, l, tau) && others.clone().all(|(_, uc)| separated(tc, l, uc, tau)) {
            clear |= 1 << t;
        }
    }
    clear
}

/// Whether `l` lies clearly off `t`'s plane (a segment in the plane is left to the full
/// test, as [`super::blockers::BlockerSets::of_segment`] leaves it).
fn sees(t: &[DVec3; 3], l: DVec3, tau: f64) -> bool {
    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
    let h = n.dot(l - t[0]);
    n != DVec3::ZERO && h.abs() > 4.0 * tau
}

/// Whether one of the planes of the module docs separates triangle `u` from
/// `conv(t, l)`.
fn separated(t: &[DVec3; 3], l: DVec3, u: &[DVec3; 3], tau: f64) -> bool {
    // t's plane, oriented towards l.
    let n_t = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
    let s = n_t.dot(l - t[0]).signum();
    if u.iter().all(|&c| s * n_t.dot(c - t[0]) <= tau) {
        return true;
    }
    // The side faces through edge (i, j) and l, oriented towards t's third corner k.
    for (i, j, k) in [(0, 1, 2), (1, 2, 0), (2, 0, 1)] {
        let m = (t[j] - t[i]).cross(l - t[i]).normalize_or_zero();
        if m == DVec3::ZERO {
            continue;
        }
        let m = m * m.dot(t[k] - t[i]).signum();
        if u.iter().all(|&c| m.dot(c - t[i]) < -tau) {
            return true;
        }
    }
    // u's plane, oriented towards l.
    let n_u = (u[1] - u[0]).cross(u[2] - u[0]).normalize_or_zero();
    if n_u == DVec3::ZERO {
        return false;
    }
    let g = |p: DVec3| n_u.dot(p - u[0]);
    let n_u = n_u * g(l).signum();
    let g = |p: DVec3| n_u.dot(p - u[0]);
    let (g_l, g_t) = (g(l), t.map(g));
    let lowest = g_t.iter().copied().fold(f64::INFINITY, f64::min);
    if lowest > tau && g_l > tau {
        return true;
    }
    let highest = g_t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if highest < -tau && g_l > tau {
        // l in front, t behind: u may lie between them.
        return false;
    }
    let d = t.iter().map(|&c| (l - c).length()).fold(0.0, f64::max);
    lowest >= -tau && g_l > 0.5 * d
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A triangle behind a plate that covers it from `l` is not clear; with the plate
    /// moved aside it is, and so is a neighbour folded towards `l` sharing an edge.
    #[test]
    fn plates_and_neighbours() {
        let l = Vec3::new(0.0, 0.0, 0.0);
        let t = [
            Vec3::new(-0.1, -0.1, 1.0),
            Vec3::new(0.1, -0.1, 1.0),
            Vec3::new(0.0, 0.1, 1.0),
        ];
        let plate = |dx: f32| {
            [
                Vec3::new(-0.5 + dx, -0.5, 0.5),
                Vec3::new(0.5 + dx, -0.5, 0.5),
                Vec3::new(dx, 0.5, 0.5),
            ]
        };
        let tau = 1e-6;
        assert_eq!(clear_toward(&[t, plate(0.0)], l, tau) & 1, 0);
        assert_eq!(clear_toward(&[t, plate(3.0)], l, tau) & 1, 1);
        // A neighbour on edge (v0, v1), folded 30° towards l: it cannot shadow t.
        let fold = [t[1], t[0], Vec3::new(0.0, -0.25, 0.9)];
        assert_eq!(clear_toward(&[t, fold], l, tau) & 1, 1);
        // Folded steeply over t, between t and l: it can.
        let over = [t[1], t[0], Vec3::new(0.0, 0.2, 0.6)];
        assert_eq!(clear_toward(&[t, over], l, tau) & 1, 0);
    }
}
