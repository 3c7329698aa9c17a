//! Coincident hidden faces: surface that is there twice, a duplicated layer in an OBJ
//! (y-tal's own `Z.obj` holds a second, slightly shrunk copy of its letter 3.4 mm inside
//! the first) or two objects placed on top of each other. Without visibility (`tri3`'s
//! `none`) both copies reflect, so that surface renders up to twice as bright; with
//! visibility the inner copy hides behind the outer one and only costs time. Either way
//! it is rarely what the user meant: the loaders warn, naming the object and the share
//! of its area.
//!
//! A face counts as covered where another face (of any object) facing the same way
//! (`n · n' > cos 2°`) lies over it within [`STACK_REL`] of the objects' size along the
//! normal. Each triangle is probed at [`PROBES`] interior points; a probe is covered if
//! its projection onto another such triangle's plane falls inside that triangle.
//! Back-to-back faces (a two-sided sheet as two one-sided faces, the two sides of a thin
//! solid) face opposite ways and are not coincident; faces sharing an edge are not
//! either (the probes are interior). Candidates come from a uniform grid over the
//! triangles' bounding boxes, so the cost is about linear in the number of triangles.

use glam::Vec3;
use std::collections::HashMap;

/// Barycentric probes per triangle: the centroid and three points towards the corners.
const PROBES: [[f32; 3]; 4] = [
    [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0],
    [2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0],
    [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
    [1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
];
/// Largest distance between stacked faces, relative to the bounding-box diagonal of all
/// hidden objects (0.5 %: 5 mm for a 1 m scene, under a typical bin width).
pub const STACK_REL: f32 = 0.005;
/// Edge tolerance, relative to the covering triangle's longest edge.
const EPS_REL: f32 = 1e-4;
/// `cos 2°`: faces within 2° of each other's orientation.
const SAME_FACING: f32 = 0.999_39;
/// Grid cells a triangle may be filed under; a triangle spanning more (much larger than
/// the median, rare) is filed at its probes' cells only, so a small face lying on it
/// away from those cells is not seen as covered: the share is then a lower bound.
const MAX_CELLS_PER_TRIANGLE: usize = 64;

/// One object's share of area covered by other faces.
#[derive(Clone, Debug, PartialEq)]
pub struct Coincident {
    pub object: usize,
    /// Fraction of the object's area (0..1).
    pub share: f64,
    /// Which objects the covering faces belong to (sorted, may include `object` itself).
    pub covered_by: Vec<usize>,
    /// The largest distance (m) between faces that counted as stacked.
    pub stack_distance: f32,
}

/// `objects[k]` = (positions, triangles) of hidden object `k`; faces up to
/// `max(STACK_REL x diagonal, min_stack)` apart count as stacked (the loaders pass half
/// the film's bin width: layers closer than that are not told apart in time). Returns
/// the objects with any covered area.
pub fn coincident_faces(objects: &[(&[Vec3], &[[u32; 3]])], min_stack: f32) -> Vec<Coincident> {
    let tris: Vec<(usize, [Vec3; 3])> = objects
        .iter()
        .enumerate()
        .flat_map(|(o, (p, t))| {
            t.iter()
                .map(move |t| (o, [p[t[0] as usize], p[t[1] as usize], p[t[2] as usize]]))
        })
        .collect();
    if tris.len() < 2 {
        return Vec::new();
    }
    let grid = Grid::build(&tris);
    let stack = (STACK_REL * grid.diagonal).max(min_stack);
    let mut area = vec![0.0f64; objects.len()];
    let mut covered = vec![0.0f64; objects.len()];
    let mut by: Vec<Vec<usize>> = vec![Vec::new(); objects.len()];
    for (i, (o, t)) in tris.iter().enumerate() {
        let a = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length() as f64;
        area[*o] += a;
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
        let mut hits = 0;
        for w in PROBES {
            let p = w[0] * t[0] + w[1] * t[1] + w[2] * t[2];
            let cover = [p, p + stack * n, p - stack * n]
                .into_iter()
                .flat_map(|q| grid.candidates(q))
                .find(|&j| j != i && covers(&tris[j].1, n, p, stack));
            if let Some(j) = cover {
                hits += 1;
                by[*o].push(tris[j].0);
            }
        }
        covered[*o] += a * hits as f64 / PROBES.len() as f64;
    }
    (0..objects.len())
        .filter(|&o| covered[o] > 0.0)
        .map(|o| {
            let mut b = std::mem::take(&mut by[o]);
            b.sort_unstable();
            b.dedup();
            Coincident {
                object: o,
                share: covered[o] / area[o].max(f64::MIN_POSITIVE),
                covered_by: b,
                stack_distance: stack,
            }
        })
        .collect()
}

/// Whether triangle `t` faces the way `n` does, lies within `stack` of `p` along its
/// normal, and contains `p`'s projection onto its plane.
fn covers(t: &[Vec3; 3], n: Vec3, p: Vec3, stack: f32) -> bool {
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    let m = e1.cross(e2);
    let len = m.length();
    if len <= 0.0 {
        return false;
    }
    let size = e1.length().max(e2.length()).max((t[2] - t[1]).length());
    let eps = EPS_REL * size;
    let nt = m / len;
    let height = (p - t[0]).dot(nt);
    if nt.dot(n) < SAME_FACING || height.abs() > stack.max(eps) {
        return false;
    }
    // Barycentrics of p's projection in t; inside with a tolerance of eps at the edges.
    let q = p - height * nt - t[0];
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (q1, q2) = (q.dot(e1), q.dot(e2));
    let det = d11 * d22 - d12 * d12;
    let b1 = (d22 * q1 - d12 * q2) / det;
    let b2 = (d11 * q2 - d12 * q1) / det;
    let tol = eps / size;
    b1 >= -tol && b2 >= -tol && b1 + b2 <= 1.0 + tol
}

/// Triangles filed by the grid cells their bounding boxes overlap.
struct Grid {
    origin: Vec3,
    /// Bounding-box diagonal of every triangle.
    diagonal: f32,
    cell: f32,
    cells: HashMap<[i32; 3], Vec<usize>>,
}

impl Grid {
    fn build(tris: &[(usize, [Vec3; 3])]) -> Grid {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut edges: Vec<f32> = Vec::with_capacity(tris.len());
        for (_, t) in tris {
            for v in t {
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
            edges.push((t[1] - t[0]).length().max((t[2] - t[0]).length()));
        }
        // Cells about the median triangle size.
        let mid = edges.len() / 2;
        let cell = *edges.select_nth_unstable_by(mid, f32::total_cmp).1;
        let cell = cell
            .max((hi - lo).max_element() * 1e-6)
            .max(f32::MIN_POSITIVE);
        let mut g = Grid {
            origin: lo,
            diagonal: (hi - lo).length(),
            cell,
            cells: HashMap::new(),
        };
        for (i, (_, t)) in tris.iter().enumerate() {
            let (a, b) = (
                g.key(t[0].min(t[1]).min(t[2])),
                g.key(t[0].max(t[1]).max(t[2])),
            );
            let count = (0..3)
                .map(|k| (b[k] - a[k] + 1) as usize)
                .product::<usize>();
            // A triangle much larger than the cells is filed at its probes' cells only.
            if count > MAX_CELLS_PER_TRIANGLE {
                for w in PROBES {
                    let p = w[0] * t[0] + w[1] * t[1] + w[2] * t[2];
                    g.cells.entry(g.key(p)).or_default().push(i);
                }
                continue;
            }
            for x in a[0]..=b[0] {
                for y in a[1]..=b[1] {
                    for z in a[2]..=b[2] {
                        g.cells.entry([x, y, z]).or_default().push(i);
                    }
                }
            }
        }
        g
    }

    fn key(&self, p: Vec3) -> [i32; 3] {
        let c = ((p - self.origin) / self.cell).floor();
        [c.x as i32, c.y as i32, c.z as i32]
    }

    fn candidates(&self, p: Vec3) -> impl Iterator<Item = usize> + '_ {
        self.cells.get(&self.key(p)).into_iter().flatten().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f32, x0: f32, side: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let p = vec![
            Vec3::new(x0, 0.0, z),
            Vec3::new(x0 + side, 0.0, z),
            Vec3::new(x0 + side, side, z),
            Vec3::new(x0, side, z),
        ];
        (p, vec![[0, 1, 2], [0, 2, 3]])
    }

    #[test]
    fn a_duplicated_layer_is_found_with_its_share() {
        // Object 0: a square, and a copy of its left half triangulated differently.
        let (mut p, mut t) = square(1.0, 0.0, 1.0);
        p.extend([
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(0.5, 0.0, 1.0),
            Vec3::new(0.5, 1.0, 1.0),
            Vec3::new(0.0, 1.0, 1.0),
        ]);
        t.extend([[4, 5, 7], [5, 6, 7]]);
        let found = coincident_faces(&[(&p, &t)], 0.0);
        assert_eq!(found.len(), 1);
        // Total area 1.5, of which the half and its copy (1.0) are covered; the probes
        // sample each triangle at 4 points, so the share is close to, not exactly, 2/3.
        assert!((found[0].share - 2.0 / 3.0).abs() < 0.12, "{:?}", found[0]);
        assert_eq!(found[0].covered_by, vec![0]);
    }

    #[test]
    fn adjacent_parallel_and_separate_faces_are_not_coincident() {
        let (a, ta) = square(1.0, 0.0, 1.0);
        let (b, tb) = square(1.0, 1.0, 1.0); // shares an edge
                                             // 10 cm in front (the scene's diagonal is about 1.4 m: 7 %)
        let (c, tc) = square(1.1, 0.0, 1.0);
        // the same square facing the other way: a two-sided sheet
        let back: Vec<[u32; 3]> = ta.iter().map(|t| [t[0], t[2], t[1]]).collect();
        assert!(coincident_faces(&[(&a, &ta), (&b, &tb)], 0.0).is_empty());
        assert!(coincident_faces(&[(&a, &ta), (&c, &tc)], 0.0).is_empty());
        assert!(coincident_faces(&[(&a, &ta), (&a, &back)], 0.0).is_empty());
        // 3 mm in front, the same way round: a stacked copy
        let (d, td) = square(1.003, 0.0, 1.0);
        assert_eq!(coincident_faces(&[(&a, &ta), (&d, &td)], 0.0).len(), 2);
        let found = coincident_faces(&[(&a, &ta), (&a, &ta)], 0.0);
        assert_eq!(found.len(), 2);
        assert!(found.iter().all(|c| (c.share - 1.0).abs() < 1e-9));
        assert_eq!(found[0].covered_by, vec![1]);
    }
}
