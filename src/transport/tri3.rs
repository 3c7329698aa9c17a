//! Deterministic per-triangle three-bounce model (DESIGN §3 rung 1; after Plack,
//! Callenberg, Schneider, Hullin 2023).
//!
//! For laser spot `x_l`, sensor point `x_s` and a (sub-)triangle `T` of area `A`, centroid
//! `c`, normal `n` and albedo `ρ`, the three-bounce contribution
//!
//! `H_T = P (ρ_w/π) ∫_T (ρ/π) G(x_l, x) V G(x, x_s) dA (ρ_w/π)`
//!
//! is computed with the integrand `w(x) = (ρ/π) G(x_l, x) G(x, x_s)` and the OPL
//! `τ(x) = |x_l − x| + |x − x_s|` evaluated at the three corners and taken as linear over
//! the triangle: the weighted pulse `∫_T w δ(t − τ) dA` is then exact in closed form,
//! integrated over each bin through the film's kernel ([`Film::splat_triangle`]). Its
//! total is the trapezoidal rule `A (w0 + w1 + w2)/3`.
//!
//! The OPL is not linear: its curvature displaces a sub-triangle's pulse by about
//! `h²/r` (`h` the edge, `r` the distance to the wall). The pulse is therefore shifted so
//! its mean is the quadratic-exact mean `(1/12) Σ τ(v_i) + (3/4) τ(c)` (a second-order
//! correction); what remains is a shape error of the same order. Triangles are
//! subdivided, before any measurement, into `4^L` sub-triangles by midpoint subdivision,
//! with the smallest `L` such that every sub-triangle's longest edge `h` satisfies
//! `h² / (r w) ≤ subdivision` (the curvature displacement in units of the film's
//! resolution `w` = max(bin width, σ)) and `h ≤ r / 4` (the weight's linearity), `r` the
//! triangle's smallest height above the wall (a lower bound on its distance to any wall
//! point). The error this leaves is measured against Monte Carlo (`tests/tri3.rs`;
//! error-vs-threshold table in `BENCHMARKS.md`, from `umbra bench tri3`).
//!
//! Visibility: `none`; `centroid` (one shadow ray from the original triangle's centroid
//! to `x_l` and one to `x_s`, shared by its sub-triangles); `subtriangle` (the same per
//! sub-triangle).
//!
//! Supports: all capture types, one- and two-sided surfaces, per-vertex albedo, box and
//! Gaussian kernels, a point laser spot. Does not: interreflections, a finite laser spot
//! (treated as its centre), partial occlusion within a (sub-)triangle.

use super::mc3::TriParams;
use super::tri3_kernel::{self, BlockFrames, PulseBlock, TriBlock, W};
use super::MeasurementCtx;
use crate::film::{splat_lanes, Film, LaneRow, PulseLanes, LANES, SPLAT_PAD};
use crate::geometry::{HiddenTri, SceneGeometry};
use crate::scene::{KernelSpec, Scene, Visibility};
use glam::{DVec3, Vec3};
use std::collections::HashMap;
use std::f32::consts::FRAC_1_PI;
use std::sync::atomic::{AtomicU8, Ordering};

/// Subdivision is capped at this level (`4^8` sub-triangles per triangle).
pub const MAX_LEVEL: u32 = 8;

/// Films longer than this many bins get a scratch histogram over only the bins the
/// hidden geometry can reach in each measurement (its bounding box's OPL range), not
/// over the whole film: a 1 x 1 scan with 1e8 bins used to take 32 bytes a bin per
/// thread (3.5 GB) for a 400 MB output. Shorter films keep the whole-film histogram,
/// whose few megabytes cost nothing.
pub const WINDOW_MIN_BINS: u64 = 1 << 16;

/// The hidden meshes subdivided for the model, structure of arrays. Vertices at the
/// same position within an object are shared, so the per-vertex work of a measurement
/// (distances, cosines at the wall) is done once per vertex, not once per corner.
#[derive(Clone, Debug, Default)]
pub struct Tri3Mesh {
    /// Sub-triangle vertices.
    pub vertices: Vec<Vec3>,
    /// Per vertex: `ρ/π` (1/sr).
    pub vertex_brdf: Vec<f32>,
    /// Per sub-triangle: vertex indices.
    pub tris: Vec<[u32; 3]>,
    /// Per sub-triangle: unit normal (its original triangle's).
    pub normal: Vec<Vec3>,
    /// Per sub-triangle: its plane's offset `n · v` (m).
    pub plane: Vec<f32>,
    /// Per sub-triangle: reflects on both sides.
    pub two_sided: Vec<bool>,
    /// Per sub-triangle: retroreflective.
    pub retro: Vec<bool>,
    /// Per sub-triangle: a retroreflector's angular falloff exponent (`cos^m θ`).
    pub retro_falloff: Vec<f32>,
    /// Per sub-triangle: area (m²).
    pub area: Vec<f32>,
    /// Per sub-triangle: centroid (curvature shift, `subtriangle` visibility).
    pub centroid: Vec<Vec3>,
    /// Per sub-triangle: flat index of the original triangle.
    pub parent: Vec<u32>,
    /// Per sub-triangle: barycentrics `(b1, b2)` of its corners in the original triangle.
    pub corner_bary: Vec<[[f32; 2]; 3]>,
    /// Per original triangle: its centroid (for `centroid` visibility).
    pub parent_centroid: Vec<Vec3>,
    /// The sub-triangles packed for the inner loop.
    pub blocks: Vec<TriBlock>,
    /// The blocks' origins (the mean of each block's corners, m), by axis.
    pub block_origin: [Vec<f64>; 3],
    /// Bounding box of the sub-triangles' vertices (m).
    pub bounds: (Vec3, Vec3),
    /// Longest sub-triangle edge (m).
    pub longest_edge: f32,
    /// Original triangles stopped at [`MAX_LEVEL`] short of the threshold: their
    /// sub-triangles are coarser than asked (measured: 1.7 % per-bin error at 5.7x the
    /// threshold, `tests/stability.rs`). Split such triangles in the mesh itself.
    pub capped: usize,
}

impl Tri3Mesh {
    /// Subdivides every hidden triangle of `geom` for the scene's wall and film (see
    /// the module doc for the rule).
    pub fn build(scene: &Scene, geom: &SceneGeometry, subdivision: f32) -> Tri3Mesh {
        let resolution = match scene.film.kernel {
            KernelSpec::Box => scene.film.bin_width_opl,
            KernelSpec::Gaussian { sigma_opl } => sigma_opl.max(scene.film.bin_width_opl),
        };
        let mut m = Tri3Mesh::default();
        let mut shared: HashMap<(u32, [u32; 3], u32), u32> = HashMap::new();
        for (flat, t) in geom.hidden.iter().enumerate() {
            let r =
                t.v.iter()
                    .map(|&v| scene.wall.height_above(v))
                    .fold(f32::INFINITY, f32::min)
                    .max(1e-4);
            let edge = (t.v[1] - t.v[0])
                .length()
                .max((t.v[2] - t.v[1]).length())
                .max((t.v[0] - t.v[2]).length());
            let max_edge = (subdivision * resolution * r).sqrt().min(0.25 * r);
            let mut level = 0;
            while level < MAX_LEVEL && edge / (1u32 << level) as f32 > max_edge {
                level += 1;
            }
            m.capped += usize::from(edge / (1u32 << level) as f32 > max_edge);
            m.parent_centroid.push((t.v[0] + t.v[1] + t.v[2]) / 3.0);
            let object = geom.flat_to_local[flat].0;
            m.push_subdivided(flat as u32, object, t, level, &mut shared);
        }
        m.reorder(&tri3_kernel::block_order(&m.centroid));
        m.bounds = m.vertices.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), v| (lo.min(*v), hi.max(*v)),
        );
        m.longest_edge = m
            .tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                (b - a).length().max((c - b).length()).max((a - c).length())
            })
            .fold(0.0, f32::max);
        // The corners in f64 from the original triangle's, as the f64 model has them
        // (`tri3_exact`): the lanes keep them from their block's origin, where f32 holds
        // them to ~1e-9 m (their f32 positions are ~1e-7 m off).
        let corners = m
            .tris
            .iter()
            .zip(&m.corner_bary)
            .zip(&m.parent)
            .map(|((tri, bary), &p)| {
                let parent = TriParams::constant64(&geom.hidden[p as usize]);
                let at = |b: [f32; 2]| DVec3::from_array(parent.point(b));
                (bary.map(at), tri.map(|i| m.vertex_brdf[i as usize]))
            });
        (m.blocks, m.block_origin) = tri3_kernel::pack(
            corners,
            &m.normal,
            &m.plane,
            &m.area,
            &m.two_sided,
            &m.retro,
            &m.retro_falloff,
        );
        m
    }

    /// The frames of blocks `range` for the measurement of `frame`.
    pub fn block_frames(
        &self,
        frame: &tri3_kernel::Frame,
        range: std::ops::Range<usize>,
        out: &mut BlockFrames,
    ) {
        let [x, y, z] = &self.block_origin;
        let r = range;
        out.compute(frame, &x[r.clone()], &y[r.clone()], &z[r]);
    }

    /// The frame of block `b` alone (tests and tools; the render and the adjoint take runs
    /// of blocks through [`Tri3Mesh::block_frames`]).
    pub fn block_frame(&self, frame: &tri3_kernel::Frame, b: usize) -> tri3_kernel::BlockFrame {
        let mut one = BlockFrames::default();
        self.block_frames(frame, b..b + 1, &mut one);
        one.get(frame, 0)
    }

    /// The film bins `(first, len)` that any pulse of this mesh can reach in the
    /// measurement of `frame`, within `[0, bins)`: the OPL range of the bounding box
    /// from both wall points, widened by the curvature shift (at most `1.5` longest
    /// edges, since `|τ(c) − τ_i| ≤ 2 |c − v_i|`) and two bins.
    fn reach(&self, frame: &tri3_kernel::Frame, bins: usize) -> (usize, usize) {
        let (lo, hi) = self.bounds;
        let near = |x: Vec3| f64::from((x.clamp(lo, hi) - x).length());
        let far = |x: Vec3| f64::from((x - lo).abs().max((x - hi).abs()).length());
        let (x_l, x_s) = (frame.x_l, frame.x_s);
        // In f64: at 1e8 bins an f32 bin index is 8 bins coarse.
        let (w, offset) = (frame.inv_width, frame.offset);
        // The kernel's times are its blocks' origins' (f64) plus f32 leg differences,
        // which round to a few ulps of the block's extent; the f32 positions of the
        // block's wall points move them by a few ulps of the distances: bounded as such.
        let rounding = 8.0 * f64::from(f32::EPSILON) * (far(x_l) + far(x_s) + offset.abs()) * w;
        let margin = 1.5 * f64::from(self.longest_edge) * w + rounding + 2.0;
        let t_lo = (near(x_l) + near(x_s) + offset) * w - margin;
        let t_hi = (far(x_l) + far(x_s) + offset) * w + rounding + 2.0;
        let nbins = bins as f64;
        // Non-finite bounds (an empty mesh has an inverted box) give an empty window.
        let first = if t_lo >= 0.0 {
            t_lo.min(nbins) as usize
        } else {
            0
        };
        let end = if t_hi <= nbins {
            t_hi.max(0.0) as usize
        } else {
            bins
        };
        (first, end.saturating_sub(first))
    }

    /// The measurement's frame for the kernel, and the bins `first .. first + len` its
    /// box lanes work on: the whole film, or for a film longer than [`WINDOW_MIN_BINS`]
    /// (box kernel) only the bins the mesh can reach, with the frame's bin numbers relative
    /// to `first` so they stay exact in `f32`. The render and the adjoint both use it.
    pub fn frame(&self, ctx: &MeasurementCtx, film: &Film) -> (tri3_kernel::Frame, usize, usize) {
        let mut frame = tri3_kernel::frame(ctx, film);
        let gaussian = matches!(film.kernel, KernelSpec::Gaussian { .. });
        if gaussian || film.bins as u64 <= WINDOW_MIN_BINS {
            return (frame, 0, film.bins);
        }
        let (first, len) = self.reach(&frame, film.bins);
        frame.offset -= first as f64 * film.width;
        frame.lo -= first as f64;
        frame.hi -= first as f64;
        frame.bins = len;
        (frame, first, len)
    }

    /// Puts sub-triangle `order[k]` at `k`.
    fn reorder(&mut self, order: &[usize]) {
        fn apply<T: Copy>(v: &mut Vec<T>, order: &[usize]) {
            *v = order.iter().map(|&k| v[k]).collect();
        }
        apply(&mut self.tris, order);
        apply(&mut self.normal, order);
        apply(&mut self.plane, order);
        apply(&mut self.two_sided, order);
        apply(&mut self.retro, order);
        apply(&mut self.retro_falloff, order);
        apply(&mut self.area, order);
        apply(&mut self.centroid, order);
        apply(&mut self.parent, order);
        apply(&mut self.corner_bary, order);
    }

    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// `centroid` visibility: for every original triangle, whether its centroid sees both
    /// wall points of the measurement (left empty for the other modes).
    pub fn parent_visibility(&self, v: Visibility, out: &mut Vec<AtomicU8>) {
        out.clear();
        if v == Visibility::Centroid {
            // Filled on first use by `visible`: parents whose sub-triangles all face
            // away from the wall point (dead before visibility) cast no ray.
            out.resize_with(self.parent_centroid.len(), || AtomicU8::new(UNKNOWN));
        }
    }

    /// Kills the live lanes of block `b`'s pulses whose sub-triangle does not count for
    /// the measurement under visibility mode `v` (not `None`); `cache(k)`: the cache entry
    /// of sub-triangle `k`'s parent ([`Tri3Mesh::visible_at`]). Out of line, so that the
    /// block loops of the render and the adjoint keep their registers for the kernel
    /// (inlined, it made the render 5-8 % slower, even with visibility off; measured).
    #[inline(never)]
    pub fn cull<'c>(
        &self,
        b: usize,
        ctx: &MeasurementCtx,
        v: Visibility,
        lanes: &mut PulseLanes,
        cache: impl Fn(usize) -> Option<&'c AtomicU8>,
    ) {
        for j in 0..W {
            let k = b * W + j;
            if lanes.live()[j] && !self.visible_at(k, ctx, v, cache(k)) {
                lanes.kill(j);
            }
        }
    }

    /// Whether sub-triangle `k` counts for the measurement, under visibility mode `v`
    /// (`parents` from [`Tri3Mesh::parent_visibility`], completed as it goes).
    #[inline(always)]
    pub fn visible(
        &self,
        k: usize,
        ctx: &MeasurementCtx,
        v: Visibility,
        parents: &[AtomicU8],
    ) -> bool {
        let cached = parents.get(self.parent[k] as usize);
        self.visible_at(k, ctx, v, cached)
    }

    /// [`Tri3Mesh::visible`] given its parent's entry of a cache (`UNKNOWN` = 0 until
    /// first use; needed for `centroid` visibility only). The cache may be shared between
    /// threads: a ray's answer does not depend on who traces it, so a race costs at most
    /// a second ray, never a different result.
    #[inline(always)]
    pub fn visible_at(
        &self,
        k: usize,
        ctx: &MeasurementCtx,
        v: Visibility,
        cached: Option<&AtomicU8>,
    ) -> bool {
        match v {
            Visibility::None => true,
            Visibility::Centroid => {
                // The cached answer inline (asked for every live lane); the ray not.
                let state = cached.map_or(UNKNOWN, |c| c.load(Ordering::Relaxed));
                if state != UNKNOWN {
                    state == SEEN
                } else {
                    self.trace_parent(k, ctx, cached)
                }
            }
            Visibility::Subtriangle => seen(ctx, self.centroid[k]),
        }
    }

    /// Traces `centroid` visibility for sub-triangle `k`'s original triangle, and caches
    /// it in `cached`.
    #[inline(never)]
    #[cold]
    fn trace_parent(&self, k: usize, ctx: &MeasurementCtx, cached: Option<&AtomicU8>) -> bool {
        let p = self.parent[k] as usize;
        let visible = seen(ctx, self.parent_centroid[p]);
        if let Some(c) = cached {
            c.store(if visible { SEEN } else { HIDDEN }, Ordering::Relaxed);
        }
        visible
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Midpoint subdivision into `4^level` triangles on a barycentric grid of
    /// `n = 2^level` steps: vertex `(i, j)` has barycentrics `(i/n, j/n)`.
    fn push_subdivided(
        &mut self,
        flat: u32,
        object: u32,
        t: &HiddenTri,
        level: u32,
        shared: &mut HashMap<(u32, [u32; 3], u32), u32>,
    ) {
        let n = 1u32 << level;
        let mut grid = Vec::with_capacity(((n + 1) * (n + 2) / 2) as usize);
        let bary_of = |i: u32, j: u32| [i as f32 / n as f32, j as f32 / n as f32];
        for j in 0..=n {
            for i in 0..=(n - j) {
                let bary = bary_of(i, j);
                let p = t.point(bary);
                let brdf = t.albedo_at(bary) * FRAC_1_PI;
                let key = (object, p.to_array().map(f32::to_bits), brdf.to_bits());
                let next = self.vertices.len() as u32;
                let id = *shared.entry(key).or_insert(next);
                if id == next {
                    self.vertices.push(p);
                    self.vertex_brdf.push(brdf);
                }
                grid.push(id);
            }
        }
        // Row j of the grid starts after rows 0..j, of n + 1, n, … entries.
        let row = |j: u32| (j * (n + 1) - j * j.saturating_sub(1) / 2) as usize;
        let vid = |i: u32, j: u32| grid[row(j) + i as usize];
        for j in 0..n {
            for i in 0..(n - j) {
                let up = [(i, j), (i + 1, j), (i, j + 1)];
                // The "down" triangle exists only inside the grid's diagonal.
                let tris = if i + j + 1 < n {
                    &[up, [(i + 1, j), (i + 1, j + 1), (i, j + 1)]][..]
                } else {
                    &[up][..]
                };
                for &ij in tris {
                    let tri = ij.map(|(i, j)| vid(i, j));
                    self.corner_bary.push(ij.map(|(i, j)| bary_of(i, j)));
                    let [pa, pb, pc] = tri.map(|k| self.vertices[k as usize]);
                    self.tris.push(tri);
                    self.normal.push(t.n);
                    self.plane.push(t.n.dot((pa + pb + pc) / 3.0));
                    self.two_sided.push(t.two_sided);
                    self.retro.push(t.retro);
                    self.retro_falloff.push(t.retro_falloff);
                    self.area.push(0.5 * (pb - pa).cross(pc - pa).length());
                    self.centroid.push((pa + pb + pc) / 3.0);
                    self.parent.push(flat);
                }
            }
        }
    }
}

/// Centroid visibility of a parent triangle, per measurement.
pub const UNKNOWN: u8 = 0;
const SEEN: u8 = 1;
const HIDDEN: u8 = 2;

/// `c` sees the laser spot and the sensor point (one ray in confocal capture).
fn seen(ctx: &MeasurementCtx, c: glam::Vec3) -> bool {
    !ctx.geom.occluded(c, ctx.x_l) && (ctx.x_s == ctx.x_l || !ctx.geom.occluded(c, ctx.x_s))
}

/// Reusable per-thread buffers: no allocation per measurement once warm.
#[derive(Default)]
pub struct Tri3Scratch {
    /// Per original triangle: centroid visibility (UNKNOWN, SEEN, HIDDEN).
    visible: Vec<AtomicU8>,
    /// Box kernel: the measurement's bins, one row of eight lanes each, and
    /// [`SPLAT_PAD`] rows of scratch.
    hist32: Vec<LaneRow>,
    /// Gaussian kernel: the measurement's bins.
    hist64: Vec<f64>,
    /// The blocks' frames for the measurement.
    frames: BlockFrames,
}

/// Adds the three-bounce transient of one measurement to `out` (its `bins` values).
/// The per-triangle arithmetic is in [`tri3_kernel`], eight triangles at a time.
pub fn render_measurement(
    mesh: &Tri3Mesh,
    ctx: &MeasurementCtx,
    film: &Film,
    visibility: Visibility,
    scratch: &mut Tri3Scratch,
    out: &mut [f32],
) {
    mesh.parent_visibility(visibility, &mut scratch.visible);
    // A Gaussian kernel far wider than the bins is applied to the sum of the pulses,
    // box-binned into its cells, rather than to each pulse ([`Film::cells`]).
    let cells = film.cells();
    let binned = cells.as_ref().unwrap_or(film);
    let gaussian = matches!(binned.kernel, KernelSpec::Gaussian { .. });
    // The box histogram spans bins `first .. first + bins` of `binned`.
    let (frame, first, bins) = mesh.frame(ctx, binned);
    if gaussian {
        scratch.hist64.clear();
        scratch.hist64.resize(bins, 0.0);
    } else {
        scratch.hist32.clear();
        scratch.hist32.resize(bins + SPLAT_PAD, [0.0; LANES]);
    }
    let confocal = frame.confocal();
    let mut pulses = PulseBlock::default();
    mesh.block_frames(&frame, 0..mesh.blocks.len(), &mut scratch.frames);
    for (b, block) in mesh.blocks.iter().enumerate() {
        let here = scratch.frames.get(&frame, b);
        if confocal {
            block.pulses::<true>(&frame, &here, &mut pulses);
        } else {
            block.pulses::<false>(&frame, &here, &mut pulses);
        }
        if visibility != Visibility::None {
            let cache = &scratch.visible;
            mesh.cull(b, ctx, visibility, &mut pulses.lanes, |k| {
                cache.get(mesh.parent[k] as usize)
            });
        }
        // Pulse times count from the block's base bin.
        let base = pulses.base;
        if gaussian {
            for j in (0..W).filter(|&j| pulses.lanes.live()[j]) {
                let opl = pulses
                    .lanes
                    .t()
                    .map(|t| binned.start + (base as f64 + t[j] as f64) * binned.width);
                let w = pulses.w.map(|w| w[j] as f64);
                binned.splat_triangle(opl, w, pulses.area[j] as f64, &mut scratch.hist64);
            }
        } else {
            splat_lanes(&pulses.lanes, base, bins, &mut scratch.hist32);
        }
    }
    let scale = ctx.three_bounce_constant();
    let lanes_sum = |h: &LaneRow| h.iter().sum::<f32>();
    if gaussian {
        for (o, h) in out.iter_mut().zip(&scratch.hist64) {
            *o += (*h * scale as f64) as f32;
        }
    } else if let Some(cells) = &cells {
        scratch.hist64.clear();
        scratch.hist64.resize(film.bins, 0.0);
        let mass = scratch.hist32[..bins].iter().map(|h| lanes_sum(h) as f64);
        film.blur_cells(cells, first, mass, scale as f64, &mut scratch.hist64);
        for (o, h) in out.iter_mut().zip(&scratch.hist64) {
            *o += *h as f32;
        }
    } else {
        for (o, h) in out[first..first + bins].iter_mut().zip(&scratch.hist32) {
            *o += lanes_sum(h) * scale;
        }
    }
}
