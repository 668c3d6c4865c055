//! A disparity map against a ground-truth one, with the figures Middlebury and
//! `shared/bench/peers.py sgbm` report: bad-N (error above N px, invalid
//! estimates counted as bad), coverage, and the errors of valid estimates.

/// How an estimated disparity map compares to the truth, over the evaluated
/// pixels: those where the truth is known (finite and not 0: Middlebury files
/// mark unknown pixels 0 or inf; negative disparities of verged rigs count) and
/// the mask, if any, is set.
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityErrors {
    /// Pixels evaluated.
    pub evaluated: usize,
    /// Evaluated pixels with a valid (finite) estimate.
    pub valid: usize,
    /// For each threshold t (px), the % of evaluated pixels whose estimate is
    /// invalid or off by more than t.
    pub bad_pct: Vec<f64>,
    /// Mean absolute error over valid estimates, px (NaN if none).
    pub mae_px: f64,
    /// Mean signed error (estimate - truth) over valid estimates, px (NaN if
    /// none): the map's bias, which moves a surface along the line of sight.
    pub mean_signed_px: f64,
    /// Median signed error over valid estimates, px (NaN if none): the bias
    /// of the bulk of the map, blind to mismatches.
    pub median_signed_px: f64,
    /// Root mean square error over valid estimates, px (NaN if none).
    pub rmse_px: f64,
    /// Valid estimates among evaluated pixels, %.
    pub coverage_pct: f64,
}

/// Compares `estimate` to `truth` (same length, px, NaN or infinite = no
/// estimate) at the pixels where `mask` (if given) is true.
pub fn disparity_errors(
    estimate: &[f32],
    truth: &[f32],
    mask: Option<&[bool]>,
    thresholds_px: &[f64],
) -> Result<DisparityErrors, String> {
    if estimate.len() != truth.len() {
        return Err(format!(
            "the estimate has {} pixels but the truth {}",
            estimate.len(),
            truth.len()
        ));
    }
    if let Some(m) = mask
        && m.len() != truth.len()
    {
        return Err(format!(
            "the mask has {} pixels but the truth {}",
            m.len(),
            truth.len()
        ));
    }
    let (mut evaluated, mut valid) = (0usize, 0usize);
    let mut bad = vec![0usize; thresholds_px.len()];
    let (mut sum_signed, mut sum_abs, mut sum_sq) = (0.0f64, 0.0f64, 0.0f64);
    let mut signed_errors = Vec::new();
    for (i, (&d, &t)) in estimate.iter().zip(truth).enumerate() {
        if !(t.is_finite() && t != 0.0) || mask.is_some_and(|m| !m[i]) {
            continue;
        }
        evaluated += 1;
        if !d.is_finite() {
            bad.iter_mut().for_each(|b| *b += 1);
            continue;
        }
        valid += 1;
        let signed = d as f64 - t as f64;
        let e = signed.abs();
        sum_signed += signed;
        signed_errors.push(signed);
        sum_abs += e;
        sum_sq += e * e;
        for (b, &th) in bad.iter_mut().zip(thresholds_px) {
            if e > th {
                *b += 1;
            }
        }
    }
    let pct = |n: usize| 100.0 * n as f64 / evaluated as f64;
    signed_errors.sort_by(f64::total_cmp);
    let median_signed_px = signed_errors
        .get(signed_errors.len() / 2)
        .copied()
        .unwrap_or(f64::NAN);
    Ok(DisparityErrors {
        evaluated,
        valid,
        bad_pct: bad.into_iter().map(pct).collect(),
        mae_px: sum_abs / valid as f64,
        mean_signed_px: sum_signed / valid as f64,
        median_signed_px,
        rmse_px: (sum_sq / valid as f64).sqrt(),
        coverage_pct: pct(valid),
    })
}

/// The metric name of threshold `t_px`: `bad_2_pct`, `bad_0_5_pct`.
pub fn bad_metric_name(t_px: f64) -> String {
    format!("bad_{}_pct", format!("{t_px}").replace(['.', '-'], "_"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_figures() {
        let nan = f32::NAN;
        // Truth unknown at 0 (zero), 1 (NaN), 2 (inf): left out.
        let truth = [0.0, nan, f32::INFINITY, 10.0, 10.0, 10.0, 10.0, 20.0, 30.0];
        let est = [5.0, 5.0, 5.0, 10.25, 11.5, 13.0, nan, 20.0, 24.0];
        let e = disparity_errors(&est, &truth, None, &[0.5, 1.0, 2.0, 4.0]).unwrap();
        assert_eq!((e.evaluated, e.valid), (6, 5));
        // Errors of valid estimates: 0.25, 1.5, 3, 0, 6; plus one invalid.
        // > 0.5: 1.5, 3, 6 + invalid = 4 of 6; > 1: same 4; > 2: 3, 6 + invalid = 3;
        // > 4: 6 + invalid = 2.
        let expected = [4.0, 4.0, 3.0, 2.0].map(|n| 100.0 * n / 6.0);
        for (a, b) in e.bad_pct.iter().zip(expected) {
            assert!((a - b).abs() < 1e-12, "{:?} vs {expected:?}", e.bad_pct);
        }
        assert!((e.mae_px - 10.75 / 5.0).abs() < 1e-12);
        // Signed: 0.25 + 1.5 + 3 + 0 - 6.
        assert!((e.mean_signed_px - (-1.25 / 5.0)).abs() < 1e-12);
        // Sorted: -6, 0, 0.25, 1.5, 3.
        assert_eq!(e.median_signed_px, 0.25);
        let ms = (0.0625 + 2.25 + 9.0 + 0.0 + 36.0) / 5.0;
        assert!((e.rmse_px - f64::sqrt(ms)).abs() < 1e-12);
        assert!((e.coverage_pct - 100.0 * 5.0 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn mask_restricts_and_sizes_must_agree() {
        let truth = [1.0, 2.0, 3.0];
        let est = [1.0, f32::NAN, 6.0];
        let e = disparity_errors(&est, &truth, Some(&[true, false, false]), &[1.0]).unwrap();
        assert_eq!((e.evaluated, e.valid, e.bad_pct[0]), (1, 1, 0.0));
        assert!(disparity_errors(&est[..2], &truth, None, &[1.0]).is_err());
        let err = disparity_errors(&est, &truth, Some(&[true]), &[1.0]).unwrap_err();
        assert!(err.contains("mask"), "{err}");
        let none = disparity_errors(&[f32::NAN], &[2.0], None, &[1.0]).unwrap();
        assert_eq!((none.bad_pct[0], none.coverage_pct), (100.0, 0.0));
        assert!(none.mae_px.is_nan());
        // A verged rig's negative disparities are known values, not unknown.
        let neg = disparity_errors(&[-3.0], &[-3.5], None, &[1.0]).unwrap();
        assert_eq!((neg.evaluated, neg.mae_px), (1, 0.5));
    }

    #[test]
    fn metric_names() {
        assert_eq!(bad_metric_name(2.0), "bad_2_pct");
        assert_eq!(bad_metric_name(0.5), "bad_0_5_pct");
        assert_eq!(bad_metric_name(4.0), "bad_4_pct");
    }
}
