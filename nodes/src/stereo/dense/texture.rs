//! Where an image has no texture of its own: windows whose grey-level spread
//! is within a small multiple of the sensor noise. Matching there only
//! measures noise, and semi-global matching fills such regions from their
//! surroundings, which is right inside a surface but invents islands of depth
//! in a blank background. The noise level comes from the image itself
//! (Immerkaer, "Fast noise variance estimation", CVIU 1996), so the test adapts
//! to each camera and exposure instead of a fixed grey-level threshold. A
//! pair's own residual at its matches measures its noise for the census
//! cost's smoothing of noisy pairs.

use super::pair::GreyImage;
use crate::numeric::kth_smallest_f32;
use rayon::prelude::*;

/// The standard deviation of the image noise, grey levels (Immerkaer: the
/// mean absolute response to a Laplacian-difference mask that cancels smooth
/// image content). Texture raises it a little, which only makes the texture
/// test more cautious.
pub fn noise_sigma(img: &GreyImage) -> f64 {
    let (w, h) = (img.width, img.height);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let total: f64 = (1..h - 1)
        .into_par_iter()
        .map(|y| {
            let p = |x: usize, y: usize| img.at(x, y) as i32;
            (1..w - 1)
                .map(|x| {
                    let v = p(x - 1, y - 1) - 2 * p(x, y - 1) + p(x + 1, y - 1) - 2 * p(x - 1, y)
                        + 4 * p(x, y)
                        - 2 * p(x + 1, y)
                        + p(x - 1, y + 1)
                        - 2 * p(x, y + 1)
                        + p(x + 1, y + 1);
                    v.unsigned_abs() as f64
                })
                .sum::<f64>()
        })
        .sum();
    (std::f64::consts::PI / 2.0).sqrt() * total / (6.0 * ((w - 2) * (h - 2)) as f64)
}

/// The noise of a rectified pair, grey levels per image, from its own
/// photometric residual: left minus right at the matched `disparity` (px,
/// NaN = none), its median absolute deviation (robust to occlusions and to an
/// exposure offset) over sqrt 2. Unlike a one-image estimate it is blind to
/// texture, and it sees the noise that resampling (rectification) has
/// spread over neighbouring pixels. `None` with under 1,000 matched pixels.
pub fn pair_noise_dn(left: &GreyImage, right: &GreyImage, disparity: &[f32]) -> Option<f64> {
    let w = left.width;
    if w < 2 {
        return None; // no pixel has a right neighbour to interpolate with
    }
    // Row by row (a pixel's column from its index would be a division).
    // Every pixel's residual is written and only a matched one kept (the
    // next one overwrites the rest): no branch on the data.
    let mut residuals = vec![0f32; disparity.len()];
    let mut kept = 0;
    for (y, row) in disparity.chunks(w).enumerate() {
        let (left_row, right_row) = (left.row(y), right.row(y));
        for (x, &d) in row.iter().enumerate() {
            let xr = x as f32 - d;
            let matched = d.is_finite() & (xr >= 0.0) & (xr < (w - 1) as f32);
            let xr = if matched { xr } else { 0.0 };
            let x0 = xr as usize;
            let t = xr - x0 as f32;
            let r = right_row[x0] as f32 * (1.0 - t) + right_row[x0 + 1] as f32 * t;
            residuals[kept] = left_row[x] as f32 - r;
            kept += matched as usize;
        }
    }
    residuals.truncate(kept);
    if residuals.len() < 1000 {
        return None;
    }
    let mid = residuals.len() / 2;
    let centre = kth_smallest_f32(&residuals, mid)?;
    // The residuals' deviations from their median, in their place.
    for r in residuals.iter_mut() {
        *r = (*r - centre).abs();
    }
    let deviation = kth_smallest_f32(&residuals, mid)?;
    Some(1.4826 * deviation as f64 / std::f64::consts::SQRT_2)
}

/// The Gaussian smoothing (sigma, px) a census cost needs on a pair whose
/// noise is `noise_dn` grey levels per image: a census bit compares two
/// single pixels, so noise of a few grey levels flips the bits of weak
/// texture and the matcher finds nothing unique. The sigma brings white
/// noise down to 1 grey level (a 2D Gaussian of sigma s divides it by
/// 2 s sqrt(pi)), at most 2 px so texture of a few px survives; none under
/// 0.7 px (about 2.5 grey levels: clean pairs, Middlebury's among them, are
/// matched as they are).
pub fn census_prefilter_sigma_px(noise_dn: f64) -> f64 {
    let sigma = noise_dn / (2.0 * std::f64::consts::PI.sqrt());
    if sigma < 0.7 { 0.0 } else { sigma.min(2.0) }
}

/// `img` smoothed by a Gaussian of `sigma_px` (the `image` crate's).
pub fn smoothed(img: &GreyImage, sigma_px: f64) -> GreyImage {
    let buffer = image::GrayImage::from_raw(img.width as u32, img.height as u32, img.data.clone())
        .expect("a grey image holds width x height bytes");
    GreyImage {
        width: img.width,
        height: img.height,
        data: image::imageops::blur(&buffer, sigma_px as f32).into_raw(),
    }
}

/// For every pixel, whether the `win_w x win_h` window around it (clamped to
/// the image) has a grey-level standard deviation below `min_std`.
pub fn flat_windows(img: &GreyImage, win_w: usize, win_h: usize, min_std: f64) -> Vec<bool> {
    let (w, h) = (img.width, img.height);
    let (rx, ry) = ((win_w / 2) as isize, (win_h / 2) as isize);
    let mut flat = vec![false; w * h];
    flat.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        // Column sums over the window's rows, then a running sum along x.
        let rows: Vec<usize> = (-ry..=ry)
            .map(|dy| (y as isize + dy).clamp(0, h as isize - 1) as usize)
            .collect();
        let (mut s1, mut s2) = (vec![0f64; w], vec![0f64; w]);
        for &yy in &rows {
            for (x, v) in img.row(yy).iter().enumerate() {
                let v = *v as f64;
                s1[x] += v;
                s2[x] += v * v;
            }
        }
        let n = (rows.len() * (2 * rx as usize + 1)) as f64;
        for (x, f) in row.iter_mut().enumerate() {
            let (mut a, mut b) = (0.0, 0.0);
            for dx in -rx..=rx {
                let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                a += s1[xx];
                b += s2[xx];
            }
            let var = (b / n - (a / n).powi(2)).max(0.0);
            *f = var.sqrt() < min_std;
        }
    });
    flat
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy(
        w: usize,
        h: usize,
        sigma: f64,
        seed: u64,
        texture: impl Fn(usize, usize) -> f64,
    ) -> GreyImage {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let n = Normal::new(0.0, sigma).unwrap();
        GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| {
                    (texture(i % w, i / w) + n.sample(&mut rng))
                        .round()
                        .clamp(0.0, 255.0) as u8
                })
                .collect(),
        }
    }

    #[test]
    fn estimates_the_noise_of_a_flat_image() {
        for sigma in [2.0, 5.0] {
            let img = noisy(200, 150, sigma, 7, |_, _| 100.0);
            let s = noise_sigma(&img);
            assert!((s - sigma).abs() < 0.15 * sigma, "{s} vs {sigma}");
        }
    }

    #[test]
    fn flags_only_the_blank_half() {
        // Left half blank (noise only), right half a texture.
        let img = noisy(120, 60, 2.0, 7, |x, y| {
            if x < 60 {
                40.0
            } else {
                120.0 + 50.0 * ((x as f64 * 0.9).sin() * (y as f64 * 0.7).cos())
            }
        });
        let sigma = noise_sigma(&img);
        let flat = flat_windows(&img, 9, 7, 2.0 * sigma);
        let share = |xs: std::ops::Range<usize>| {
            let n = xs.len() * 50;
            let f = (5..55)
                .flat_map(|y| xs.clone().map(move |x| (x, y)))
                .filter(|&(x, y)| flat[y * 120 + x])
                .count();
            f as f64 / n as f64
        };
        assert!(share(5..50) > 0.99, "{}", share(5..50));
        assert!(share(70..115) < 0.01, "{}", share(70..115));
    }

    #[test]
    fn the_pair_residual_measures_the_noise_not_the_texture() {
        // Left(x) = texture(x), right(x) = texture(x + 5): disparity 5.
        let (w, h) = (160, 120);
        let wave =
            |x: usize, y: usize| 128.0 + 60.0 * ((x as f64 * 0.7).sin() * (y as f64 * 0.3).cos());
        for noise in [0.0, 4.0, 10.0] {
            let (left, right) = (
                noisy(w, h, noise, 1, wave),
                noisy(w, h, noise, 2, |x, y| wave(x + 5, y)),
            );
            let disparity = vec![5.0f32; w * h];
            let measured = pair_noise_dn(&left, &right, &disparity).unwrap();
            // Rounding noisy values to grey levels adds 0.29 in quadrature.
            let expected = if noise > 0.0 {
                (noise * noise + 1.0 / 12.0).sqrt()
            } else {
                0.0
            };
            assert!(
                (measured - expected).abs() < 0.1 * expected + 0.15,
                "{noise}: {measured}"
            );
        }
        let small = noisy(20, 20, 1.0, 1, wave);
        assert_eq!(
            pair_noise_dn(&small, &small, &[0.0; 400]),
            None,
            "too few matches"
        );
    }

    #[test]
    fn census_smooths_noisy_pairs_only() {
        assert_eq!(census_prefilter_sigma_px(2.0), 0.0, "clean");
        let s = census_prefilter_sigma_px(5.0);
        assert!((s - 5.0 / 3.5449).abs() < 1e-3, "{s}");
        assert_eq!(census_prefilter_sigma_px(40.0), 2.0, "capped");
        // Smoothing white noise by that sigma leaves about 1 grey level.
        let flat = noisy(200, 200, 5.0, 3, |_, _| 128.0);
        let after = smoothed(&flat, census_prefilter_sigma_px(5.0));
        let n = after.data.len() as f64;
        let mean = after.data.iter().map(|&v| v as f64).sum::<f64>() / n;
        let std = (after
            .data
            .iter()
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        assert!((std - 1.0).abs() < 0.3, "{std}");
    }
}
