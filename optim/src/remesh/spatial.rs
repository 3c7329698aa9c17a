//! Nearest-point queries on the input surface (and its boundary) through a uniform grid,
//! used to project relaxed vertices back onto the surface being remeshed.

use super::geom::{closest_on_segment, closest_on_triangle, dist2, dot, unit_normal, V3};

/// Uniform grid over axis-aligned boxes: each item is listed in every cell its box touches.
struct Grid {
    lo: V3,
    cell: f64,
    dims: [usize; 3],
    /// Cell `c` holds `items[starts[c]..starts[c + 1]]`.
    starts: Vec<u32>,
    items: Vec<u32>,
}

/// At most this many grid cells per item (and cell entries are capped at 64 per item).
const CELLS_PER_ITEM: f64 = 4.0;

impl Grid {
    fn new(boxes: &[(V3, V3)]) -> Grid {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (bl, bh) in boxes {
            for d in 0..3 {
                lo[d] = lo[d].min(bl[d]);
                hi[d] = hi[d].max(bh[d]);
            }
        }
        let ext = [0, 1, 2].map(|d| (hi[d] - lo[d]).max(0.0));
        let max_ext = ext.iter().fold(0.0f64, |a, &b| a.max(b));
        if boxes.is_empty() || max_ext <= 0.0 || !max_ext.is_finite() {
            let n = boxes.len() as u32;
            return Grid {
                lo: if boxes.is_empty() { [0.0; 3] } else { lo },
                cell: 1.0,
                dims: [1, 1, 1],
                starts: vec![0, n],
                items: (0..n).collect(),
            };
        }
        // Largest cell size whose grid has at least CELLS_PER_ITEM * n cells (bisection in
        // log scale), then coarsened while the cell lists get too long.
        let want = (CELLS_PER_ITEM * boxes.len() as f64).max(1.0);
        let count = |cell: f64| -> f64 { ext.iter().map(|&e| (e / cell).floor() + 1.0).product() };
        let (mut small, mut large) = (max_ext / want.max(2.0), max_ext * 2.0);
        for _ in 0..60 {
            let mid = (small * large).sqrt();
            if count(mid) >= want {
                small = mid;
            } else {
                large = mid;
            }
        }
        let mut cell = small;
        loop {
            let grid = Grid::fill(boxes, lo, cell, ext);
            if grid.items.len() <= 64 * boxes.len() + (1 << 20) {
                return grid;
            }
            cell *= 2.0;
        }
    }

    fn fill(boxes: &[(V3, V3)], lo: V3, cell: f64, ext: V3) -> Grid {
        let dims = [0, 1, 2].map(|d| ((ext[d] / cell).floor() as usize + 1).max(1));
        let ncell = dims[0] * dims[1] * dims[2];
        let range = |b: &(V3, V3), d: usize| -> (usize, usize) {
            let c0 = ((b.0[d] - lo[d]) / cell).floor().max(0.0) as usize;
            let c1 = ((b.1[d] - lo[d]) / cell).floor().max(0.0) as usize;
            (c0.min(dims[d] - 1), c1.min(dims[d] - 1))
        };
        let mut counts = vec![0u32; ncell + 1];
        let visit = |f: &mut dyn FnMut(usize, u32)| {
            for (i, b) in boxes.iter().enumerate() {
                let (x0, x1) = range(b, 0);
                let (y0, y1) = range(b, 1);
                let (z0, z1) = range(b, 2);
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        for x in x0..=x1 {
                            f(x + dims[0] * (y + dims[1] * z), i as u32);
                        }
                    }
                }
            }
        };
        visit(&mut |c, _| counts[c + 1] += 1);
        for c in 0..ncell {
            counts[c + 1] += counts[c];
        }
        let starts = counts.clone();
        let mut items = vec![0u32; counts[ncell] as usize];
        visit(&mut |c, i| {
            items[counts[c] as usize] = i;
            counts[c] += 1;
        });
        Grid {
            lo,
            cell,
            dims,
            starts,
            items,
        }
    }

    /// The item minimising `eval` (squared distance; `None` skips the item), searching
    /// shells of cells around `p` until no unvisited cell can hold anything closer. Ties go
    /// to the item met first.
    fn nearest(&self, p: V3, mut eval: impl FnMut(u32) -> Option<f64>) -> Option<(u32, f64)> {
        let c = [0, 1, 2].map(|d| {
            let x = ((p[d] - self.lo[d]) / self.cell).floor();
            if x.is_nan() {
                0
            } else {
                (x.max(0.0) as usize).min(self.dims[d] - 1)
            }
        });
        let mut best: Option<(u32, f64)> = None;
        let max_k = self.dims.iter().copied().max().unwrap_or(1);
        for k in 0..=max_k {
            let lo = [0, 1, 2].map(|d| c[d].saturating_sub(k));
            let hi = [0, 1, 2].map(|d| (c[d] + k).min(self.dims[d] - 1));
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    let on_shell_yz = z.abs_diff(c[2]) == k || y.abs_diff(c[1]) == k;
                    let mut visit = |x: usize| {
                        let cell = x + self.dims[0] * (y + self.dims[1] * z);
                        let (s, e) = (self.starts[cell] as usize, self.starts[cell + 1] as usize);
                        for &item in &self.items[s..e] {
                            if let Some(d2) = eval(item) {
                                if best.is_none_or(|(_, b)| d2 < b) {
                                    best = Some((item, d2));
                                }
                            }
                        }
                    };
                    if on_shell_yz {
                        (lo[0]..=hi[0]).for_each(&mut visit);
                    } else {
                        // k > 0 here: only the two end cells of the row are on the shell.
                        if c[0] >= k {
                            visit(c[0] - k);
                        }
                        if c[0] + k < self.dims[0] {
                            visit(c[0] + k);
                        }
                    }
                }
            }
            // Distance from p to the part of the grid not yet searched.
            let mut bound = f64::INFINITY;
            for d in 0..3 {
                if lo[d] > 0 {
                    bound = bound.min(p[d] - (self.lo[d] + lo[d] as f64 * self.cell));
                }
                if hi[d] + 1 < self.dims[d] {
                    bound = bound.min(self.lo[d] + (hi[d] + 1) as f64 * self.cell - p[d]);
                }
            }
            if bound == f64::INFINITY {
                break;
            }
            if let Some((_, b)) = best {
                if bound > 0.0 && b <= bound * bound {
                    break;
                }
            }
        }
        best
    }
}

/// The input surface to project onto: its triangles and boundary segments, with values.
pub(super) struct Reference {
    tris: Vec<[V3; 3]>,
    tri_vals: Vec<[f64; 3]>,
    tri_normals: Vec<Option<V3>>,
    tri_grid: Grid,
    segs: Vec<[V3; 2]>,
    seg_vals: Vec<[f64; 2]>,
    seg_grid: Grid,
}

fn bbox(points: &[V3]) -> (V3, V3) {
    let mut lo = points[0];
    let mut hi = points[0];
    for p in &points[1..] {
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    (lo, hi)
}

impl Reference {
    /// `values` empty or one per vertex; `segments` are the boundary edges.
    pub fn new(pos: &[V3], values: &[f64], faces: &[[u32; 3]], segments: &[[u32; 2]]) -> Self {
        let value = |v: u32| values.get(v as usize).copied().unwrap_or(0.0);
        let tris: Vec<[V3; 3]> = faces.iter().map(|f| f.map(|v| pos[v as usize])).collect();
        let segs: Vec<[V3; 2]> = segments
            .iter()
            .map(|s| s.map(|v| pos[v as usize]))
            .collect();
        let tri_boxes: Vec<_> = tris.iter().map(|t| bbox(t)).collect();
        let seg_boxes: Vec<_> = segs.iter().map(|s| bbox(s)).collect();
        Reference {
            tri_vals: faces.iter().map(|f| f.map(value)).collect(),
            tri_normals: tris.iter().map(|t| unit_normal(t[0], t[1], t[2])).collect(),
            tri_grid: Grid::new(&tri_boxes),
            tris,
            seg_vals: segments.iter().map(|s| s.map(value)).collect(),
            seg_grid: Grid::new(&seg_boxes),
            segs,
        }
    }

    /// Nearest point to `p` on the surface, with the value interpolated there. With a
    /// `normal`, triangles facing the other way (the far side of a thin part) are skipped
    /// unless nothing else is found.
    pub fn project_surface(&self, p: V3, normal: Option<V3>) -> Option<(V3, f64)> {
        let eval_filtered = |i: u32| {
            let n = self.tri_normals[i as usize];
            if let (Some(n), Some(vn)) = (n, normal) {
                if dot(n, vn) < 0.0 {
                    return None;
                }
            }
            let [a, b, c] = self.tris[i as usize];
            Some(dist2(p, closest_on_triangle(p, a, b, c).0))
        };
        let found = self.tri_grid.nearest(p, eval_filtered).or_else(|| {
            self.tri_grid.nearest(p, |i| {
                let [a, b, c] = self.tris[i as usize];
                Some(dist2(p, closest_on_triangle(p, a, b, c).0))
            })
        });
        let (i, _) = found?;
        let [a, b, c] = self.tris[i as usize];
        let (q, w) = closest_on_triangle(p, a, b, c);
        let v = self.tri_vals[i as usize];
        Some((q, w[0] * v[0] + w[1] * v[1] + w[2] * v[2]))
    }

    /// Nearest point to `p` on the input's boundary, with the value interpolated there.
    pub fn project_boundary(&self, p: V3) -> Option<(V3, f64)> {
        let (i, _) = self.seg_grid.nearest(p, |i| {
            let [a, b] = self.segs[i as usize];
            Some(dist2(p, closest_on_segment(p, a, b).0))
        })?;
        let [a, b] = self.segs[i as usize];
        let (q, t) = closest_on_segment(p, a, b);
        let v = self.seg_vals[i as usize];
        Some((q, (1.0 - t) * v[0] + t * v[1]))
    }
}
