//! Local block matching: every pixel takes the disparity whose window matches
//! best, by the sum of absolute differences (SAD), zero-mean normalised
//! cross-correlation (ZNCC) or summed census Hamming distances. The reference
//! against which semi-global matching earns its keep.
//!
//! Window sums are column sums over the window's rows followed by a running
//! sum along the row, so the cost is independent of the window's width.

use super::cost::census_transform;
use super::pair::{DisparityRange, GreyImage};
use super::select::{SelectParams, select};
use super::simd::Isa;
use super::volume::valid_ks;
use fusegraph_plugin_api::derive::Choice;

/// How windows are compared (the `cost` of `stereo.block_match`, by its
/// snake-case name).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum BlockCost {
    /// 1 - zero-mean normalised cross-correlation.
    Zncc,
    /// Sum of absolute grey-level differences.
    Sad,
    /// Sum over the window of Hamming distances between 5 x 5 census codes.
    Census,
}

/// Census window of [`BlockCost::Census`] (per pixel, before summing).
const CENSUS_SIDE: usize = 5;

/// Disparities (px, NaN = invalid) of `left` by block matching with a square
/// `window` (odd, px).
pub fn block_match(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
    cost: BlockCost,
    window: usize,
    select_params: &SelectParams,
) -> Vec<f32> {
    let (w, h) = (left.width, left.height);
    let r = window / 2;
    match cost {
        BlockCost::Sad => {
            let pc = |x: usize, y: usize, xr: usize| left.at(x, y).abs_diff(right.at(xr, y)) as u32;
            select(
                w,
                h,
                range,
                range.count,
                |y, out: &mut Vec<u32>| window_sums(y, r, w, h, range, &pc, out),
                select_params,
            )
        }
        BlockCost::Census => {
            let isa = Isa::detect();
            let (cl, cr) = rayon::join(
                || census_transform(left, CENSUS_SIDE, CENSUS_SIDE, isa),
                || census_transform(right, CENSUS_SIDE, CENSUS_SIDE, isa),
            );
            let pc = |x: usize, y: usize, xr: usize| (cl[y * w + x] ^ cr[y * w + xr]).count_ones();
            select(
                w,
                h,
                range,
                range.count,
                |y, out: &mut Vec<u32>| window_sums(y, r, w, h, range, &pc, out),
                select_params,
            )
        }
        BlockCost::Zncc => {
            let left_stats = window_stats(left, r);
            let area = ((2 * r + 1) * (2 * r + 1)) as f64;
            let product =
                |x: usize, y: usize, xr: usize| left.at(x, y) as u32 * right.at(xr, y) as u32;
            // The right window's sums over exactly the columns paired with the
            // left window's (they differ from the right pixel's own window at
            // the borders, where columns are clamped).
            let grey = |_: usize, y: usize, xr: usize| right.at(xr, y) as u32;
            let square = |_: usize, y: usize, xr: usize| (right.at(xr, y) as u32).pow(2);
            let n = range.count;
            select(
                w,
                h,
                range,
                range.count,
                |y, out: &mut Vec<f32>| {
                    let (mut lr, mut rs, mut rs2) = (Vec::new(), Vec::new(), Vec::new());
                    window_sums(y, r, w, h, range, &product, &mut lr);
                    window_sums(y, r, w, h, range, &grey, &mut rs);
                    window_sums(y, r, w, h, range, &square, &mut rs2);
                    out.clear();
                    out.resize(w * n, 2.0);
                    for x in 0..w {
                        let (k_lo, k_hi) = valid_ks(x, w, range);
                        let (ml, sdl) = left_stats[y * w + x];
                        for k in k_lo..k_hi {
                            let i = x * n + k;
                            let mr = rs[i] as f64 / area;
                            let sdr = (rs2[i] as f64 / area - mr * mr).max(0.0).sqrt();
                            let denom = sdl * sdr;
                            out[i] = if denom > 1e-6 {
                                let ncc = (lr[i] as f64 / area - ml * mr) / denom;
                                (1.0 - ncc.clamp(-1.0, 1.0)) as f32
                            } else {
                                1.0 // a flat window correlates with nothing
                            };
                        }
                    }
                },
                select_params,
            )
        }
    }
}

/// Mean and standard deviation of the grey levels in the window around every
/// pixel (clamped at the borders, like [`window_sums`]).
fn window_stats(img: &GreyImage, r: usize) -> Vec<(f64, f64)> {
    let (w, h) = (img.width, img.height);
    let area = ((2 * r + 1) * (2 * r + 1)) as f64;
    let mut out = vec![(0.0, 0.0); w * h];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for yy in clamped(y, r, h) {
                for xx in clamped(x, r, w) {
                    let v = img.at(xx, yy) as f64;
                    s += v;
                    s2 += v * v;
                }
            }
            let mean = s / area;
            out[y * w + x] = (mean, (s2 / area - mean * mean).max(0.0).sqrt());
        }
    }
    out
}

/// The indices `c - r ..= c + r` clamped into `0..len`.
fn clamped(c: usize, r: usize, len: usize) -> impl Iterator<Item = usize> {
    (c as isize - r as isize..=c as isize + r as isize)
        .map(move |i| i.clamp(0, len as isize - 1) as usize)
}

/// Row `y`'s window sums `[x][k]` of `pixel_cost(x, y, x_right)` over
/// `(2r + 1)^2` windows; the window's pixels are clamped to the image and keep
/// the disparity of its centre. Impossible matches get `u32::MAX / 2`.
fn window_sums(
    y: usize,
    r: usize,
    w: usize,
    h: usize,
    range: DisparityRange,
    pixel_cost: &(impl Fn(usize, usize, usize) -> u32 + Sync),
    out: &mut Vec<u32>,
) {
    let n = range.count;
    out.clear();
    out.resize(w * n, u32::MAX / 2);
    let mut column = vec![0u32; w];
    for k in 0..n {
        let d = range.min_px as i64 + k as i64;
        for (x, c) in column.iter_mut().enumerate() {
            let xr = (x as i64 - d).clamp(0, w as i64 - 1) as usize;
            *c = clamped(y, r, h).map(|yy| pixel_cost(x, yy, xr)).sum();
        }
        let mut acc: u32 = clamped(0, r, w).map(|xx| column[xx]).sum();
        for x in 0..w {
            let (k_lo, k_hi) = valid_ks(x, w, range);
            if (k_lo..k_hi).contains(&k) {
                out[x * n + k] = acc;
            }
            // Slide the window: drop its first column, add the next one.
            let first = (x as isize - r as isize).clamp(0, w as isize - 1) as usize;
            let next = (x + r + 1).min(w - 1);
            acc = acc + column[next] - column[first];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_dot(w: usize, h: usize, seed: u64) -> Vec<u8> {
        let mut s = seed;
        (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect()
    }

    #[test]
    fn every_cost_finds_a_constant_shift() {
        let (w, h, shift) = (64, 24, 7usize);
        let base = random_dot(w + shift, h, 3);
        let left = GreyImage {
            width: w,
            height: h,
            data: (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| base[y * (w + shift) + x])
                .collect(),
        };
        let right = GreyImage {
            width: w,
            height: h,
            data: (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| base[y * (w + shift) + x + shift])
                .collect(),
        };
        let range = DisparityRange::new(0, 15, w).unwrap();
        let p = SelectParams {
            uniqueness_pct: 5.0,
            lr_max_diff_px: Some(1.0),
            subpixel: false,
        };
        for cost in [BlockCost::Sad, BlockCost::Zncc, BlockCost::Census] {
            let d = block_match(&left, &right, range, cost, 5, &p);
            let inner: Vec<f32> = (3..h - 3)
                .flat_map(|y| (shift + 3..w - 3).map(move |x| (x, y)))
                .map(|(x, y)| d[y * w + x])
                .collect();
            let right_ones = inner.iter().filter(|&&v| v == shift as f32).count();
            assert_eq!(right_ones, inner.len(), "{cost:?}");
        }
    }

    #[test]
    fn same_bits_on_any_number_of_threads() {
        let (w, h) = (80, 120);
        let grey = |seed| GreyImage {
            width: w,
            height: h,
            data: random_dot(w, h, seed),
        };
        let (left, right) = (grey(5), grey(6));
        let range = DisparityRange::new(0, 15, w).unwrap();
        let p = SelectParams {
            uniqueness_pct: 5.0,
            lr_max_diff_px: Some(1.0),
            subpixel: true,
        };
        for cost in [BlockCost::Sad, BlockCost::Zncc, BlockCost::Census] {
            let bits = |threads| {
                crate::on_threads(threads, || block_match(&left, &right, range, cost, 7, &p))
                    .iter()
                    .map(|v| v.to_bits())
                    .collect::<Vec<u32>>()
            };
            assert_eq!(bits(1), bits(3), "{cost:?}");
        }
    }

    #[test]
    fn window_sums_equal_direct_sums() {
        let (w, h) = (9, 6);
        let img: Vec<u32> = (0..w * h).map(|i| (i * 7 % 11) as u32).collect();
        let range = DisparityRange::new(-1, 2, w).unwrap();
        let pc = |x: usize, y: usize, xr: usize| img[y * w + x] * 3 + img[y * w + xr];
        let mut out = Vec::new();
        window_sums(2, 1, w, h, range, &pc, &mut out);
        for x in 0..w {
            for k in 0..4 {
                let d = k as i64 - 1;
                let (lo, hi) = valid_ks(x, w, range);
                let expect = if (lo..hi).contains(&k) {
                    let mut s = 0;
                    for yy in clamped(2, 1, h) {
                        for xx in clamped(x, 1, w) {
                            let xr = (xx as i64 - d).clamp(0, w as i64 - 1) as usize;
                            s += pc(xx, yy, xr);
                        }
                    }
                    s
                } else {
                    u32::MAX / 2
                };
                assert_eq!(out[x * 4 + k], expect, "x {x} k {k}");
            }
        }
    }
}
