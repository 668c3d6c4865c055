//! Descriptor matching between the left and right images: nearest neighbour
//! with Lowe's ratio test, an optional mutual (cross) check and, for rectified
//! pairs, candidates restricted to the same rows (keypoints sorted by y, so the
//! search is a binary search plus a short scan).

use super::{Descriptors, Features, Keypoint};
use rayon::prelude::*;

/// Settings of [`match_features`].
#[derive(Debug, Clone, PartialEq)]
pub struct MatchParams {
    /// Lowe's ratio: keep a match only when its distance is below `ratio` times
    /// the second-nearest candidate's (0..1; 1 disables the test).
    pub ratio: f32,
    /// Keep a match only when the left keypoint is also the right one's nearest.
    pub mutual: bool,
    /// Rectified pair: candidates must lie within `row_tolerance_px` rows.
    pub rectified: bool,
    /// Largest |y_left - y_right|, px, when `rectified`.
    pub row_tolerance_px: f32,
    /// Allowed disparities (`x_left - x_right`, px), inclusive; `None`: any.
    pub disparity_bounds_px: Option<(f32, f32)>,
}

impl Default for MatchParams {
    fn default() -> Self {
        MatchParams {
            ratio: 0.8,
            mutual: true,
            rectified: true,
            row_tolerance_px: 2.0,
            disparity_bounds_px: None,
        }
    }
}

/// One match: keypoint indices, positions (px, each in its own image),
/// disparity `x_left - x_right` (px) and descriptor distance (L2 for float
/// descriptors, Hamming bits for binary ones; lower is better).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureMatch {
    /// Index of the left keypoint.
    pub left: usize,
    /// Index of the right keypoint.
    pub right: usize,
    /// Left column, px.
    pub x_left_px: f32,
    /// Left row, px.
    pub y_left_px: f32,
    /// Right column, px.
    pub x_right_px: f32,
    /// Right row, px.
    pub y_right_px: f32,
    /// `x_left_px - x_right_px`.
    pub disparity_px: f32,
    /// Descriptor distance.
    pub score: f32,
}

/// One image's keypoints with their indices sorted by row.
struct Side<'a> {
    keypoints: &'a [Keypoint],
    by_row: Vec<usize>,
}

impl<'a> Side<'a> {
    fn new(keypoints: &'a [Keypoint]) -> Self {
        let mut by_row: Vec<usize> = (0..keypoints.len()).collect();
        by_row.sort_by(|&a, &b| keypoints[a].y_px.total_cmp(&keypoints[b].y_px));
        Side { keypoints, by_row }
    }

    /// Indices of the keypoints with |y - `y_px`| <= `tol` (all when `tol` is None).
    fn near_row(&self, y_px: f32, tol: Option<f32>) -> &[usize] {
        let Some(tol) = tol else {
            return &self.by_row;
        };
        let kp = self.keypoints;
        let lo = self.by_row.partition_point(|&i| kp[i].y_px < y_px - tol);
        let hi = self.by_row.partition_point(|&i| kp[i].y_px <= y_px + tol);
        &self.by_row[lo..hi.max(lo)]
    }
}

/// Nearest and second-nearest distances and the nearest index.
fn best_two(cands: impl Iterator<Item = (usize, f32)>) -> Option<(usize, f32, f32)> {
    let mut best: Option<(usize, f32, f32)> = None;
    for (j, d) in cands {
        best = match best {
            None => Some((j, d, f32::INFINITY)),
            Some((_, b1, b2)) if d < b1 => Some((j, d, b1.min(b2))),
            Some((bj, b1, b2)) => Some((bj, b1, b2.min(d))),
        };
    }
    best
}

/// Matches keypoints of the left image to the right image's. Features must
/// come from the same detector (float or binary descriptors on both sides);
/// with float (SURF) descriptors the Laplacian signs must agree. Result in left
/// keypoint order.
pub fn match_features(
    left: &Features,
    right: &Features,
    params: &MatchParams,
) -> Result<Vec<FeatureMatch>, String> {
    if !(params.ratio > 0.0 && params.ratio <= 1.0) {
        return Err(format!("ratio {} must be in (0, 1]", params.ratio));
    }
    if !(params.row_tolerance_px.is_finite() && params.row_tolerance_px >= 0.0) {
        return Err(format!(
            "row_tolerance_px {} must be >= 0",
            params.row_tolerance_px
        ));
    }
    if let Some((lo, hi)) = params.disparity_bounds_px
        && !(lo.is_finite() && hi.is_finite() && lo <= hi)
    {
        return Err(format!("disparity bounds [{lo}, {hi}] px: need min <= max"));
    }
    for (name, f) in [("left", left), ("right", right)] {
        if f.keypoints.len() != f.descriptors.len() {
            return Err(format!(
                "{name}: {} keypoints but {} descriptors",
                f.keypoints.len(),
                f.descriptors.len()
            ));
        }
    }
    let use_laplacian;
    let dist: Box<dyn Fn(usize, usize) -> f32 + Sync> = match (
        &left.descriptors,
        &right.descriptors,
    ) {
        (Descriptors::Float(l), Descriptors::Float(r)) => {
            use_laplacian = true;
            Box::new(move |i, j| {
                l[i].iter()
                    .zip(&r[j])
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f32>()
                    .sqrt()
            })
        }
        (Descriptors::Binary(l), Descriptors::Binary(r)) => {
            use_laplacian = false;
            Box::new(move |i, j| {
                l[i].iter()
                    .zip(&r[j])
                    .map(|(a, b)| (a ^ b).count_ones())
                    .sum::<u32>() as f32
            })
        }
        _ => {
            return Err(
                "left and right features come from different detectors (float and binary descriptors)"
                    .into(),
            );
        }
    };
    let (lk, rk) = (&left.keypoints, &right.keypoints);
    let allowed = |i: usize, j: usize| -> bool {
        let d = lk[i].x_px - rk[j].x_px;
        let in_bounds = params
            .disparity_bounds_px
            .is_none_or(|(lo, hi)| d >= lo && d <= hi);
        in_bounds && (!use_laplacian || lk[i].laplacian_positive == rk[j].laplacian_positive)
    };
    let tol = params.rectified.then_some(params.row_tolerance_px);
    let (lside, rside) = (Side::new(lk), Side::new(rk));
    let forward: Vec<(usize, usize, f32)> = (0..lk.len())
        .into_par_iter()
        .filter_map(|i| {
            let cands = rside.near_row(lk[i].y_px, tol);
            let (j, d1, d2) = best_two(
                cands
                    .iter()
                    .filter(|&&j| allowed(i, j))
                    .map(|&j| (j, dist(i, j))),
            )?;
            // Lowe: the nearest must be clearly nearer than the second.
            (d2.is_infinite() || d1 < params.ratio * d2).then_some((i, j, d1))
        })
        .collect();
    let kept: Vec<(usize, usize, f32)> = if params.mutual {
        forward
            .into_par_iter()
            .filter(|&(i, j, _)| {
                let cands = lside.near_row(rk[j].y_px, tol);
                let back = best_two(
                    cands
                        .iter()
                        .filter(|&&k| allowed(k, j))
                        .map(|&k| (k, dist(k, j))),
                );
                back.is_some_and(|(k, _, _)| k == i)
            })
            .collect()
    } else {
        forward
    };
    Ok(kept
        .into_iter()
        .map(|(i, j, score)| FeatureMatch {
            left: i,
            right: j,
            x_left_px: lk[i].x_px,
            y_left_px: lk[i].y_px,
            x_right_px: rk[j].x_px,
            y_right_px: rk[j].y_px,
            disparity_px: lk[i].x_px - rk[j].x_px,
            score,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::features::test_images::BlobTexture;
    use crate::stereo::features::{FastParams, HessianParams, detect_fast, detect_hessian};

    fn kp(x: f32, y: f32, lap: bool) -> Keypoint {
        Keypoint {
            x_px: x,
            y_px: y,
            size_px: 9.0,
            angle_rad: 0.0,
            response: 1.0,
            laplacian_positive: lap,
        }
    }

    fn unit(v: &[f32]) -> [f32; 64] {
        let mut d = [0.0f32; 64];
        d[..v.len()].copy_from_slice(v);
        let n = d.iter().map(|x| x * x).sum::<f32>().sqrt();
        d.map(|x| x / n)
    }

    #[test]
    fn hand_made_descriptors_follow_every_rule() {
        // Left 0 matches right 0 (same descriptor); left 1 has two nearly equal
        // candidates (ratio test drops it); left 2's only look-alike is 5 rows
        // away (row test drops it); left 3's look-alike has the other Laplacian.
        let left = Features {
            keypoints: vec![
                kp(50.0, 10.0, true),
                kp(50.0, 20.0, true),
                kp(50.0, 30.0, true),
                kp(50.0, 40.0, true),
            ],
            descriptors: Descriptors::Float(vec![
                unit(&[1.0, 0.0, 0.0]),
                unit(&[0.0, 1.0, 0.0]),
                unit(&[0.0, 0.0, 1.0]),
                unit(&[1.0, 1.0, 1.0]),
            ]),
        };
        let right = Features {
            keypoints: vec![
                kp(40.0, 10.5, true),
                kp(30.0, 20.0, true),
                kp(35.0, 20.0, true),
                kp(30.0, 35.0, true),
                kp(30.0, 40.0, false),
            ],
            descriptors: Descriptors::Float(vec![
                unit(&[1.0, 0.05, 0.0]),
                unit(&[0.1, 1.0, 0.0]),
                unit(&[0.0, 1.0, 0.1]),
                unit(&[0.0, 0.0, 1.0]),
                unit(&[1.0, 1.0, 1.0]),
            ]),
        };
        let m = match_features(&left, &right, &MatchParams::default()).unwrap();
        assert_eq!(m.len(), 1, "{m:?}");
        assert_eq!((m[0].left, m[0].right), (0, 0));
        assert_eq!(m[0].disparity_px, 10.0);
        assert!(
            (m[0].score - 0.05).abs() < 1e-3,
            "L2 distance {}",
            m[0].score
        );
        // Without the row restriction, left 2 finds right 3.
        let p = MatchParams {
            rectified: false,
            ..MatchParams::default()
        };
        let m = match_features(&left, &right, &p).unwrap();
        assert!(m.iter().any(|m| (m.left, m.right) == (2, 3)));
        // Disparity bounds exclude the 10 px match.
        let p = MatchParams {
            disparity_bounds_px: Some((11.0, 30.0)),
            ..MatchParams::default()
        };
        let m = match_features(&left, &right, &p).unwrap();
        assert!(m.iter().all(|m| m.left != 0));
    }

    #[test]
    fn mutual_check_drops_one_sided_matches() {
        // Left 0 and left 1 both prefer right 0; right 0 prefers left 1.
        let b = |bits: u64| [bits, 0, 0, 0];
        let left = Features {
            keypoints: vec![kp(20.0, 5.0, false), kp(30.0, 5.0, false)],
            descriptors: Descriptors::Binary(vec![b(0b1111), b(0b1)]),
        };
        let right = Features {
            keypoints: vec![kp(10.0, 5.0, false), kp(12.0, 5.0, false)],
            descriptors: Descriptors::Binary(vec![b(0b11), b(0xFFFF_0000)]),
        };
        let p = MatchParams {
            ratio: 1.0,
            ..MatchParams::default()
        };
        let m = match_features(&left, &right, &p).unwrap();
        assert_eq!(m.len(), 1);
        assert_eq!((m[0].left, m[0].right), (1, 0));
        assert_eq!(m[0].score, 1.0, "one bit differs");
        let p = MatchParams {
            ratio: 1.0,
            mutual: false,
            ..MatchParams::default()
        };
        assert_eq!(match_features(&left, &right, &p).unwrap().len(), 2);
    }

    #[test]
    fn different_detectors_and_bad_params_are_errors() {
        let f = Features {
            keypoints: vec![kp(1.0, 1.0, false)],
            descriptors: Descriptors::Float(vec![[0.0; 64]]),
        };
        let b = Features {
            keypoints: vec![kp(1.0, 1.0, false)],
            descriptors: Descriptors::Binary(vec![[0; 4]]),
        };
        let err = match_features(&f, &b, &MatchParams::default()).unwrap_err();
        assert!(err.contains("different detectors"), "{err}");
        let p = MatchParams {
            ratio: 1.5,
            ..MatchParams::default()
        };
        assert!(match_features(&f, &f, &p).is_err());
        let p = MatchParams {
            disparity_bounds_px: Some((5.0, 1.0)),
            ..MatchParams::default()
        };
        assert!(match_features(&f, &f, &p).is_err());
    }

    /// A rectified pair of a slanted background (disparity 12 + 8 y / h px)
    /// with a fronto-parallel box at 31 px in front, `w` x `h` px. Returns the
    /// left and right images and the true disparity at a right pixel.
    pub(crate) fn synthetic_pair(
        w: usize,
        h: usize,
        offset_px: f32,
    ) -> (Vec<f32>, Vec<f32>, impl Fn(f32, f32) -> f32) {
        let tex = BlobTexture::new(
            -20.0,
            -20.0,
            w as f32 + offset_px + 60.0,
            h as f32 + 20.0,
            11,
        );
        let (bx0, bx1, by0, by1) = (
            0.3 * w as f32,
            0.6 * w as f32,
            0.3 * h as f32,
            0.7 * h as f32,
        );
        let hf = h as f32;
        let truth = move |xr: f32, yr: f32| {
            if (bx0..bx1).contains(&xr) && (by0..by1).contains(&yr) {
                offset_px + 31.0
            } else {
                offset_px + 12.0 + 8.0 * yr / hf
            }
        };
        let left = tex.render(w, h, |x, y| (x, y));
        let right = tex.render(w, h, |x, y| (x + truth(x, y), y));
        (left, right, truth)
    }

    fn check_pair(detector: &str, offset_px: f32) -> (usize, f32) {
        // Widen the images by the offset so that the overlap stays 320 px.
        let (w, h) = (320 + offset_px as usize, 200usize);
        let (l, r, truth) = synthetic_pair(w, h, offset_px);
        let (fl, fr) = match detector {
            "hessian" => {
                let p = HessianParams::default();
                (
                    detect_hessian(&l, w, h, &p).unwrap(),
                    detect_hessian(&r, w, h, &p).unwrap(),
                )
            }
            _ => {
                let p = FastParams::default();
                (
                    detect_fast(&l, w, h, &p).unwrap(),
                    detect_fast(&r, w, h, &p).unwrap(),
                )
            }
        };
        let m = match_features(&fl, &fr, &MatchParams::default()).unwrap();
        let good = m
            .iter()
            .filter(|m| (m.disparity_px - truth(m.x_right_px, m.y_right_px)).abs() <= 1.0)
            .count();
        (m.len(), good as f32 / m.len().max(1) as f32)
    }

    #[test]
    fn surf_matches_follow_a_known_disparity_field() {
        let (n, good) = check_pair("hessian", 0.0);
        assert!(n >= 150, "{n} matches");
        assert!(good >= 0.9, "{:.1} % within 1 px", 100.0 * good);
    }

    #[test]
    fn fast_matches_follow_a_known_disparity_field() {
        let (n, good) = check_pair("fast", 0.0);
        assert!(n >= 150, "{n} matches");
        assert!(good >= 0.9, "{:.1} % within 1 px", 100.0 * good);
    }

    #[test]
    fn a_wide_pair_with_200_px_of_disparity_matches_too() {
        let (n, good) = check_pair("hessian", 200.0);
        assert!(n >= 100, "{n} matches");
        assert!(good >= 0.9, "{:.1} % within 1 px", 100.0 * good);
    }
}
