//! The mesh's combinatorial Laplacian and what the fit builds on it (Nicolet, Jacobson,
//! Jakob 2021, "Large steps in inverse rendering of geometry"):
//!
//! - `L = D − A`, the uniform graph Laplacian (`D` the vertex degrees, `A` the adjacency),
//!   so `(L x)_i = Σ_{j ~ i} (x_i − x_j)`: zero on a flat, regular patch, large on spikes;
//! - the smoothness energy `R(x) = ‖L x‖² / (V h²)` with `h` a reference edge length, so
//!   it is dimensionless and comparable across mesh resolutions; `∇R = 2 Lᵀ L x / (V h²)`;
//! - the large-steps operator `M = I + λ L` (symmetric positive definite): the optimiser
//!   works on `u = M x`, so a gradient step in `u` moves `x` by `M⁻¹ Δu`, a smooth
//!   displacement; `∂loss/∂u = M⁻¹ ∂loss/∂x` (as `M` is symmetric). Both solves run
//!   Jacobi-preconditioned conjugate gradients, warm-started, per axis.

use crate::mesh::Mesh;

/// A symmetric sparse matrix in compressed rows.
#[derive(Clone, Debug, Default)]
pub struct Laplacian {
    /// Row `i`'s neighbours: `cols[start[i]..start[i + 1]]`, sorted.
    start: Vec<usize>,
    cols: Vec<u32>,
}

impl Laplacian {
    /// The uniform Laplacian of `mesh`'s edge graph.
    pub fn new(mesh: &Mesh) -> Laplacian {
        let n = mesh.vertices.len();
        let mut edges: Vec<(u32, u32)> = Vec::with_capacity(mesh.faces.len() * 6);
        for f in &mesh.faces {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                if a != b && (a as usize) < n && (b as usize) < n {
                    edges.push((a, b));
                    edges.push((b, a));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        let mut start = vec![0usize; n + 1];
        for &(a, _) in &edges {
            start[a as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        Laplacian {
            start,
            cols: edges.into_iter().map(|(_, b)| b).collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn neighbours(&self, i: usize) -> &[u32] {
        &self.cols[self.start[i]..self.start[i + 1]]
    }

    /// `y = L x` for one coordinate.
    pub fn apply(&self, x: &[f64], y: &mut [f64]) {
        for (i, yi) in y.iter_mut().enumerate() {
            let nb = self.neighbours(i);
            *yi = nb.len() as f64 * x[i] - nb.iter().map(|&j| x[j as usize]).sum::<f64>();
        }
    }

    /// `y = (I + λ L) x`.
    fn apply_m(&self, lambda: f64, x: &[f64], y: &mut [f64]) {
        self.apply(x, y);
        for (yi, xi) in y.iter_mut().zip(x) {
            *yi = xi + lambda * *yi;
        }
    }

    /// Solves `(I + λ L) x = b` by Jacobi-preconditioned CG from the guess in `x`, to a
    /// relative residual of `tol`. Returns the iterations used.
    pub fn solve_m(&self, lambda: f64, b: &[f64], x: &mut [f64], tol: f64) -> usize {
        let n = b.len();
        let diag: Vec<f64> = (0..n)
            .map(|i| 1.0 + lambda * self.neighbours(i).len() as f64)
            .collect();
        let mut r = vec![0.0; n];
        self.apply_m(lambda, x, &mut r);
        for i in 0..n {
            r[i] = b[i] - r[i];
        }
        let norm_b = dot(b, b).sqrt().max(f64::MIN_POSITIVE);
        let mut z: Vec<f64> = r.iter().zip(&diag).map(|(r, d)| r / d).collect();
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let mut q = vec![0.0; n];
        for it in 0..(4 * n + 20) {
            if dot(&r, &r).sqrt() <= tol * norm_b {
                return it;
            }
            self.apply_m(lambda, &p, &mut q);
            let alpha = rz / dot(&p, &q);
            for i in 0..n {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
                z[i] = r[i] / diag[i];
            }
            let rz_new = dot(&r, &z);
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
        }
        4 * n + 20
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// Splits positions into three coordinate arrays.
pub fn split_axes(v: &[[f64; 3]]) -> [Vec<f64>; 3] {
    [0, 1, 2].map(|k| v.iter().map(|p| p[k]).collect())
}

/// Inverse of [`split_axes`].
pub fn join_axes(a: &[Vec<f64>; 3]) -> Vec<[f64; 3]> {
    (0..a[0].len())
        .map(|i| [a[0][i], a[1][i], a[2][i]])
        .collect()
}

/// `R(x) = ‖L x‖² / (V h²)` and its gradient (added into `grad`).
pub fn smoothness(lap: &Laplacian, v: &[[f64; 3]], h: f64, grad: &mut [[f64; 3]]) -> f64 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    let scale = 1.0 / (n as f64 * h * h);
    let mut energy = 0.0;
    let (mut lx, mut llx) = (vec![0.0; n], vec![0.0; n]);
    for (k, x) in split_axes(v).iter().enumerate() {
        lap.apply(x, &mut lx);
        energy += dot(&lx, &lx);
        lap.apply(&lx, &mut llx);
        for (g, d) in grad.iter_mut().zip(&llx) {
            g[k] += 2.0 * scale * d;
        }
    }
    energy * scale
}

/// Mean edge length of `mesh` (m), over its faces' edges.
pub fn mean_edge(mesh: &Mesh) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for f in &mesh.faces {
        for k in 0..3 {
            let (a, b) = (
                mesh.vertices[f[k] as usize],
                mesh.vertices[f[(k + 1) % 3] as usize],
            );
            sum += ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            count += 1;
        }
    }
    if count == 0 {
        0.0
    } else {
        sum / count as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> Mesh {
        let mut v = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                v.push([i as f64 / n as f64, j as f64 / n as f64, 0.0]);
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut f = Vec::new();
        for j in 0..n {
            for i in 0..n {
                f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        Mesh::new(v, f)
    }

    #[test]
    fn solve_inverts_m() {
        let mesh = grid(6);
        let lap = Laplacian::new(&mesh);
        let n = lap.len();
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut x = vec![0.0; n];
        lap.solve_m(20.0, &b, &mut x, 1e-12);
        let mut mx = vec![0.0; n];
        lap.apply_m(20.0, &x, &mut mx);
        let err: f64 = mx
            .iter()
            .zip(&b)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-9, "{err}");
    }

    #[test]
    fn smoothness_gradient_matches_finite_differences() {
        let mut mesh = grid(4);
        for (i, p) in mesh.vertices.iter_mut().enumerate() {
            p[2] = (i as f64 * 1.3).sin() * 0.1;
        }
        let lap = Laplacian::new(&mesh);
        let mut g = vec![[0.0; 3]; mesh.vertices.len()];
        let r0 = smoothness(&lap, &mesh.vertices, 0.25, &mut g);
        assert!(r0 > 0.0);
        for (i, k) in [(3, 2), (7, 0), (12, 1)] {
            let eps = 1e-6;
            let mut v = mesh.vertices.clone();
            v[i][k] += eps;
            let rp = smoothness(&lap, &v, 0.25, &mut vec![[0.0; 3]; v.len()]);
            v[i][k] -= 2.0 * eps;
            let rm = smoothness(&lap, &v, 0.25, &mut vec![[0.0; 3]; v.len()]);
            let fd = (rp - rm) / (2.0 * eps);
            assert!(
                (fd - g[i][k]).abs() < 1e-6 * g[i][k].abs().max(1.0),
                "{fd} {}",
                g[i][k]
            );
        }
        // A flat regular grid's interior has L x = 0 in z.
        let flat = grid(4);
        let mut g = vec![[0.0; 3]; flat.vertices.len()];
        smoothness(&Laplacian::new(&flat), &flat.vertices, 0.25, &mut g);
        assert_eq!(g[12][2], 0.0);
    }
}
