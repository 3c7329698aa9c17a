//! Small vector helpers and closest-point queries used by the remesher.

pub(super) type V3 = [f64; 3];

#[inline]
pub(super) fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub(super) fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline]
pub(super) fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a + s (b - a)`.
#[inline]
pub(super) fn lerp(a: V3, b: V3, s: f64) -> V3 {
    add(a, scale(sub(b, a), s))
}

#[inline]
pub(super) fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(super) fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
pub(super) fn norm2(a: V3) -> f64 {
    dot(a, a)
}

#[inline]
pub(super) fn dist2(a: V3, b: V3) -> f64 {
    norm2(sub(a, b))
}

#[inline]
pub(super) fn midpoint(a: V3, b: V3) -> V3 {
    [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ]
}

/// Twice the area vector of triangle `(a, b, c)` (points along its counter-clockwise normal).
#[inline]
pub(super) fn tri_cross(a: V3, b: V3, c: V3) -> V3 {
    cross(sub(b, a), sub(c, a))
}

/// Sine of the angle below which a triangle counts as degenerate (its normal is unreliable).
const DEGENERATE_SIN: f64 = 1e-6;

/// Unit normal of `(a, b, c)`, or `None` when the triangle is (nearly) degenerate:
/// `|ab x ac| <= 1e-6 |ab| |ac|` or not finite.
pub(super) fn unit_normal(a: V3, b: V3, c: V3) -> Option<V3> {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let n = cross(ab, ac);
    let len2 = norm2(n);
    let limit = DEGENERATE_SIN * DEGENERATE_SIN * norm2(ab) * norm2(ac);
    if len2 > limit && len2 > 0.0 && len2.is_finite() {
        Some(scale(n, 1.0 / len2.sqrt()))
    } else {
        None
    }
}

/// Normalised `a`, or `None` for a zero or non-finite vector.
pub(super) fn normalized(a: V3) -> Option<V3> {
    let l2 = norm2(a);
    if l2 > 0.0 && l2.is_finite() {
        Some(scale(a, 1.0 / l2.sqrt()))
    } else {
        None
    }
}

/// Closest point to `p` on segment `[a, b]` and its parameter `t` (point = a + t (b - a)).
pub(super) fn closest_on_segment(p: V3, a: V3, b: V3) -> (V3, f64) {
    let ab = sub(b, a);
    let l2 = norm2(ab);
    let t = if l2 > 0.0 {
        (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (lerp(a, b, t), t)
}

/// Closest point to `p` on triangle `(a, b, c)` with its barycentric coordinates.
///
/// Classifies `p` into the Voronoi regions of the vertices, edges and interior of the
/// triangle (the region tests of Ericson, *Real-Time Collision Detection*, §5.1.5).
/// Degenerate triangles are handled as the union of their three edges.
pub fn closest_on_triangle(p: V3, a: V3, b: V3, c: V3) -> (V3, [f64; 3]) {
    if unit_normal(a, b, c).is_none() {
        return closest_on_degenerate(p, a, b, c);
    }
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let t = d1 / (d1 - d3);
        return (lerp(a, b, t), [1.0 - t, t, 0.0]);
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let t = d2 / (d2 - d6);
        return (lerp(a, c, t), [1.0 - t, 0.0, t]);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        let t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (lerp(b, c, t), [0.0, 1.0 - t, t]);
    }
    let inv = 1.0 / (va + vb + vc);
    let v = vb * inv;
    let w = vc * inv;
    let q = add(a, add(scale(ab, v), scale(ac, w)));
    (q, [1.0 - v - w, v, w])
}

fn closest_on_degenerate(p: V3, a: V3, b: V3, c: V3) -> (V3, [f64; 3]) {
    let (q0, t0) = closest_on_segment(p, a, b);
    let (q1, t1) = closest_on_segment(p, b, c);
    let (q2, t2) = closest_on_segment(p, c, a);
    let (d0, d1, d2) = (dist2(p, q0), dist2(p, q1), dist2(p, q2));
    if d0 <= d1 && d0 <= d2 {
        (q0, [1.0 - t0, t0, 0.0])
    } else if d1 <= d2 {
        (q1, [0.0, 1.0 - t1, t1])
    } else {
        (q2, [t2, 0.0, 1.0 - t2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let (q, w) = closest_on_triangle([0.25, 0.25, 3.0], a, b, c);
        assert_eq!(q, [0.25, 0.25, 0.0]);
        assert!((w[0] - 0.5).abs() < 1e-15 && (w[1] - 0.25).abs() < 1e-15);
        let (q, _) = closest_on_triangle([2.0, -1.0, 0.0], a, b, c);
        assert_eq!(q, b);
        let (q, w) = closest_on_triangle([1.0, 1.0, 0.0], a, b, c);
        assert!((q[0] - 0.5).abs() < 1e-15 && (q[1] - 0.5).abs() < 1e-15);
        assert!((w[1] - 0.5).abs() < 1e-15);
        // Degenerate (collinear) triangle: closest point on its edges, finite weights.
        let (q, w) = closest_on_triangle([0.5, 1.0, 0.0], a, b, [2.0, 0.0, 0.0]);
        assert_eq!(q, [0.5, 0.0, 0.0]);
        assert!(w.iter().all(|x| x.is_finite()));
    }
}
