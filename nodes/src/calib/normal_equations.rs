//! Gauss-Newton normal equations J^T J x = -J^T r for Levenberg-Marquardt: a
//! dense form, and the block form of calibration problems, solved through the
//! Schur complement. In calibration every residual depends on parameters all
//! views share (intrinsics, the rig) and on its own view's pose (6) only, so
//! J^T J is an arrow: a small shared block U, one 6 x 6 block V_i per view on
//! the diagonal and couplings W_i between them. Eliminating the poses leaves
//! S = U - sum W_i^T V_i^-1 W_i, as small as the shared parameters, whatever
//! the number of views (Triggs et al., "Bundle Adjustment: A Modern
//! Synthesis", 2000, section 6.1).

use nalgebra::{DMatrix, DVector, Matrix6, Vector6};

/// Normal equations that can be solved with Marquardt's damping: the diagonal
/// of J^T J scaled by 1 + lambda.
pub trait DampedSystem {
    /// The step solving (J^T J + lambda diag(J^T J)) step = -J^T r, or `None`
    /// when the damped matrix is not positive definite.
    fn solve_damped(&self, lambda: f64) -> Option<DVector<f64>>;
    /// The diagonal of J^T J, in the solver vector's order.
    fn diagonal(&self) -> DVector<f64>;
}

/// The floor of a damped diagonal entry, so that a parameter the residuals do
/// not (yet) depend on still gets a finite step.
const DIAGONAL_FLOOR: f64 = 1e-12;

/// Dense normal equations.
#[derive(Debug, Clone)]
pub struct DenseNormal {
    /// J^T J.
    pub jtj: DMatrix<f64>,
    /// J^T r.
    pub jtr: DVector<f64>,
}

impl DenseNormal {
    /// From a Jacobian and the residuals.
    pub fn new(jacobian: &DMatrix<f64>, residuals: &DVector<f64>) -> Self {
        Self {
            jtj: jacobian.tr_mul(jacobian),
            jtr: jacobian.tr_mul(residuals),
        }
    }
}

impl DampedSystem for DenseNormal {
    fn solve_damped(&self, lambda: f64) -> Option<DVector<f64>> {
        let mut a = self.jtj.clone();
        for i in 0..a.nrows() {
            a[(i, i)] += lambda * self.jtj[(i, i)].max(DIAGONAL_FLOOR);
        }
        Some(a.cholesky()?.solve(&(-&self.jtr)))
    }

    fn diagonal(&self) -> DVector<f64> {
        self.jtj.diagonal()
    }
}

/// One view's part of block normal equations.
#[derive(Debug, Clone)]
struct ViewBlock {
    /// V_i: J_pose^T J_pose.
    v: Matrix6<f64>,
    /// W_i: J_pose^T J_shared (6 x shared).
    w: DMatrix<f64>,
    /// J_pose^T r.
    g: Vector6<f64>,
}

/// Block normal equations over `shared` parameters followed by 6 per view
/// (the solver vector's order).
#[derive(Debug, Clone)]
pub struct BlockNormal {
    /// U: J_shared^T J_shared.
    u: DMatrix<f64>,
    /// J_shared^T r.
    g: DVector<f64>,
    views: Vec<ViewBlock>,
}

impl BlockNormal {
    /// Empty equations for `shared` parameters and `views` poses.
    pub fn new(shared: usize, views: usize) -> Self {
        Self {
            u: DMatrix::zeros(shared, shared),
            g: DVector::zeros(shared),
            views: vec![
                ViewBlock {
                    v: Matrix6::zeros(),
                    w: DMatrix::zeros(6, shared),
                    g: Vector6::zeros(),
                };
                views
            ],
        }
    }

    /// Adds one residual `r` of view `view`, whose derivatives are `d_shared`
    /// (one per shared parameter) and `d_pose` (its view's pose).
    pub fn add(&mut self, view: usize, d_shared: &[f64], d_pose: &Vector6<f64>, r: f64) {
        let n = self.g.len();
        debug_assert_eq!(d_shared.len(), n);
        let block = &mut self.views[view];
        block.v += d_pose * d_pose.transpose();
        block.g += d_pose * r;
        // Shared derivatives are mostly zero in stereo (each camera's rows
        // miss the other's intrinsics): skip those columns.
        for (j, &dj) in d_shared.iter().enumerate() {
            if dj == 0.0 {
                continue;
            }
            self.g[j] += dj * r;
            for (i, &di) in d_shared.iter().enumerate().take(j + 1) {
                self.u[(i, j)] += di * dj;
            }
            for k in 0..6 {
                block.w[(k, j)] += d_pose[k] * dj;
            }
        }
    }

    /// Mirrors U's upper triangle (what [`add`](Self::add) fills) into the lower.
    fn symmetric_u(&self) -> DMatrix<f64> {
        let mut u = self.u.clone();
        for j in 0..u.ncols() {
            for i in 0..j {
                u[(j, i)] = u[(i, j)];
            }
        }
        u
    }
}

impl BlockNormal {
    /// The shared parameters' part of (J^T J)^-1: the inverse of the
    /// undamped Schur complement S = U - sum W_i^T V_i^-1 W_i, which at a
    /// least-squares optimum, times the residuals' variance, is those
    /// parameters' covariance with the poses marginalised out. `None` when
    /// J^T J is singular (a parameter the residuals do not determine).
    pub fn shared_inverse(&self) -> Option<DMatrix<f64>> {
        let (s, _, _) = self.schur(0.0)?;
        s.cholesky().map(|c| c.inverse())
    }

    /// The Schur complement of the damped system, its right-hand side, and
    /// per view V_i^-1 W_i and V_i^-1 g_i for the back-substitution.
    #[allow(clippy::type_complexity)]
    fn schur(
        &self,
        lambda: f64,
    ) -> Option<(
        DMatrix<f64>,
        DVector<f64>,
        Vec<(DMatrix<f64>, Vector6<f64>)>,
    )> {
        let n = self.g.len();
        let mut s = self.symmetric_u();
        for i in 0..n {
            s[(i, i)] += lambda * self.u[(i, i)].max(DIAGONAL_FLOOR);
        }
        let mut rhs = -&self.g;
        let mut eliminated = Vec::with_capacity(self.views.len());
        for block in &self.views {
            let mut v = block.v;
            for i in 0..6 {
                v[(i, i)] += lambda * block.v[(i, i)].max(DIAGONAL_FLOOR);
            }
            let v = v.cholesky()?;
            let vinv_w = v.solve(&block.w);
            let vinv_g = v.solve(&block.g);
            s -= block.w.tr_mul(&vinv_w);
            rhs += block.w.tr_mul(&vinv_g);
            eliminated.push((vinv_w, vinv_g));
        }
        Some((s, rhs, eliminated))
    }
}

impl DampedSystem for BlockNormal {
    fn solve_damped(&self, lambda: f64) -> Option<DVector<f64>> {
        let n = self.g.len();
        let (s, rhs, eliminated) = self.schur(lambda)?;
        let shared_step = s.cholesky()?.solve(&rhs);
        let mut step = DVector::zeros(n + 6 * self.views.len());
        step.rows_mut(0, n).copy_from(&shared_step);
        for (i, (vinv_w, vinv_g)) in eliminated.iter().enumerate() {
            let pose_step = -vinv_g - vinv_w * &shared_step;
            step.rows_mut(n + 6 * i, 6).copy_from(&pose_step);
        }
        Some(step)
    }

    fn diagonal(&self) -> DVector<f64> {
        let poses = self.views.iter().flat_map(|b| (0..6).map(|i| b.v[(i, i)]));
        DVector::from_iterator(
            self.g.len() + 6 * self.views.len(),
            self.u.diagonal().iter().copied().chain(poses),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A random arrow-shaped Jacobian: 3 shared parameters, 4 views of 9
    /// residuals each.
    fn arrow() -> (DMatrix<f64>, DVector<f64>, BlockNormal) {
        let (shared, views, rows) = (3, 4, 9);
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let n = shared + 6 * views;
        let mut j = DMatrix::zeros(views * rows, n);
        let mut r = DVector::zeros(views * rows);
        let mut block = BlockNormal::new(shared, views);
        for v in 0..views {
            for k in 0..rows {
                let row = v * rows + k;
                // One shared derivative left at zero, as stereo has.
                let d_shared: Vec<f64> = (0..shared)
                    .map(|i| if i == (row % shared) { 0.0 } else { next() })
                    .collect();
                let d_pose = Vector6::from_fn(|_, _| next());
                r[row] = next();
                for (i, d) in d_shared.iter().enumerate() {
                    j[(row, i)] = *d;
                }
                for i in 0..6 {
                    j[(row, shared + 6 * v + i)] = d_pose[i];
                }
                block.add(v, &d_shared, &d_pose, r[row]);
            }
        }
        (j, r, block)
    }

    #[test]
    fn the_schur_complement_solves_the_dense_system() {
        let (j, r, block) = arrow();
        let dense = DenseNormal::new(&j, &r);
        for lambda in [0.0, 1e-3, 10.0] {
            let a = dense.solve_damped(lambda).unwrap();
            let b = block.solve_damped(lambda).unwrap();
            assert!(
                (&a - &b).norm() <= 1e-10 * a.norm(),
                "lambda {lambda}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn the_shared_inverse_is_the_shared_block_of_the_dense_inverse() {
        let (j, r, block) = arrow();
        let dense = DenseNormal::new(&j, &r).jtj.try_inverse().unwrap();
        let shared = block.shared_inverse().unwrap();
        let expected = dense.view((0, 0), (3, 3)).clone_owned();
        assert!(
            (&shared - &expected).norm() <= 1e-9 * expected.norm(),
            "{shared} vs {expected}"
        );
    }
}
