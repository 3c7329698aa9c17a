//! Visibility boundary terms of `path`'s paths with two or more hidden vertices (4 bounces
//! and more; issue 18, `notes/boundary-methods.md` §6). [`super::boundary`] has the
//! three-bounce terms and the derivation; here every leg of a longer path
//! `x_s → y_1 → … → y_k → x_l` gets its term, in the area form
//!
//! `− ∫_E W (∂y/∂θ − (1 − ρ) E[v_a] − ρ E[v_b])·n dℓ`,   `ρ = r_y / r_b`,
//!
//! for a viewpoint `a` (the leg's first vertex), the receiver `b` behind the edge point
//! `y`, and `W` everything else the path carries there (the prefix up to `a`, the
//! geometry of the leg per unit edge length `cos_a sin φ / r_y²`, and the suffix from `b`
//! to the far wall point, through the film's adjoint at each path's OPL). `E[v]` are the
//! vertices' velocities as the interior derivative moves them, averaged over the
//! sampling techniques ([`super::chain`]); where a vertex may be reached by BSDF sampling
//! from `a`, the occluder's own point at the edge adds `+ w_bsdf W_fg (∂y/∂θ − v_ray)·n`.
//!
//! - **First leg** (`x_s → y_1`, seen from `x_s`) and **last leg** (`y_k → x_l`, seen from
//!   `x_l`): the nodes of the three-bounce terms, with the rest of the path estimated by a
//!   walk from the receiver toward the other wall point ([`LongerPaths::link`], `path`'s own
//!   step routine). The last leg's receiver velocity needs the path before it: the walk's
//!   vertices, reversed, are that path.
//! - **Hidden→hidden legs** (`y_i → y_{i+1}`): `count` walks per measurement from `x_s`
//!   (as `path` extends its paths); at every hidden vertex `a`, one silhouette point seen
//!   from `a`, edges picked in proportion to the angle they subtend
//!   ([`super::edge_nodes::EdgeSet::sample_node`]), and the suffix from its receiver.
//!
//! All random numbers are drawn from streams of their own, keyed by seed, measurement and
//! node or sample: same bits on any thread count. Not covered: shadows falling on the
//! relay wall mid-path and hidden points seen from the wall mid-path (paths of 5 or more
//! bounces that bounce on the wall); the motion of triangles beyond the
//! [`crate::transport::path::PATH_TRIANGLES`] nearest the receiver in a chain (dropped;
//! `path`'s replay keeps the first four of a path instead).

use super::boundary::{scatter, Motion, VertexGrad};
use super::chain::{ChainDual, ChainNum, Last};
use super::dual::{self, Real};
use super::edge_nodes::{occluder_at, EdgeSet, Node, Point};
use crate::film::Film;
use crate::rng::Sampler;
use crate::scene::{Model, Scene};
use crate::transport::path_step::{bsdf_share, walk, WalkVertex};
use crate::transport::{MeasurementCtx, RenderOptions};
use glam::Vec3;

/// The longer paths' part of a `path` gradient's boundary terms.
pub struct LongerPaths {
    seed: u64,
    /// Hidden→hidden samples per measurement.
    count: u32,
    /// `path` mixes BSDF sampling in (foreground terms).
    mixture: bool,
}

/// The longer paths' terms are estimated on one node in `SPLIT` of the three-bounce terms
/// (each picked with probability `1/SPLIT`, its estimate weighted by `SPLIT`: unbiased)
/// and by `spp / SPLIT` hidden→hidden walks per measurement: they carry a small share of
/// the transient, and at one walk per node they made a `path` gradient 2.7–3.3x the
/// interior-only one (`umbra bench grad`).
const SPLIT: u32 = 4;

/// Stream of the boundary walks of measurement `m` (`tag` tells the walks apart); far
/// from the interior samples' streams (`m`).
fn stream(m: usize, tag: u64) -> u64 {
    0xB0DA_0000_0000_0000 ^ ((m as u64) << 4) ^ tag
}

impl LongerPaths {
    /// `Some` for `path` gradients whose paths can have 4 bounces or more.
    pub fn new(scene: &Scene, opts: &RenderOptions) -> Option<LongerPaths> {
        let r = &scene.render;
        let longest = r.longest_bounces();
        (opts.model == Model::Path && longest >= 4).then(|| LongerPaths {
            seed: opts.seed,
            count: opts.spp.max(1).div_ceil(SPLIT),
            mixture: r.techniques.bsdf_sampling,
        })
    }

    /// A sampler for the walks of node `index` of the view in `slot` of measurement `m`,
    /// if the node is one of those that estimate the longer paths: one in [`SPLIT`]
    /// consecutive nodes, from a random offset per view (systematic, like the nodes).
    pub fn node_sampler(&self, m: usize, slot: u64, index: u32) -> Option<Sampler<'_>> {
        let offset = Sampler::new(self.seed, stream(m, slot | 8), 0).next_1d() * SPLIT as f32;
        (index % SPLIT == (offset as u32).min(SPLIT - 1))
            .then(|| Sampler::new(self.seed, stream(m, slot), index))
    }

    /// Walks from `start` (a hidden point, on the side of the viewpoint) toward the wall
    /// point `other` past at least one more hidden vertex, and calls `each(vertices,
    /// a · value)` for every path it closes by a connection to `other`: `value` the
    /// transport from `start` (its BRDF included) to `other` (its BRDF not), `a` the
    /// film's adjoint at the path's OPL: `opl0`, what was walked and the connection. `bounces0` is the
    /// bounce count of the path closed at `start`.
    #[allow(clippy::too_many_arguments)]
    pub fn link(
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        start: WalkVertex,
        other: Vec3,
        (opl0, bounces0): (f32, u32),
        sampler: &mut Sampler,
        mut each: impl FnMut(&[WalkVertex], f64),
    ) {
        let r = &ctx.scene.render;
        let last = r.longest_bounces();
        let mut vertices = Vec::with_capacity(8);
        walk(
            ctx,
            start,
            sampler,
            bounces0,
            last,
            &mut vertices,
            |v, beta, opl| {
                let z = &v[v.len() - 1];
                let bounces = bounces0 + v.len() as u32 - 1;
                if z.on_wall() || r.filter_bounces.is_some_and(|f| f != bounces) {
                    return;
                }
                let Some((g, r_z)) = connect(ctx, z, other) else {
                    return;
                };
                let a = film.adjoint_value(opl0 + opl + r_z, adjoint);
                if a != 0.0 && !ctx.geom.occluded(z.p(), other) {
                    each(v, a * (beta * z.s.f * g) as f64);
                }
            },
        );
    }

    /// The first leg's part for a node seen from `x_s` whose receiver (or occluder point)
    /// is `p`: `Σ a · value` of the paths that continue from `p` past one more hidden
    /// vertex to `x_l`, times the node's `C cos_o sin φ / r_y² dℓ` ([`Self::leg_factor`]).
    pub fn first_leg(
        &self,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        p: &Point,
        node: &Node,
        sampler: &mut Sampler,
    ) -> f64 {
        let mut sum = 0.0;
        Self::node_link(ctx, film, adjoint, p, node, ctx.x_l, sampler, |_, w| {
            sum += w
        });
        sum * Self::leg_factor(ctx, node)
    }

    /// [`Self::link`] from a wall-point node's hidden point `p` (on the side facing the
    /// node's wall point, OPL so far `|p − o|` and the two legs, 3 bounces if closed at `p`)
    /// toward `other`.
    #[allow(clippy::too_many_arguments)]
    fn node_link(
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        p: &Point,
        node: &Node,
        other: Vec3,
        sampler: &mut Sampler,
        each: impl FnMut(&[WalkVertex], f64),
    ) {
        let o = node.frame.o;
        if let Some(start) = receiver_vertex(ctx, p, o) {
            let opl0 = leg_opl(ctx, p.x, o);
            Self::link(ctx, film, adjoint, start, other, (opl0, 3), sampler, each);
        }
    }

    /// `C cos_o sin φ / r_y² dℓ` of a node seen from a wall point (`C = P (ρ_w/π)²`),
    /// over the probability [`SPLIT`] of the node's walks.
    fn leg_factor(ctx: &MeasurementCtx, node: &Node) -> f64 {
        let c = ctx.three_bounce_constant();
        (c * node.cos_o * node.frame.area_per_length() * node.length) as f64 * SPLIT as f64
    }

    /// The last leg's term for a node seen from `x_l` with receiver `p`: the paths from
    /// `x_s` that reach `p` past at least one more hidden vertex, sampled backward from
    /// `p`; the receiver moves as those paths' sampling moves it.
    #[allow(clippy::too_many_arguments)]
    pub fn last_leg(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        p: &Point,
        node: &Node,
        sampler: &mut Sampler,
        grad: &mut VertexGrad,
    ) {
        let factor = Self::leg_factor(ctx, node);
        let rho = node.frame.r_y / (p.x - node.frame.o).length();
        let n = dual::constant::<ChainNum>(node.frame.n);
        let mut edge = 0.0;
        let mut chain = Vec::with_capacity(8);
        Self::node_link(ctx, film, adjoint, p, node, ctx.x_s, sampler, |v, w| {
            let w = w * factor;
            if !w.is_finite() {
                return;
            }
            chain.clear();
            chain.push(WalkVertex::wall(ctx, ctx.x_s));
            chain.extend(v.iter().rev());
            let c = ChainDual::new(ctx, &chain, Last::Expected);
            let s = dual::dot(n, c.points[chain.len() - 1]).s(rho);
            c.scatter(scene, ctx, &s, w, grad);
            edge -= w;
        });
        scatter(scene, ctx, node, None, Motion::edge(edge), grad);
    }

    /// The hidden→hidden legs of measurement `m` (module docs).
    #[allow(clippy::too_many_arguments)]
    pub fn hidden_legs(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        edges: &EdgeSet,
        m: usize,
        grad: &mut VertexGrad,
    ) {
        let r = &ctx.scene.render;
        let last = r.longest_bounces();
        let scale = (ctx.power * ctx.f_wall) as f64 / self.count as f64;
        let mut vertices = Vec::with_capacity(8);
        let mut chain = Vec::with_capacity(8);
        for i in 0..self.count {
            let mut sampler = Sampler::new(self.seed, stream(m, 2), i);
            let mut inner = Sampler::new(self.seed, stream(m, 3), i);
            let start = WalkVertex::wall(ctx, ctx.x_s);
            // A vertex y_k closes paths of k + 2 bounces; a leg after it needs k + 3.
            walk(
                ctx,
                start,
                &mut sampler,
                2,
                last - 1,
                &mut vertices,
                |v, beta, opl| {
                    let a = &v[v.len() - 1];
                    if a.on_wall() {
                        return;
                    }
                    let bounces = v.len() as u32 + 2; // x_s, y_1..y_k = a, b, x_l
                    let u = inner.next_2d();
                    let Some(node) =
                        edges.sample_node(ctx.geom, (a.p(), a.n_side()), u, self.mixture)
                    else {
                        return;
                    };
                    let prefix = scale
                        * (beta * a.s.f * node.cos_o * node.frame.area_per_length() * node.length)
                            as f64;
                    let opl_a = ctx.opl_sensor_leg + opl;
                    let n = dual::constant::<ChainNum>(node.frame.n);
                    if let Some(b) = &node.receiver {
                        let w = prefix
                            * self.suffix(
                                ctx,
                                film,
                                adjoint,
                                b,
                                a.p(),
                                (opl_a, bounces),
                                &mut inner,
                            );
                        if w != 0.0 && w.is_finite() {
                            chain.clear();
                            chain.extend_from_slice(v);
                            chain.push(WalkVertex::hidden(ctx.geom, b.flat, b.bary, b.x, a.p()));
                            let c = ChainDual::new(ctx, &chain, Last::Expected);
                            let rho = node.frame.r_y / (b.x - a.p()).length();
                            let k = chain.len() - 1;
                            let s: [ChainNum; 3] = std::array::from_fn(|i| {
                                c.points[k - 1][i].s(1.0 - rho) + c.points[k][i].s(rho)
                            });
                            c.scatter(scene, ctx, &dual::dot(n, s), w, grad);
                            scatter(scene, ctx, &node, None, Motion::edge(-w), grad);
                        }
                    }
                    if self.mixture {
                        self.foreground(
                            scene,
                            ctx,
                            film,
                            adjoint,
                            v,
                            &node,
                            prefix,
                            (opl_a, bounces),
                            &mut inner,
                            &mut chain,
                            grad,
                        );
                    }
                },
            );
        }
    }

    /// The occluder's point at the edge seen from `a = v.last()`, for the share of the
    /// continuation from `a` that BSDF sampling makes (it slides along its ray).
    #[allow(clippy::too_many_arguments)]
    fn foreground(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        v: &[WalkVertex],
        node: &Node,
        prefix: f64,
        (opl_a, bounces): (f32, u32),
        sampler: &mut Sampler,
        chain: &mut Vec<WalkVertex>,
        grad: &mut VertexGrad,
    ) {
        let a = &v[v.len() - 1];
        let f = &node.frame;
        let Some(fg) = occluder_at(ctx.geom, a.p(), f) else {
            return;
        };
        let fg_vertex = WalkVertex::hidden(ctx.geom, fg.flat, fg.bary, fg.x, a.p());
        let share = bsdf_share(ctx, &a.s, false, &fg_vertex) as f64;
        if share == 0.0 {
            return;
        }
        let w =
            share * prefix * self.suffix(ctx, film, adjoint, &fg, a.p(), (opl_a, bounces), sampler);
        if w == 0.0 || !w.is_finite() {
            return;
        }
        chain.clear();
        chain.extend_from_slice(v);
        chain.push(fg_vertex);
        let c = ChainDual::new(ctx, chain, Last::Ray);
        let n = dual::constant::<ChainNum>(f.n);
        c.scatter(
            scene,
            ctx,
            &dual::dot(n, c.points[chain.len() - 1]),
            -w,
            grad,
        );
        scatter(scene, ctx, node, None, Motion::edge(w), grad);
    }

    /// `Σ a · value` of the paths from `b` (seen from `a`, OPL `opl_a + |a − b|` so far,
    /// closing with `bounces` bounces if `b` connects straight to `x_l`) to `x_l`, `b`'s
    /// BRDF included.
    #[allow(clippy::too_many_arguments)]
    fn suffix(
        &self,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        b: &Point,
        a: Vec3,
        (opl_a, bounces): (f32, u32),
        sampler: &mut Sampler,
    ) -> f64 {
        let Some(start) = receiver_vertex(ctx, b, a) else {
            return 0.0;
        };
        let r = &ctx.scene.render;
        let opl0 = opl_a + (b.x - a).length() + ctx.opl_laser_leg(ctx.x_l);
        let mut sum = 0.0;
        if r.keeps_bounces(bounces) {
            if let Some((g, r_l)) = connect(ctx, &start, ctx.x_l) {
                let adj = film.adjoint_value(opl0 + r_l, adjoint);
                if adj != 0.0 && !ctx.geom.occluded(b.x, ctx.x_l) {
                    sum += adj * (start.s.f * g) as f64;
                }
            }
        }
        Self::link(
            ctx,
            film,
            adjoint,
            start,
            ctx.x_l,
            (opl0, bounces),
            sampler,
            |_, w| sum += w,
        );
        sum
    }
}

/// The hidden point `p` as a walk's start on the side facing `o`; `None` if a one-sided
/// surface turns its back to `o`.
fn receiver_vertex(ctx: &MeasurementCtx, p: &Point, o: Vec3) -> Option<WalkVertex> {
    let tri = &ctx.geom.hidden[p.flat as usize];
    if tri.retro || (!tri.two_sided && tri.n.dot(o - p.x) <= 0.0) {
        return None;
    }
    Some(WalkVertex::hidden(ctx.geom, p.flat, p.bary, p.x, o))
}

/// OPL of the path pieces a wall-point node fixes: `|x − o|` and the laser and detector
/// legs.
fn leg_opl(ctx: &MeasurementCtx, x: Vec3, o: Vec3) -> f32 {
    (x - o).length() + ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg
}

/// `(cos θ_z cos θ_wall / r², r)` of the connection from `z` to the wall point `w`, or
/// `None` if either surface turns away.
fn connect(ctx: &MeasurementCtx, z: &WalkVertex, w: Vec3) -> Option<(f32, f32)> {
    let d = w - z.p();
    let r = d.length();
    let cos_z = z.n_side().dot(d) / r;
    let cos_w = -ctx.n_w.dot(d) / r;
    (cos_z > 0.0 && cos_w > 0.0).then(|| (cos_z * cos_w / (r * r), r))
}
