//! The disparity range a dense matcher searches, from sparse matches (the
//! paper sets it from SURF matches): robust percentiles of the matched
//! disparities widened by a margin.
//!
//! Percentiles drop the few wrong matches but also the true extremes, and
//! surfaces with little texture (often the nearest or farthest) get few
//! features; so the margin has a fixed part (`margin_px`, covering the tails a
//! handful of matches cannot show) and a part proportional to the spread
//! (`margin_fraction`, because a scene twice as deep in disparity has tails
//! twice as long). Range = [p_low - m, p_high + m], m = margin_px +
//! margin_fraction * (p_high - p_low), rounded outwards to whole pixels.
//! The fixed part is 16 px by default: a search that stops short of a surface
//! (the far edge of a table, say) forces its pixels to wrong disparities inside
//! the range, which triangulate to points floating in front of it, while 32
//! more disparities cost a dense matcher little.

/// The disparities of the matches that nearby matches agree with: those with
/// at least `min_support` other matches within `radius_px` in the left image
/// whose disparity is within `tolerance_px` of theirs (and at least
/// `lowest_px`, when given: nothing in front of the rig has a smaller one).
///
/// Surfaces are piecewise smooth, so a right match has neighbours at nearly
/// its disparity; a wrong one (repeated texture, a blank wall) lands at a
/// disparity of its own. On real low-texture pairs such matches were a third
/// of the total and ran to -665 px on pairs whose disparities lie in 0..60:
/// percentiles alone cannot drop so many. `matches` are (x, y, disparity) in
/// px; a `radius_px` of 0 keeps every match.
pub fn supported_disparities(
    matches: &[(f32, f32, f32)],
    radius_px: f64,
    tolerance_px: f64,
    min_support: usize,
    lowest_px: Option<f64>,
) -> Vec<f32> {
    let possible: Vec<(f32, f32, f32)> = matches
        .iter()
        .copied()
        .filter(|m| m.2.is_finite() && lowest_px.is_none_or(|low| m.2 as f64 >= low))
        .collect();
    if radius_px <= 0.0 {
        return possible.iter().map(|m| m.2).collect();
    }
    // Buckets of radius_px squares: neighbours are in the 3 x 3 around.
    let cell = radius_px as f32;
    let key = |m: &(f32, f32, f32)| ((m.0 / cell).floor() as i64, (m.1 / cell).floor() as i64);
    let mut grid: std::collections::HashMap<(i64, i64), Vec<usize>> =
        std::collections::HashMap::new();
    for (i, m) in possible.iter().enumerate() {
        grid.entry(key(m)).or_default().push(i);
    }
    let (r2, tolerance) = ((radius_px * radius_px) as f32, tolerance_px as f32);
    possible
        .iter()
        .enumerate()
        .filter(|&(i, m)| {
            let (cx, cy) = key(m);
            let agreeing = (cx - 1..=cx + 1)
                .flat_map(|x| (cy - 1..=cy + 1).map(move |y| (x, y)))
                .filter_map(|c| grid.get(&c))
                .flatten()
                .filter(|&&j| {
                    let n = &possible[j];
                    j != i
                        && (n.0 - m.0).powi(2) + (n.1 - m.1).powi(2) <= r2
                        && (n.2 - m.2).abs() <= tolerance
                })
                .take(min_support)
                .count();
            agreeing >= min_support
        })
        .map(|(_, m)| m.2)
        .collect()
}

/// The matches a range is bounded by: those nearby matches agree with
/// ([`supported_disparities`]) and every other possible match within the
/// margin of their percentiles. Sparse matches on real surfaces (a table's
/// far edge, often a handful) lie next to the supported ones' range and stay;
/// wrong matches hundreds of pixels off go.
pub fn core_disparities(
    matches: &[(f32, f32, f32)],
    support: (f64, f64, usize),
    lowest_px: Option<f64>,
    params: &RangeParams,
) -> Vec<f32> {
    let (radius, tolerance, min_support) = support;
    let supported = supported_disparities(matches, radius, tolerance, min_support, lowest_px);
    if supported.is_empty() || radius <= 0.0 {
        return supported;
    }
    let mut sorted: Vec<f64> = supported.iter().map(|&d| d as f64).collect();
    sorted.sort_by(f64::total_cmp);
    let (lo, hi) = (
        percentile(&sorted, params.low_percentile),
        percentile(&sorted, params.high_percentile),
    );
    let margin = params.margin_px + params.margin_fraction * (hi - lo);
    matches
        .iter()
        .map(|m| m.2)
        .filter(|&d| {
            let d = d as f64;
            d.is_finite()
                && lowest_px.is_none_or(|low| d >= low)
                && d >= lo - margin
                && d <= hi + margin
        })
        .collect()
}

/// Settings of [`disparity_range`].
#[derive(Debug, Clone, PartialEq)]
pub struct RangeParams {
    /// Lower percentile of the matched disparities, % (0..100).
    pub low_percentile: f64,
    /// Upper percentile, %; above `low_percentile`.
    pub high_percentile: f64,
    /// Fixed margin added on both sides, px.
    pub margin_px: f64,
    /// Margin added on both sides as a fraction of the percentile spread.
    pub margin_fraction: f64,
    /// Fewest matches to trust; fewer is an error.
    pub min_matches: usize,
}

impl Default for RangeParams {
    fn default() -> Self {
        RangeParams {
            low_percentile: 2.0,
            high_percentile: 98.0,
            margin_px: 16.0,
            margin_fraction: 0.1,
            min_matches: 10,
        }
    }
}

/// Percentile `p` (0..100) of ascending `sorted` values, linearly interpolated
/// between ranks; `sorted` must not be empty.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    let pos = (p / 100.0).clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, pos - pos.floor());
    match sorted.get(i + 1) {
        Some(next) => sorted[i] + frac * (next - sorted[i]),
        None => sorted[i],
    }
}

/// The smallest and largest disparity (px, whole pixels, min <= max) a dense
/// matcher should search, from matched disparities (`x_left - x_right`, px).
/// Non-finite disparities are ignored; fewer than `min_matches` left is an error.
pub fn disparity_range(disparities_px: &[f32], params: &RangeParams) -> Result<(i32, i32), String> {
    let (lo, hi) = (params.low_percentile, params.high_percentile);
    if !(0.0..=100.0).contains(&lo) || !(0.0..=100.0).contains(&hi) || lo >= hi {
        return Err(format!(
            "percentiles {lo} and {hi}: need 0 <= low_percentile < high_percentile <= 100"
        ));
    }
    let non_negative = |v: f64| v.is_finite() && v >= 0.0;
    if !non_negative(params.margin_px) || !non_negative(params.margin_fraction) {
        return Err("margin_px and margin_fraction must be >= 0".into());
    }
    let mut d: Vec<f64> = disparities_px
        .iter()
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .collect();
    if d.len() < params.min_matches.max(1) {
        return Err(format!(
            "only {} matches (min_matches = {}): too few to bound the disparity range; \
             set the dense matcher's disparity range by its parameters instead",
            d.len(),
            params.min_matches
        ));
    }
    d.sort_by(f64::total_cmp);
    let (p_lo, p_hi) = (percentile(&d, lo), percentile(&d, hi));
    let margin = params.margin_px + params.margin_fraction * (p_hi - p_lo);
    let (min, max) = ((p_lo - margin).floor(), (p_hi + margin).ceil());
    if min < i32::MIN as f64 || max > i32::MAX as f64 {
        return Err(format!(
            "disparity range [{min}, {max}] px is out of bounds"
        ));
    }
    Ok((min as i32, max as i32))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_interpolate_between_ranks() {
        let v = [0.0, 10.0, 20.0, 30.0, 40.0];
        assert_eq!(percentile(&v, 0.0), 0.0);
        assert_eq!(percentile(&v, 50.0), 20.0);
        assert_eq!(percentile(&v, 100.0), 40.0);
        assert!((percentile(&v, 10.0) - 4.0).abs() < 1e-12);
        assert_eq!(percentile(&[7.0], 98.0), 7.0);
    }

    #[test]
    fn range_by_hand() {
        // 0, 1, ..., 100: p2 = 2, p98 = 98, margin = 16 + 0.1 * 96 = 25.6.
        let d: Vec<f32> = (0..=100).map(|v| v as f32).collect();
        let (min, max) = disparity_range(&d, &RangeParams::default()).unwrap();
        assert_eq!((min, max), (-24, 124));
    }

    #[test]
    fn wrong_matches_do_not_stretch_the_range() {
        // 500 matches on two surfaces (20..30 px and 45..60 px) plus 1 % wild
        // outliers: the range covers both surfaces and ignores the outliers.
        let mut d: Vec<f32> = (0..250).map(|i| 20.0 + 10.0 * i as f32 / 249.0).collect();
        d.extend((0..250).map(|i| 45.0 + 15.0 * i as f32 / 249.0));
        d.extend([-300.0, 400.0, 900.0, -50.0, 1000.0]);
        let (min, max) = disparity_range(&d, &RangeParams::default()).unwrap();
        assert!(min <= 20 && max >= 60, "[{min}, {max}]");
        assert!(
            min >= 20 - 16 - 5 && max <= 60 + 16 + 5,
            "[{min}, {max}] too wide"
        );
    }

    /// A smooth surface over a 640 x 480 image (disparity 10 + 40 x / 640)
    /// seen by `inliers` matches, and `outliers` wrong ones anywhere in the
    /// image at disparities spread over -665..107 px (what real low-texture
    /// pairs gave), by a fixed linear congruential sequence.
    fn surface_with_wild_matches(inliers: usize, outliers: usize) -> Vec<(f32, f32, f32)> {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f32 / (1u64 << 31) as f32
        };
        let mut m = Vec::new();
        for _ in 0..inliers {
            let (x, y) = (next() * 640.0, next() * 480.0);
            m.push((x, y, 10.0 + 40.0 * x / 640.0 + (next() - 0.5) * 0.6));
        }
        for _ in 0..outliers {
            m.push((next() * 640.0, next() * 480.0, -665.0 + 772.0 * next()));
        }
        m
    }

    #[test]
    fn unsupported_matches_do_not_stretch_the_range() {
        // 35 % wild matches: percentiles alone give a range hundreds of px
        // wide; the supported matches give the surface's.
        let m = surface_with_wild_matches(650, 350);
        let all: Vec<f32> = m.iter().map(|m| m.2).collect();
        let (wide_min, _) = disparity_range(&all, &RangeParams::default()).unwrap();
        assert!(wide_min < -500, "{wide_min}");
        let kept = supported_disparities(&m, 48.0, 3.0, 1, None);
        assert!(kept.len() >= 640 && kept.len() <= 720, "{}", kept.len());
        let (min, max) = disparity_range(&kept, &RangeParams::default()).unwrap();
        assert!(min <= 10 && max >= 50, "[{min}, {max}] misses the surface");
        // The few wrong matches a neighbour happens to agree with widen it by
        // tens of pixels, not hundreds.
        assert!(min >= -60 && max <= 110, "[{min}, {max}] too wide");
        // Matches near the supported ones' range stay (wrong ones among them
        // widen it a little); the wild ones go.
        let core = core_disparities(&m, (48.0, 3.0, 1), None, &RangeParams::default());
        let (min, max) = disparity_range(&core, &RangeParams::default()).unwrap();
        assert!(min <= 10 && max >= 50, "[{min}, {max}] misses the surface");
        assert!(min >= -60 && max <= 110, "[{min}, {max}] too wide");
        // A sparsely matched far surface beside the main one (30 lone
        // matches at -3 and -7 px, 50 px apart, none agreeing with a
        // neighbour) stays in the range: the search must not stop short of it.
        let mut sparse = surface_with_wild_matches(650, 0);
        sparse.extend((0..30).map(|k| {
            let (x, y) = (
                10.0 + 60.0 * (k % 10) as f32,
                330.0 + 50.0 * (k / 10) as f32,
            );
            (x, y, -3.0 - 4.0 * (k % 2) as f32)
        }));
        let support = (48.0, 3.0, 1);
        let params = RangeParams::default();
        let core = core_disparities(&sparse, support, None, &params);
        let (min, _) = disparity_range(&core, &params).unwrap();
        assert!(min <= -20, "{min}: the sparse surface's tail is cut");
        let supported = supported_disparities(&sparse, support.0, support.1, support.2, None);
        let (without, _) = disparity_range(&supported, &params).unwrap();
        assert!(
            without > -20,
            "{without}: support alone drops the sparse surface"
        );
        // The rig's geometry refuses what lies behind the cameras.
        let possible = supported_disparities(&m, 0.0, 2.0, 2, Some(0.0));
        assert!(possible.iter().all(|&d| d >= 0.0));
        assert_eq!(supported_disparities(&m, 0.0, 2.0, 2, None).len(), 1000);
    }

    #[test]
    fn a_wide_pair_gets_a_wide_range() {
        // 200 .. 260 px, uniform.
        let d: Vec<f32> = (0..300).map(|i| 200.0 + 60.0 * i as f32 / 299.0).collect();
        let (min, max) = disparity_range(&d, &RangeParams::default()).unwrap();
        assert!(min <= 200 && max >= 260, "[{min}, {max}]");
        // Margin 16 + 0.1 * 60 = 22 on each side, and no more.
        assert!(min >= 176 && max <= 284, "[{min}, {max}]");
    }

    #[test]
    fn too_few_matches_or_bad_params_are_errors() {
        let err = disparity_range(&[1.0, 2.0, f32::NAN], &RangeParams::default()).unwrap_err();
        assert!(err.contains("only 2 matches"), "{err}");
        assert!(err.contains("parameters"), "{err}");
        let p = RangeParams {
            low_percentile: 90.0,
            high_percentile: 10.0,
            ..RangeParams::default()
        };
        let d: Vec<f32> = (0..20).map(|v| v as f32).collect();
        assert!(disparity_range(&d, &p).is_err());
        let p = RangeParams {
            min_matches: 0,
            ..RangeParams::default()
        };
        assert!(disparity_range(&[], &p).is_err(), "no disparity at all");
    }
}
