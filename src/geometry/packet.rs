//! Ray queries against few triangles, eight at a time: the triangles are stored in
//! structure-of-arrays packets of eight lanes, and one ray is tested against a whole
//! packet with SIMD arithmetic (lane loops the compiler vectorises: AVX on x86-64-v3),
//! by Möller and Trumbore's test ("Fast, minimum storage ray/triangle intersection",
//! 1997): with `e1 = v0 − v1`, `e2 = v2 − v0`, `n = e1 × e2`, `c = v0 − o`, `r = d × c`,
//!
//! `det = n·d,  u = r·e2 / det,  v = r·e1 / det,  t = n·c / det`,
//!
//! a hit when `det ≠ 0`, `u, v, 1 − u − v ≥ 0` and `tmin ≤ t ≤ tmax`. That is the same
//! test as obvhs's `Triangle::intersect`, lane by lane. For the small hidden meshes of NLOS
//! scenes (a letter, a few dozen triangles) a packet loop costs less than a BVH traversal's
//! fixed cost (`accel::PACKET_TRIANGLES` has the measurement); unused lanes hold a
//! degenerate triangle (`n = 0`), which never hits.

use glam::Vec3;

/// Triangles per packet: 8 lanes, one 256-bit AVX register per coordinate on x86-64-v3
/// (the lane loops below are written for the compiler to vectorise).
pub const LANES: usize = 8;

type Lanes = [f32; LANES];

/// Eight triangles, coordinate by coordinate.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub struct TriPacket {
    v0: [Lanes; 3],
    e1: [Lanes; 3],
    e2: [Lanes; 3],
    n: [Lanes; 3],
}

/// Packs triangles `[v0, v1, v2]` eight to a packet (the last one padded).
pub fn pack(tris: &[[Vec3; 3]]) -> Vec<TriPacket> {
    tris.chunks(LANES)
        .map(|group| {
            let lane = |k: usize| group.get(k).copied().unwrap_or([Vec3::ZERO; 3]);
            let coords = |f: &dyn Fn([Vec3; 3]) -> Vec3| {
                let p: [Vec3; LANES] = std::array::from_fn(|k| f(lane(k)));
                [0, 1, 2].map(|a| p.map(|v| v[a]))
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

impl TriPacket {
    /// The hit distance of the ray `o + t d` on each lane, `INFINITY` where it misses or
    /// falls outside `[tmin, tmax]`. Each lane runs the scalar test's operations in its
    /// order (`a0 b0 + a1 b1 + a2 b2` for every dot product, no fused multiply-add).
    #[inline(always)]
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Lanes {
        let mut out = [f32::INFINITY; LANES];
        for (k, out) in out.iter_mut().enumerate() {
            let c = [
                self.v0[0][k] - o.x,
                self.v0[1][k] - o.y,
                self.v0[2][k] - o.z,
            ];
            let r = [
                d.y * c[2] - d.z * c[1],
                d.z * c[0] - d.x * c[2],
                d.x * c[1] - d.y * c[0],
            ];
            let (n, e1, e2) = (&self.n, &self.e1, &self.e2);
            let det = n[0][k] * d.x + n[1][k] * d.y + n[2][k] * d.z;
            let inv_det = 1.0 / det;
            let u = (r[0] * e2[0][k] + r[1] * e2[1][k] + r[2] * e2[2][k]) * inv_det;
            let v = (r[0] * e1[0][k] + r[1] * e1[1][k] + r[2] * e1[2][k]) * inv_det;
            let w = 1.0 - u - v;
            let t = (n[0][k] * c[0] + n[1][k] * c[1] + n[2][k] * c[2]) * inv_det;
            // `&`, not `&&`: no branch per lane.
            let hit =
                (det != 0.0) & (u >= 0.0) & (v >= 0.0) & (w >= 0.0) & (t >= tmin) & (t <= tmax);
            *out = if hit { t } else { f32::INFINITY };
        }
        out
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
        let m = t.iter().copied().fold(f32::INFINITY, f32::min);
        if m < f32::INFINITY {
            // Lanes are in triangle order; on a tie the lowest index wins.
            let lane = t.iter().position(|&x| x == m).unwrap_or(0);
            best = (m, (LANES * k + lane) as u32);
            found = true;
        }
    }
    found.then_some(best)
}

/// Whether any of `packets` is hit within `[tmin, tmax]`.
#[inline]
pub fn any_hit(packets: &[TriPacket], o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
    packets.iter().any(|p| {
        p.intersect(o, d, tmin, tmax)
            .iter()
            .fold(false, |any, &t| any | (t < f32::INFINITY))
    })
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
        for n in [1usize, 3, 4, 5, 8, 9, 11, 17] {
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
                    .flat_map(|p| p.intersect(o, d, tmin, tmax))
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
