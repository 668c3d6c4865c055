//! Sub-pixel refinement of disparities on slanted windows: around each valid
//! disparity, the shift that best aligns a window of the left image with the
//! right image when the window is warped by the surface's own slant, the
//! disparity gradient of the (filled, smoothed) map around it, as PatchMatch
//! stereo's slanted support windows do (Bleyer, Rhemann & Rother, BMVC
//! 2011). A square window assumes a fronto-parallel surface: on a slanted one
//! (the dome's flanks, seen obliquely) the left window's columns meet the
//! right image at disparities that differ by the slope times their offset,
//! and the best single shift is biased where texture is weak and uneven
//! across the window. Zero-mean sum of squared differences, Gauss-Newton on
//! the shift, the right image linearly interpolated along its rows.
//! Written here: no crate refines disparities.

use super::pair::GreyImage;
use rayon::prelude::*;

/// How far the map may leave a window's plane at its rim for the window to
/// grow that far, px.
const OFF_PLANE_PX: f32 = 0.5;

/// How the slanted refinement runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlantedParams {
    /// Smallest window half-size, px (side 2 * half + 1).
    pub half_window: usize,
    /// Largest window half-size, px: a window grows (by half again, from
    /// `half_window`) until its gradients predict the shift to within
    /// `target_px`, or reaches this.
    pub max_half_window: usize,
    /// The shift's predicted standard deviation a window must reach, px:
    /// sqrt(2) sigma / sqrt(sum of squared gradients), sigma the images'
    /// noise (at least 8-bit quantisation's).
    pub target_px: f32,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Largest change from the input disparity, px; beyond it the input is
    /// kept.
    pub max_change_px: f32,
    /// Distance over which the slope is measured, px (central differences
    /// `slope_step` px either side); 0 = square windows (no slant).
    pub slope_step: usize,
}

impl Default for SlantedParams {
    fn default() -> Self {
        SlantedParams {
            half_window: 4,
            max_half_window: 4,
            target_px: 0.0,
            iterations: 4,
            max_change_px: 1.0,
            slope_step: 3,
        }
    }
}

/// `disparity` (left rectified image, px, NaN = invalid, row-major `w x h`)
/// refined on windows slanted by its own gradient; returns the refined map
/// and how many values changed. Values whose window leaves either image,
/// whose right window has no gradient, or that would move by more than
/// `max_change_px` keep their input value.
pub fn refine_slanted(
    left: &GreyImage,
    right: &GreyImage,
    disparity: &[f32],
    p: &SlantedParams,
) -> (Vec<f32>, usize) {
    let (w, h) = (left.width, left.height);
    let d_at = |x: isize, y: isize| -> Option<f32> {
        if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
            return None;
        }
        let v = disparity[x as usize + y as usize * w];
        (!v.is_nan()).then_some(v)
    };
    // Noise per image, from the pair's own residual at these disparities
    // (blind to texture, unlike a one-image estimate; that one where too few
    // pixels match), at least 8-bit quantisation's (1 / sqrt(12)).
    let sigma = super::pair_noise_dn(left, right, disparity)
        .unwrap_or_else(|| super::noise_sigma(left).max(super::noise_sigma(right)))
        .max(12f64.recip().sqrt()) as f32;
    let halves = window_halves(p);
    let k = p.slope_step as isize;
    let refined: Vec<(f32, bool)> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let d0 = disparity[i];
            if d0.is_nan() {
                return (d0, false);
            }
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let slope = |a: Option<f32>, b: Option<f32>| match (a, b) {
                (Some(a), Some(b)) if k > 0 => (b - a) / (2 * k) as f32,
                _ => 0.0,
            };
            let window = Window {
                x,
                y,
                gx: slope(d_at(x - k, y), d_at(x + k, y)),
                gy: slope(d_at(x, y - k), d_at(x, y + k)),
            };
            // The smallest window whose gradients pin the shift well enough.
            let mut half = None;
            for (n, &hw) in halves.iter().enumerate() {
                // A larger window only where the surface stays on the
                // window's plane out to it (not across a depth edge or
                // round a bend the plane does not follow).
                let r = hw as isize;
                let planar = |&(i, j): &(isize, isize)| {
                    d_at(x + i, y + j).is_some_and(|d| {
                        (d - (d0 + window.gx * i as f32 + window.gy * j as f32)).abs()
                            <= OFF_PLANE_PX
                    })
                };
                let rim = [
                    (-r, -r),
                    (0, -r),
                    (r, -r),
                    (-r, 0),
                    (r, 0),
                    (-r, r),
                    (0, r),
                    (r, r),
                ];
                if n > 0 && !rim.iter().all(planar) {
                    break;
                }
                let Some((_, energy, _)) = window.step(left, right, d0, hw) else {
                    break;
                };
                half = Some(hw);
                if std::f32::consts::SQRT_2 * sigma / energy.max(1e-6).sqrt() <= p.target_px {
                    break;
                }
            }
            let Some(half) = half else {
                return (d0, false);
            };
            let mut d = d0;
            for _ in 0..p.iterations {
                let Some((step, energy, n)) = window.step(left, right, d, half) else {
                    return (d0, false);
                };
                if energy < 0.1 * n {
                    // Under about a third of a grey level of gradient per
                    // pixel (quantisation's own): the window does not pin a
                    // shift.
                    return (d0, false);
                }
                d += step.clamp(-0.5, 0.5);
                if step.abs() < 1e-3 {
                    break;
                }
            }
            if (d - d0).abs() > p.max_change_px {
                (d0, false)
            } else {
                (d, true)
            }
        })
        .collect();
    let changed = refined.iter().filter(|(_, c)| *c).count();
    (refined.into_iter().map(|(d, _)| d).collect(), changed)
}

/// The window half-sizes tried, smallest first: from `half_window`, each
/// half as large again, up to `max_half_window`.
fn window_halves(p: &SlantedParams) -> Vec<usize> {
    let mut halves = vec![p.half_window];
    while let Some(&last) = halves.last() {
        let next = (last + last.div_ceil(2)).min(p.max_half_window).min(15);
        if next <= last {
            break;
        }
        halves.push(next);
    }
    halves
}

/// A window around (x, y), slanted by the disparity gradient (gx, gy).
struct Window {
    x: isize,
    y: isize,
    gx: f32,
    gy: f32,
}

impl Window {
    /// One Gauss-Newton step of the disparity `d` on the window of
    /// half-size `half`: the step, the zero-mean right gradients' energy
    /// and the window's pixel count; `None` where the window leaves either
    /// image.
    fn step(
        &self,
        left: &GreyImage,
        right: &GreyImage,
        d: f32,
        half: usize,
    ) -> Option<(f32, f32, f32)> {
        let (w, h) = (left.width, left.height);
        let half = half as isize;
        let (x, y) = (self.x, self.y);
        if x - half < 0 || y - half < 0 || x + half >= w as isize || y + half >= h as isize {
            return None;
        }
        let at = |img: &GreyImage, x: usize, y: usize| img.data[x + y * w] as f64;
        // One pass of sums (no buffer per window: this runs for every pixel
        // and iteration): with e = (l - r) - mean(l - r) and gz = g - mean(g),
        // sum(e gz) = sum((l - r) g) - n mean(l - r) mean(g), and
        // sum(gz^2) = sum(g^2) - n mean(g)^2.
        let (mut s_lr, mut s_g, mut s_lrg, mut s_gg) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for j in -half..=half {
            let yy = (y + j) as usize;
            for ii in -half..=half {
                let xr = (x + ii) as f32 - (d + self.gx * ii as f32 + self.gy * j as f32);
                if xr < 1.0 || xr >= (w - 2) as f32 {
                    return None;
                }
                let x0 = xr.floor();
                let t = (xr - x0) as f64;
                let x0 = x0 as usize;
                let (r0, r1) = (at(right, x0, yy), at(right, x0 + 1, yy));
                let r = r0 + (r1 - r0) * t;
                // The gradient of the interpolated row: its slope between
                // the samples around.
                let g = 0.5
                    * ((r1 - at(right, x0 - 1, yy)) * (1.0 - t) + (at(right, x0 + 2, yy) - r0) * t);
                let lr = at(left, (x + ii) as usize, yy) - r;
                s_lr += lr;
                s_g += g;
                s_lrg += lr * g;
                s_gg += g * g;
            }
        }
        let side = (2 * half + 1) as f64;
        let n = side * side;
        // Raising d moves the right samples left: r changes by -g per px.
        let num = s_lrg - s_lr * s_g / n;
        let energy = (s_gg - s_g * s_g / n).max(0.0);
        Some(((-num / energy.max(1e-12)) as f32, energy as f32, n as f32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A weakly textured plane slanted along the rows: true disparity
    /// `d0 + slope * x`; the right image is the left one warped by it
    /// (smooth texture, so linear interpolation is close to exact).
    fn slanted_pair(w: usize, h: usize, d0: f32, slope: f32) -> (GreyImage, GreyImage, Vec<f32>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // Smooth texture: sums of random sinusoids, 12 grey levels of contrast.
        let waves: Vec<(f32, f32, f32, f32)> = (0..12)
            .map(|_| {
                (
                    rng.random_range(0.08..0.5f32),
                    rng.random_range(0.05..0.4f32),
                    rng.random_range(0.0..6.28f32),
                    rng.random_range(1.0..2.5f32),
                )
            })
            .collect();
        let texture = |u: f32, v: f32| {
            128.0
                + waves
                    .iter()
                    .map(|&(a, b, ph, amp)| amp * (a * u + b * v + ph).sin())
                    .sum::<f32>()
        };
        let mut left = vec![0u8; w * h];
        let mut right = vec![0u8; w * h];
        let truth: Vec<f32> = (0..w * h).map(|i| d0 + slope * (i % w) as f32).collect();
        for y in 0..h {
            for x in 0..w {
                left[x + y * w] = texture(x as f32, y as f32).round() as u8;
                // Right pixel xr sees the left point x with x - d(x) = xr:
                // x = (xr + d0) / (1 - slope).
                let xl = (x as f32 + d0) / (1.0 - slope);
                right[x + y * w] = texture(xl, y as f32).round() as u8;
            }
        }
        (
            GreyImage {
                width: w,
                height: h,
                data: left,
            },
            GreyImage {
                width: w,
                height: h,
                data: right,
            },
            truth,
        )
    }

    /// Mean absolute error against `truth` (row-major, `w` wide) over the
    /// pixels `margin` px inside the image, and right of x = 60 (where every
    /// right window is inside the right image).
    fn mean_error_inside(v: &[f32], truth: &[f32], w: usize, margin: usize) -> f64 {
        let h = truth.len() / w;
        let (mut sum, mut n) = (0.0, 0);
        for y in margin..h - margin {
            for x in 60..w - margin {
                sum += (v[x + y * w] - truth[x + y * w]).abs() as f64;
                n += 1;
            }
        }
        sum / n as f64
    }

    #[test]
    fn a_slanted_plane_is_refined_without_the_square_windows_bias() {
        let (w, h) = (200, 60);
        let (left, right, truth) = slanted_pair(w, h, 20.0, 0.3);
        // The input: the truth 0.4 px off (a matcher's bias), its slope right.
        let biased: Vec<f32> = truth.iter().map(|d| d + 0.4).collect();
        let mean_error = |v: &[f32]| mean_error_inside(v, &truth, w, 10);
        let (slanted, changed) = refine_slanted(&left, &right, &biased, &SlantedParams::default());
        assert!(changed > w * h / 2, "{changed} refined");
        let square = SlantedParams {
            slope_step: 0,
            ..SlantedParams::default()
        };
        let (flat, _) = refine_slanted(&left, &right, &biased, &square);
        let (before, on_slant, on_square) =
            (mean_error(&biased), mean_error(&slanted), mean_error(&flat));
        assert!(
            on_slant < 0.08 && on_slant < 0.5 * on_square,
            "mean error: {before:.3} px in, {on_slant:.3} px slanted, {on_square:.3} px square"
        );
    }

    #[test]
    fn windows_grow_on_weak_texture_until_they_pin_the_shift() {
        let (w, h) = (200, 70);
        let (left, right, truth) = slanted_pair(w, h, 20.0, 0.3);
        let biased: Vec<f32> = truth.iter().map(|d| d + 0.4).collect();
        let mean_error = |v: &[f32]| mean_error_inside(v, &truth, w, 16);
        let fixed = SlantedParams::default();
        let growing = SlantedParams {
            max_half_window: 10,
            target_px: 0.02,
            ..fixed
        };
        assert_eq!(window_halves(&growing), vec![4, 6, 9, 10]);
        let (a, _) = refine_slanted(&left, &right, &biased, &fixed);
        let (b, _) = refine_slanted(&left, &right, &biased, &growing);
        let (fixed_error, growing_error) = (mean_error(&a), mean_error(&b));
        assert!(
            growing_error < 0.7 * fixed_error,
            "mean error: fixed window {fixed_error:.4} px, growing {growing_error:.4} px"
        );
    }
}
