//! Intensity operations on whole volumes: percentile contrast stretch (MATLAB's
//! `imadjust(V, stretchlim(V))`) and Otsu's threshold.

/// The values at the `low` and `high` percentiles (0-100) of `values`, by exact
/// order statistics (nearest rank). NaNs are ignored.
pub fn percentiles(values: &[f32], low: f64, high: f64) -> Option<(f32, f32)> {
    let mut v: Vec<f32> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return None;
    }
    let rank = |p: f64| (((p / 100.0) * (v.len() - 1) as f64).round() as usize).min(v.len() - 1);
    let (lo_rank, hi_rank) = (rank(low), rank(high));
    let (_, &mut lo, upper) = v.select_nth_unstable_by(lo_rank, f32::total_cmp);
    let hi = if hi_rank == lo_rank {
        lo
    } else {
        let (_, &mut hi, _) = upper.select_nth_unstable_by(hi_rank - lo_rank - 1, f32::total_cmp);
        hi
    };
    Some((lo, hi))
}

/// Maps [lo, hi] linearly to [0, 1], clamping outside.
pub fn stretch(values: &[f32], lo: f32, hi: f32) -> Vec<f32> {
    let scale = 1.0 / (hi - lo);
    values
        .iter()
        .map(|&v| ((v - lo) * scale).clamp(0.0, 1.0))
        .collect()
}

/// Otsu's threshold over all of `values` with a histogram of `bins` bins
/// between their minimum and maximum: the value that maximises the
/// between-class variance. Voxels strictly above it form the foreground.
///
/// `None` when the values have no spread (all equal, or none finite) or
/// `bins < 2`.
///
/// # Examples
///
/// ```
/// use fusegraph_nodes::mri::otsu_threshold;
///
/// // Dark background near 10, bright markers near 50.
/// let values = [10.0, 11.0, 12.0, 10.5, 48.0, 49.0, 50.0];
/// let t = otsu_threshold(&values, 40).unwrap();
/// assert!(t > 12.0 && t < 48.0, "{t}");
/// assert_eq!(values.iter().filter(|&&v| v > t).count(), 3);
/// assert_eq!(otsu_threshold(&[7.0; 4], 40), None);
/// ```
pub fn otsu_threshold(values: &[f32], bins: usize) -> Option<f32> {
    let (min, max) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    // Also covers "no finite value" (min = inf, max = -inf).
    if max <= min || bins < 2 {
        return None;
    }
    let width = (max - min) as f64 / bins as f64;
    let mut histogram = vec![0u64; bins];
    for &v in values.iter().filter(|v| v.is_finite()) {
        let b = (((v - min) as f64 / width) as usize).min(bins - 1);
        histogram[b] += 1;
    }
    let total: u64 = histogram.iter().sum();
    let centre = |b: usize| min as f64 + (b as f64 + 0.5) * width;
    let sum_all: f64 = histogram
        .iter()
        .enumerate()
        .map(|(b, &n)| n as f64 * centre(b))
        .sum();
    let (mut weight_below, mut sum_below) = (0u64, 0.0);
    let (mut best, mut best_bin) = (-1.0, 0);
    for (b, &n) in histogram.iter().enumerate().take(bins - 1) {
        weight_below += n;
        sum_below += n as f64 * centre(b);
        let weight_above = total - weight_below;
        if weight_below == 0 || weight_above == 0 {
            continue;
        }
        let mean_below = sum_below / weight_below as f64;
        let mean_above = (sum_all - sum_below) / weight_above as f64;
        let between = weight_below as f64 * weight_above as f64 * (mean_below - mean_above).powi(2);
        if between > best {
            best = between;
            best_bin = b;
        }
    }
    // The threshold is the upper edge of the last background bin.
    Some((min as f64 + (best_bin + 1) as f64 * width) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_by_rank() {
        let v: Vec<f32> = (0..101).map(|x| x as f32).rev().collect();
        assert_eq!(percentiles(&v, 1.0, 99.0), Some((1.0, 99.0)));
        assert_eq!(percentiles(&v, 0.0, 100.0), Some((0.0, 100.0)));
        assert_eq!(percentiles(&[f32::NAN], 1.0, 99.0), None);
        assert_eq!(
            stretch(&[0.0, 5.0, 10.0, 20.0], 0.0, 10.0),
            vec![0.0, 0.5, 1.0, 1.0]
        );
    }

    #[test]
    fn otsu_splits_a_known_bimodal_histogram() {
        // 600 values around 2 and 400 around 8: any threshold between the modes
        // separates them; Otsu's maximises sigma_b^2 = w0 w1 (mu0 - mu1)^2, which
        // is the same for every cut in the empty gap, so the first (lowest) is
        // taken: the upper edge of the bin holding 2.5.
        let mut v = Vec::new();
        for i in 0..600 {
            v.push(1.5 + (i % 11) as f32 * 0.1);
        }
        for i in 0..400 {
            v.push(7.5 + (i % 11) as f32 * 0.1);
        }
        let t = otsu_threshold(&v, 70).unwrap();
        assert!(t > 2.5 && t < 7.5, "{t}");
        assert!((t - 2.6).abs() < 1e-5, "{t}");
        assert!(v.iter().filter(|&&x| x > t).count() == 400);
        assert_eq!(otsu_threshold(&[3.0; 10], 256), None);
    }

    #[test]
    fn otsu_matches_a_hand_computation_on_three_levels() {
        // 0.5 (x5), 1.5 (x3), 2.5 (x2); 3 bins of width 2/3 with centres
        // 5/6, 3/2, 13/6. Between-class w0 w1 (mu0 - mu1)^2:
        //   cut after bin 0: 5 * 5 * (5/6 - 53/30)^2 = 21.78
        //   cut after bin 1: 8 * 2 * (13/12 - 13/6)^2 = 18.78
        // so the threshold is the upper edge of bin 0: 0.5 + 2/3.
        let v = [0.5, 0.5, 0.5, 0.5, 0.5, 1.5, 1.5, 1.5, 2.5, 2.5];
        let t = otsu_threshold(&v, 3).unwrap();
        assert!((t - (0.5 + 2.0 / 3.0)).abs() < 1e-6, "{t}");
    }
}
