//! Predicted target registration error (TRE) of a rigid point-based
//! registration: how far a target may land from where it is, given how well
//! the fiducials (markers) were localised. Fitzpatrick, West & Maurer,
//! "Predicting error in rigid-body point-based registration", IEEE TMI
//! 17(5), 1998: for N fiducials with independent, isotropic localisation
//! errors of RMS FLE, to first order
//!
//! <TRE^2(r)> = <FLE^2> / N (1 + 1/3 sum_k d_k^2 / f_k^2),
//!
//! d_k the target's distance from the fiducials' k-th principal axis
//! (through their centroid), f_k the fiducials' RMS distance from it; and
//! the fiducials' own residual after the fit, <FRE^2> = (1 - 2 / N) <FLE^2>,
//! estimates FLE when nothing else does. Beyond the RMS, the error vector's
//! covariance (Fitzpatrick & West, IEEE TMI 20(9), 2001) is, with s^2 =
//! <FLE^2> / 3 per axis and x_i the fiducials about their centroid,
//!
//! C(r) = s^2 / N I + s^2 [r]x A^-1 [r]x^T,  A = sum_i (|x_i|^2 I - x_i x_i^T),
//!
//! (the translation's and the rotation's errors, uncorrelated about the
//! centroid), whose trace is the formula above; its 95 % bound on |TRE|
//! comes from the distribution of a quadratic form in Gaussians, matched by
//! a scaled chi-square (Welch-Satterthwaite) and the Wilson-Hilferty
//! quantile (within 1 % of the exact one for isotropic errors).
//! Written here: no crate predicts TRE.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

/// The fiducials' configuration, as the prediction needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct FiducialConfiguration {
    /// Their centroid, mm.
    pub centroid: Point3<f64>,
    /// How many.
    pub count: usize,
    /// A = sum_i (|x_i|^2 I - x_i x_i^T) about the centroid, mm^2.
    pub inertia_mm2: Matrix3<f64>,
}

impl FiducialConfiguration {
    /// The configuration of `fiducials` (mm); `None` with fewer than 3 or
    /// all on one line (a rotation about it is then undetermined).
    pub fn new(fiducials: &[Point3<f64>]) -> Option<Self> {
        if fiducials.len() < 3 {
            return None;
        }
        let n = fiducials.len() as f64;
        let centroid = Point3::from(fiducials.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n);
        let inertia_mm2 = fiducials
            .iter()
            .map(|p| {
                let x = p - centroid;
                Matrix3::identity() * x.norm_squared() - x * x.transpose()
            })
            .sum::<Matrix3<f64>>();
        let eigen = SymmetricEigen::new(inertia_mm2);
        let largest = eigen.eigenvalues.max();
        if eigen.eigenvalues.min() <= 1e-9 * largest.max(f64::MIN_POSITIVE) {
            return None;
        }
        Some(Self {
            centroid,
            count: fiducials.len(),
            inertia_mm2,
        })
    }

    /// The covariance of the error at `target` (mm^2, in the fiducials'
    /// frame) for an RMS fiducial localisation error `fle_mm` (of the
    /// difference between the two sides' fiducials, isotropic).
    pub fn tre_covariance(&self, target: &Point3<f64>, fle_mm: f64) -> Matrix3<f64> {
        let s2 = fle_mm * fle_mm / 3.0;
        let r = (target - self.centroid).cross_matrix();
        let inverse = self
            .inertia_mm2
            .try_inverse()
            .expect("a configuration holds an invertible inertia");
        Matrix3::identity() * (s2 / self.count as f64) + r * inverse * r.transpose() * s2
    }

    /// Fitzpatrick's 1 + 1/3 sum_k d_k^2 / f_k^2 at `target`: the expected
    /// TRE^2 in units of <FLE^2> / N.
    pub fn tre_factor(&self, target: &Point3<f64>) -> f64 {
        let eigen = SymmetricEigen::new(self.inertia_mm2);
        // The inertia's eigenvectors are the principal axes; its eigenvalue
        // about axis k is sum_i (distance from axis k)^2 = N f_k^2.
        let n = self.count as f64;
        let r = target - self.centroid;
        1.0 + (0..3)
            .map(|k| {
                let axis = eigen.eigenvectors.column(k);
                let along = r.dot(&axis);
                let d2 = r.norm_squared() - along * along;
                d2 / (eigen.eigenvalues[k] / n)
            })
            .sum::<f64>()
            / 3.0
    }

    /// Predicted RMS TRE at `target`, mm, for an RMS FLE `fle_mm`.
    pub fn tre_rms_mm(&self, target: &Point3<f64>, fle_mm: f64) -> f64 {
        (fle_mm * fle_mm / self.count as f64 * self.tre_factor(target)).sqrt()
    }
}

/// The RMS FLE (mm) that a rigid fit's RMS fiducial residual `fre_mm`
/// implies for `count` fiducials: <FLE^2> = <FRE^2> N / (N - 2); `None`
/// with 2 or fewer.
pub fn fle_from_fre(fre_mm: f64, count: usize) -> Option<f64> {
    (count > 2).then(|| fre_mm * (count as f64 / (count as f64 - 2.0)).sqrt())
}

/// The RMS FRE (mm) expected for `count` fiducials of RMS FLE `fle_mm`.
pub fn expected_fre(fle_mm: f64, count: usize) -> f64 {
    fle_mm * (1.0 - 2.0 / count as f64).max(0.0).sqrt()
}

/// The length `p` of the error vectors of covariance `covariance` (mm^2)
/// stay within, mm (zero-mean Gaussian; `p` in (0, 1), e.g. 0.95): |e|^2 is
/// a sum of the eigenvalues times chi-square(1) variables, matched in mean
/// and variance by g chi-square(h) and its quantile taken by
/// Wilson-Hilferty.
pub fn error_bound_mm(covariance: &Matrix3<f64>, p: f64) -> f64 {
    let lambda = SymmetricEigen::new(*covariance)
        .eigenvalues
        .map(|l| l.max(0.0));
    let mean = lambda.sum();
    let variance = 2.0 * lambda.norm_squared();
    if mean <= 0.0 {
        return 0.0;
    }
    let (g, h) = (variance / (2.0 * mean), 2.0 * mean * mean / variance);
    let z = standard_normal_quantile(p);
    let c = 2.0 / (9.0 * h);
    let chi2 = h * (1.0 - c + z * c.sqrt()).max(0.0).powi(3);
    (g * chi2).sqrt()
}

/// The predicted error of a markers-only rigid registration at each target.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerPrediction {
    /// RMS residual of the markers after their rigid fit, mm.
    pub fre_mm: f64,
    /// The RMS localisation error that residual implies, mm.
    pub fle_mm: f64,
    /// Per target: predicted RMS TRE and its 95 % bound, mm.
    pub targets: Vec<(f64, f64)>,
}

/// Predicts the TRE at `targets` (mm, in the frame of `markers`) of the
/// rigid registration of `markers` onto `matched` (the same markers seen in
/// the other frame, same order), with FLE estimated from the fit's own
/// residual; `None` with fewer than 4 markers (3 fit exactly and say
/// nothing of FLE) or all on one line.
pub fn predict_marker_tre(
    markers: &[Point3<f64>],
    matched: &[Point3<f64>],
    targets: &[Point3<f64>],
) -> Option<MarkerPrediction> {
    if markers.len() < 4 || markers.len() != matched.len() {
        return None;
    }
    let config = FiducialConfiguration::new(markers)?;
    let fit = super::umeyama(markers, matched, None, false)?;
    let fre_mm = fit.rmse(markers, matched);
    let fle_mm = fle_from_fre(fre_mm, markers.len())?;
    Some(MarkerPrediction {
        fre_mm,
        fle_mm,
        targets: targets
            .iter()
            .map(|t| {
                (
                    config.tre_rms_mm(t, fle_mm),
                    error_bound_mm(&config.tre_covariance(t, fle_mm), 0.95),
                )
            })
            .collect(),
    })
}

/// The standard normal's quantile (Acklam's rational approximation,
/// relative error below 1.2e-9).
fn standard_normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::register::umeyama;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn fitzpatricks_formula_on_a_hand_computed_cross() {
        // Four fiducials at (+-50, 0, 0) and (0, +-50, 0): principal axes x,
        // y, z with f_x^2 = f_y^2 = 50^2 / 2 and f_z^2 = 50^2. A target 100
        // mm above the centre lies 100 mm from the x and y axes and on z:
        // factor 1 + (10^4 / 1250 + 10^4 / 1250) / 3 = 1 + 16 / 3.
        let a = 50.0;
        let cross = [
            Point3::new(a, 0.0, 0.0),
            Point3::new(-a, 0.0, 0.0),
            Point3::new(0.0, a, 0.0),
            Point3::new(0.0, -a, 0.0),
        ];
        let c = FiducialConfiguration::new(&cross).unwrap();
        let target = Point3::new(0.0, 0.0, 100.0);
        assert!((c.tre_factor(&target) - (1.0 + 16.0 / 3.0)).abs() < 1e-12);
        // FLE 1 mm: TRE^2 = 1 / 4 * 19 / 3.
        let expected = (19.0f64 / 12.0).sqrt();
        assert!((c.tre_rms_mm(&target, 1.0) - expected).abs() < 1e-12);
        // The covariance's trace is the same.
        let trace = c.tre_covariance(&target, 1.0).trace();
        assert!((trace - expected * expected).abs() < 1e-12, "{trace}");
        // At the centroid only the translation's error is left: FLE^2 / N.
        assert!((c.tre_rms_mm(&Point3::origin(), 1.0) - 0.5).abs() < 1e-12);
        // Collinear fiducials pin no rotation about their line.
        let line = [cross[0], cross[1], Point3::new(10.0, 0.0, 0.0)];
        assert!(FiducialConfiguration::new(&line).is_none());
    }

    #[test]
    fn fre_and_fle_convert_both_ways() {
        assert!((fle_from_fre(expected_fre(1.3, 12), 12).unwrap() - 1.3).abs() < 1e-12);
        assert_eq!(fle_from_fre(1.0, 2), None);
    }

    #[test]
    fn the_bound_is_the_chi_square_quantile_for_isotropic_errors() {
        // |e|^2 / s^2 ~ chi-square(3): its 95 % quantile is 7.8147.
        let bound = error_bound_mm(&Matrix3::identity(), 0.95);
        assert!((bound * bound - 7.8147).abs() < 0.05, "{}", bound * bound);
        // One axis only: chi-square(1), 95 % at 1.96^2.
        let one = error_bound_mm(&Matrix3::from_diagonal(&Vector3::new(1.0, 0.0, 0.0)), 0.95);
        assert!((one - 1.96).abs() < 0.05, "{one}");
    }

    /// 2,000 rigid registrations of six fiducials under isotropic noise
    /// (Procrustes, as register.procrustes fits): the observed mean TRE^2 at
    /// three targets, the FRE and the 95 % bound's coverage match the
    /// predictions.
    #[test]
    fn the_prediction_matches_a_monte_carlo_of_procrustes() {
        let fiducials = [
            Point3::new(40.0, 10.0, 5.0),
            Point3::new(-35.0, 20.0, 0.0),
            Point3::new(5.0, -45.0, 10.0),
            Point3::new(-10.0, 30.0, 35.0),
            Point3::new(25.0, -20.0, 40.0),
            Point3::new(-30.0, -25.0, 25.0),
        ];
        let targets = [
            Point3::new(0.0, 0.0, 20.0),
            Point3::new(60.0, 0.0, -40.0),
            Point3::new(-20.0, 80.0, 60.0),
        ];
        let fle = 1.2;
        let noise = Normal::new(0.0, fle / 3f64.sqrt()).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let config = FiducialConfiguration::new(&fiducials).unwrap();
        let draws = 2000;
        let (mut tre2, mut inside, mut fre2) = ([0.0; 3], [0usize; 3], 0.0);
        for _ in 0..draws {
            let measured: Vec<Point3<f64>> = fiducials
                .iter()
                .map(|p| {
                    p + Vector3::new(
                        noise.sample(&mut rng),
                        noise.sample(&mut rng),
                        noise.sample(&mut rng),
                    )
                })
                .collect();
            let fit = umeyama(&measured, &fiducials, None, false).unwrap();
            fre2 += fit.rmse(&measured, &fiducials).powi(2);
            for (k, t) in targets.iter().enumerate() {
                let e = (fit.apply(t) - t).norm();
                tre2[k] += e * e;
                let bound = error_bound_mm(&config.tre_covariance(t, fle), 0.95);
                inside[k] += usize::from(e <= bound);
            }
        }
        let fre = (fre2 / draws as f64).sqrt();
        let expected = expected_fre(fle, fiducials.len());
        assert!(
            (fre - expected).abs() < 0.05 * expected,
            "FRE {fre} against {expected}"
        );
        for (k, t) in targets.iter().enumerate() {
            let observed = (tre2[k] / draws as f64).sqrt();
            let predicted = config.tre_rms_mm(t, fle);
            assert!(
                (observed - predicted).abs() < 0.05 * predicted,
                "target {k}: RMS TRE {observed:.3} mm, predicted {predicted:.3}"
            );
            let coverage = inside[k] as f64 / draws as f64;
            assert!(
                (0.93..=0.97).contains(&coverage),
                "target {k}: {coverage} inside the 95 % bound"
            );
        }
    }
}
