//! Ray queries against few triangles, four at a time: the triangles are stored in
//! structure-of-arrays packets of four lanes, and one ray is tested against a whole packet
//! with SIMD arithmetic (glam's `Vec4`, SSE2 on x86-64), by Möller and Trumbore's test
//! ("Fast, minimum storage ray/triangle intersection", 1997): with `e1 = v0 − v1`,
//! `e2 = v2 − v0`, `n = e1 × e2`, `c = v0 − o`, `r = d × c`,
//!
//! `det = n·d,  u = r·e2 / det,  v = r·e1 / det,  t = n·c / det`,
//!
//! a hit when `det ≠ 0`, `u, v, 1 − u − v ≥ 0` and `tmin ≤ t ≤ tmax`. That is the same
//! test as obvhs's `Triangle::intersect`, lane by lane. For the small hidden meshes of NLOS
//! scenes (a letter, a few dozen triangles) a packet loop costs less than a BVH traversal's
//! fixed cost (`accel::PACKET_TRIANGLES` has the measurement); unused lanes hold a
//! degenerate triangle (`n = 0`), which never hits.

use glam::{Vec3, Vec4};

/// Four triangles, coordinate by coordinate.
#[derive(Clone, Copy, Debug)]
pub struct TriPacket {
    v0: [Vec4; 3],
    e1: [Vec4; 3],
    e2: [Vec4; 3],
    n: [Vec4; 3],
}

/// Packs triangles `[v0, v1, v2]` four to a packet (the last one padded).
pub fn pack(tris: &[[Vec3; 3]]) -> Vec<TriPacket> {
    tris.chunks(4)
        .map(|group| {
            let lane = |k: usize| group.get(k).copied().unwrap_or([Vec3::ZERO; 3]);
            let coords = |f: &dyn Fn([Vec3; 3]) -> Vec3| {
                let p: [Vec3; 4] = std::array::from_fn(|k| f(lane(k)));
                [0, 1, 2].map(|a| Vec4::from_array(p.map(|v| v[a])))
            };
            TriPacket {
                v0: coords(&|t| t[0]),
                e1: coords(&|t| t[0] - t[1]),
                e2: coords(&|t| t[2] - t[0]),
                n: coords(&|t| (t[0] - t[1]).cross(t[2] - t[0])),
            }
        })
        .collect()
}

#[inline(always)]
fn dot(a: &[Vec4; 3], b: &[Vec4; 3]) -> Vec4 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl TriPacket {
    /// The hit distance of the ray `o + t d` on each lane, `INFINITY` where it misses or
    /// falls outside `[tmin, tmax]`.
    #[inline(always)]
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Vec4 {
        let c = [
            self.v0[0] - Vec4::splat(o.x),
            self.v0[1] - Vec4::splat(o.y),
            self.v0[2] - Vec4::splat(o.z),
        ];
        let (dx, dy, dz) = (Vec4::splat(d.x), Vec4::splat(d.y), Vec4::splat(d.z));
        let r = [
            dy * c[2] - dz * c[1],
            dz * c[0] - dx * c[2],
            dx * c[1] - dy * c[0],
        ];
        let det = self.n[0] * dx + self.n[1] * dy + self.n[2] * dz;
        let inv_det = Vec4::ONE / det;
        let u = dot(&r, &self.e2) * inv_det;
        let v = dot(&r, &self.e1) * inv_det;
        let w = Vec4::ONE - u - v;
        let t = dot(&self.n, &c) * inv_det;
        let hit = det.cmpne(Vec4::ZERO)
            & u.cmpge(Vec4::ZERO)
            & v.cmpge(Vec4::ZERO)
            & w.cmpge(Vec4::ZERO)
            & t.cmpge(Vec4::splat(tmin))
            & t.cmple(Vec4::splat(tmax));
        Vec4::select(hit, t, Vec4::INFINITY)
    }
}

/// The closest hit among `packets`: `(t, triangle index)`, or `None`.
#[inline]
pub fn closest(
    packets: &[TriPacket],
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<(f32, u32)> {
    let mut best = (tmax, u32::MAX);
    let mut found = false;
    for (k, p) in packets.iter().enumerate() {
        let t = p.intersect(o, d, tmin, best.0);
        let m = t.min_element();
        if m < f32::INFINITY {
            // Lanes are in triangle order; on a tie the lowest index wins.
            let lane = t.to_array().iter().position(|&x| x == m).unwrap_or(0);
            best = (m, (4 * k + lane) as u32);
            found = true;
        }
    }
    found.then_some(best)
}

/// Whether any of `packets` is hit within `[tmin, tmax]`.
#[inline]
pub fn any_hit(packets: &[TriPacket], o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
    packets
        .iter()
        .any(|p| p.intersect(o, d, tmin, tmax).cmplt(Vec4::INFINITY).any())
}

#[cfg(test)]
mod tests {
    use super::*;
    use obvhs::ray::Ray;
    use obvhs::triangle::Triangle;

    fn obvhs_t(t: [Vec3; 3], o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> f32 {
        let tri = Triangle {
            v0: t[0].into(),
            v1: t[1].into(),
            v2: t[2].into(),
        };
        tri.intersect(&Ray::new(o.into(), d.into(), tmin, tmax))
    }

    /// Every lane agrees with obvhs's scalar test on random rays and triangles, and
    /// `closest` / `any_hit` with a loop over those.
    #[test]
    fn lanes_agree_with_the_scalar_test() {
        let mut s = crate::rng::Sampler::independent(3, 1, 0);
        let mut p3 = |scale: f32| {
            let [a, b] = s.next_2d();
            let [c, _] = s.next_2d();
            Vec3::new(a - 0.5, b - 0.5, c - 0.5) * scale
        };
        for n in [1usize, 3, 4, 5, 11] {
            for _ in 0..400 {
                let tris: Vec<[Vec3; 3]> = (0..n)
                    .map(|_| {
                        let c = p3(2.0);
                        [c + p3(1.0), c + p3(1.0), c + p3(1.0)]
                    })
                    .collect();
                let o = p3(4.0);
                let d = (p3(2.0) - o).normalize_or(Vec3::Z);
                let (tmin, tmax) = (1e-4, 3.0);
                let scalar: Vec<f32> = tris.iter().map(|&t| obvhs_t(t, o, d, tmin, tmax)).collect();
                let packets = pack(&tris);
                let lanes: Vec<f32> = packets
                    .iter()
                    .flat_map(|p| p.intersect(o, d, tmin, tmax).to_array())
                    .take(n)
                    .collect();
                for (a, b) in scalar.iter().zip(&lanes) {
                    let close = (a - b).abs() <= 1e-5 * a.abs().max(1.0);
                    assert!(a == b || close, "scalar {a} packet {b}");
                }
                let best = scalar
                    .iter()
                    .enumerate()
                    .filter(|(_, t)| t.is_finite())
                    .min_by(|x, y| x.1.total_cmp(y.1));
                match (best, closest(&packets, o, d, tmin, tmax)) {
                    (None, None) => {}
                    (Some((i, &t)), Some((tp, ip))) => {
                        assert!((t - tp).abs() <= 1e-5, "{t} vs {tp}");
                        assert!(ip as usize == i || (scalar[ip as usize] - t).abs() <= 1e-5);
                    }
                    (a, b) => panic!("scalar {a:?} packets {b:?}"),
                }
                assert_eq!(best.is_some(), any_hit(&packets, o, d, tmin, tmax));
            }
        }
    }
}
