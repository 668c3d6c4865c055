//! Sparse features of a grey image: keypoints with descriptors, to match the
//! two images of a rectified pair (the matches bound the dense matcher's
//! disparity range).
//!
//! Two detectors, both our own implementations because no maintained Rust crate
//! provides them (see `../shared/CRATES.md`: rust-cv is dead, `akaze` needs
//! nightly):
//! - `hessian` ([`detect_hessian`]): SURF after Bay, Ess, Tuytelaars and Van
//!   Gool, "Speeded-Up Robust Features (SURF)", CVIU 2008. Fast-Hessian on an
//!   integral image, sub-pixel and sub-scale extrema, Haar orientation, 64-float
//!   descriptor, sign of the Laplacian.
//! - `fast` ([`detect_fast`]): patent-free; FAST-9 corners (Rosten and Drummond,
//!   "Machine learning for high-speed corner detection", ECCV 2006) ranked by the
//!   Harris measure, with a 256-bit BRIEF descriptor steered by the intensity
//!   centroid, as in ORB (Rublee, Rabaud, Konolige and Bradski, ICCV 2011).
//!
//! Both keep at most `max_features`, strongest first but spread over a grid of
//! cells, so texture-poor regions still get features.
//!
//! Then [`match_features`] pairs the keypoints of the two images by their
//! descriptors, and [`disparity_range`] turns the matched disparities into the
//! range a dense matcher searches.
//!
//! Frame: pixel coordinates of the input image, x right, y down, integer values
//! at pixel centres; angles in rad from +x towards +y.

#[cfg(test)]
mod eval;
mod fast;
mod integral;
mod matching;
mod range;
mod surf;
mod table;

pub use fast::{FastParams, detect_fast};
pub use integral::Integral;
pub use matching::{FeatureMatch, MatchParams, match_features};
pub use range::{
    RangeParams, core_disparities, disparity_range, percentile, supported_disparities,
};
pub use surf::{HessianParams, detect_hessian};
pub use table::{features_from_table, features_to_table};

/// One detected keypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Column, px (sub-pixel).
    pub x_px: f32,
    /// Row, px (sub-pixel).
    pub y_px: f32,
    /// Feature size, px: the (interpolated) box-filter side for `hessian`
    /// (Gaussian scale = 1.2 * size / 9), the 31 px patch times the pyramid
    /// scale for `fast`.
    pub size_px: f32,
    /// Orientation, rad (0 when upright).
    pub angle_rad: f32,
    /// Detector strength: scale-normalised Hessian determinant (`hessian`) or
    /// Harris measure (`fast`); larger is stronger.
    pub response: f32,
    /// Sign of the Laplacian (`hessian`: true for a dark blob on a bright
    /// background); always false for `fast`, which does not use it.
    pub laplacian_positive: bool,
}

/// Descriptors, one per keypoint, in keypoint order.
#[derive(Debug, Clone, PartialEq)]
pub enum Descriptors {
    /// SURF: 64 floats of unit length, compared by L2 distance.
    Float(Vec<[f32; 64]>),
    /// BRIEF: 256 bits, compared by Hamming distance.
    Binary(Vec<[u64; 4]>),
}

impl Descriptors {
    /// Number of descriptors.
    pub fn len(&self) -> usize {
        match self {
            Descriptors::Float(d) => d.len(),
            Descriptors::Binary(d) => d.len(),
        }
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Keypoints and their descriptors.
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    /// Keypoints, strongest first.
    pub keypoints: Vec<Keypoint>,
    /// One descriptor per keypoint.
    pub descriptors: Descriptors,
}

/// Checks a grey image's buffer: `width * height` finite values.
fn check_image(grey: &[f32], width: usize, height: usize) -> Result<(), String> {
    if grey.len() != width * height {
        return Err(format!(
            "image: {} pixels for {width} x {height}",
            grey.len()
        ));
    }
    if let Some(i) = grey.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "image: pixel ({}, {}) is not a finite number",
            i % width.max(1),
            i / width.max(1)
        ));
    }
    Ok(())
}

/// At most `max` keypoints, strongest first, spread over the image: the image
/// is cut into a grid of up to 8 x 8 cells and each cell first keeps up to an
/// equal share of its strongest; shares that weak cells leave unused go to the
/// strongest remaining keypoints anywhere.
pub fn keep_strongest_spread(
    candidates: Vec<Keypoint>,
    width: usize,
    height: usize,
    max: usize,
) -> Vec<Keypoint> {
    keep_spread_by(candidates, |k| k, width, height, max)
}

/// [`keep_strongest_spread`] for items that carry a keypoint.
pub(crate) fn keep_spread_by<T>(
    mut candidates: Vec<T>,
    key: impl Fn(&T) -> &Keypoint,
    width: usize,
    height: usize,
    max: usize,
) -> Vec<T> {
    let by_strength = |a: &T, b: &T| {
        let (a, b) = (key(a), key(b));
        b.response
            .total_cmp(&a.response)
            .then(a.y_px.total_cmp(&b.y_px))
            .then(a.x_px.total_cmp(&b.x_px))
            .then(a.size_px.total_cmp(&b.size_px))
    };
    candidates.sort_by(by_strength);
    if candidates.len() <= max {
        return candidates;
    }
    let per_side = ((max / 4) as f64).sqrt().floor().clamp(1.0, 8.0) as usize;
    let cell_w = (width as f32 / per_side as f32).max(1.0);
    let cell_h = (height as f32 / per_side as f32).max(1.0);
    let share = max.div_ceil(per_side * per_side);
    let mut used = vec![0usize; per_side * per_side];
    let mut kept = Vec::with_capacity(max);
    let mut rest = Vec::new();
    for item in candidates {
        let kp = key(&item);
        let cx = ((kp.x_px / cell_w).max(0.0) as usize).min(per_side - 1);
        let cy = ((kp.y_px / cell_h).max(0.0) as usize).min(per_side - 1);
        let cell = &mut used[cy * per_side + cx];
        if *cell < share {
            *cell += 1;
            kept.push(item);
        } else {
            rest.push(item);
        }
    }
    kept.truncate(max);
    let missing = max - kept.len();
    kept.extend(rest.into_iter().take(missing));
    kept.sort_by(by_strength);
    kept
}

#[cfg(test)]
pub(crate) mod test_images;

#[cfg(test)]
mod tests {
    use super::*;
    use test_images::blob_texture;

    fn kp(x: f32, y: f32, response: f32) -> Keypoint {
        Keypoint {
            x_px: x,
            y_px: y,
            size_px: 9.0,
            angle_rad: 0.0,
            response,
            laplacian_positive: false,
        }
    }

    #[test]
    fn the_cap_keeps_weak_regions() {
        // 100 strong keypoints in the left half, 10 weak ones in the right half
        // of a 100 x 100 image; a cap of 40 on a 3 x 3 grid (share 5 per cell)
        // must keep weak ones on the right too.
        let mut c: Vec<Keypoint> = (0..100)
            .map(|i| {
                kp(
                    (i % 10) as f32 * 4.0,
                    (i / 10) as f32 * 10.0,
                    10.0 + i as f32,
                )
            })
            .collect();
        c.extend((0..10).map(|i| kp(80.0, i as f32 * 10.0, 1.0 + i as f32 * 0.01)));
        let kept = keep_strongest_spread(c, 100, 100, 40);
        assert_eq!(kept.len(), 40);
        let right = kept.iter().filter(|k| k.x_px > 50.0).count();
        assert_eq!(
            right, 10,
            "every weak keypoint fits the right cells' shares"
        );
        assert!(kept.windows(2).all(|w| w[0].response >= w[1].response));
        // The strongest of all is always kept.
        assert!(kept.iter().any(|k| k.response == 109.0));
    }

    #[test]
    fn under_the_cap_everything_is_kept() {
        let c = vec![kp(1.0, 1.0, 1.0), kp(2.0, 2.0, 3.0)];
        let kept = keep_strongest_spread(c, 10, 10, 5);
        assert_eq!(kept.len(), 2);
        assert_eq!(kept[0].response, 3.0);
    }

    /// Detects on a blob texture and on the same texture moved by (`sx`, `sy`)
    /// px; returns the fraction of keypoints found again within 0.3 px of the
    /// moved position, the number of descriptor matches, and the fraction of
    /// those pairing a keypoint with its moved self (within 1 px).
    fn repeatability(
        detect: &dyn Fn(&[f32], usize, usize) -> Features,
        tol: &dyn Fn(&Keypoint) -> f32,
        sx: f32,
        sy: f32,
    ) -> (f32, usize, f32) {
        let (w, h) = (200usize, 160usize);
        let a = detect(&blob_texture(w, h, 0.0, 0.0, 21), w, h);
        let b = detect(&blob_texture(w, h, sx, sy, 21), w, h);
        // Only keypoints well inside both images can be found in both.
        let inside = |k: &&Keypoint| {
            let m = 20.0 + k.size_px;
            k.x_px > m && k.y_px > m && k.x_px < w as f32 - m - sx && k.y_px < h as f32 - m - sy
        };
        let pts: Vec<&Keypoint> = a.keypoints.iter().filter(inside).collect();
        let found = pts
            .iter()
            .filter(|k| {
                b.keypoints.iter().any(|q| {
                    let (dx, dy) = (q.x_px - k.x_px - sx, q.y_px - k.y_px - sy);
                    dx * dx + dy * dy <= tol(k) * tol(k)
                })
            })
            .count();
        let p = MatchParams {
            rectified: false,
            ..Default::default()
        };
        let m = match_features(&a, &b, &p).unwrap();
        let right = m
            .iter()
            .filter(|m| {
                (m.x_right_px - m.x_left_px - sx).abs() <= 1.0
                    && (m.y_right_px - m.y_left_px - sy).abs() <= 1.0
            })
            .count();
        (
            found as f32 / pts.len().max(1) as f32,
            m.len(),
            right as f32 / m.len().max(1) as f32,
        )
    }

    #[test]
    fn hessian_keypoints_follow_integer_and_subpixel_shifts() {
        let detect = |g: &[f32], w, h| detect_hessian(g, w, h, &HessianParams::default()).unwrap();
        for (sx, sy) in [(6.0, 3.0), (2.4, 0.7)] {
            let (found, n, right) = repeatability(&detect, &|_| 0.3, sx, sy);
            eprintln!(
                "hessian shift ({sx}, {sy}): {found:.2} found again, {n} matches, {right:.2} right"
            );
            assert!(found >= 0.7, "shift ({sx}, {sy}): {found:.2} found again");
            assert!(n >= 100, "shift ({sx}, {sy}): {n} matches");
            assert!(right >= 0.97, "shift ({sx}, {sy}): {right:.2} right");
        }
    }

    #[test]
    fn fast_keypoints_follow_integer_and_subpixel_shifts() {
        // The segment test on smooth blobs is less repeatable under sub-pixel
        // shifts than the Hessian (corners appear and vanish at the threshold),
        // and its Harris-quadratic positions are coarser: checked within half a
        // pyramid-level pixel.
        let detect = |g: &[f32], w, h| detect_fast(g, w, h, &FastParams::default()).unwrap();
        for (sx, sy) in [(6.0, 3.0), (2.4, 0.7)] {
            let (found, n, right) = repeatability(&detect, &|k| 0.5 * k.size_px / 31.0, sx, sy);
            eprintln!(
                "fast shift ({sx}, {sy}): {found:.2} found again, {n} matches, {right:.2} right"
            );
            assert!(found >= 0.45, "shift ({sx}, {sy}): {found:.2} found again");
            assert!(n >= 100, "shift ({sx}, {sy}): {n} matches");
            assert!(right >= 0.93, "shift ({sx}, {sy}): {right:.2} right");
        }
    }

    #[test]
    fn bad_buffers_are_errors() {
        assert!(check_image(&[0.0; 5], 2, 3).is_err());
        let err = check_image(&[0.0, f32::INFINITY, 0.0, 0.0], 2, 2).unwrap_err();
        assert!(err.contains("(1, 0)"), "{err}");
    }
}
