//! Lens blur: the fixed blur of a sharp lens and sensor, and defocus from the
//! thin-lens blur circle, c = A f |D1 - D2| / ((D1 - f) D2) (the paper's
//! module B; [`crate::design::blur_circle_mm`]), for a lens of focal length f
//! and aperture A = f / N focused at D1, at each pixel's depth D2.
//!
//! Defocus is layered, not per-pixel kernels: the image is blurred at a few
//! blur-circle diameters (0, then doubling from 0.5 px), each a separable
//! Gaussian of the disc's second moment (sigma = c / 4 for a disc of diameter
//! c), and each pixel blends the two layers that bracket its own diameter,
//! weighted so the blend's second moment is its own disc's.
//! Written here: two passes of a 1-D kernel over our own image layout.

use crate::design::blur_circle_mm;
use crate::simd::Isa;
use rayon::prelude::*;

/// A lens that focuses: what defocus needs besides each pixel's depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    /// Focal length, mm.
    pub focal_mm: f64,
    /// f-number N (aperture diameter f / N).
    pub f_number: f64,
    /// Distance the lens is focused at, along the optical axis, mm.
    pub focus_mm: f64,
    /// Pixel pitch, mm.
    pub pixel_mm: f64,
}

impl Lens {
    /// Blur-circle diameter, px, of a point `depth_mm` in front of the lens
    /// (along the optical axis); 0 for a point at infinity's limit or beyond
    /// reach of the formula (nearer than the focal length).
    pub fn blur_circle_px(&self, depth_mm: f64) -> f64 {
        if !depth_mm.is_finite() {
            let aperture = self.focal_mm / self.f_number;
            // D2 -> infinity: c = A f / (D1 - f).
            return aperture * self.focal_mm / (self.focus_mm - self.focal_mm) / self.pixel_mm;
        }
        if depth_mm <= self.focal_mm {
            return 0.0;
        }
        blur_circle_mm(
            self.focal_mm / self.f_number,
            self.focal_mm,
            self.focus_mm,
            depth_mm,
        ) / self.pixel_mm
    }
}

/// Separable Gaussian blur with clamped borders.
pub fn gaussian_blur(image: &[[f32; 3]], w: usize, h: usize, sigma: f64) -> Vec<[f32; 3]> {
    let radius = (3.0 * sigma).ceil() as isize;
    let mut kernel: Vec<f32> = (-radius..=radius)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let total: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= total);
    // Each output pixel sums its taps in kernel order in both passes (the
    // same bits whichever way the loops run).
    let isa = Isa::detect();
    let along_rows = |src: &[[f32; 3]]| -> Vec<[f32; 3]> {
        let mut dst = vec![[0.0f32; 3]; w * h];
        dst.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let src_row = &src[y * w..(y + 1) * w];
            blur_row(isa, row, src_row, &kernel);
        });
        dst
    };
    // Down the columns a whole row of taps at a time: memory is read in
    // order instead of one row apart per tap.
    let down_columns = |src: &[[f32; 3]]| -> Vec<[f32; 3]> {
        let mut dst = vec![[0.0f32; 3]; w * h];
        dst.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            isa.convolve_across_rows(
                row.as_flattened_mut(),
                src.as_flattened(),
                3 * w,
                y,
                &kernel,
            );
        });
        dst
    };
    down_columns(&along_rows(image))
}

/// One row of `src` blurred along itself by `kernel` (odd length, centred)
/// into `row`, edges clamped: each output sums its taps in kernel order.
/// The inside is a correlation along the row, RGB flattened (a step of 3
/// floats a tap), vectorised across outputs with the bits of a tap loop per
/// output.
fn blur_row(isa: Isa, row: &mut [[f32; 3]], src: &[[f32; 3]], kernel: &[f32]) {
    let (w, r) = (row.len(), kernel.len() / 2);
    let clamped = |x: usize| {
        let mut acc = [0.0f32; 3];
        for (k, &kw) in kernel.iter().enumerate() {
            let s = src[(x + k).saturating_sub(r).min(w - 1)];
            (0..3).for_each(|c| acc[c] += kw * s[c]);
        }
        acc
    };
    if w <= 2 * r {
        for (x, px) in row.iter_mut().enumerate() {
            *px = clamped(x);
        }
        return;
    }
    let inside = r..w - r;
    {
        // Output x reads src[x - r + k]: the run from 3 k floats in.
        let out = row[inside.clone()].as_flattened_mut();
        isa.correlate(out, src.as_flattened(), kernel, 3);
    }
    for x in (0..r).chain(w - r..w) {
        row[x] = clamped(x);
    }
}

/// The diameters of the layers, px: 0, then 0.5, 1, 2, ... up to the first at
/// or past `largest`.
fn layer_diameters(largest: f64) -> Vec<f64> {
    let mut d = vec![0.0];
    let mut c = 0.5;
    while d.last().is_some_and(|&last| last < largest) {
        d.push(c);
        c *= 2.0;
    }
    d
}

/// Blurs each pixel of `image` by a disc of its own diameter `circle_px`
/// (row-major, same size), by blending layers (see the module doc).
pub fn defocus(image: &[[f32; 3]], w: usize, h: usize, circle_px: &[f32]) -> Vec<[f32; 3]> {
    let largest = circle_px.iter().copied().fold(0.0f32, f32::max) as f64;
    let diameters = layer_diameters(largest);
    if diameters.len() < 2 {
        // Everything in focus.
        return image.to_vec();
    }
    let layers: Vec<Vec<[f32; 3]>> = diameters
        .iter()
        .map(|&c| {
            if c == 0.0 {
                image.to_vec()
            } else {
                gaussian_blur(image, w, h, c / 4.0)
            }
        })
        .collect();
    let mut out = vec![[0.0f32; 3]; w * h];
    out.par_iter_mut().enumerate().for_each(|(i, px)| {
        let c = circle_px[i] as f64;
        let upper = diameters
            .iter()
            .position(|&d| d >= c)
            .unwrap_or(diameters.len() - 1)
            .max(1);
        let (d0, d1) = (diameters[upper - 1], diameters[upper]);
        // A blend of two blurs has the weighted mean of their variances.
        let t = ((c * c - d0 * d0) / (d1 * d1 - d0 * d0)).clamp(0.0, 1.0) as f32;
        let (a, b) = (layers[upper - 1][i], layers[upper][i]);
        *px = std::array::from_fn(|ch| a[ch] + (b[ch] - a[ch]) * t);
    });
    out
}

/// The standard deviation (px) of the line spread of a bright-to-dark edge
/// along `row`: the second moment of the row's differences.
#[cfg(test)]
pub(crate) fn line_spread_sigma_px(row: &[f64]) -> f64 {
    let lsf: Vec<f64> = row.windows(2).map(|p| p[0] - p[1]).collect();
    let total: f64 = lsf.iter().sum();
    let mean = lsf
        .iter()
        .enumerate()
        .map(|(i, v)| i as f64 * v)
        .sum::<f64>()
        / total;
    let var = lsf
        .iter()
        .enumerate()
        .map(|(i, v)| (i as f64 - mean).powi(2) * v)
        .sum::<f64>()
        / total;
    var.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_blur_circle_is_the_thin_lens_formula() {
        // 8 mm lens at f/2 (A = 4 mm) focused at 500 mm: a point at 400 mm
        // blurs over 4 * 8 * 100 / (492 * 400) = 0.01626 mm = 2.71 px at
        // 6 um pixels; the focused distance is sharp.
        let lens = Lens {
            focal_mm: 8.0,
            f_number: 2.0,
            focus_mm: 500.0,
            pixel_mm: 0.006,
        };
        let expected = 4.0 * 8.0 * 100.0 / (492.0 * 400.0) / 0.006;
        assert!((lens.blur_circle_px(400.0) - expected).abs() < 1e-12);
        assert_eq!(lens.blur_circle_px(500.0), 0.0);
        assert!((lens.blur_circle_px(f64::INFINITY) - 4.0 * 8.0 / 492.0 / 0.006).abs() < 1e-12);
    }

    #[test]
    fn the_row_pass_gives_the_bits_of_a_tap_loop_per_output() {
        let w = 37;
        let src: Vec<[f32; 3]> = (0..w)
            .map(|x| [x as f32 * 0.37 % 1.0, (x * x) as f32 * 0.011 % 1.0, 0.5])
            .collect();
        for taps in [1usize, 3, 7, 13, 75] {
            let kernel: Vec<f32> = (0..taps).map(|k| 0.1 + k as f32 * 0.013).collect();
            let r = taps as isize / 2;
            let mut row = vec![[0.0f32; 3]; w];
            blur_row(Isa::detect(), &mut row, &src, &kernel);
            for (x, px) in row.iter().enumerate() {
                let mut acc = [0.0f32; 3];
                for (k, &kw) in kernel.iter().enumerate() {
                    let sx = (x as isize + k as isize - r).clamp(0, w as isize - 1);
                    (0..3).for_each(|c| acc[c] += kw * src[sx as usize][c]);
                }
                assert_eq!(
                    px.map(f32::to_bits),
                    acc.map(f32::to_bits),
                    "{taps} taps, x {x}"
                );
            }
        }
    }

    #[test]
    fn layers_bracket_every_diameter() {
        assert_eq!(layer_diameters(0.0), vec![0.0]);
        assert_eq!(layer_diameters(3.0), vec![0.0, 0.5, 1.0, 2.0, 4.0]);
    }

    #[test]
    fn a_uniform_circle_blurs_an_edge_by_its_second_moment() {
        // A vertical edge blurred by a 6 px circle everywhere: the line
        // spread's standard deviation is c / 4 = 1.5 px.
        let (w, h) = (64, 8);
        let image: Vec<[f32; 3]> = (0..w * h)
            .map(|i| if i % w < w / 2 { [1.0; 3] } else { [0.0; 3] })
            .collect();
        let out = defocus(&image, w, h, &vec![6.0; w * h]);
        let row: Vec<f64> = (0..w).map(|x| out[x + 4 * w][0] as f64).collect();
        let sigma = line_spread_sigma_px(&row);
        assert!((sigma - 1.5).abs() < 0.05, "{sigma}");
    }
}
