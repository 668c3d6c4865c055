//! SURF-style detector and descriptor (Bay et al. 2008, "Speeded-Up Robust
//! Features"): the determinant of a box-filter Hessian on an integral image,
//! extrema over position and scale refined to sub-pixel and sub-scale, a
//! Haar-wavelet orientation and the 64-float descriptor.

use super::integral::Integral;
use super::{Descriptors, Features, Keypoint, check_image, keep_strongest_spread};
use crate::simd::{Isa, kernels};
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// Settings of the Fast-Hessian detector.
#[derive(Debug, Clone, PartialEq)]
pub struct HessianParams {
    /// Smallest scale-normalised Hessian determinant kept (grey 0..1 images;
    /// Bay et al.'s 0.0004 on this scale is a sparse setting).
    pub threshold: f32,
    /// Number of octaves (filter sizes 9-27 in the first, doubling after).
    pub octaves: usize,
    /// No orientation (angle 0): right for rectified pairs, and faster.
    pub upright: bool,
    /// At most this many keypoints, strongest first, spread over the image.
    pub max_features: usize,
}

impl Default for HessianParams {
    fn default() -> Self {
        HessianParams {
            threshold: 0.0001,
            octaves: 4,
            upright: true,
            max_features: 4000,
        }
    }
}

/// Box-filter side (px) of layer `i` (0..4) of octave `o`: 9, 15, 21, 27 for
/// the first octave, 15, 27, 39, 51 for the second, ...
fn filter_size(o: usize, i: usize) -> i64 {
    3 * ((1i64 << (o + 1)) * (i as i64 + 1) + 1)
}

/// One response layer: the Hessian determinant on a grid of `step` px.
struct Layer {
    size: i64,
    step: i64,
    cols: usize,
    rows: usize,
    response: Vec<f32>,
    laplacian_positive: Vec<bool>,
}

impl Layer {
    fn compute(ii: &Integral, size: i64, step: i64) -> Layer {
        Self::compute_with(ii, size, step, true)
    }

    /// [`Layer::compute`], the runs inside the image by [`Isa::hessian_run`]
    /// or (`runs` false, for tests) pixel by pixel.
    fn compute_with(ii: &Integral, size: i64, step: i64, runs: bool) -> Layer {
        let cols = ii.width().div_ceil(step as usize);
        let rows = ii.height().div_ceil(step as usize);
        let mut response = vec![0.0f32; cols * rows];
        let mut laplacian_positive = vec![false; cols * rows];
        let b = (size - 1) / 2;
        let l = size / 3;
        let norm = 1.0 / (size * size) as f64;
        // Each box as four signed table offsets from the entry of its centre
        // pixel, with a weight: no clamping where the filter lies inside.
        let stride = ii.stride() as i64;
        let corners = |x0: i64, y0: i64, w: i64, h: i64| -> [i64; 4] {
            [
                (y0 + h) * stride + x0 + w,
                y0 * stride + x0 + w,
                (y0 + h) * stride + x0,
                y0 * stride + x0,
            ]
        };
        // The two boxes of dxx, the two of dyy, the four of dxy.
        let boxes: [([i64; 4], f64); 8] = [
            (corners(-b, -l + 1, size, 2 * l - 1), 1.0),
            (corners(-l / 2, -l + 1, l, 2 * l - 1), -3.0),
            (corners(-l + 1, -b, 2 * l - 1, size), 1.0),
            (corners(-l + 1, -l / 2, 2 * l - 1, l), -3.0),
            (corners(1, -l, l, l), 1.0),
            (corners(-l, 1, l, l), 1.0),
            (corners(-l, -l, l, l), -1.0),
            (corners(1, 1, l, l), -1.0),
        ];
        let table = ii.table();
        let apply = |base: i64, boxes: &[([i64; 4], f64)]| -> f64 {
            boxes
                .iter()
                .map(|(o, wt)| {
                    let at = |k: usize| table[(base + o[k]) as usize];
                    wt * (at(0) - at(1) - at(2) + at(3))
                })
                .sum()
        };
        let (w, h) = (ii.width() as i64, ii.height() as i64);
        let isa = Isa::detect();
        let pixel = |x: i64, y: i64, inside_y: bool| -> (f32, bool) {
            let (dxx, dyy, dxy) = if inside_y && x >= b && x <= w - 1 - b {
                let base = y * stride + x;
                (
                    apply(base, &boxes[..2]),
                    apply(base, &boxes[2..4]),
                    apply(base, &boxes[4..]),
                )
            } else {
                (
                    ii.box_sum(x - b, y - l + 1, size, 2 * l - 1)
                        - 3.0 * ii.box_sum(x - l / 2, y - l + 1, l, 2 * l - 1),
                    ii.box_sum(x - l + 1, y - b, 2 * l - 1, size)
                        - 3.0 * ii.box_sum(x - l + 1, y - l / 2, 2 * l - 1, l),
                    ii.box_sum(x + 1, y - l, l, l) + ii.box_sum(x - l, y + 1, l, l)
                        - ii.box_sum(x - l, y - l, l, l)
                        - ii.box_sum(x + 1, y + 1, l, l),
                )
            };
            let (dxx, dyy, dxy) = (dxx * norm, dyy * norm, dxy * norm);
            ((dxx * dyy - 0.81 * dxy * dxy) as f32, dxx + dyy >= 0.0)
        };
        response
            .par_chunks_mut(cols)
            .zip(laplacian_positive.par_chunks_mut(cols))
            .enumerate()
            .for_each(|(r, (resp, lap))| {
                let y = r as i64 * step;
                let inside_y = y >= b && y <= h - 1 - b;
                // At step 1 the filters that lie inside the image, a run of
                // the row, are one kernel over the table's rows (the same
                // operations per pixel as `pixel`).
                let run = if runs && inside_y && step == 1 && b <= w - 1 - b {
                    b as usize..(w - b) as usize
                } else {
                    0..0
                };
                if !run.is_empty() {
                    isa.hessian_run(
                        table,
                        (y * stride + run.start as i64) as usize,
                        &boxes,
                        norm,
                        &mut resp[run.clone()],
                        &mut lap[run.clone()],
                    );
                }
                for c in (0..cols).filter(|c| !run.contains(c)) {
                    (resp[c], lap[c]) = pixel(c as i64 * step, y, inside_y);
                }
            });
        Layer {
            size,
            step,
            cols,
            rows,
            response,
            laplacian_positive,
        }
    }

    #[inline]
    fn at(&self, c: i64, r: i64) -> f64 {
        self.response[r as usize * self.cols + c as usize] as f64
    }
}

kernels! {
    /// A Hessian layer's responses along a run of one row where every filter
    /// lies inside the image, at step 1: `start` is the table entry of the
    /// run's first pixel, `boxes` the eight boxes' corners from it with
    /// their weights (the two of dxx, the two of dyy, the four of dxy);
    /// each pixel computed by [`Layer::compute`]'s per-pixel operations in
    /// their order, so the same bits, several pixels at once.
    fn hessian_run(
        table: &[f64],
        start: usize,
        boxes: &[([i64; 4], f64); 8],
        norm: f64,
        response: &mut [f32],
        laplacian_positive: &mut [bool],
    ) {
        let n = response.len().min(laplacian_positive.len());
        let corners: [[&[f64]; 4]; 8] = std::array::from_fn(|k| {
            std::array::from_fn(|j| {
                let from = (start as i64 + boxes[k].0[j]) as usize;
                &table[from..from + n]
            })
        });
        for i in 0..n {
            let t = |k: usize| {
                let c = &corners[k];
                boxes[k].1 * (c[0][i] - c[1][i] - c[2][i] + c[3][i])
            };
            let dxx = t(0) + t(1);
            let dyy = t(2) + t(3);
            let dxy = t(4) + t(5) + t(6) + t(7);
            let (dxx, dyy, dxy) = (dxx * norm, dyy * norm, dxy * norm);
            response[i] = (dxx * dyy - 0.81 * dxy * dxy) as f32;
            laplacian_positive[i] = dxx + dyy >= 0.0;
        }
    }
}

/// Local maxima of one octave's middle layers above `threshold`, interpolated
/// in position and scale.
fn octave_extrema(layers: &[Layer], width: usize, height: usize, threshold: f32) -> Vec<Keypoint> {
    let mut found = Vec::new();
    for i in 1..layers.len() - 1 {
        let (below, mid, above) = (&layers[i - 1], &layers[i], &layers[i + 1]);
        let step = mid.step;
        // The largest filter of the triple must lie inside the image.
        let border = (above.size - 1) / 2 + 1;
        let c0 = ((border + step - 1) / step).max(1);
        let r0 = c0;
        let c1 = ((width as i64 - 1 - border) / step).min(mid.cols as i64 - 2);
        let r1 = ((height as i64 - 1 - border) / step).min(mid.rows as i64 - 2);
        if c1 < c0 || r1 < r0 {
            continue;
        }
        let rows: Vec<Vec<Keypoint>> = (r0..=r1)
            .into_par_iter()
            .map(|r| {
                let mut out = Vec::new();
                for c in c0..=c1 {
                    let v = mid.at(c, r);
                    if v <= threshold as f64 || !is_maximum(below, mid, above, c, r, v) {
                        continue;
                    }
                    if let Some(kp) = interpolate(below, mid, above, c, r) {
                        out.push(kp);
                    }
                }
                out
            })
            .collect();
        found.extend(rows.into_iter().flatten());
    }
    found
}

fn is_maximum(below: &Layer, mid: &Layer, above: &Layer, c: i64, r: i64, v: f64) -> bool {
    for layer in [below, mid, above] {
        for dr in -1..=1 {
            for dc in -1..=1 {
                if std::ptr::eq(layer, mid) && dr == 0 && dc == 0 {
                    continue;
                }
                if layer.at(c + dc, r + dr) >= v {
                    return false;
                }
            }
        }
    }
    true
}

/// Fits a 3D quadratic to the 3x3x3 neighbourhood and moves the extremum to its
/// peak; `None` when the peak lies more than one sample away (an unstable one).
fn interpolate(below: &Layer, mid: &Layer, above: &Layer, c: i64, r: i64) -> Option<Keypoint> {
    let v = mid.at(c, r);
    let dx = (mid.at(c + 1, r) - mid.at(c - 1, r)) / 2.0;
    let dy = (mid.at(c, r + 1) - mid.at(c, r - 1)) / 2.0;
    let ds = (above.at(c, r) - below.at(c, r)) / 2.0;
    let dxx = mid.at(c + 1, r) + mid.at(c - 1, r) - 2.0 * v;
    let dyy = mid.at(c, r + 1) + mid.at(c, r - 1) - 2.0 * v;
    let dss = above.at(c, r) + below.at(c, r) - 2.0 * v;
    let dxy = (mid.at(c + 1, r + 1) - mid.at(c - 1, r + 1) - mid.at(c + 1, r - 1)
        + mid.at(c - 1, r - 1))
        / 4.0;
    let dxs =
        (above.at(c + 1, r) - above.at(c - 1, r) - below.at(c + 1, r) + below.at(c - 1, r)) / 4.0;
    let dys =
        (above.at(c, r + 1) - above.at(c, r - 1) - below.at(c, r + 1) + below.at(c, r - 1)) / 4.0;
    let h = nalgebra::Matrix3::new(dxx, dxy, dxs, dxy, dyy, dys, dxs, dys, dss);
    let offset = -(h.try_inverse()? * nalgebra::Vector3::new(dx, dy, ds));
    if !offset.iter().all(|o| o.is_finite() && o.abs() <= 1.0) {
        return None;
    }
    let step = mid.step as f64;
    let size = mid.size as f64 + offset.z * (above.size - mid.size) as f64;
    Some(Keypoint {
        x_px: ((c as f64 + offset.x) * step) as f32,
        y_px: ((r as f64 + offset.y) * step) as f32,
        size_px: size as f32,
        angle_rad: 0.0,
        response: v as f32,
        laplacian_positive: mid.laplacian_positive[r as usize * mid.cols + c as usize],
    })
}

/// SURF scale (the Gaussian sigma the box filter approximates), px.
fn scale_of(kp: &Keypoint) -> f64 {
    1.2 * kp.size_px as f64 / 9.0
}

/// Even Haar wavelet side (px) for a side of `side` px, at least 2.
fn haar_side(side: f64) -> i64 {
    (((side / 2.0).round() as i64) * 2).max(2)
}

/// Dominant orientation (rad, image frame: x right, y down) from Haar responses
/// in a disc of radius 6 s, in a sliding window of 60 degrees.
fn orientation(ii: &Integral, kp: &Keypoint) -> f32 {
    let s = scale_of(kp);
    let side = haar_side(4.0 * s);
    let mut samples: Vec<(f64, f64, f64)> = Vec::with_capacity(113);
    for j in -6i64..=6 {
        for i in -6i64..=6 {
            if i * i + j * j >= 36 {
                continue;
            }
            let x = (kp.x_px as f64 + i as f64 * s).round() as i64;
            let y = (kp.y_px as f64 + j as f64 * s).round() as i64;
            let w = (-((i * i + j * j) as f64) / (2.0 * 2.5 * 2.5)).exp();
            let (dx, dy) = ii.haar(x, y, side);
            let (dx, dy) = (w * dx, w * dy);
            samples.push((dy.atan2(dx), dx, dy));
        }
    }
    let mut best = (0.0f64, 0.0f64, 0.0f64);
    let mut start = -PI;
    while start < PI {
        let (mut sx, mut sy) = (0.0, 0.0);
        for &(a, dx, dy) in &samples {
            let rel = (a - start).rem_euclid(2.0 * PI);
            if rel < PI / 3.0 {
                sx += dx;
                sy += dy;
            }
        }
        let m = sx * sx + sy * sy;
        if m > best.0 {
            best = (m, sx, sy);
        }
        start += 0.15;
    }
    best.2.atan2(best.1) as f32
}

/// The 64-float descriptor: 4 x 4 subregions of 5 x 5 samples (spacing s) over a
/// 20 s window turned by the keypoint's angle; per subregion the Gaussian-weighted
/// (sigma 3.3 s) sums of dx, dy, |dx|, |dy|; unit length.
fn descriptor(ii: &Integral, kp: &Keypoint) -> [f32; 64] {
    let s = scale_of(kp);
    let side = haar_side(2.0 * s);
    let (sin, cos) = (kp.angle_rad as f64).sin_cos();
    // Gaussian weights (sigma 3.3 s) in sample units, the same at every scale.
    static WEIGHTS: OnceLock<[f64; 400]> = OnceLock::new();
    let weights = WEIGHTS.get_or_init(|| {
        std::array::from_fn(|i| {
            let (u, v) = ((i % 20) as f64 - 9.5, (i / 20) as f64 - 9.5);
            (-(u * u + v * v) / (2.0 * 3.3 * 3.3)).exp()
        })
    });
    let mut d = [0.0f64; 64];
    for k in 0..20 {
        for l in 0..20 {
            let u = (k as f64 - 9.5) * s;
            let v = (l as f64 - 9.5) * s;
            let x = (kp.x_px as f64 + u * cos - v * sin).round() as i64;
            let y = (kp.y_px as f64 + u * sin + v * cos).round() as i64;
            let w = weights[l * 20 + k];
            let (dx, dy) = ii.haar(x, y, side);
            let rx = w * (dx * cos + dy * sin);
            let ry = w * (-dx * sin + dy * cos);
            let cell = 4 * ((l / 5) * 4 + k / 5);
            d[cell] += rx;
            d[cell + 1] += ry;
            d[cell + 2] += rx.abs();
            d[cell + 3] += ry.abs();
        }
    }
    let norm = d.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut out = [0.0f32; 64];
    if norm > 0.0 {
        for (o, v) in out.iter_mut().zip(d) {
            *o = (v / norm) as f32;
        }
    }
    out
}

/// Fast-Hessian keypoints with SURF descriptors of a grey image (0..1,
/// row-major, `width * height`); positions in px of that image.
pub fn detect_hessian(
    grey: &[f32],
    width: usize,
    height: usize,
    params: &HessianParams,
) -> Result<Features, String> {
    check_image(grey, width, height)?;
    if params.octaves == 0 || params.octaves > 6 {
        return Err(format!("octaves {} must be 1..6", params.octaves));
    }
    if !(params.threshold.is_finite() && params.threshold >= 0.0) {
        return Err(format!(
            "hessian threshold {} must be >= 0",
            params.threshold
        ));
    }
    let ii = Integral::new(grey, width, height);
    let mut candidates = Vec::new();
    for o in 0..params.octaves {
        let step = 1i64 << o;
        // An octave whose smallest middle-layer triple does not fit adds nothing.
        if filter_size(o, 2) >= width.min(height) as i64 {
            break;
        }
        let layers: Vec<Layer> = (0..4)
            .map(|i| Layer::compute(&ii, filter_size(o, i), step))
            .collect();
        candidates.extend(octave_extrema(&layers, width, height, params.threshold));
    }
    let mut keypoints = keep_strongest_spread(candidates, width, height, params.max_features);
    let descriptors: Vec<[f32; 64]> = keypoints
        .par_iter_mut()
        .map(|kp| {
            if !params.upright {
                kp.angle_rad = orientation(&ii, kp);
            }
            descriptor(&ii, kp)
        })
        .collect();
    Ok(Features {
        keypoints,
        descriptors: Descriptors::Float(descriptors),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::features::test_images::{blob_texture, gaussian_blob_image};

    #[test]
    fn layers_by_runs_have_the_per_pixel_bits() {
        // Every layer of the four octaves, on an image both wider and
        // narrower than the filters: grey levels of every magnitude (so the
        // table's sums round) and a flat part. The responses are f32, so a
        // reordered f64 sum seldom shows; a wrong box or weight does.
        let (w, h) = (203, 61);
        let grey: Vec<f32> = (0..w * h)
            .map(|i| {
                let noise = ((i as f64 * 12.9898).sin() * 43_758.545_3).fract().abs();
                let scale = 10f64.powi((i % 9) as i32 - 6);
                if i % w > 150 {
                    0.25
                } else {
                    (noise * scale) as f32
                }
            })
            .collect();
        let ii = Integral::new(&grey, w, h);
        for o in 0..4 {
            for i in 0..4 {
                let (size, step) = (filter_size(o, i), 1i64 << o);
                let runs = Layer::compute_with(&ii, size, step, true);
                let pixels = Layer::compute_with(&ii, size, step, false);
                let bits = |l: &Layer| l.response.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&runs), bits(&pixels), "octave {o}, layer {i}");
                assert_eq!(runs.laplacian_positive, pixels.laplacian_positive);
            }
        }
    }

    #[test]
    fn filter_sizes_follow_bay() {
        let first: Vec<i64> = (0..4).map(|i| filter_size(0, i)).collect();
        let second: Vec<i64> = (0..4).map(|i| filter_size(1, i)).collect();
        assert_eq!(first, vec![9, 15, 21, 27]);
        assert_eq!(second, vec![15, 27, 39, 51]);
    }

    #[test]
    fn finds_a_gaussian_blob_at_its_centre_with_a_size_that_scales() {
        // A bright Gaussian blob: the Hessian determinant peaks at its centre,
        // and the selected size is proportional to the blob's sigma (box
        // filters of Bay's sizes peak near L = 5 sigma, not 9 sigma / 1.2).
        let (w, h) = (120, 120);
        let strongest = |sigma: f32, cx: f32, cy: f32| {
            let img = gaussian_blob_image(w, h, cx, cy, sigma);
            let f = detect_hessian(&img, w, h, &HessianParams::default()).unwrap();
            *f.keypoints
                .iter()
                .max_by(|a, b| a.response.total_cmp(&b.response))
                .expect("a keypoint")
        };
        let small = strongest(2.5, 60.3, 57.6);
        let large = strongest(5.0, 61.7, 58.2);
        for (k, cx, cy) in [(small, 60.3, 57.6), (large, 61.7, 58.2)] {
            assert!((k.x_px - cx).abs() < 0.25, "x {} for {cx}", k.x_px);
            assert!((k.y_px - cy).abs() < 0.25, "y {} for {cy}", k.y_px);
            // A bright blob has negative second derivatives: Laplacian negative.
            assert!(!k.laplacian_positive);
        }
        let ratio = large.size_px / small.size_px;
        assert!(
            (ratio - 2.0).abs() < 0.3,
            "sizes {} and {} px",
            small.size_px,
            large.size_px
        );
    }

    #[test]
    fn descriptors_are_unit_length_and_upright_angle_is_zero() {
        let (w, h) = (128, 96);
        let img = blob_texture(w, h, 0.0, 0.0, 7);
        let f = detect_hessian(&img, w, h, &HessianParams::default()).unwrap();
        let Descriptors::Float(d) = &f.descriptors else {
            panic!("float descriptors expected")
        };
        assert!(f.keypoints.len() > 20, "{} keypoints", f.keypoints.len());
        assert_eq!(d.len(), f.keypoints.len());
        for (kp, desc) in f.keypoints.iter().zip(d) {
            assert_eq!(kp.angle_rad, 0.0);
            let n: f32 = desc.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((n - 1.0).abs() < 1e-4);
        }
    }

    #[test]
    fn orientation_turns_with_the_image() {
        // An image and the same turned by 90 degrees (x' = h-1-y, y' = x):
        // the strongest keypoint's angle must differ by +90 degrees.
        let (w, h) = (96, 96);
        let img = blob_texture(w, h, 0.0, 0.0, 3);
        let mut turned = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                turned[x * w + (h - 1 - y)] = img[y * w + x];
            }
        }
        let p = HessianParams {
            upright: false,
            ..HessianParams::default()
        };
        let a = detect_hessian(&img, w, h, &p).unwrap();
        let b = detect_hessian(&turned, w, h, &p).unwrap();
        // A blob-like keypoint's orientation is only as well defined as its
        // neighbourhood is asymmetric, so most, not all, must turn with it.
        let (mut checked, mut agree) = (0, 0);
        for ka in &a.keypoints {
            let (tx, ty) = (h as f32 - 1.0 - ka.y_px, ka.x_px);
            let Some(kb) = b
                .keypoints
                .iter()
                .find(|k| (k.x_px - tx).abs() < 0.5 && (k.y_px - ty).abs() < 0.5)
            else {
                continue;
            };
            let diff = (kb.angle_rad - ka.angle_rad - std::f32::consts::FRAC_PI_2)
                .rem_euclid(2.0 * std::f32::consts::PI);
            let diff = diff.min(2.0 * std::f32::consts::PI - diff);
            checked += 1;
            if diff < 0.2 {
                agree += 1;
            }
        }
        assert!(checked >= 20, "only {checked} keypoints compared");
        eprintln!("orientation: {agree} of {checked} turn with the image");
        assert!(agree as f32 >= 0.7 * checked as f32, "{agree} of {checked}");
    }

    #[test]
    fn bad_input_is_an_error() {
        let p = HessianParams::default();
        assert!(detect_hessian(&[0.0; 10], 4, 4, &p).is_err());
        assert!(detect_hessian(&[f32::NAN; 16], 4, 4, &p).is_err());
        let tiny = detect_hessian(&[0.5; 16], 4, 4, &p).unwrap();
        assert!(tiny.keypoints.is_empty());
    }
}
