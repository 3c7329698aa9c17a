//! How the interior derivative moves the vertices of a `path` path, in expectation over
//! its sampling techniques (issue 18, `notes/boundary-methods.md` §6): the velocities the
//! boundary terms of longer paths must use for their viewpoint and receiver.
//!
//! `path` reaches vertex `y_k` from `y_{k−1}` by one-sample MIS: hidden-geometry sampling
//! keeps `y_k`'s barycentrics (it moves with its material), BSDF sampling keeps the
//! direction's coordinates in `y_{k−1}`'s frame (it slides along a ray that starts at the
//! moving `y_{k−1}` and turns with its normal). The estimator's derivative is linear in
//! these velocities, so what a boundary term needs is their mean over the technique
//! choices, the balance weights `w_k` of the two techniques for this path:
//!
//! `E[v_k] = (1 − w_k) v_material(y_k) + w_k v_ray(E[v_{k−1}], ṅ_{k−1})`,
//!
//! a recursion from the sensor point (fixed) written in dual numbers over the corners of
//! up to [`PATH_TRIANGLES`] hidden triangles (the last vertices' first: the viewpoint and
//! receiver of a boundary term come last). Wall vertices do not move with the scene; a
//! BSDF-sampled one slides along its ray.

use super::boundary::VertexGrad;
use crate::geometry::sampling::{frame_coordinates, frame_direction};
use crate::scene::Scene;
use crate::transport::mc3::TriParams;
use crate::transport::path::PATH_TRIANGLES;
use crate::transport::path_step::{bsdf_share, WalkVertex};
use crate::transport::MeasurementCtx;
use dual::V3;

use super::dual::{self, Real};

/// Dual numbers over the corner positions of [`PATH_TRIANGLES`] triangles.
pub type ChainNum = super::dual::Dual<f32, { 9 * PATH_TRIANGLES }>;

/// How the chain's last vertex moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Last {
    /// As the path's sampling moves it on average (a receiver).
    Expected,
    /// Along its ray from the previous vertex (the occluder's point at a silhouette,
    /// reached by BSDF sampling).
    Ray,
}

/// The vertices of a chain in dual numbers over the corners of its triangles.
pub struct ChainDual {
    groups: [u32; PATH_TRIANGLES],
    used: usize,
    pub points: Vec<V3<ChainNum>>,
}

impl ChainDual {
    /// `E[v]` of every vertex of `chain` (`chain[0]` the sensor point), [`Last`] for the
    /// last one.
    pub fn new(ctx: &MeasurementCtx, chain: &[WalkVertex], last: Last) -> ChainDual {
        let geom = ctx.geom;
        let mut groups = [u32::MAX; PATH_TRIANGLES];
        let mut used = 0;
        for v in chain.iter().rev() {
            if !v.on_wall() && used < PATH_TRIANGLES && !groups[..used].contains(&v.flat) {
                groups[used] = v.flat;
                used += 1;
            }
        }
        // Corner positions are variables in their triangle's slots (albedos constants).
        let tri = |flat: u32| -> TriParams<ChainNum> {
            let t = &geom.hidden[flat as usize];
            let slot = groups[..used].iter().position(|&g| g == flat);
            let corner = |i: usize, k: usize| match slot {
                Some(g) => ChainNum::var(t.v[i][k], 9 * g + 3 * i + k),
                None => ChainNum::c(t.v[i][k] as f64),
            };
            TriParams {
                v: std::array::from_fn(|i| std::array::from_fn(|k| corner(i, k))),
                albedo: t.albedo.map(|a| ChainNum::c(a as f64)),
                two_sided: t.two_sided,
                retro: t.retro,
                retro_falloff: t.retro_falloff,
            }
        };
        let wall_n: V3<ChainNum> = dual::constant(ctx.n_w);
        let wall_c: V3<ChainNum> = dual::constant(ctx.scene.wall.center);
        let mut points: Vec<V3<ChainNum>> = vec![dual::constant(chain[0].p())];
        let mut normals = vec![wall_n];
        for k in 1..chain.len() {
            let (prev, v) = (&chain[k - 1], &chain[k]);
            let (material, plane_n, plane_p, n_side) = if v.on_wall() {
                let p = dual::constant(v.p());
                (p, wall_n, wall_c, wall_n)
            } else {
                let t = tri(v.flat);
                let (n, _) = t.normal_area();
                let flip = dual::value(n).dot(v.n_side()) < 0.0;
                let n_side = if flip { n.map(|c| -c) } else { n };
                (t.point(v.bary), n, t.v[0], n_side)
            };
            let w = if k == chain.len() - 1 && last == Last::Ray {
                1.0
            } else {
                bsdf_share(ctx, &prev.s, prev.on_wall(), v)
            };
            let point = if w > 0.0 {
                // The ray from the previous vertex, its direction fixed in that vertex's
                // frame, met with this vertex's plane.
                let (x, n_x) = (points[k - 1], normals[k - 1]);
                let dir = (v.p() - prev.p()).normalize();
                let d = frame_direction(n_x, frame_coordinates(prev.n_side(), dir));
                let t = dual::dot(plane_n, dual::sub(plane_p, x)) / dual::dot(plane_n, d);
                let ray: V3<ChainNum> = std::array::from_fn(|i| x[i] + d[i] * t);
                std::array::from_fn(|i| material[i] + (ray[i] - material[i]).s(w))
            } else {
                material
            };
            points.push(point);
            normals.push(n_side);
        }
        ChainDual {
            groups,
            used,
            points,
        }
    }

    /// Adds `weight · ∂s/∂θ` to the vertices of the chain's triangles (nothing if a
    /// derivative is not finite: a ray grazing its receiver's plane).
    pub fn scatter(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        s: &ChainNum,
        weight: f64,
        grad: &mut VertexGrad,
    ) {
        if s.d.iter().any(|d| !d.is_finite()) {
            return;
        }
        for (g, &flat) in self.groups[..self.used].iter().enumerate() {
            let (o, t) = ctx.geom.flat_to_local[flat as usize];
            let corners = scene.objects[o as usize].mesh.triangles[t as usize];
            for (i, &v) in corners.iter().enumerate() {
                let g = &s.d[9 * g + 3 * i..9 * g + 3 * i + 3];
                for (acc, d) in grad[o as usize][v as usize].iter_mut().zip(g) {
                    *acc += weight * *d as f64;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::Film;
    use crate::geometry::mesh::TriMesh;
    use crate::geometry::SceneGeometry;
    use crate::scene::toml_format;
    use glam::Vec3;
    use std::path::Path;

    /// Two hidden triangles: `A` facing the wall, `B` tilted behind it.
    const OBJ: &str = "v -0.2 -0.2 0.5\nv 0.2 -0.15 0.55\nv 0.0 0.2 0.45\n\
                       v -0.3 -0.3 0.8\nv 0.3 -0.2 0.9\nv 0.0 0.3 0.6\nf 1 2 3\nf 4 5 6\n";

    fn scene(obj: &str) -> crate::scene::Scene {
        let toml = "capture_type = \"confocal\"\n[wall]\nsize = [2.0, 2.0]\n[laser]\n\
                    origin = [0.3, -0.4, 1.0]\n[scan]\nresolution = [1, 1]\nsize = [0.5, 0.5]\n\
                    [film]\ntemporal_bins = 64\nbin_width_opl = 0.05\nstart_opl = 0.0\n\
                    [[objects]]\nfile = \"t.obj\"\ntwo_sided = true\n\
                    [render]\nmodel = \"path\"\nbsdf_sampling = false\n";
        let text = obj.to_string();
        toml_format::parse(toml, Path::new("t.toml"), &|f| {
            TriMesh::parse_obj(&text, Path::new(f))
        })
        .unwrap()
    }

    /// `x_s → a` (area sampled: `a` moves with its material) `→ b` (on its ray from `a`,
    /// the direction held in `a`'s frame): the dual velocities of `b` against finite
    /// differences of that construction, for every corner coordinate of both triangles.
    #[test]
    fn ray_velocity_turns_with_the_previous_normal() {
        let base = scene(OBJ);
        let (bary_a, bary_b) = ([0.3, 0.3], [0.25, 0.4]);
        let place = |s: &crate::scene::Scene| {
            let geom = SceneGeometry::build(s);
            let (ta, tb) = (&geom.hidden[0], &geom.hidden[1]);
            let a = ta.point(bary_a);
            (a, ta.n, tb.v, geom)
        };
        let (a, n_a, _, geom) = place(&base);
        let b0 = geom.hidden[1].point(bary_b);
        let film = Film::new(&base.film);
        let ctx = MeasurementCtx::new(&base, &geom, &film, 0);
        let x_s = WalkVertex::wall(&ctx, ctx.x_s);
        let va = WalkVertex::hidden(&geom, 0, bary_a, a, ctx.x_s);
        let vb0 = WalkVertex::hidden(&geom, 1, bary_b, b0, a);
        let chain = ChainDual::new(&ctx, &[x_s, va, vb0], Last::Ray);
        // The direction from a to b in a's frame (a's side toward x_s).
        let side = if n_a.dot(ctx.x_s - a) > 0.0 {
            n_a
        } else {
            -n_a
        };
        let local = frame_coordinates(side, (b0 - a).normalize());
        let h = 1e-3f32;
        let mut worst = 0.0f32;
        for (t, v, k) in
            (0..2).flat_map(|t| (0..3).flat_map(move |v| (0..3).map(move |k| (t, v, k))))
        {
            let moved = |d: f32| {
                let mut s = base.clone();
                s.objects[0].mesh.positions[3 * t + v][k] += d;
                let (a, n_a, vb, _) = place(&s);
                let side = if n_a.dot(ctx.x_s - a) > 0.0 {
                    n_a
                } else {
                    -n_a
                };
                let w = Vec3::from_array(frame_direction(side.to_array(), local));
                let n_b = (vb[1] - vb[0]).cross(vb[2] - vb[0]);
                a + w * (n_b.dot(vb[0] - a) / n_b.dot(w))
            };
            let fd = (moved(h) - moved(-h)) / (2.0 * h);
            let slot = chain.groups[..chain.used]
                .iter()
                .position(|&g| g == t as u32)
                .unwrap();
            let dual = Vec3::from_array(std::array::from_fn(|i| {
                chain.points[2][i].d[9 * slot + 3 * v + k]
            }));
            worst = worst.max((dual - fd).length() / fd.length().max(1e-3));
        }
        assert!(worst < 2e-2, "worst relative error {worst}");
    }
}
