//! The relay wall as what it is, a flat parallelogram, intersected analytically instead
//! of as two triangles in the BVH. With centre `c`, edge vectors `a_u`, `a_v` and unit
//! normal `n`, the ray `o + t d` meets its plane at
//!
//! `t = n·(c − o) / n·d`,
//!
//! and the point `p` lies on the wall when its coordinates along the dual basis of
//! `(a_u, a_v)` (`α = (p − c)·u*`, `β = (p − c)·v*`, with `u*·a_u = v*·a_v = 1`,
//! `u*·a_v = v*·a_u = 0`) are both within `[−½, ½]`. A segment between two points on the
//! same side of the plane (or on it, as every wall point of a path is) never crosses it,
//! so most shadow rays skip the wall with two dot products.

use glam::Vec3;

/// The wall's plane and extent.
#[derive(Clone, Copy, Debug)]
pub struct WallPlane {
    center: Vec3,
    normal: Vec3,
    dual_u: Vec3,
    dual_v: Vec3,
}

impl WallPlane {
    pub fn new(center: Vec3, axis_u: Vec3, axis_v: Vec3) -> WallPlane {
        let (uu, uv, vv) = (axis_u.dot(axis_u), axis_u.dot(axis_v), axis_v.dot(axis_v));
        let det = uu * vv - uv * uv;
        WallPlane {
            center,
            normal: axis_u.cross(axis_v).normalize(),
            dual_u: (vv * axis_u - uv * axis_v) / det,
            dual_v: (uu * axis_v - uv * axis_u) / det,
        }
    }

    fn contains(&self, p: Vec3) -> bool {
        let q = p - self.center;
        q.dot(self.dual_u).abs() <= 0.5 && q.dot(self.dual_v).abs() <= 0.5
    }

    /// Distance along the ray `o + t d` to the wall, if it is hit within `[tmin, tmax]`.
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<f32> {
        let nd = self.normal.dot(d);
        if nd == 0.0 {
            return None;
        }
        let t = self.normal.dot(self.center - o) / nd;
        (t >= tmin && t <= tmax && self.contains(o + t * d)).then_some(t)
    }

    /// Whether the wall blocks the segment `a → b` (unit direction `d`) within
    /// `[tmin, tmax]`: only if `a` and `b` lie strictly on opposite sides.
    #[inline]
    pub fn blocks(&self, a: Vec3, b: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        self.separates(a, b) && self.intersect(a, d, tmin, tmax).is_some()
    }

    /// Whether `a` and `b` lie strictly on opposite sides of the wall's plane (only then
    /// can the wall block the segment between them).
    #[inline]
    pub fn separates(&self, a: Vec3, b: Vec3) -> bool {
        let (sa, sb) = (
            self.normal.dot(a - self.center),
            self.normal.dot(b - self.center),
        );
        (sa > 0.0) != (sb > 0.0) && sa != 0.0 && sb != 0.0
    }

    /// [`WallPlane::separates`] of `L` segments at once (the same operations per lane).
    #[inline]
    pub fn separates_lanes<const L: usize>(
        &self,
        a: &[[f32; L]; 3],
        b: &[[f32; L]; 3],
    ) -> [bool; L] {
        let (n, c) = (self.normal, self.center);
        let side = |p: &[[f32; L]; 3], k: usize| {
            n.x * (p[0][k] - c.x) + n.y * (p[1][k] - c.y) + n.z * (p[2][k] - c.z)
        };
        std::array::from_fn(|k| {
            let (sa, sb) = (side(a, k), side(b, k));
            (sa > 0.0) != (sb > 0.0) && sa != 0.0 && sb != 0.0
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_inside_the_parallelogram_only() {
        // A sheared wall: axes not orthogonal.
        let w = WallPlane::new(
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(0.5, 1.0, 0.0),
        );
        let down = Vec3::new(0.0, 0.0, -1.0);
        // Centre, and just inside / outside each edge along the dual coordinates.
        assert_eq!(
            w.intersect(Vec3::new(0.0, 0.0, 1.0), down, 0.0, 10.0),
            Some(1.0)
        );
        let at = |a: f32, b: f32| Vec3::new(2.0 * a + 0.5 * b, b, 1.0);
        assert!(w.intersect(at(0.49, 0.49), down, 0.0, 10.0).is_some());
        assert!(w.intersect(at(0.51, 0.0), down, 0.0, 10.0).is_none());
        assert!(w.intersect(at(0.0, -0.51), down, 0.0, 10.0).is_none());
        // Outside [tmin, tmax], parallel, and from the plane itself.
        assert!(w
            .intersect(Vec3::new(0.0, 0.0, 1.0), down, 0.0, 0.5)
            .is_none());
        assert!(w
            .intersect(Vec3::new(0.0, 0.0, 1.0), Vec3::X, 0.0, 10.0)
            .is_none());
        assert!(w.intersect(Vec3::ZERO, down, 1e-6, 10.0).is_none());
        // A segment through the wall is blocked; one on one side, or ending on it, is not.
        let (a, b) = (Vec3::new(0.1, 0.1, 1.0), Vec3::new(0.1, 0.1, -1.0));
        assert!(w.blocks(a, b, (b - a).normalize(), 1e-6, 2.0 - 1e-6));
        let c = Vec3::new(0.3, 0.2, 0.0);
        assert!(!w.blocks(a, c, (c - a).normalize(), 1e-6, (c - a).length()));
        let e = Vec3::new(0.5, 0.5, 0.5);
        assert!(!w.blocks(a, e, (e - a).normalize(), 1e-6, (e - a).length()));
    }
}
