//! Found markers against true ones, without assuming order or equal counts.

/// How found markers compare to the truth.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerComparison {
    /// (found index, true index, error mm) of each matched pair.
    pub pairs: Vec<(usize, usize, f64)>,
    /// True markers with no match.
    pub missed: usize,
    /// Found markers with no match.
    pub spurious: usize,
}

impl MarkerComparison {
    /// Mean error over matched pairs, mm (NaN if none).
    pub fn mean_error_mm(&self) -> f64 {
        self.pairs.iter().map(|p| p.2).sum::<f64>() / self.pairs.len() as f64
    }

    /// Largest error over matched pairs, mm (NaN if none).
    pub fn max_error_mm(&self) -> f64 {
        self.pairs.iter().map(|p| p.2).fold(f64::NAN, f64::max)
    }
}

/// Matches `found` to `truth` (both mm, same frame) greedily by increasing
/// distance, each at most once and no further apart than `max_distance_mm`.
pub fn compare_markers(
    found: &[[f64; 3]],
    truth: &[[f64; 3]],
    max_distance_mm: f64,
) -> MarkerComparison {
    let dist = |a: &[f64; 3], b: &[f64; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let mut candidates: Vec<(f64, usize, usize)> = found
        .iter()
        .enumerate()
        .flat_map(|(i, f)| {
            truth
                .iter()
                .enumerate()
                .map(move |(j, t)| (dist(f, t), i, j))
        })
        .filter(|c| c.0 <= max_distance_mm)
        .collect();
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut found_used, mut truth_used) = (vec![false; found.len()], vec![false; truth.len()]);
    let mut pairs = Vec::new();
    for (d, i, j) in candidates {
        if !found_used[i] && !truth_used[j] {
            found_used[i] = true;
            truth_used[j] = true;
            pairs.push((i, j, d));
        }
    }
    MarkerComparison {
        missed: truth.len() - pairs.len(),
        spurious: found.len() - pairs.len(),
        pairs,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_without_order_and_counts_misses() {
        let truth = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]];
        let found = [[0.0, 10.1, 0.0], [50.0, 0.0, 0.0], [0.2, 0.0, 0.0]];
        let c = compare_markers(&found, &truth, 5.0);
        assert_eq!((c.pairs.len(), c.missed, c.spurious), (2, 1, 1));
        assert!((c.mean_error_mm() - 0.15).abs() < 1e-12);
        assert!((c.max_error_mm() - 0.2).abs() < 1e-12);
        assert!(compare_markers(&[], &truth, 5.0).mean_error_mm().is_nan());
    }
}
