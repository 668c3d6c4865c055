//! Where an image has no texture of its own: windows whose grey-level spread
//! is within a small multiple of the sensor noise. Matching there only
//! measures noise, and semi-global matching fills such regions from their
//! surroundings, which is right inside a surface but invents islands of depth
//! in a blank background. The noise level comes from the image itself
//! (Immerkaer, "Fast noise variance estimation", CVIU 1996), so the test adapts
//! to each camera and exposure instead of a fixed grey-level threshold.

use super::pair::GreyImage;
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

    fn noisy(w: usize, h: usize, sigma: f64, texture: impl Fn(usize, usize) -> f64) -> GreyImage {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
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
            let img = noisy(200, 150, sigma, |_, _| 100.0);
            let s = noise_sigma(&img);
            assert!((s - sigma).abs() < 0.15 * sigma, "{s} vs {sigma}");
        }
    }

    #[test]
    fn flags_only_the_blank_half() {
        // Left half blank (noise only), right half a texture.
        let img = noisy(120, 60, 2.0, |x, y| {
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
}
