//! Levenberg-Marquardt for nonlinear least squares, with Marquardt's diagonal
//! scaling. Written here (not the levenberg-marquardt crate): that crate pins
//! nalgebra 0.34 while the workspace uses 0.35, and calibration problems supply
//! their own block-structured Jacobians anyway.

use nalgebra::{DMatrix, DVector};

/// A problem: minimise the sum of squared residuals over `x`.
pub trait LeastSquares {
    /// Residuals at `x`.
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64>;
    /// Jacobian of the residuals at `x` (rows: residuals, columns: parameters).
    fn jacobian(&self, x: &DVector<f64>) -> DMatrix<f64>;
}

/// The outcome of a minimisation.
#[derive(Debug, Clone)]
pub struct LmReport {
    /// The minimiser.
    pub x: DVector<f64>,
    /// Sum of squared residuals at `x`.
    pub cost: f64,
    /// Iterations taken.
    pub iterations: usize,
    /// Whether the relative decrease fell below the tolerance.
    pub converged: bool,
}

/// Minimises from `x0`; stops when an accepted step lowers the cost by less than
/// `tolerance` relative, or after `max_iterations`.
pub fn levenberg_marquardt(
    problem: &impl LeastSquares,
    x0: DVector<f64>,
    max_iterations: usize,
    tolerance: f64,
) -> LmReport {
    let mut x = x0;
    let mut r = problem.residuals(&x);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = false;
    while iterations < max_iterations {
        iterations += 1;
        let j = problem.jacobian(&x);
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let mut accepted = false;
        for _ in 0..30 {
            let mut a = jtj.clone();
            for i in 0..a.nrows() {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-&g))) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = &x + &step;
            let r_new = problem.residuals(&candidate);
            let new_cost = r_new.norm_squared();
            if new_cost.is_finite() && new_cost < cost {
                let decrease = (cost - new_cost) / cost.max(1e-300);
                x = candidate;
                r = r_new;
                cost = new_cost;
                lambda = (lambda * 0.3).max(1e-12);
                accepted = true;
                if decrease < tolerance {
                    converged = true;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !accepted || converged {
            converged = converged || !accepted;
            break;
        }
    }
    LmReport {
        x,
        cost,
        iterations,
        converged,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = (10 (y - x^2), 1 - x).
    struct Rosenbrock;

    impl LeastSquares for Rosenbrock {
        fn residuals(&self, p: &DVector<f64>) -> DVector<f64> {
            DVector::from_vec(vec![10.0 * (p[1] - p[0] * p[0]), 1.0 - p[0]])
        }
        fn jacobian(&self, p: &DVector<f64>) -> DMatrix<f64> {
            DMatrix::from_row_slice(2, 2, &[-20.0 * p[0], 10.0, -1.0, 0.0])
        }
    }

    #[test]
    fn finds_the_rosenbrock_minimum() {
        let report =
            levenberg_marquardt(&Rosenbrock, DVector::from_vec(vec![-1.2, 1.0]), 200, 1e-15);
        assert!(
            (report.x[0] - 1.0).abs() < 1e-6 && (report.x[1] - 1.0).abs() < 1e-6,
            "{:?}",
            report.x
        );
        assert!(report.cost < 1e-12);
    }
}
