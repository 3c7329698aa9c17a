//! Edge-preserving total variation (TV) of per-vertex values (albedo) on a triangle mesh:
//!
//! `TV(a) = Σ_e ℓ_e φ(a_i − a_j) / √A`,   `φ(d) = √(d² + ε²) − ε`
//!
//! over the mesh's undirected edges `e = (i, j)`, with `ℓ_e` the edge's length and `A`
//! the total area of the mesh's faces. Both are taken once, from the mesh given to
//! [`TotalVariation::new`] (the fit: the stage's template), and then held fixed, so TV
//! depends on the values alone and has no gradient with respect to the vertex positions.
//!
//! `φ` is the Charbonnier penalty with `ε =` [`EPSILON`]: smooth (its curvature is at
//! most `1/ε`, so L-BFGS works on it), and `≈ |d| − ε` once `|d| ≫ ε`. A jump costs its
//! height, not its square: a sharp step costs what a ramp of the same rise does, so TV
//! takes out noise (many small oscillations) without blurring the edges of a
//! piecewise-constant albedo, which the quadratic `Σ (a_i − a_j)²` would.
//!
//! Scale: a step of height `Δ` along a curve of length `L` on a mesh of edge length `h`
//! crosses about `c L / h` edges, each of length about `h`, so `TV ≈ c L |Δ| / √A`: the
//! same at any mesh resolution, and dimensionless (the same for the scene scaled). The
//! factor `c` depends on the triangulation and the curve's direction, not on `h`:
//! `4√3/π ≈ 2.2` averaged over directions on an equilateral mesh (Crofton's formula),
//! `1 + √2 ≈ 2.41` across a grid line of a regular grid of right triangles (its
//! diagonals are crossed too). So a weight `w` on TV trades `w c L |Δ| / √A` of
//! regularisation against the data.
//!
//! Gradient: `∂TV/∂a_i = Σ_{e = (i, j)} ℓ_e φ'(a_i − a_j) / √A`, `φ'(d) = d / √(d² + ε²)`.

use crate::mesh::Mesh;

/// `ε` of the Charbonnier penalty `φ(d) = √(d² + ε²) − ε`: far below any albedo
/// difference that matters (albedo is in `[0, 1]`), far above rounding.
pub const EPSILON: f64 = 1e-3;

/// `φ(d)` and `φ'(d)` of the Charbonnier penalty with [`EPSILON`].
pub fn charbonnier(d: f64) -> (f64, f64) {
    let r = (d * d + EPSILON * EPSILON).sqrt();
    (r - EPSILON, d / r)
}

/// The TV term of one mesh's topology and geometry (module doc).
#[derive(Clone, Debug, Default)]
pub struct TotalVariation {
    /// Undirected edges `(i, j)`, `i < j`, each once.
    edges: Vec<(u32, u32)>,
    /// `ℓ_e / √A` per edge.
    weights: Vec<f64>,
    /// `A`, m².
    area: f64,
}

impl TotalVariation {
    /// The edges, their lengths and the area of `mesh` (degenerate faces and edges, and
    /// indices out of range, are skipped). A mesh of no area is taken as `A = 1e-18 m²`
    /// (`√A = 1e-9 m`, the floor of [`crate::laplacian::mean_edge`]'s use in the fit).
    pub fn new(mesh: &Mesh) -> TotalVariation {
        let n = mesh.vertices.len();
        let p = |i: u32| mesh.vertices[i as usize];
        let mut edges: Vec<(u32, u32)> = Vec::with_capacity(3 * mesh.faces.len());
        let mut area = 0.0;
        for f in &mesh.faces {
            if f.iter().any(|&i| i as usize >= n) {
                continue;
            }
            let (a, b, c) = (p(f[0]), p(f[1]), p(f[2]));
            area += 0.5 * norm(cross(sub(b, a), sub(c, a)));
            for k in 0..3 {
                let (i, j) = (f[k], f[(k + 1) % 3]);
                if i != j {
                    edges.push((i.min(j), i.max(j)));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        let root = area.sqrt().max(1e-9);
        let weights = edges
            .iter()
            .map(|&(i, j)| norm(sub(p(i), p(j))) / root)
            .collect();
        TotalVariation {
            edges,
            weights,
            area,
        }
    }

    /// The undirected edges `(i, j)`, `i < j`, sorted.
    pub fn edges(&self) -> &[(u32, u32)] {
        &self.edges
    }

    /// `ℓ_e / √A` of each edge of [`TotalVariation::edges`].
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// `A`: the mesh's total face area, m².
    pub fn area(&self) -> f64 {
        self.area
    }

    /// `TV(values)`, its gradient added into `grad` (one entry per vertex, like
    /// `values`).
    pub fn evaluate(&self, values: &[f64], grad: &mut [f64]) -> f64 {
        let mut tv = 0.0;
        for (&(i, j), &w) in self.edges.iter().zip(&self.weights) {
            let (i, j) = (i as usize, j as usize);
            let (phi, dphi) = charbonnier(values[i] - values[j]);
            tv += w * phi;
            grad[i] += w * dphi;
            grad[j] -= w * dphi;
        }
        tv
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charbonnier_is_smooth_at_zero_and_close_to_abs_beyond_epsilon() {
        assert_eq!(charbonnier(0.0), (0.0, 0.0));
        let (phi, dphi) = charbonnier(0.5);
        assert!((phi - (0.5 - EPSILON)).abs() < 1e-5, "{phi}");
        assert!((dphi - 1.0).abs() < 1e-5, "{dphi}");
        assert_eq!(charbonnier(-0.5).1, -dphi);
    }

    #[test]
    fn one_triangle_has_its_area_and_three_edges() {
        let mesh = Mesh::new(
            vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
            vec![[0, 1, 2]],
        );
        let tv = TotalVariation::new(&mesh);
        assert!((tv.area() - 2.0).abs() < 1e-15);
        assert_eq!(tv.edges(), &[(0, 1), (0, 2), (1, 2)]);
        let root = 2f64.sqrt();
        let want = [2.0 / root, 2.0 / root, 8f64.sqrt() / root];
        for (w, want) in tv.weights().iter().zip(want) {
            assert!((w - want).abs() < 1e-15, "{w} vs {want}");
        }
        // Constant values: no variation, no gradient.
        let mut g = vec![0.0; 3];
        assert_eq!(tv.evaluate(&[0.4; 3], &mut g), 0.0);
        assert_eq!(g, vec![0.0; 3]);
    }
}
