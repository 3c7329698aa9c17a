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
use std::collections::HashMap;
use std::sync::Mutex;

/// Most triangles the bit set holds.
pub const MAX_TRIANGLES: usize = 64;

/// The triangles' corners and unit normals in `f64`, worked out once, and the bit sets
/// already asked for, by point: a single capture asks for the same spot in every
/// measurement, and a gradient's forward and adjoint passes ask twice.
pub struct PointShadow {
    tris: Vec<Tri>,
    tau: f64,
    cache: Mutex<HashMap<[u32; 3], u64>>,
}

struct Tri {
    c: [DVec3; 3],
    /// Unit normal, zero for a degenerate triangle.
    n: DVec3,
}

impl PointShadow {
    /// `tris[t]` triangle `t`'s corners, `tau` the coplanarity tolerance (m). No
    /// triangles kept past [`MAX_TRIANGLES`]: every bit set is then empty.
    pub fn new(tris: &[[Vec3; 3]], tau: f32) -> Self {
        let tris = if tris.len() > MAX_TRIANGLES {
            Vec::new()
        } else {
            tris.iter()
                .map(|t| {
                    let c = t.map(|c| c.as_dvec3());
                    let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize_or_zero();
                    Tri { c, n }
                })
                .collect()
        };
        PointShadow {
            tris,
            tau: tau as f64,
            cache: Mutex::new(HashMap::new()),
        }
    }

    /// Bit `t` set: no triangle other than `t` can block a segment from a point of
    /// triangle `t` to `l`. From the cache where `l` was asked before.
    pub fn clear_toward(&self, l: Vec3) -> u64 {
        let key = l.to_array().map(f32::to_bits);
        if let Some(bits) = self.cache.lock().ok().and_then(|c| c.get(&key).copied()) {
            return bits;
        }
        let bits = self.work_out(l.as_dvec3());
        if let Ok(mut c) = self.cache.lock() {
            c.insert(key, bits);
        }
        bits
    }

    fn work_out(&self, l: DVec3) -> u64 {
        let mut clear = 0u64;
        for (t, tt) in self.tris.iter().enumerate() {
            let Some(toward) = Toward::new(tt, l, self.tau) else {
                continue;
            };
            let mut others = self.tris.iter().enumerate().filter(|&(u, _)| u != t);
            if others.all(|(_, u)| toward.separates(u)) {
                clear |= 1 << t;
            }
        }
        clear
    }
}

/// `conv(t, l)`'s planes for one triangle `t` and point `l`: `t`'s plane and the side
/// faces, oriented as the module docs say.
struct Toward<'a> {
    t: &'a Tri,
    l: DVec3,
    tau: f64,
    /// `t`'s normal towards `l`.
    n_t: DVec3,
    /// The side faces through edge `(i, i + 1)` and `l`, towards `t`'s third corner;
    /// `None` where `l` is on the edge's line.
    sides: [Option<DVec3>; 3],
    /// The longest distance from `t`'s corners to `l`.
    d: f64,
}

impl<'a> Toward<'a> {
    /// `None` unless `l` lies clearly off `t`'s plane (a segment in the plane is left to
    /// the full test, as [`super::blockers::BlockerSets::of_segment`] leaves it).
    fn new(t: &'a Tri, l: DVec3, tau: f64) -> Option<Self> {
        let c = &t.c;
        let h = t.n.dot(l - c[0]);
        if t.n == DVec3::ZERO || h.abs() <= 4.0 * tau {
            return None;
        }
        let sides = [(0, 1, 2), (1, 2, 0), (2, 0, 1)].map(|(i, j, k)| {
            let m = (c[j] - c[i]).cross(l - c[i]).normalize_or_zero();
            (m != DVec3::ZERO).then(|| m * m.dot(c[k] - c[i]).signum())
        });
        Some(Toward {
            t,
            l,
            tau,
            n_t: t.n * h.signum(),
            sides,
            d: c.iter().map(|&p| (l - p).length()).fold(0.0, f64::max),
        })
    }

    /// Whether one of the planes of the module docs separates triangle `u` from
    /// `conv(t, l)`.
    fn separates(&self, u: &Tri) -> bool {
        let (t, l, tau) = (&self.t.c, self.l, self.tau);
        // t's plane.
        if u.c.iter().all(|&p| self.n_t.dot(p - t[0]) <= tau) {
            return true;
        }
        // The side faces: u more than tau outside one.
        for (i, m) in self.sides.iter().enumerate() {
            if let Some(m) = m {
                if u.c.iter().all(|&p| m.dot(p - t[i]) < -tau) {
                    return true;
                }
            }
        }
        // u's plane, oriented towards l.
        if u.n == DVec3::ZERO {
            return false;
        }
        let n_u = u.n * u.n.dot(l - u.c[0]).signum();
        let g = |p: DVec3| n_u.dot(p - u.c[0]);
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
        lowest >= -tau && g_l > 0.5 * self.d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A triangle behind a plate that covers it from `l` is not clear; with the plate
    /// moved aside it is, and so is a neighbour folded towards `l` sharing an edge.
    #[test]
    fn plates_and_neighbours() {
        let clear_toward = |tris: &[[Vec3; 3]], l, tau| PointShadow::new(tris, tau).clear_toward(l);
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
