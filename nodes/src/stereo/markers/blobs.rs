//! Blobs of a binary image: morphology with a disc, 8-connected components,
//! moment ellipses with a fit-quality measure, and sub-pixel centroids weighted
//! by a soft membership so partial-volume edge pixels count by their share.
//!
//! Masks are row-major `width * height` booleans; pixel (x, y) has its centre at
//! integer coordinates (OpenCV), so centroids are in px in that convention.

use crate::mri::{Connectivity, label_components};
use rayon::prelude::*;

/// Offsets (dx, dy) of the disc of `radius_px` (Euclidean, inclusive).
fn disc(radius_px: usize) -> Vec<(isize, isize)> {
    let r = radius_px as isize;
    let r2 = (radius_px * radius_px) as isize;
    (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|(dx, dy)| dx * dx + dy * dy <= r2)
        .collect()
}

/// Dilation (`grow = true`) or erosion of `mask` by the disc of `radius_px`;
/// outside the image counts as unset for dilation and as set for erosion, so
/// blobs touching the border are not eaten from outside.
fn morph(mask: &[bool], width: usize, height: usize, radius_px: usize, grow: bool) -> Vec<bool> {
    if radius_px == 0 {
        return mask.to_vec();
    }
    let offsets = disc(radius_px);
    let mut out = vec![false; mask.len()];
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let hit = |&(dx, dy): &(isize, isize)| {
                    let (nx, ny) = (x as isize + dx, y as isize + dy);
                    if nx < 0 || ny < 0 || nx >= width as isize || ny >= height as isize {
                        !grow
                    } else {
                        mask[ny as usize * width + nx as usize]
                    }
                };
                *o = if grow {
                    offsets.iter().any(hit)
                } else {
                    offsets.iter().all(hit)
                };
            }
        });
    out
}

/// Dilation of `mask` by the disc of `radius_px`.
pub fn dilate(mask: &[bool], width: usize, height: usize, radius_px: usize) -> Vec<bool> {
    morph(mask, width, height, radius_px, true)
}

/// Erosion of `mask` by the disc of `radius_px`.
pub fn erode(mask: &[bool], width: usize, height: usize, radius_px: usize) -> Vec<bool> {
    morph(mask, width, height, radius_px, false)
}

/// Opening (removes specks and thin spurs) then closing (fills pinholes and
/// notches), both with the disc of `radius_px`.
pub fn open_close(mask: &[bool], width: usize, height: usize, radius_px: usize) -> Vec<bool> {
    let opened = dilate(
        &erode(mask, width, height, radius_px),
        width,
        height,
        radius_px,
    );
    erode(
        &dilate(&opened, width, height, radius_px),
        width,
        height,
        radius_px,
    )
}

/// The 8-connected components of `mask`: labels (0 = background, then 1..=n in
/// raster order of each component's first pixel) and the pixel indices of each
/// component (entry `k` holds label `k + 1`).
pub fn components(mask: &[bool], width: usize, height: usize) -> (Vec<u32>, Vec<Vec<usize>>) {
    let bytes: Vec<u8> = mask.iter().map(|&m| m as u8).collect();
    // In a single slice, 18-connectivity is the 8 in-plane neighbours.
    let (labels, sizes) = label_components(&bytes, [width, height, 1], Connectivity::Eighteen);
    let mut pixels: Vec<Vec<usize>> = sizes[1..].iter().map(|&n| Vec::with_capacity(n)).collect();
    for (i, &l) in labels.iter().enumerate() {
        if l > 0 {
            pixels[l as usize - 1].push(i);
        }
    }
    (labels, pixels)
}

/// The ellipse with the same area-normalised second moments as a set of pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct MomentEllipse {
    /// Centroid of the pixel centres, px.
    pub centre_px: (f64, f64),
    /// Covariance (xx, xy, yy) of the pixels taken as unit squares, px^2.
    pub covariance_px2: (f64, f64, f64),
    /// Semi-axes (major, minor), px: twice the square roots of the eigenvalues,
    /// which is exact for a uniformly filled ellipse.
    pub semi_axes_px: (f64, f64),
}

impl MomentEllipse {
    /// The moment ellipse of `pixels` (indices into a row-major image `width`
    /// wide); `None` for an empty set.
    pub fn of(pixels: &[usize], width: usize) -> Option<Self> {
        if pixels.is_empty() {
            return None;
        }
        let n = pixels.len() as f64;
        let xy = |i: usize| ((i % width) as f64, (i / width) as f64);
        let (sx, sy) = pixels.iter().fold((0.0, 0.0), |(a, b), &i| {
            let (x, y) = xy(i);
            (a + x, b + y)
        });
        let (cx, cy) = (sx / n, sy / n);
        let (mut xx, mut xy2, mut yy) = (0.0, 0.0, 0.0);
        for &i in pixels {
            let (x, y) = xy(i);
            xx += (x - cx) * (x - cx);
            xy2 += (x - cx) * (y - cy);
            yy += (y - cy) * (y - cy);
        }
        // Each pixel is a unit square, whose own variance is 1/12 per axis.
        let (xx, xy2, yy) = (xx / n + 1.0 / 12.0, xy2 / n, yy / n + 1.0 / 12.0);
        let mean = 0.5 * (xx + yy);
        let spread = (0.25 * (xx - yy) * (xx - yy) + xy2 * xy2).sqrt();
        let (l1, l2) = (mean + spread, (mean - spread).max(0.0));
        Some(MomentEllipse {
            centre_px: (cx, cy),
            covariance_px2: (xx, xy2, yy),
            semi_axes_px: (2.0 * l1.sqrt(), 2.0 * l2.sqrt()),
        })
    }

    /// Major over minor semi-axis (infinite for a line).
    pub fn aspect(&self) -> f64 {
        self.semi_axes_px.0 / self.semi_axes_px.1
    }

    /// Whether the pixel centre (x, y) lies inside the ellipse.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (xx, xy, yy) = self.covariance_px2;
        let det = xx * yy - xy * xy;
        if det.is_nan() || det <= 0.0 {
            return false;
        }
        let (dx, dy) = (x - self.centre_px.0, y - self.centre_px.1);
        // Mahalanobis distance 2 is the boundary of a uniform ellipse.
        (yy * dx * dx - 2.0 * xy * dx * dy + xx * dy * dy) / det <= 4.0
    }
}

/// How well a blob fills its own moment ellipse: intersection over union of the
/// blob's pixels and the pixels whose centres lie inside the ellipse (1 for a
/// perfect ellipse, about 0.9 for a well-rasterised one of radius 4 px and more,
/// lower for ragged, notched, hollow or branching shapes, whose moments spread
/// the ellipse over pixels they do not cover). It accepts discs seen at any
/// tilt, since a tilted disc projects to an ellipse; elongation is judged
/// separately by [`MomentEllipse::aspect`].
pub fn ellipse_fit(pixels: &[usize], width: usize, height: usize) -> f64 {
    let Some(e) = MomentEllipse::of(pixels, width) else {
        return 0.0;
    };
    let reach = e.semi_axes_px.0.ceil() as isize + 1;
    let (cx, cy) = (
        e.centre_px.0.round() as isize,
        e.centre_px.1.round() as isize,
    );
    let in_blob: std::collections::HashSet<usize> = pixels.iter().copied().collect();
    let mut inside = 0usize;
    let mut both = 0usize;
    for y in (cy - reach).max(0)..=(cy + reach).min(height as isize - 1) {
        for x in (cx - reach).max(0)..=(cx + reach).min(width as isize - 1) {
            if e.contains(x as f64, y as f64) {
                inside += 1;
                if in_blob.contains(&(y as usize * width + x as usize)) {
                    both += 1;
                }
            }
        }
    }
    let union = inside + pixels.len() - both;
    both as f64 / union as f64
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

/// Sub-pixel centroid (px) of blob `label` of `labels`, weighting each pixel by
/// its share of the colour class, from `score` (a per-pixel colour measure that
/// is linear in the pixel's RGB, so a pixel covered a fraction `a` by the blob
/// scores `a * inside + (1 - a) * outside`):
///
/// - pixels of the blob eroded by 1 px (its core) weigh 1, so shading across
///   the blob does not pull the centroid;
/// - pixels of the blob's edge and of a `border_px` band around it weigh
///   `(score - outside) / (inside - outside)`, clamped to 0..1, where `inside`
///   is the mean score of the core pixels and `outside` that of a ring 1-2 px
///   beyond the band, both within `border_px + 3` px of the pixel: local
///   references, because what surrounds a marker differs around it (skin on
///   one side, its own bright rim on the other); the medians over the whole
///   core and ring stand in where no such pixel is near;
/// - pixels of other blobs are left out.
///
/// Returns the centroid and the sum of weights (the blob's area in px with
/// edges counted by their share). Falls back to the binary centroid when the
/// inside and outside scores are not separated.
pub fn soft_centroid(
    labels: &[u32],
    width: usize,
    height: usize,
    label: u32,
    pixels: &[usize],
    score: &[f64],
    border_px: usize,
) -> ((f64, f64), f64) {
    let xy = |i: usize| ((i % width) as isize, (i / width) as isize);
    let (mut x0, mut y0, mut x1, mut y1) = (isize::MAX, isize::MAX, isize::MIN, isize::MIN);
    for &i in pixels {
        let (x, y) = xy(i);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    // Work in a window around the blob wide enough for the background ring.
    let pad = border_px as isize + 3;
    let (wx0, wy0) = ((x0 - pad).max(0), (y0 - pad).max(0));
    let (wx1, wy1) = (
        (x1 + pad).min(width as isize - 1),
        (y1 + pad).min(height as isize - 1),
    );
    let (ww, wh) = ((wx1 - wx0 + 1) as usize, (wy1 - wy0 + 1) as usize);
    let global = |lx: usize, ly: usize| (wy0 as usize + ly) * width + wx0 as usize + lx;
    let mut own = vec![false; ww * wh];
    for &i in pixels {
        let (x, y) = xy(i);
        own[(y - wy0) as usize * ww + (x - wx0) as usize] = true;
    }
    let core = erode(&own, ww, wh, 1);
    let band = dilate(&own, ww, wh, border_px);
    let other = |k: usize| {
        let l = labels[global(k % ww, k / ww)];
        l != 0 && l != label
    };
    let ring: Vec<bool> = dilate(&own, ww, wh, border_px + 2)
        .iter()
        .enumerate()
        .map(|(k, &r)| r && !band[k] && !other(k))
        .collect();
    let local_score = |k: usize| score[global(k % ww, k / ww)];
    let inside = median((0..ww * wh).filter(|&k| core[k]).map(local_score).collect())
        .or_else(|| median(pixels.iter().map(|&i| score[i]).collect()));
    let outside = median((0..ww * wh).filter(|&k| ring[k]).map(local_score).collect());
    let binary = || {
        let n = pixels.len() as f64;
        let (sx, sy) = pixels.iter().fold((0.0, 0.0), |(a, b), &i| {
            (a + (i % width) as f64, b + (i / width) as f64)
        });
        ((sx / n, sy / n), n)
    };
    let (Some(inside), Some(outside)) = (inside, outside) else {
        return binary();
    };
    if !(inside - outside).is_finite() || (inside - outside).abs() <= 1e-6 {
        return binary();
    }
    // Mean of `score` over the pixels of `set` within `reach` of (lx, ly).
    let reach = border_px as isize + 3;
    let local_mean = |set: &[bool], lx: usize, ly: usize, fallback: f64| {
        let (mut sum, mut n) = (0.0, 0usize);
        for y in (ly as isize - reach).max(0)..=(ly as isize + reach).min(wh as isize - 1) {
            for x in (lx as isize - reach).max(0)..=(lx as isize + reach).min(ww as isize - 1) {
                let k = y as usize * ww + x as usize;
                if set[k] {
                    sum += local_score(k);
                    n += 1;
                }
            }
        }
        if n > 0 { sum / n as f64 } else { fallback }
    };
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for k in 0..ww * wh {
        if !band[k] || other(k) {
            continue;
        }
        let (lx, ly) = (k % ww, k / ww);
        let w = if core[k] {
            1.0
        } else {
            let (fg, bg) = (
                local_mean(&core, lx, ly, inside),
                local_mean(&ring, lx, ly, outside),
            );
            let contrast = if (fg - bg).abs() > 1e-6 {
                fg - bg
            } else {
                inside - outside
            };
            ((local_score(k) - bg) / contrast).clamp(0.0, 1.0)
        };
        sw += w;
        sx += w * (wx0 as usize + lx) as f64;
        sy += w * (wy0 as usize + ly) as f64;
    }
    if sw.is_nan() || sw <= 0.0 {
        return binary();
    }
    ((sx / sw, sy / sw), sw)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask_of(width: usize, height: usize, f: impl Fn(f64, f64) -> bool) -> Vec<bool> {
        (0..width * height)
            .map(|i| f((i % width) as f64, (i / width) as f64))
            .collect()
    }

    #[test]
    fn opening_removes_specks_and_closing_fills_holes() {
        let (w, h) = (40, 30);
        let mut m = mask_of(w, h, |x, y| (x - 20.0).powi(2) + (y - 15.0).powi(2) <= 64.0);
        m[15 * w + 20] = false; // pinhole
        m[3 * w + 3] = true; // speck
        let c = open_close(&m, w, h, 1);
        assert!(c[15 * w + 20] && !c[3 * w + 3]);
        let (_, blobs) = components(&c, w, h);
        assert_eq!(blobs.len(), 1);
        // A disc of radius 8 keeps its size through open/close with radius 1.
        assert!(
            (blobs[0].len() as i64 - 197).abs() <= 8,
            "{}",
            blobs[0].len()
        );
    }

    #[test]
    fn components_are_8_connected_in_raster_order() {
        let (w, h) = (6, 4);
        let mut m = vec![false; w * h];
        for i in [1, w + 2, 2 * w + 3, 5, 3 * w] {
            m[i] = true;
        }
        let (labels, blobs) = components(&m, w, h);
        assert_eq!(blobs.len(), 3);
        assert_eq!(blobs[0], vec![1, w + 2, 2 * w + 3]);
        assert_eq!((labels[5], labels[3 * w]), (2, 3));
    }

    #[test]
    fn moment_ellipse_recovers_axes_and_fit_separates_shapes() {
        let (w, h) = (120, 100);
        // Ellipse with semi-axes 20 and 8, rotated 30 deg.
        let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let ellipse = mask_of(w, h, |x, y| {
            let (dx, dy) = (x - 60.3, y - 50.6);
            let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
            (u / 20.0).powi(2) + (v / 8.0).powi(2) <= 1.0
        });
        let px: Vec<usize> = (0..w * h).filter(|&i| ellipse[i]).collect();
        let e = MomentEllipse::of(&px, w).unwrap();
        assert!(
            (e.semi_axes_px.0 - 20.0).abs() < 0.15,
            "{:?}",
            e.semi_axes_px
        );
        assert!(
            (e.semi_axes_px.1 - 8.0).abs() < 0.15,
            "{:?}",
            e.semi_axes_px
        );
        assert!((e.aspect() - 2.5).abs() < 0.06);
        let fit = ellipse_fit(&px, w, h);
        assert!(fit > 0.9, "ellipse {fit}");
        // A plus sign of two 40 x 6 bars: same span, poor fit.
        let plus = mask_of(w, h, |x, y| {
            let (dx, dy) = ((x - 60.0).abs(), (y - 50.0).abs());
            (dx <= 20.0 && dy <= 3.0) || (dy <= 20.0 && dx <= 3.0)
        });
        let px: Vec<usize> = (0..w * h).filter(|&i| plus[i]).collect();
        let fit = ellipse_fit(&px, w, h);
        assert!(fit < 0.5, "plus {fit}");
    }

    #[test]
    fn soft_centroid_counts_edge_pixels_by_their_share() {
        // A 1-D check of the weighting: a square whose right column is 30 %
        // covered; scores are linear in coverage (inside 1, outside 0.2).
        let (w, h) = (30, 30);
        let mut score = vec![0.2; w * h];
        let mut mask = vec![false; w * h];
        for y in 10..20 {
            for x in 10..20 {
                score[y * w + x] = 1.0;
                mask[y * w + x] = true;
            }
            score[y * w + 20] = 0.2 + 0.3 * 0.8;
        }
        let (labels, blobs) = components(&mask, w, h);
        let ((cx, cy), area) = soft_centroid(&labels, w, h, 1, &blobs[0], &score, 2);
        // Columns 10..=19 fully, column 20 at 0.3: mean x = (10 * 14.5 + 0.3 * 20) / 10.3.
        let expected = (10.0 * 14.5 + 0.3 * 20.0) / 10.3;
        assert!((cx - expected).abs() < 1e-9, "{cx} vs {expected}");
        assert!((cy - 14.5).abs() < 1e-9);
        assert!((area - 103.0).abs() < 1e-9);
    }
}
