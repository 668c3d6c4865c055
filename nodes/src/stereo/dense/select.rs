//! From costs to a disparity map: winner-takes-all per pixel, a uniqueness
//! test, a left-right consistency check against the right image's own
//! winners (taken from the same costs), and a parabola through the best cost
//! and its neighbours for sub-pixel disparity. Shared by every matcher.

use super::pair::DisparityRange;
use super::simd::Isa;
use super::volume::valid_ks;
use rayon::prelude::*;

/// How disparities are chosen from costs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelectParams {
    /// A pixel is invalid when a disparity more than one step from the best
    /// costs less than `best * (1 + uniqueness_pct / 100)` (OpenCV's
    /// uniquenessRatio); 0 turns the test off.
    pub uniqueness_pct: f64,
    /// Largest difference (px) between the left disparity and the right image's
    /// disparity at the matched pixel (the disparity of the cheapest left
    /// winner landing there, as in OpenCV); `None` turns the check off.
    pub lr_max_diff_px: Option<f64>,
    /// Fit a parabola for sub-pixel disparities.
    pub subpixel: bool,
}

/// Chooses a disparity per pixel (NaN = invalid) from the costs of each row,
/// `[x][k]` with `stride` (>= the disparity count) entries per pixel, which
/// `row_costs(y, buffer)` writes into `buffer`. Costs of
/// impossible matches must be at least as high as any possible one.
pub fn select<T, F>(
    width: usize,
    height: usize,
    range: DisparityRange,
    stride: usize,
    row_costs: F,
    params: &SelectParams,
) -> Vec<f32>
where
    T: Cost,
    F: Fn(usize, &mut Vec<T>) + Sync,
{
    let mut out = vec![f32::NAN; width * height];
    out.par_chunks_mut(width)
        .enumerate()
        .for_each_init(Vec::new, |costs, (y, row)| {
            row_costs(y, costs);
            select_row(costs, width, range, stride, params, row);
        });
    out
}

/// A matching cost: ordered, with a value no cost exceeds.
pub trait Cost: Copy + PartialOrd + Into<f64> + Send + Sync {
    /// Larger than or equal to every cost.
    const WORST: Self;

    /// The lowest cost of `c` and its first index (`None` when `c` is
    /// empty), and the lowest cost more than one index away from it
    /// ([`Cost::WORST`] when there is none).
    fn winner(c: &[Self]) -> Option<Winner<Self>> {
        let best = lowest(c);
        let k = c.iter().position(|&v| v == best)?;
        let runner_up = lowest(&c[..k.saturating_sub(1)]);
        let after = lowest(&c[(k + 2).min(c.len())..]);
        Some(Winner {
            best,
            k,
            runner_up: if after < runner_up { after } else { runner_up },
        })
    }

    /// [`Cost::winner`] of every pixel of a row, into `out` (`width`
    /// entries): pixel x's costs are `costs[x * stride..x * stride + n]`,
    /// `n >= 1`. A cost type may take the row with `isa`'s kernels.
    fn row_winners(
        costs: &[Self],
        stride: usize,
        n: usize,
        _isa: Isa,
        width: usize,
        out: &mut Vec<Winner<Self>>,
    ) {
        out.clear();
        out.extend(
            (0..width)
                .map_while(|x| costs.get(x * stride..x * stride + n))
                .map_while(Self::winner),
        );
    }
}

/// The cheapest disparity of a pixel and its nearest rival.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Winner<T> {
    /// Its cost.
    pub best: T,
    /// Its index (first of equal costs).
    pub k: usize,
    /// The cheapest cost more than one index away.
    pub runner_up: T,
}

impl Cost for u16 {
    const WORST: Self = u16::MAX;

    fn row_winners(
        costs: &[Self],
        stride: usize,
        n: usize,
        isa: Isa,
        width: usize,
        out: &mut Vec<Winner<Self>>,
    ) {
        // The pixels whose costs the row holds, as the default's.
        let whole = (0..width)
            .take_while(|x| x * stride + n <= costs.len())
            .count();
        let mut found = vec![(u16::MAX, 0, u16::MAX); whole];
        isa.winners_u16(costs, stride, n, &mut found);
        out.clear();
        out.extend(
            found
                .into_iter()
                .map(|(best, k, runner_up)| Winner { best, k, runner_up }),
        );
    }
}

impl Cost for u32 {
    const WORST: Self = u32::MAX;
}

impl Cost for f32 {
    const WORST: Self = f32::INFINITY;
}

/// The smallest value of `c` ([`Cost::WORST`] when empty).
#[inline]
fn lowest<T: Cost>(c: &[T]) -> T {
    c.iter().fold(T::WORST, |a, &b| if b < a { b } else { a })
}

/// [`select`] for one row of costs (`stride` entries per pixel) into `row`.
pub(crate) fn select_row<T: Cost>(
    costs: &[T],
    width: usize,
    range: DisparityRange,
    stride: usize,
    params: &SelectParams,
    row: &mut [f32],
) {
    let n = range.count;
    let u = params.uniqueness_pct / 100.0;
    if n == 0 {
        return;
    }
    let mut found = Vec::with_capacity(width);
    T::row_winners(costs, stride, n, Isa::detect(), width, &mut found);
    // Winners of the left pixels (k, or n for none).
    let mut winner = vec![n; width];
    for (x, (w, &Winner { best, k, runner_up })) in winner.iter_mut().zip(&found).enumerate() {
        let (k_lo, k_hi) = valid_ks(x, width, range);
        if k < k_lo || k >= k_hi {
            continue; // no possible match at all
        }
        // A winner on the edge of the search range is most likely a disparity
        // beyond it (far background, a too narrow range): not a match.
        if n > 2 && (k == 0 || k == n - 1) {
            continue;
        }
        if u > 0.0 && runner_up.into() < best.into() * (1.0 + u) {
            continue;
        }
        *w = k;
    }
    // The right image's winners as OpenCV finds them: each right pixel keeps
    // the disparity of the cheapest left winner that lands on it.
    let right: Option<Vec<(T, usize)>> = params.lr_max_diff_px.map(|_| {
        let mut right = vec![(T::WORST, n); width];
        for (x, &k) in winner.iter().enumerate().filter(|(_, k)| **k < n) {
            let xr = (x as i64 - range.min_px as i64 - k as i64) as usize;
            let c = costs[x * stride + k];
            if c < right[xr].0 {
                right[xr] = (c, k);
            }
        }
        right
    });
    for (x, &k) in winner.iter().enumerate().filter(|(_, k)| **k < n) {
        if let (Some(max_diff), Some(right)) = (params.lr_max_diff_px, &right) {
            let xr = (x as i64 - range.min_px as i64 - k as i64) as usize;
            if (right[xr].1 as f64 - k as f64).abs() > max_diff {
                continue;
            }
        }
        let c = &costs[x * stride..x * stride + n];
        let mut d = (range.min_px + k as i32) as f64;
        if params.subpixel && k > 0 && k + 1 < n {
            let (a, b, m): (f64, f64, f64) = (c[k - 1].into(), c[k + 1].into(), c[k].into());
            let denom = a + b - 2.0 * m;
            if denom > 0.0 {
                d += ((a - b) / (2.0 * denom)).clamp(-0.5, 0.5);
            }
        }
        row[x] = d as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(costs: &[u16], width: usize, range: DisparityRange, p: SelectParams) -> Vec<f32> {
        let costs = costs.to_vec();
        select(
            width,
            1,
            range,
            range.count,
            |_, buf: &mut Vec<u16>| buf.clone_from(&costs),
            &p,
        )
    }

    #[test]
    fn parabola_uniqueness_and_left_right() {
        let range = DisparityRange::new(0, 3, 6).unwrap();
        let plain = SelectParams {
            uniqueness_pct: 0.0,
            lr_max_diff_px: None,
            subpixel: true,
        };
        // Pixel 5: costs 10, 4, 6, 20 -> best k = 1, parabola offset
        // (10 - 6) / (2 * (10 + 6 - 8)) = 0.25 -> d = 1.25.
        let mut costs = vec![50u16; 6 * 4];
        costs[20..24].copy_from_slice(&[10, 4, 6, 20]);
        let d = run(&costs, 6, range, plain);
        assert!((d[5] - 1.25).abs() < 1e-6, "{d:?}");
        // Uniqueness 10 %: a far disparity costing 4.3 (< 4.4) makes it ambiguous.
        costs[20..24].copy_from_slice(&[10, 4, 6, 4]);
        let strict = SelectParams {
            uniqueness_pct: 10.0,
            ..plain
        };
        assert!(run(&costs, 6, range, strict)[5].is_nan());
        // A winner on the edge of the range is refused.
        costs[8..12].copy_from_slice(&[9, 8, 7, 1]);
        assert!(run(&costs, 6, range, plain)[2].is_nan());
    }

    #[test]
    fn left_right_check_rejects_a_pixel_the_right_image_gives_elsewhere() {
        let range = DisparityRange::new(0, 3, 5).unwrap();
        // Pixels 3 and 4 both claim right pixel 2 (d = 1 and d = 2); pixel 4's
        // match is cheaper, so pixel 3 fails the check.
        let mut costs = vec![9u16; 5 * 4];
        costs[3 * 4..4 * 4].copy_from_slice(&[9, 3, 9, 9]);
        costs[4 * 4..5 * 4].copy_from_slice(&[9, 9, 1, 9]);
        let p = SelectParams {
            uniqueness_pct: 0.0,
            lr_max_diff_px: Some(0.0),
            subpixel: false,
        };
        let d = run(&costs, 5, range, p);
        assert!(d[3].is_nan(), "{d:?}");
        assert_eq!(d[4], 2.0);
    }
}
