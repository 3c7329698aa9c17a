//! `path`'s adjoint state (path replay, [`super::path`]'s module doc): the path's vertex,
//! throughput, OPL and last mixture density in dual numbers with respect to the corners
//! and albedos of the hidden triangles the path meets, following the forward pass's steps
//! as they are recorded ([`Deferred`]) when a contribution needs them.
//!
//! A path that stays on one hidden triangle (most three-bounce paths) carries 16 slots
//! (its 12 parameters, padded to one 16-lane vector: 12 measured 25 % slower than the
//! wide state, 16 faster); it widens to [`PATH_TRIANGLES`]` x 12` when it meets a second.
//! Every slot's arithmetic is its own (a dual number's operations act slot by slot), so
//! the derivatives are the same bits as with the wide state throughout.

use super::mc3::TriParams;
use super::path::{Spot, PATH_TRIANGLES};
use super::path_step::{continuation, hidden_geometry_distribution, survival, Step, Surf};
use super::{HiddenGrad, MeasurementCtx};
use crate::adjoint::dual::{self, Dual, Real, V3};
use crate::geometry::sampling::cosine_dir;
use crate::geometry::SurfaceKind;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// A contribution's derivatives per triangle slot group, the groups in use, and whether
/// the path met more triangles than it could follow.
pub(super) type Grads = ([HiddenGrad; PATH_TRIANGLES], usize, bool);

/// Where next-event estimation connects: the spot point `x_l`, the MIS probabilities of
/// the continuation techniques at the hidden vertex, and area sampling's density at `x_l`.
#[derive(Clone, Copy)]
pub(super) struct NeeTarget {
    pub x_l: Vec3,
    pub from_y: (f32, f32),
    pub p_hg_l: f32,
}

/// A replay action held back until a contribution needs the replay's state: the dual
/// arithmetic of the steps after a path's last contribution (a step that lands on the
/// wall and goes no further, a walk cut by Russian roulette) is never done. Applied in
/// the order they were recorded, with the same inputs, so the derivatives are the same
/// bits as a replay that follows every step at once.
#[derive(Clone, Copy)]
pub(super) enum Deferred {
    Step(Step, (f32, f32)),
    /// Russian roulette's division by the survival probability at the replay's vertex:
    /// the wall's albedo, or (`None`) the hidden vertex's own.
    Survive(Option<f32>),
    /// The roulette's division by a constant survival probability (before `rr_bounces`).
    SurviveConstant(f32),
}

/// The adjoint pass's state: the path's vertex, throughput and OPL in dual numbers, the
/// last continuation's mixture density, and which hidden triangle owns each slot group.
pub(super) struct Replay<const N: usize> {
    groups: [u32; PATH_TRIANGLES],
    used: usize,
    truncated: bool,
    x: Surf<Dual<f32, N>>,
    beta: Dual<f32, N>,
    opl: Dual<f32, N>,
    q: Dual<f32, N>,
}

impl<const N: usize> Replay<N> {
    fn new(ctx: &MeasurementCtx) -> Self {
        Replay {
            groups: [0; PATH_TRIANGLES],
            used: 0,
            truncated: false,
            x: Surf {
                p: dual::constant(ctx.x_s),
                n_side: dual::constant(ctx.n_w),
                f: Dual::<f32, N>::c(ctx.f_wall as f64),
            },
            beta: Dual::<f32, N>::c(1.0),
            opl: Dual::<f32, N>::c(ctx.opl_sensor_leg as f64),
            q: Dual::<f32, N>::c(0.0),
        }
    }

    /// Triangle `flat` as the steps use it: in dual numbers in its own slots (constants
    /// once the slots are full), with its normal, area and area sampling's density;
    /// `cached` where a path on one triangle has it worked out already ([`TriCache`]).
    fn triangle(
        &mut self,
        ctx: &MeasurementCtx,
        flat: u32,
        cached: Option<&TriReplay<N>>,
    ) -> TriReplay<N> {
        let tri = &ctx.geom.hidden[flat as usize];
        let g = match self.groups[..self.used].iter().position(|&f| f == flat) {
            Some(g) => g,
            None if self.used < N / 12 => {
                self.groups[self.used] = flat;
                self.used += 1;
                self.used - 1
            }
            None => {
                self.truncated = true;
                let c = TriParams::constant(tri);
                let t = TriParams {
                    v: c.v.map(|v| v.map(|x| Dual::<f32, N>::c(x as f64))),
                    albedo: c.albedo.map(|a| Dual::<f32, N>::c(a as f64)),
                    two_sided: c.two_sided,
                    retro: c.retro,
                    retro_falloff: c.retro_falloff,
                };
                return TriReplay::of(ctx, flat, t);
            }
        };
        match cached {
            Some(c) if g == 0 => *c,
            _ => TriReplay::of(ctx, flat, TriParams::variables_at(tri, 12 * g)),
        }
    }

    /// The forward pass's step `st` from the replay's vertex, in dual numbers: an
    /// area-sampled point keeps its barycentrics (the wall's stays put), a ray-found point
    /// is the ray's intersection with the plane of what it hit (it moves along the ray,
    /// whose direction follows `x`'s normal); then the same [`continuation`] as the
    /// forward pass, with area sampling's density over the current triangle area.
    fn step(
        &mut self,
        ctx: &MeasurementCtx,
        st: &Step,
        techniques: (f32, f32),
        cached: Option<&TriReplay<N>>,
    ) {
        let on_ray = |x: &Surf<Dual<f32, N>>, n: V3<Dual<f32, N>>, on_plane: V3<Dual<f32, N>>| {
            let (d, _) = cosine_dir(x.n_side, st.u_dir);
            let t = dual::dot(n, dual::sub(on_plane, x.p)) / dual::dot(n, d);
            let y: V3<Dual<f32, N>> = std::array::from_fn(|k| x.p[k] + d[k] * t);
            y
        };
        let (y, n, n_side, f, p_hg) = if st.kind == SurfaceKind::Wall {
            let n = dual::constant(ctx.n_w);
            let y = if st.by_bsdf {
                on_ray(&self.x, n, dual::constant(ctx.scene.wall.center))
            } else {
                dual::constant(st.y.p())
            };
            let f = Dual::<f32, N>::c(ctx.f_wall as f64);
            (y, n, n, f, Dual::<f32, N>::c(st.p_hg as f64))
        } else {
            let TriReplay { tri, n, p_hg } = self.triangle(ctx, st.y.flat, cached);
            let (y, b) = if st.by_bsdf {
                let y = on_ray(&self.x, n, tri.v[0]);
                (y, tri.barycentric_of(y))
            } else {
                (
                    tri.point(st.y.bary),
                    st.y.bary.map(|b| Dual::<f32, N>::c(b as f64)),
                )
            };
            let n_side = if st.back { n.map(|c| -c) } else { n };
            (y, n, n_side, tri.albedo_at_r(b).s(FRAC_1_PI), p_hg)
        };
        let (factor, dist, q) = continuation(&self.x, y, n, techniques, p_hg);
        self.beta = self.beta * factor;
        self.opl = self.opl + dist;
        self.q = q;
        self.x = Surf { p: y, n_side, f };
    }

    /// Applies one deferred action (`cached`: the step's triangle, if it has one and
    /// [`TriCache`] has it).
    fn apply(&mut self, ctx: &MeasurementCtx, d: Deferred, cached: Option<&TriReplay<N>>) {
        match d {
            Deferred::Step(st, techniques) => self.step(ctx, &st, techniques, cached),
            Deferred::Survive(wall_albedo) => {
                // The albedo in dual numbers: ρ = π f at a hidden vertex.
                let albedo = match wall_albedo {
                    Some(a) => Dual::<f32, N>::c(a as f64),
                    None => self.x.f.s(PI),
                };
                self.beta = self.beta / survival(albedo);
            }
            Deferred::SurviveConstant(q) => self.beta = self.beta / Dual::<f32, N>::c(q as f64),
        }
    }

    /// The derivatives of a contribution's weight and OPL, per triangle slot (slots
    /// beyond this replay's `N / 12` groups empty).
    fn grads(&self, weight: &Dual<f32, N>, opl: &Dual<f32, N>) -> Grads {
        let g = std::array::from_fn(|g| HiddenGrad {
            flat: self.groups[g],
            weight: std::array::from_fn(|k| weight.d.get(12 * g + k).copied().unwrap_or(0.0)),
            opl: std::array::from_fn(|k| opl.d.get(12 * g + k).copied().unwrap_or(0.0)),
        });
        (g, self.used, self.truncated)
    }

    /// A continuation landing on the finite spot: its weight's and OPL's derivatives.
    fn emission(&self, ctx: &MeasurementCtx, spot: &Spot) -> Grads {
        let w = spot.emission(self.beta, self.q);
        let o = self.opl + ctx.laser_leg(self.x.p);
        self.grads(&w, &o)
    }

    /// Next-event estimation to the spot point `at`: its weight's and OPL's derivatives.
    fn nee(&self, ctx: &MeasurementCtx, spot: &Spot, at: &NeeTarget) -> Option<Grads> {
        let NeeTarget {
            x_l,
            from_y,
            p_hg_l,
        } = *at;
        let (w, r_d) = spot.nee(&self.x, self.beta, x_l, ctx.n_w, from_y, p_hg_l)?;
        let o = self.opl + r_d + Dual::<f32, N>::c(ctx.opl_laser_leg(x_l) as f64);
        Some(self.grads(&w, &o))
    }
}

/// Widens a dual number to more slots (the new ones 0).
fn widen<const A: usize, const B: usize>(x: Dual<f32, A>) -> Dual<f32, B> {
    let mut d = [0.0f32; B];
    d[..A].copy_from_slice(&x.d);
    Dual { v: x.v, d }
}

impl Replay<16> {
    /// The same state over [`PATH_TRIANGLES`] groups of slots (the first one this one's).
    fn widen(&self) -> Replay<48> {
        let v3 = |p: V3<Dual<f32, 16>>| p.map(widen);
        Replay {
            groups: self.groups,
            used: self.used,
            truncated: self.truncated,
            x: Surf {
                p: v3(self.x.p),
                n_side: v3(self.x.n_side),
                f: widen(self.x.f),
            },
            beta: widen(self.beta),
            opl: widen(self.opl),
            q: widen(self.q),
        }
    }
}

/// The replay of one path: one triangle's slots until it meets a second. One per path on
/// the stack; boxing the wide variant would allocate for every path that widens.
#[allow(clippy::large_enum_variant)]
pub(super) enum PathReplay {
    One(Replay<16>),
    Many(Replay<48>),
}

impl PathReplay {
    pub(super) fn new(ctx: &MeasurementCtx) -> Self {
        PathReplay::One(Replay::new(ctx))
    }

    /// Applies the actions deferred so far (`deferred` is left empty), widening before
    /// the first step onto a second hidden triangle.
    pub(super) fn catch_up(
        &mut self,
        ctx: &MeasurementCtx,
        deferred: &mut Vec<Deferred>,
        cache: &mut TriCache,
    ) {
        for d in deferred.drain(..) {
            let mut onto = None;
            if let (PathReplay::One(r), Deferred::Step(st, _)) = (&*self, &d) {
                if st.kind != SurfaceKind::Wall {
                    if r.used == 1 && r.groups[0] != st.y.flat {
                        *self = PathReplay::Many(r.widen());
                    } else {
                        onto = Some(st.y.flat);
                    }
                }
            }
            match self {
                PathReplay::One(r) => r.apply(ctx, d, onto.map(|f| cache.get(ctx, f))),
                PathReplay::Many(r) => r.apply(ctx, d, None),
            }
        }
    }

    /// See [`Replay::emission`].
    pub(super) fn emission(&self, ctx: &MeasurementCtx, spot: &Spot) -> Grads {
        match self {
            PathReplay::One(r) => r.emission(ctx, spot),
            PathReplay::Many(r) => r.emission(ctx, spot),
        }
    }

    /// See [`Replay::nee`].
    pub(super) fn nee(&self, ctx: &MeasurementCtx, spot: &Spot, at: &NeeTarget) -> Option<Grads> {
        match self {
            PathReplay::One(r) => r.nee(ctx, spot, at),
            PathReplay::Many(r) => r.nee(ctx, spot, at),
        }
    }
}

/// A hidden triangle as a step onto it uses it: its corners and albedos in dual numbers,
/// its unit normal, and area sampling's density `prob / A` over its current area.
#[derive(Clone, Copy)]
pub(super) struct TriReplay<const N: usize> {
    tri: TriParams<Dual<f32, N>>,
    n: V3<Dual<f32, N>>,
    p_hg: Dual<f32, N>,
}

impl<const N: usize> TriReplay<N> {
    fn of(ctx: &MeasurementCtx, flat: u32, tri: TriParams<Dual<f32, N>>) -> Self {
        let (n, area) = tri.normal_area();
        let hg = hidden_geometry_distribution(ctx.geom, &ctx.scene.render.techniques);
        let p_hg = Dual::<f32, N>::c(hg.prob(flat) as f64) / area;
        TriReplay { tri, n, p_hg }
    }
}

/// The triangles a thread's one-triangle replays ([`Replay<16>`], the triangle in slots
/// 0..12) stepped onto last, worked out once instead of per step: the same operations on
/// the same inputs, so the same bits. Direct-mapped by flat index ([`TRI_CACHE`] entries,
/// ~1 KB each); an entry is used only while its inputs are the triangle's (the bits of
/// its corners, albedos and sampling probability, and its flags), whatever scene the
/// scratch is used with next.
#[derive(Default)]
pub struct TriCache {
    entries: Vec<Option<(TriKey, TriReplay<16>)>>,
}

/// What [`TriReplay::of`] reads: flat index, corners and albedos, sampling probability,
/// one-/two-sided and retroreflective flags and falloff (as bits).
type TriKey = (u32, [u32; 14], [bool; 2]);

/// Entries of a [`TriCache`].
pub const TRI_CACHE: usize = 128;

impl TriCache {
    fn get(&mut self, ctx: &MeasurementCtx, flat: u32) -> &TriReplay<16> {
        if self.entries.is_empty() {
            self.entries = vec![None; TRI_CACHE];
        }
        let tri = &ctx.geom.hidden[flat as usize];
        let hg = hidden_geometry_distribution(ctx.geom, &ctx.scene.render.techniques);
        let [a, b, c] = tri.v;
        let bits = [
            a.x,
            a.y,
            a.z,
            b.x,
            b.y,
            b.z,
            c.x,
            c.y,
            c.z,
            tri.albedo[0],
            tri.albedo[1],
            tri.albedo[2],
            hg.prob(flat),
            tri.retro_falloff,
        ]
        .map(f32::to_bits);
        let key = (flat, bits, [tri.two_sided, tri.retro]);
        let slot = &mut self.entries[flat as usize % TRI_CACHE];
        if slot.as_ref().is_none_or(|(k, _)| *k != key) {
            let replay = TriReplay::of(ctx, flat, TriParams::variables_at(tri, 0));
            *slot = Some((key, replay));
        }
        &slot.as_ref().expect("filled above").1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::Film;
    use crate::geometry::SceneGeometry;

    /// The bits of what a step reads from a triangle.
    fn bits(t: &TriReplay<16>) -> Vec<u32> {
        let duals = t.tri.v.iter().flatten().chain(&t.tri.albedo).chain(&t.n);
        duals
            .chain(std::iter::once(&t.p_hg))
            .flat_map(|d| std::iter::once(d.v).chain(d.d))
            .map(f32::to_bits)
            .collect()
    }

    /// A cached triangle is what the step would work out, also when one scratch's cache
    /// meets another scene whose triangle of the same index moved (or another triangle of
    /// the same slot).
    #[test]
    fn the_cache_gives_what_the_step_computes_whatever_scene_comes_next() {
        let a = crate::scene::default::default_scene().unwrap();
        let mut b = a.clone();
        let v = b.objects[0].mesh.triangles[0][0] as usize;
        b.objects[0].mesh.positions[v].x += 0.01;
        let mut cache = TriCache::default();
        for scene in [&a, &b, &a] {
            let geom = SceneGeometry::build(scene);
            let film = Film::new(&scene.film);
            let ctx = MeasurementCtx::new(scene, &geom, &film, 0);
            for flat in [0, TRI_CACHE as u32, 1, 0] {
                if flat as usize >= geom.hidden.len() {
                    continue;
                }
                let tri = &geom.hidden[flat as usize];
                let fresh = TriReplay::<16>::of(&ctx, flat, TriParams::variables_at(tri, 0));
                assert_eq!(bits(cache.get(&ctx, flat)), bits(&fresh), "triangle {flat}");
            }
        }
    }
}
