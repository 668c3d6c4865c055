//! The least-squares system of one step of [`super::fit_deformation`]:
//! its data rows, and conjugate gradients with a block-Jacobi
//! preconditioner over the lattice nodes' displacements, matrix-free (a
//! data row touches 8 nodes, a regulariser term 2 or 3).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// One data row: a scan point's stencil, the direction it is measured
/// along, its target and its weight.
#[derive(Clone)]
pub(super) struct SurfaceRow {
    pub(super) stencil: [(usize, f64); 8],
    pub(super) normal: Vector3<f64>,
    /// n . (c - s), mm.
    pub(super) target: f64,
    /// The row's weight in the sum of squares.
    pub(super) weight: f64,
}

/// A landmark's row: its stencil, the projection across the skin's
/// normal and its target.
pub(super) struct LandmarkRow {
    pub(super) stencil: [(usize, f64); 8],
    /// I - n n^T.
    pub(super) across: Matrix3<f64>,
    /// P (k - m), mm.
    pub(super) target: Vector3<f64>,
}

/// One step's least-squares system over the nodes' displacements.
pub(super) struct System<'a> {
    pub(super) surface: &'a [SurfaceRow],
    pub(super) landmarks: &'a [LandmarkRow],
    pub(super) edges: &'a [(usize, usize)],
    pub(super) triples: &'a [[usize; 3]],
    pub(super) nodes: usize,
    pub(super) landmark_weight: f64,
    pub(super) edge_weight: f64,
    pub(super) bend_weight: f64,
}

impl System<'_> {
    /// (A^T W A) u. The data rows in parallel chunks, each into a buffer
    /// of its own (a row touches 8 nodes anywhere), summed in chunk order
    /// (the same sums on any number of threads).
    fn apply(&self, u: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        const CHUNK: usize = 4096;
        let mut out = self
            .surface
            .par_chunks(CHUNK)
            .map(|rows| {
                let mut part = vec![Vector3::zeros(); self.nodes];
                for r in rows {
                    let v: f64 = r
                        .stencil
                        .iter()
                        .map(|&(n, w)| w * r.normal.dot(&u[n]))
                        .sum();
                    let g = r.normal * (r.weight * v);
                    for &(n, w) in &r.stencil {
                        part[n] += g * w;
                    }
                }
                part
            })
            .collect::<Vec<_>>()
            .into_iter()
            .reduce(|mut a, b| {
                a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
                a
            })
            .unwrap_or_else(|| vec![Vector3::zeros(); self.nodes]);
        for r in self.landmarks {
            let v: Vector3<f64> = r.stencil.iter().map(|&(n, w)| u[n] * w).sum();
            let g = r.across * (r.across * v) * self.landmark_weight;
            for &(n, w) in &r.stencil {
                out[n] += g * w;
            }
        }
        for &(a, b) in self.edges {
            let d = (u[a] - u[b]) * self.edge_weight;
            out[a] += d;
            out[b] -= d;
        }
        for &[a, b, c] in self.triples {
            let d = (u[a] - u[b] * 2.0 + u[c]) * self.bend_weight;
            out[a] += d;
            out[b] -= d * 2.0;
            out[c] += d;
        }
        out
    }

    /// A^T W b.
    fn rhs(&self) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.nodes];
        for r in self.surface {
            let g = r.normal * (r.weight * r.target);
            for &(n, w) in &r.stencil {
                out[n] += g * w;
            }
        }
        for r in self.landmarks {
            let g = r.across * r.target * self.landmark_weight;
            for &(n, w) in &r.stencil {
                out[n] += g * w;
            }
        }
        out
    }

    /// The inverse of each node's 3 x 3 diagonal block.
    fn preconditioner(&self) -> Vec<Matrix3<f64>> {
        let mut blocks = vec![Matrix3::zeros(); self.nodes];
        for r in self.surface {
            let nn = r.normal * r.normal.transpose() * r.weight;
            for &(n, w) in &r.stencil {
                blocks[n] += nn * (w * w);
            }
        }
        for r in self.landmarks {
            for &(n, w) in &r.stencil {
                blocks[n] += r.across * (self.landmark_weight * w * w);
            }
        }
        for &(a, b) in self.edges {
            blocks[a] += Matrix3::identity() * self.edge_weight;
            blocks[b] += Matrix3::identity() * self.edge_weight;
        }
        for &[a, b, c] in self.triples {
            blocks[a] += Matrix3::identity() * self.bend_weight;
            blocks[b] += Matrix3::identity() * (4.0 * self.bend_weight);
            blocks[c] += Matrix3::identity() * self.bend_weight;
        }
        blocks
            .into_iter()
            .map(|b| b.try_inverse().unwrap_or_else(Matrix3::identity))
            .collect()
    }

    /// Preconditioned conjugate gradients from `start`, until the residual
    /// is `tolerance` of the right-hand side's norm or after `iterations`.
    pub(super) fn solve(
        &self,
        start: &[Vector3<f64>],
        tolerance: f64,
        iterations: usize,
    ) -> Vec<Vector3<f64>> {
        let dot = |a: &[Vector3<f64>], b: &[Vector3<f64>]| -> f64 {
            a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
        };
        let m = self.preconditioner();
        let b = self.rhs();
        let mut x = start.to_vec();
        let ax = self.apply(&x);
        let mut r: Vec<Vector3<f64>> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        let norm_b = dot(&b, &b).sqrt().max(f64::MIN_POSITIVE);
        let mut z: Vec<Vector3<f64>> = m.iter().zip(&r).map(|(m, r)| m * r).collect();
        let mut d = z.clone();
        let mut rz = dot(&r, &z);
        for _ in 0..iterations {
            if dot(&r, &r).sqrt() <= tolerance * norm_b {
                break;
            }
            let ad = self.apply(&d);
            let alpha = rz / dot(&d, &ad).max(f64::MIN_POSITIVE);
            for i in 0..x.len() {
                x[i] += d[i] * alpha;
                r[i] -= ad[i] * alpha;
            }
            z = m.iter().zip(&r).map(|(m, r)| m * r).collect();
            let rz_next = dot(&r, &z);
            let beta = rz_next / rz.max(f64::MIN_POSITIVE);
            rz = rz_next;
            for i in 0..d.len() {
                d[i] = z[i] + d[i] * beta;
            }
        }
        x
    }
}
