//! The geometry of one visibility boundary sample (issue 18, `notes/boundary-methods.md`
//! §3.1): a point `y` on a silhouette edge seen from a wall point `o`, and the receiver
//! point `x` its shadow falls on, first hit of the ray from `o` through `y`.
//!
//! Moving the scene moves the shadow curve across the receiver. Per unit length of the
//! edge, the receiver area that changes side is
//!
//! `dA = J (∂y/∂θ − (r_y/r_x) ∂x_R/∂θ)·n dℓ`,   `J = sin φ r_x² / (r_y² cos θ_x)`,
//!
//! with `n` the edge's normal across the view ray (toward the lit side, away from the
//! occluding face), `φ` the angle between the edge and the view ray, `r_y = |y − o|`,
//! `r_x = |x − o|`, `θ_x` the receiver's angle to the ray and `∂x_R/∂θ` the velocity of
//! the receiver's material point. The integrand `F` of the three-bounce measurement holds
//! `cos θ_x / r_x²`, so [`EdgePoint::area_per_length`] is meant to be multiplied by it:
//! `F J` stays finite at grazing receivers.

use glam::Vec3;

/// A point on a silhouette edge seen from `o`, with its view-ray frame.
#[derive(Clone, Copy, Debug)]
pub struct EdgePoint {
    /// The viewpoint (a wall point) (m).
    pub o: Vec3,
    /// The point on the edge (m).
    pub y: Vec3,
    /// Unit direction of the view ray `o → y`.
    pub d: Vec3,
    /// `|y − o|` (m).
    pub r_y: f32,
    /// Unit normal across the ray: `± normalize(d × e)`, pointing away from the occluding
    /// face, toward the lit side.
    pub n: Vec3,
    /// `sin φ = |e × d|`, `e` the unit edge direction.
    pub sin_phi: f32,
}

impl EdgePoint {
    /// The frame at `y` on the edge of direction `e`, for the occluding face whose third
    /// vertex is `q` (the normal points away from it). `None` when the edge lies along the
    /// view ray (`sin φ = 0`: it sweeps no area).
    pub fn new(o: Vec3, y: Vec3, e: Vec3, q: Vec3) -> Option<EdgePoint> {
        let to_y = y - o;
        let r_y = to_y.length();
        let d = to_y / r_y;
        let across = d.cross(e.normalize());
        let sin_phi = across.length();
        if !(sin_phi > 1e-6 && r_y > 0.0) {
            return None;
        }
        let mut n = across / sin_phi;
        if n.dot(q - y) > 0.0 {
            n = -n;
        }
        Some(EdgePoint {
            o,
            y,
            d,
            r_y,
            n,
            sin_phi,
        })
    }

    /// `J cos θ_x / r_x² = sin φ / r_y²`: the receiver area swept per unit edge length and
    /// unit normal displacement of the edge, times the `cos θ_x / r_x²` that the
    /// measurement's integrand carries (which cancels `J`'s receiver factors).
    pub fn area_per_length(&self) -> f32 {
        self.sin_phi / (self.r_y * self.r_y)
    }

    /// `(∂y/∂θ − (r_y/r_x) ∂x_R/∂θ)·n` for an edge-point velocity `v_y` and a receiver
    /// material-point velocity `v_x`, the receiver at `x` (m per unit of θ).
    pub fn normal_speed(&self, x: Vec3, v_y: Vec3, v_x: Vec3) -> f32 {
        let r_x = (x - self.o).length();
        (v_y - v_x * (self.r_y / r_x)).dot(self.n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square occluder at distance 0.6 in front of a plane receiver at distance 1 from a
    /// point `o` (notes §3.2): translating the occluder by `dx` moves its shadow by
    /// `m dx`, `m = 1/0.6`, and the shadow edge is `m` times the edge's length, so the
    /// receiver area swept per unit edge length is `J (v·n) = m²`.
    #[test]
    fn square_occluder_sweeps_m_squared() {
        let o = Vec3::new(0.1, 0.0, 0.0);
        let m = 1.0 / 0.6;
        // The occluder's +x edge, along y, at x = 0.2, z = 0.6; its face lies toward -x.
        let y = Vec3::new(0.2, 0.07, 0.6);
        let p = EdgePoint::new(o, y, Vec3::Y, Vec3::new(0.0, 0.0, 0.6)).unwrap();
        assert!(p.n.x > 0.0, "the normal points to the lit side, +x");
        // The receiver hit: the ray o -> y continued to z = 1.
        let x = o + p.d * (1.0 / p.d.z);
        let cos_x = p.d.z;
        let r_x = (x - o).length();
        let j = p.area_per_length() * r_x * r_x / cos_x;
        let swept = j * p.normal_speed(x, Vec3::X, Vec3::ZERO);
        assert!((swept - m * m).abs() < 1e-4 * m * m, "{swept} vs {}", m * m);
        // Moving the receiver by -m dx sweeps the same area: only relative motion counts.
        let relative = j * p.normal_speed(x, Vec3::ZERO, -Vec3::X);
        assert!((relative - m).abs() < 1e-4 * m, "{relative} vs {m}");
        // The occluder and the receiver moving together (a rigid shift along x) sweep
        // (1 - r_y/r_x) of the edge's own sweep.
        let both = j * p.normal_speed(x, Vec3::X, Vec3::X);
        assert!((both - m * m * (1.0 - 0.6)).abs() < 1e-4 * m * m, "{both}");
    }

    #[test]
    fn an_edge_along_the_view_ray_sweeps_nothing() {
        let o = Vec3::ZERO;
        let y = Vec3::new(0.0, 0.0, 1.0);
        assert!(EdgePoint::new(o, y, Vec3::Z, Vec3::X).is_none());
    }
}
