//! Levenberg-Marquardt for nonlinear least squares, with Marquardt's diagonal
//! scaling. Written here (not the levenberg-marquardt crate): that crate pins
//! nalgebra 0.34 while the workspace uses 0.35, and calibration problems supply
//! their own block-structured normal equations anyway (`normal_equations.rs`).

use super::normal_equations::DampedSystem;
use nalgebra::DVector;

/// A problem: minimise the sum of squared residuals over `x`.
pub trait LeastSquares {
    /// The Gauss-Newton normal equations' form.
    type Normal: DampedSystem;
    /// Residuals at `x`.
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64>;
    /// J^T J and J^T r at `x`, where the residuals are `r` (J: rows residuals,
    /// columns parameters).
    fn normal_equations(&self, x: &DVector<f64>, r: &DVector<f64>) -> Self::Normal;
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
    /// Whether it stopped on the step tolerance, or because no step lowered
    /// the cost any more (rounding level), rather than on `max_iterations`.
    pub converged: bool,
}

/// A relative change of the cost within its rounding (a sum of thousands of
/// squares).
const COST_ROUNDING: f64 = 1e-11;

/// Minimises from `x0`. Steps are measured scaled by the root of J^T J's
/// diagonal, relative to `x` so scaled (MINPACK's measure: it weighs every
/// parameter by how much it moves the residuals, so that fx in px and a
/// rotation in rad compare). It stops at the minimum once a step below
/// `step_tolerance` no longer shrinks to less than half the one before, or
/// raises the cost beyond rounding; when no damping makes a step lower the
/// cost; or after `max_iterations`.
///
/// Near a minimum Gauss-Newton steps shrink by orders of magnitude per
/// iteration until rounding stops them, long after the cost's change has
/// fallen below its own rounding (weakly determined parameters, such as the
/// tangential distortion, settle last). Stopping where the steps stop
/// shrinking leaves every parameter at the minimiser to near machine
/// precision, which a test on the cost's decrease cannot.
pub fn levenberg_marquardt(
    problem: &impl LeastSquares,
    x0: DVector<f64>,
    max_iterations: usize,
    step_tolerance: f64,
) -> LmReport {
    let mut x = x0;
    let mut r = problem.residuals(&x);
    let mut cost = r.norm_squared();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = false;
    let mut last_step = f64::INFINITY;
    while iterations < max_iterations && !converged {
        iterations += 1;
        let normal = problem.normal_equations(&x, &r);
        let scale = normal.diagonal().map(f64::sqrt);
        let scaled_x = x.component_mul(&scale).norm().max(f64::MIN_POSITIVE);
        let mut accepted = false;
        for _ in 0..30 {
            let Some(step) = normal.solve_damped(lambda) else {
                lambda *= 10.0;
                continue;
            };
            let size = step.component_mul(&scale).norm() / scaled_x;
            let small = size <= step_tolerance;
            let candidate = &x + &step;
            let r_new = problem.residuals(&candidate);
            let new_cost = r_new.norm_squared();
            // Below the tolerance a step is Gauss-Newton's own and the cost's
            // change is within its rounding: take it unless the cost rose.
            let lower = new_cost < cost || (small && new_cost <= cost * (1.0 + COST_ROUNDING));
            if new_cost.is_finite() && lower {
                x = candidate;
                r = r_new;
                cost = new_cost;
                lambda = (lambda * 0.3).max(1e-12);
                accepted = true;
                converged = size == 0.0 || (small && size > 0.5 * last_step);
                last_step = size;
                break;
            }
            // A small step that raises the cost: nothing left to gain.
            if small {
                converged = true;
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            converged = true;
        }
    }
    LmReport {
        x,
        cost,
        iterations,
        converged,
    }
}

/// `problem` with its normal equations from a dense Jacobian of central
/// differences (step 1e-6 of each parameter, at least 1e-8): the reference
/// the analytic, block-structured ones are tested against.
#[cfg(test)]
pub(crate) struct CentralDifferences<'a, P>(pub &'a P);

#[cfg(test)]
impl<P: LeastSquares> LeastSquares for CentralDifferences<'_, P> {
    type Normal = super::normal_equations::DenseNormal;

    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        self.0.residuals(x)
    }

    fn normal_equations(&self, x: &DVector<f64>, r: &DVector<f64>) -> Self::Normal {
        let mut j = nalgebra::DMatrix::zeros(r.len(), x.len());
        for c in 0..x.len() {
            let h = 1e-6 * x[c].abs().max(1e-2);
            let (mut plus, mut minus) = (x.clone(), x.clone());
            plus[c] += h;
            minus[c] -= h;
            let d = (self.0.residuals(&plus) - self.0.residuals(&minus)) / (2.0 * h);
            j.set_column(c, &d);
        }
        super::normal_equations::DenseNormal::new(&j, r)
    }
}

/// The largest difference between two solver vectors, relative to each
/// component's magnitude, or to `floor` for smaller ones (where a relative
/// difference says nothing: a rotation of 1e-8 rad).
#[cfg(test)]
pub(crate) fn max_relative_difference(a: &DVector<f64>, b: &DVector<f64>, floor: f64) -> f64 {
    a.iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs() / x.abs().max(floor))
        .fold(0.0, f64::max)
}

/// Checks `problem`'s normal equations at `x` against [`CentralDifferences`]:
/// J^T J's diagonal and a damped step agree to `tolerance` relative.
#[cfg(test)]
pub(crate) fn assert_normal_equations_match<P: LeastSquares>(
    problem: &P,
    x: &DVector<f64>,
    tolerance: f64,
) {
    let r = problem.residuals(x);
    let ours = problem.normal_equations(x, &r);
    let reference = CentralDifferences(problem).normal_equations(x, &r);
    let (d, d_ref) = (ours.diagonal(), reference.diagonal());
    let diagonal = max_relative_difference(&d_ref, &d, 1e-300);
    assert!(
        diagonal < tolerance,
        "J^T J diagonal: {diagonal:e} relative"
    );
    let (s, s_ref) = (
        ours.solve_damped(1.0).expect("positive definite"),
        reference.solve_damped(1.0).expect("positive definite"),
    );
    // Damped enough to be well conditioned: the step then reflects J^T r and
    // J^T J themselves rather than the problem's conditioning.
    let step = (&s - &s_ref).norm() / s_ref.norm();
    assert!(step < tolerance, "damped step: {step:e} relative");
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::normal_equations::DenseNormal;
    use nalgebra::DMatrix;

    /// Rosenbrock as least squares: r = (10 (y - x^2), 1 - x).
    struct Rosenbrock;

    impl LeastSquares for Rosenbrock {
        type Normal = DenseNormal;
        fn residuals(&self, p: &DVector<f64>) -> DVector<f64> {
            DVector::from_vec(vec![10.0 * (p[1] - p[0] * p[0]), 1.0 - p[0]])
        }
        fn normal_equations(&self, p: &DVector<f64>, r: &DVector<f64>) -> DenseNormal {
            DenseNormal::new(
                &DMatrix::from_row_slice(2, 2, &[-20.0 * p[0], 10.0, -1.0, 0.0]),
                r,
            )
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
