//! How well a calibration pins its parameters: at a least-squares optimum
//! the estimate's covariance is, to first order, sigma^2 (J^T J)^-1, sigma^2
//! the residuals' variance (the corners' localisation noise, assumed
//! independent and alike in x and y), estimated from the residuals
//! themselves with the parameters' degrees of freedom taken off.
//!
//! OpenCV 5's `calibrateCameraExtended` computes the same (on the 15 real
//! photos of `chessboard_mono`, the same standard deviations to 4 digits);
//! OpenCV 4's divided the sum of squares by (points - parameters), a point
//! being two residuals, so its standard deviations were about sqrt(2) too
//! large.

use super::lm::{LeastSquares, LmReport};
use super::normal_equations::BlockNormal;
use nalgebra::{DMatrix, Matrix3};

/// The residuals' variance (px^2) from their sum of squares `cost` over
/// `residuals` values (two per corner) and `parameters` estimated: unbiased,
/// cost / (residuals - parameters); `None` when there are no more residuals
/// than parameters.
pub fn residual_variance(cost: f64, residuals: usize, parameters: usize) -> Option<f64> {
    (residuals > parameters).then(|| cost / (residuals - parameters) as f64)
}

/// What a least-squares fit knows of its parameters' spread: the shared
/// parameters' block of (J^T J)^-1 at the optimum (the per-view poses
/// marginalised out), and the residuals it was fitted to.
#[derive(Debug, Clone)]
pub struct Spread {
    /// (J^T J)^-1's block of the shared parameters, per px^2 of residual
    /// variance.
    pub unit_covariance: DMatrix<f64>,
    /// Sum of squared residuals, px^2.
    pub cost: f64,
    /// How many residuals (two per corner).
    pub residuals: usize,
    /// How many parameters were estimated (shared and per view).
    pub parameters: usize,
}

impl Spread {
    /// The spread of `problem`'s shared parameters at its optimum `report`
    /// (the normal equations taken again there); `None` when J^T J is
    /// singular at it.
    pub(crate) fn at_optimum<P: LeastSquares<Normal = BlockNormal>>(
        problem: &P,
        report: &LmReport,
    ) -> Option<Spread> {
        let residuals = problem.residuals(&report.x);
        let unit_covariance = problem
            .normal_equations(&report.x, &residuals)
            .shared_inverse()?;
        Some(Spread {
            unit_covariance,
            cost: report.cost,
            residuals: residuals.len(),
            parameters: report.x.len(),
        })
    }

    /// The shared parameters' covariance; `None` without spare residuals.
    pub fn covariance(&self) -> Option<DMatrix<f64>> {
        residual_variance(self.cost, self.residuals, self.parameters)
            .map(|v| &self.unit_covariance * v)
    }
}

/// Standard deviation of each intrinsic in solver order (fx, fy, cx, cy in
/// px, then k1, k2, p1, p2, k3): `estimated` (solver-order indices) are the
/// spread's parameters from `offset` on; 0 for one held fixed, NaN without
/// a spread or spare residuals.
pub fn intrinsics_sd(spread: Option<&Spread>, estimated: &[usize], offset: usize) -> [f64; 9] {
    let mut sd = [0.0; 9];
    let covariance = spread.and_then(Spread::covariance);
    for (k, &i) in estimated.iter().enumerate() {
        let j = offset + k;
        sd[i] = covariance
            .as_ref()
            .map_or(f64::NAN, |c| c[(j, j)].max(0.0).sqrt());
    }
    sd
}

/// The 3 x 3 block of `covariance` at `offset`.
pub fn block3(covariance: &DMatrix<f64>, offset: usize) -> Matrix3<f64> {
    covariance.fixed_view::<3, 3>(offset, offset).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DVector, Vector2};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A line y = a + b x fitted to noisy samples: the covariance from
    /// sigma^2 (J^T J)^-1 with sigma^2 from the residuals matches the spread
    /// of 2,000 fits (Monte Carlo), for intercept, slope and their
    /// correlation.
    #[test]
    fn a_line_fits_covariance_matches_its_monte_carlo_spread() {
        let xs: Vec<f64> = (0..12).map(|i| i as f64 * 0.5 - 2.0).collect();
        let (a, b, sigma) = (1.5, -0.7, 0.3);
        let jacobian = DMatrix::from_fn(xs.len(), 2, |r, c| if c == 0 { 1.0 } else { xs[r] });
        let jtj_inverse = jacobian.tr_mul(&jacobian).try_inverse().unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, sigma).unwrap();
        let draws = 2000;
        let mut estimates = Vec::with_capacity(draws);
        let mut predicted = DMatrix::zeros(2, 2);
        for _ in 0..draws {
            let y = DVector::from_iterator(
                xs.len(),
                xs.iter().map(|x| a + b * x + noise.sample(&mut rng)),
            );
            let fit = &jtj_inverse * jacobian.tr_mul(&y);
            let cost = (&jacobian * &fit - &y).norm_squared();
            let variance = residual_variance(cost, xs.len(), 2).unwrap();
            predicted += &jtj_inverse * variance;
            estimates.push(Vector2::new(fit[0], fit[1]));
        }
        predicted /= draws as f64;
        let mean = estimates.iter().sum::<Vector2<f64>>() / draws as f64;
        let observed = estimates
            .iter()
            .map(|e| (e - mean) * (e - mean).transpose())
            .sum::<nalgebra::Matrix2<f64>>()
            / (draws - 1) as f64;
        for (r, c) in [(0, 0), (1, 1), (0, 1)] {
            let (p, o) = (predicted[(r, c)], observed[(r, c)]);
            // 2,000 draws estimate a variance to about 3 % (sd sqrt(2 / n)).
            assert!(
                (p - o).abs()
                    <= 0.1
                        * p.abs()
                            .max(predicted[(r, r)].sqrt() * predicted[(c, c)].sqrt()),
                "({r}, {c}): predicted {p:.3e}, observed {o:.3e}"
            );
        }
        // With the true sigma, the same: the estimate of sigma^2 is unbiased.
        let with_truth = &jtj_inverse * (sigma * sigma);
        assert!((with_truth[(1, 1)] - observed[(1, 1)]).abs() <= 0.1 * with_truth[(1, 1)]);
    }
}
