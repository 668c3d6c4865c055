//! Confidence-aware, edge-aware filling and smoothing of a disparity map.
//!
//! Normalised convolution (Knutsson & Westin, CVPR 1993): the valid
//! disparities times their confidence (1 valid, 0 invalid) and the confidence
//! alone are smoothed by the same filter, and their ratio is the filtered
//! disparity; where no valid pixel lies within reach the ratio is undefined
//! and the pixel stays invalid. The filter is the domain transform's
//! recursive filter (Gastal & Oliveira, SIGGRAPH 2011), an edge-aware
//! smoother in O(pixels) for any reach: distances along rows and columns grow
//! with the left image's grey-level steps and with the disparity's own steps
//! between valid neighbours, so it neither smooths nor fills across an
//! object's outline or a depth edge. This is the idea of OpenCV's
//! disparity WLS filter and the fast global smoother (guided, confidence
//! weighted), written here for our types: no crate provides it.
//!
//! Why: on weakly textured surfaces the matcher's disparities carry
//! correlated errors of a few tenths of a pixel (the phantom's lab preset:
//! MAE 0.48 px on the skin) and holes where the left-right or uniqueness test
//! refused a match. A smooth surface is what the holes most likely hold and
//! what the noise hides.

use super::pair::GreyImage;
use crate::simd::{Isa, kernels};
use rayon::prelude::*;

/// How [`fill_disparity`] filters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FillParams {
    /// Spatial reach (the filter's standard deviation on a flat, edge-free
    /// image), px.
    pub sigma_px: f32,
    /// A grey-level step this large in the left image counts as far as
    /// `sigma_px` pixels: edges stop the filter.
    pub sigma_grey: f32,
    /// A disparity step this large between valid neighbours counts as far
    /// as `sigma_px` pixels: depth edges stop the filter, px.
    pub sigma_disparity_px: f32,
    /// A hole is filled where the valid pixels' share of the filter's
    /// weight there is at least this (0..1; a hole's share is below 1, so
    /// 1 fills none).
    pub min_support: f32,
    /// Whether valid pixels take the filtered value too (smoothing; one
    /// it would move by more than `sigma_disparity_px` keeps its own), or
    /// only holes are filled.
    pub smooth: bool,
}

/// Recursive-filter iterations (Gastal & Oliveira's three: the kernel's
/// shape is close to a Gaussian and the stripes of one pass are gone).
const ITERATIONS: i32 = 3;

/// Fills (and, with `smooth`, smooths) `disparity` (`guide.width x
/// guide.height`, px, NaN = invalid) in place, guided by the left image.
/// Returns how many holes were filled.
///
/// # Panics
///
/// When `disparity` is not `guide.width * guide.height` long.
pub fn fill_disparity(disparity: &mut [f32], guide: &GreyImage, p: &FillParams) -> usize {
    let (w, h) = (guide.width, guide.height);
    assert_eq!(disparity.len(), w * h, "disparity and guide differ in size");
    if w == 0 || h == 0 || p.sigma_px <= 0.0 {
        return 0;
    }
    let valid = |d: f32| !d.is_nan();
    let grey = p.sigma_px / p.sigma_grey.max(1e-6);
    let depth = p.sigma_px / p.sigma_disparity_px.max(1e-6);
    // The domain transform's distance between neighbouring pixels a and b.
    let step = |a: usize, b: usize| {
        let di = (guide.data[a] as f32 - guide.data[b] as f32).abs();
        let (da, db) = (disparity[a], disparity[b]);
        let dd = if valid(da) && valid(db) {
            (da - db).abs()
        } else {
            0.0
        };
        1.0 + grey * di + depth * dd
    };
    // Distance between a pixel and its predecessor along x, and along y,
    // both row-major.
    let mut along_x = vec![1.0f32; w * h];
    along_x.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, d) in row.iter_mut().enumerate().skip(1) {
            *d = step(y * w + x, y * w + x - 1);
        }
    });
    let mut along_y = vec![1.0f32; w * h];
    along_y
        .par_chunks_mut(w)
        .enumerate()
        .skip(1)
        .for_each(|(y, row)| {
            for (x, d) in row.iter_mut().enumerate() {
                *d = step(y * w + x, (y - 1) * w + x);
            }
        });
    let mut num: Vec<f32> = disparity
        .iter()
        .map(|&d| if valid(d) { d } else { 0.0 })
        .collect();
    let mut den: Vec<f32> = disparity.iter().map(|&d| valid(d) as u8 as f32).collect();
    let n = ITERATIONS;
    let mut weights = vec![0.0f32; w * h];
    for i in 0..n {
        let sigma = p.sigma_px * 3f32.sqrt() * 2f32.powi(n - i - 1) / (4f32.powi(n) - 1.0).sqrt();
        let log_a = -(2f32.sqrt()) / sigma;
        exp_weights(&along_x, log_a, &mut weights);
        along_rows(&mut num, &mut den, &weights, w);
        exp_weights(&along_y, log_a, &mut weights);
        along_columns(&mut num, &mut den, &weights, w);
    }
    let mut filled = 0;
    for ((d, &nu), &de) in disparity.iter_mut().zip(&num).zip(&den) {
        if valid(*d) {
            // A valid pixel's own weight is in its sum: `de` > 0. Smoothing
            // moves a disparity by its noise; a neighbourhood that would
            // move it further disagrees with it (mismatches around it, as
            // under heavy sensor noise), and it keeps its own value.
            let smoothed = nu / de;
            if p.smooth && de > 0.0 && (smoothed - *d).abs() <= p.sigma_disparity_px {
                *d = smoothed;
            }
        } else if de >= p.min_support && de > 0.0 {
            filled += 1;
            *d = nu / de;
        }
    }
    filled
}

/// `out[i] = exp(log_a * distance[i])`: the recursive filter's feedback
/// weights.
fn exp_weights(distance: &[f32], log_a: f32, out: &mut [f32]) {
    out.par_chunks_mut(4096)
        .zip(distance.par_chunks(4096))
        .for_each(|(o, d)| {
            for (o, &d) in o.iter_mut().zip(d) {
                *o = (log_a * d).exp();
            }
        });
}

/// Rows the passes along rows take at once, one a vector lane.
const ROWS_TOGETHER: usize = 8;

/// One pass of the recursive filter along every row of `a` and `b`
/// (`width` wide), both directions: J[x] += w[x] (J[x-1] - J[x]), then the
/// same from the right. A row's recursion is a chain of dependent steps, so
/// [`ROWS_TOGETHER`] rows are taken at once, transposed so that each is a
/// lane of one vector (each lane's arithmetic is its row's, so the same
/// bits); blocks of rows run in parallel.
fn along_rows(a: &mut [f32], b: &mut [f32], weights: &[f32], width: usize) {
    let block = width * ROWS_TOGETHER;
    let isa = Isa::detect();
    a.par_chunks_mut(block)
        .zip(b.par_chunks_mut(block))
        .zip(weights.par_chunks(block))
        .for_each_init(
            || [(); 3].map(|_| vec![[0.0f32; ROWS_TOGETHER]; width]),
            |[ta, tb, tw], ((ba, bb), bw)| {
                if ba.len() < block {
                    for ((ra, rb), rw) in ba
                        .chunks_mut(width)
                        .zip(bb.chunks_mut(width))
                        .zip(bw.chunks(width))
                    {
                        recurse_along_row(ra, rb, rw);
                    }
                    return;
                }
                for (rows, lanes) in [(&*ba, &mut *ta), (&*bb, &mut *tb), (bw, &mut *tw)] {
                    for (r, row) in rows.chunks(width).enumerate() {
                        for (lane, &v) in lanes.iter_mut().zip(row) {
                            lane[r] = v;
                        }
                    }
                }
                isa.recurse_along_lanes(ta, tb, tw);
                for (rows, lanes) in [(ba, &*ta), (bb, &*tb)] {
                    for (r, row) in rows.chunks_mut(width).enumerate() {
                        for (v, lane) in row.iter_mut().zip(lanes) {
                            *v = lane[r];
                        }
                    }
                }
            },
        );
}

/// The recursion along one row of `a` and `b` with its weights.
fn recurse_along_row(ra: &mut [f32], rb: &mut [f32], rw: &[f32]) {
    let width = ra.len();
    for x in 1..width {
        let k = rw[x];
        ra[x] += k * (ra[x - 1] - ra[x]);
        rb[x] += k * (rb[x - 1] - rb[x]);
    }
    for x in (0..width.saturating_sub(1)).rev() {
        let k = rw[x + 1];
        ra[x] += k * (ra[x + 1] - ra[x]);
        rb[x] += k * (rb[x + 1] - rb[x]);
    }
}

kernels! {
    /// [`recurse_along_row`] on [`ROWS_TOGETHER`] rows at once, transposed:
    /// `a[x][r]` is row r's value at x.
    fn recurse_along_lanes(
        a: &mut [[f32; ROWS_TOGETHER]],
        b: &mut [[f32; ROWS_TOGETHER]],
        w: &[[f32; ROWS_TOGETHER]],
    ) {
        let width = a.len().min(b.len()).min(w.len());
        let step = |to: &mut [f32; ROWS_TOGETHER], from: &[f32; ROWS_TOGETHER], k: &[f32; ROWS_TOGETHER]| {
            for r in 0..ROWS_TOGETHER {
                to[r] += k[r] * (from[r] - to[r]);
            }
        };
        for x in 1..width {
            let (from_a, from_b) = (a[x - 1], b[x - 1]);
            step(&mut a[x], &from_a, &w[x]);
            step(&mut b[x], &from_b, &w[x]);
        }
        for x in (0..width.saturating_sub(1)).rev() {
            let (from_a, from_b) = (a[x + 1], b[x + 1]);
            step(&mut a[x], &from_a, &w[x + 1]);
            step(&mut b[x], &from_b, &w[x + 1]);
        }
    }
}

/// The same down and up every column, a whole row at a time (the inner
/// loop runs along the row and vectorises; rows depend on each other).
fn along_columns(a: &mut [f32], b: &mut [f32], weights: &[f32], width: usize) {
    let h = a.len() / width.max(1);
    // Row `to` moves towards row `from` by the weights of row `link`.
    let step = |v: &mut [f32], to: usize, from: usize, link: usize| {
        let k = &weights[link * width..(link + 1) * width];
        let (lo, hi) = v.split_at_mut(to.max(from) * width);
        let (t, f) = if to > from {
            (&mut hi[..width], &lo[from * width..(from + 1) * width])
        } else {
            (&mut lo[to * width..(to + 1) * width], &hi[..width])
        };
        for ((t, &f), &k) in t.iter_mut().zip(f).zip(k) {
            *t += k * (f - *t);
        }
    };
    for y in 1..h {
        step(a, y, y - 1, y);
        step(b, y, y - 1, y);
    }
    for y in (0..h.saturating_sub(1)).rev() {
        step(a, y, y + 1, y + 1);
        step(b, y, y + 1, y + 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The passes along rows, blocks of rows taken at once on either
    /// instruction set, give each row's own recursion's bits (a tail of
    /// rows under a block included).
    #[test]
    fn rows_taken_together_keep_each_rows_bits() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(6);
        let width = 37;
        for rows in [1, ROWS_TOGETHER, 2 * ROWS_TOGETHER + 3] {
            let mut random = |lo: f32, hi: f32| -> Vec<f32> {
                (0..width * rows)
                    .map(|_| rng.random_range(lo..hi))
                    .collect()
            };
            let (a, b, w) = (random(-50.0, 50.0), random(0.0, 1.0), random(0.0, 1.0));
            let (mut want_a, mut want_b) = (a.clone(), b.clone());
            for ((ra, rb), rw) in want_a
                .chunks_mut(width)
                .zip(want_b.chunks_mut(width))
                .zip(w.chunks(width))
            {
                recurse_along_row(ra, rb, rw);
            }
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let (mut got_a, mut got_b) = (a.clone(), b.clone());
            along_rows(&mut got_a, &mut got_b, &w, width);
            assert_eq!(bits(&got_a), bits(&want_a), "{rows} rows");
            assert_eq!(bits(&got_b), bits(&want_b), "{rows} rows");
            if rows >= ROWS_TOGETHER {
                let lanes = |v: &[f32]| -> Vec<[f32; ROWS_TOGETHER]> {
                    (0..width)
                        .map(|x| std::array::from_fn(|r| v[r * width + x]))
                        .collect()
                };
                for isa in [Isa::Scalar, Isa::detect()] {
                    let (mut la, mut lb) = (lanes(&a), lanes(&b));
                    isa.recurse_along_lanes(&mut la, &mut lb, &lanes(&w));
                    assert_eq!(
                        bits(la.as_flattened()),
                        bits(lanes(&want_a).as_flattened()),
                        "{isa:?}"
                    );
                    assert_eq!(
                        bits(lb.as_flattened()),
                        bits(lanes(&want_b).as_flattened()),
                        "{isa:?}"
                    );
                }
            }
        }
    }

    fn params() -> FillParams {
        FillParams {
            sigma_px: 8.0,
            sigma_grey: 16.0,
            sigma_disparity_px: 2.0,
            min_support: 0.3,
            smooth: true,
        }
    }

    fn flat_guide(w: usize, h: usize) -> GreyImage {
        GreyImage {
            width: w,
            height: h,
            data: vec![100; w * h],
        }
    }

    #[test]
    fn a_plane_with_holes_is_filled_and_kept_exactly() {
        // A slanted plane (the filter keeps linear functions inside a
        // region; within about 2 sigma of the image's border its one-sided
        // kernel leans) with a 6 px hole.
        let (w, h) = (80, 60);
        let plane = |x: usize, y: usize| 20.0 + 0.05 * x as f32 + 0.02 * y as f32;
        let mut d: Vec<f32> = (0..w * h).map(|i| plane(i % w, i / w)).collect();
        for y in 27..33 {
            for x in 37..43 {
                d[y * w + x] = f32::NAN;
            }
        }
        let filled = fill_disparity(&mut d, &flat_guide(w, h), &params());
        assert_eq!(filled, 36);
        for y in 16..44 {
            for x in 16..64 {
                let e = (d[y * w + x] - plane(x, y)).abs();
                assert!(e < 0.02, "({x}, {y}): {e} px off");
            }
        }
    }

    #[test]
    fn noise_falls_and_edges_stay() {
        // Two regions, disparity 10 and 30, split at x = 40 where the guide
        // steps from grey 60 to 180; +-0.5 px alternating noise on both.
        let (w, h) = (80, 60);
        let guide = GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| if i % w < 40 { 60 } else { 180 })
                .collect(),
        };
        let truth = |x: usize| if x < 40 { 10.0f32 } else { 30.0 };
        let noise = |i: usize| if (i * 7919) % 13 < 6 { 0.5 } else { -0.5 };
        let mut d: Vec<f32> = (0..w * h).map(|i| truth(i % w) + noise(i)).collect();
        fill_disparity(&mut d, &guide, &params());
        let mae: f32 =
            (0..w * h).map(|i| (d[i] - truth(i % w)).abs()).sum::<f32>() / (w * h) as f32;
        assert!(mae < 0.15, "mean error {mae} px after, 0.5 before");
        for y in 0..h {
            assert!((d[y * w + 39] - 10.0).abs() < 0.5, "{}", d[y * w + 39]);
            assert!((d[y * w + 40] - 30.0).abs() < 0.5, "{}", d[y * w + 40]);
        }
    }

    #[test]
    fn holes_beyond_reach_or_across_an_outline_stay_invalid() {
        let (w, h) = (120, 40);
        // Valid only on the left third; the guide steps at x = 40.
        let guide = GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| if i % w < 40 { 50 } else { 200 })
                .collect(),
        };
        let mut d: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 40 { 12.0 } else { f32::NAN })
            .collect();
        let smooth_only = FillParams {
            smooth: false,
            ..params()
        };
        let filled = fill_disparity(&mut d, &guide, &smooth_only);
        assert_eq!(filled, 0, "the outline stops the fill");
        // Without the outline the fill reaches beyond a straight border
        // (where the support is at most a half) about as far as the
        // support stays above its minimum, not to the far end.
        let mut d: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 40 { 12.0 } else { f32::NAN })
            .collect();
        let reach = FillParams {
            min_support: 0.2,
            ..smooth_only
        };
        fill_disparity(&mut d, &flat_guide(w, h), &reach);
        assert!(!d[20 * w + 45].is_nan());
        assert!(d[20 * w + 119].is_nan());
        assert!(
            d.iter()
                .filter(|v| !v.is_nan())
                .all(|&v| (v - 12.0).abs() < 1e-4)
        );
    }

    #[test]
    fn a_valid_disparity_far_from_its_neighbourhood_keeps_its_value() {
        // Valid pixels on a checkerboard (no two valid ones adjacent, so no
        // disparity step stops the filter between them, as with scattered
        // mismatches under heavy noise), 10 px on even columns and 30 px on
        // odd ones: their neighbourhood averages about 20 px.
        let (w, h) = (20, 20);
        let d: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match ((x + y) % 2, x % 2) {
                    (0, 0) => 10.0,
                    (0, _) => 30.0,
                    _ => f32::NAN,
                }
            })
            .collect();
        // Allowed to move by up to 1000 px, they do move...
        let mut loose = d.clone();
        let p = FillParams {
            sigma_disparity_px: 1000.0,
            ..params()
        };
        fill_disparity(&mut loose, &flat_guide(w, h), &p);
        let centre = 10 * w + 10;
        assert_eq!(d[centre], 10.0);
        assert!((loose[centre] - 10.0).abs() > 5.0, "{}", loose[centre]);
        // ...by more than 2 px each: with 2 px they keep their own values.
        let mut kept = d.clone();
        fill_disparity(&mut kept, &flat_guide(w, h), &params());
        for (a, b) in kept.iter().zip(&d).filter(|(_, b)| !b.is_nan()) {
            assert_eq!(a, b);
        }
    }

    #[test]
    fn off_changes_nothing() {
        let (w, h) = (10, 10);
        let mut d = vec![f32::NAN; w * h];
        d[5] = 3.0;
        let before = d.clone();
        let off = FillParams {
            sigma_px: 0.0,
            ..params()
        };
        assert_eq!(fill_disparity(&mut d, &flat_guide(w, h), &off), 0);
        assert_eq!(format!("{d:?}"), format!("{before:?}"));
    }
}
