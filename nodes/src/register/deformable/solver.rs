//! The least-squares system of one step of [`super::fit_deformation`]:
//! its data rows, and conjugate gradients on it, preconditioned by a
//! multigrid V-cycle on the lattice (see [`super::multigrid`]).

use super::multigrid::{Multigrid, PointTerm, Regularisers, term_at};
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
    /// The lattice's nodes along x, y, z.
    pub(super) dims: [usize; 3],
    pub(super) landmark_weight: f64,
    /// The membrane's weight per lattice edge.
    pub(super) edge_weight: f64,
    /// The bending's weight per line of three nodes.
    pub(super) bend_weight: f64,
}

/// How a solve ended.
#[derive(Debug, Clone, Copy)]
pub(super) struct SolveReport {
    pub(super) iterations: usize,
    /// The residual's norm over the right-hand side's.
    pub(super) relative_residual: f64,
}

impl System<'_> {
    /// Every data row as a term at its point: its stencil's position and
    /// its 3 x 3 weight.
    fn terms(&self) -> Vec<PointTerm> {
        let mut terms: Vec<PointTerm> = self
            .surface
            .par_iter()
            .map(|r| {
                term_at(
                    self.dims,
                    &r.stencil,
                    r.normal * r.normal.transpose() * r.weight,
                )
            })
            .collect();
        terms.extend(self.landmarks.iter().map(|r| {
            term_at(
                self.dims,
                &r.stencil,
                r.across * r.across * self.landmark_weight,
            )
        }));
        terms
    }

    /// A^T W b.
    fn rhs(&self) -> Vec<Vector3<f64>> {
        let nodes = self.dims.iter().product();
        let mut out = vec![Vector3::zeros(); nodes];
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

    /// Conjugate gradients from `start`, preconditioned by a multigrid
    /// V-cycle, until the residual is `tolerance` of the right-hand side's
    /// norm or after `iterations`.
    pub(super) fn solve(
        &self,
        start: &[Vector3<f64>],
        tolerance: f64,
        iterations: usize,
    ) -> (Vec<Vector3<f64>>, SolveReport) {
        let dot = |a: &[Vector3<f64>], b: &[Vector3<f64>]| -> f64 {
            a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
        };
        let regularisers = Regularisers {
            edge: self.edge_weight,
            bend: self.bend_weight,
        };
        let multigrid = Multigrid::new(self.dims, &self.terms(), regularisers);
        let a = multigrid.matrix();
        let b = self.rhs();
        let mut x = start.to_vec();
        let ax = a.apply(&x);
        let mut r: Vec<Vector3<f64>> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        let norm_b = dot(&b, &b).sqrt().max(f64::MIN_POSITIVE);
        let mut z = multigrid.precondition(&r);
        let mut d = z.clone();
        let mut rz = dot(&r, &z);
        let mut done = 0;
        while done < iterations && dot(&r, &r).sqrt() > tolerance * norm_b {
            let ad = a.apply(&d);
            let alpha = rz / dot(&d, &ad).max(f64::MIN_POSITIVE);
            for i in 0..x.len() {
                x[i] += d[i] * alpha;
                r[i] -= ad[i] * alpha;
            }
            z = multigrid.precondition(&r);
            let rz_next = dot(&r, &z);
            let beta = rz_next / rz.max(f64::MIN_POSITIVE);
            rz = rz_next;
            for i in 0..d.len() {
                d[i] = z[i] + d[i] * beta;
            }
            done += 1;
        }
        let report = SolveReport {
            iterations: done,
            relative_residual: dot(&r, &r).sqrt() / norm_b,
        };
        (x, report)
    }
}

#[cfg(test)]
mod tests {
    use super::super::lattice::trilinear_stencil;
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn conjugate_gradients_reach_the_tolerance_in_few_iterations() {
        // Surface rows on a shell through a 17 x 15 x 12 lattice, the stiff
        // bending of the fit's first stage: what block-Jacobi took
        // hundreds of iterations for. The solution is checked against the
        // normal equations' true residual, b - A x, not only the one CG's
        // recurrence carries (A's assembly is tested on its own).
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let dims = [17, 15, 12];
        let nodes: usize = dims.iter().product();
        let centre = [8.0, 7.0, 3.0];
        let surface: Vec<SurfaceRow> = (0..6000)
            .map(|_| {
                let n = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(0.0..1.0),
                )
                .normalize();
                let at = std::array::from_fn(|a| centre[a] + 6.0 * n[a]);
                SurfaceRow {
                    stencil: trilinear_stencil(dims, at),
                    normal: n,
                    target: rng.random_range(-2.0..2.0),
                    weight: 1.0 / 6000.0,
                }
            })
            .collect();
        let system = System {
            surface: &surface,
            landmarks: &[],
            dims,
            landmark_weight: 0.0,
            edge_weight: 1e-4 * 1600.0 / (3.0 * nodes as f64 * 100.0),
            bend_weight: 1600.0 * 1600.0 / (3.0 * nodes as f64 * 1e4),
        };
        let (x, report) = system.solve(&vec![Vector3::zeros(); nodes], 1e-10, 200);
        assert!(report.relative_residual <= 1e-10, "{report:?}");
        assert!(report.iterations < 60, "{report:?}");
        // The true residual b - A x, recomputed from the solution.
        let regularisers = Regularisers {
            edge: system.edge_weight,
            bend: system.bend_weight,
        };
        let a = Multigrid::new(dims, &system.terms(), regularisers);
        let ax = a.matrix().apply(&x);
        let b = system.rhs();
        let residual: f64 = b.iter().zip(&ax).map(|(b, a)| (b - a).norm_squared()).sum();
        let norm_b: f64 = b.iter().map(|v| v.norm_squared()).sum();
        assert!((residual / norm_b).sqrt() <= 1e-10);
    }
}
