//! Found markers against true ones, without assuming order or equal counts.

use super::frame_to_world;
use crate::phantom::{GroundTruth, MarkerTruth};
use nalgebra::Point3;

/// How found markers compare to the truth.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerComparison {
    /// (found index, true index, error mm) of each matched pair.
    pub pairs: Vec<(usize, usize, f64)>,
    /// True markers with no match.
    pub missed: usize,
    /// Found markers with no match.
    pub spurious: usize,
}

impl MarkerComparison {
    /// Mean error over matched pairs, mm (NaN if none).
    pub fn mean_error_mm(&self) -> f64 {
        self.pairs.iter().map(|p| p.2).sum::<f64>() / self.pairs.len() as f64
    }

    /// Largest error over matched pairs, mm (NaN if none).
    pub fn max_error_mm(&self) -> f64 {
        self.pairs.iter().map(|p| p.2).fold(f64::NAN, f64::max)
    }
}

/// Matches `found` to `truth` (both mm, same frame) greedily by increasing
/// distance, each at most once and no further apart than `max_distance_mm`.
pub fn compare_markers(
    found: &[[f64; 3]],
    truth: &[[f64; 3]],
    max_distance_mm: f64,
) -> MarkerComparison {
    let dist = |a: &[f64; 3], b: &[f64; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let mut candidates: Vec<(f64, usize, usize)> = found
        .iter()
        .enumerate()
        .flat_map(|(i, f)| {
            truth
                .iter()
                .enumerate()
                .map(move |(j, t)| (dist(f, t), i, j))
        })
        .filter(|c| c.0 <= max_distance_mm)
        .collect();
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut found_used, mut truth_used) = (vec![false; found.len()], vec![false; truth.len()]);
    let mut pairs = Vec::new();
    for (d, i, j) in candidates {
        if !found_used[i] && !truth_used[j] {
            found_used[i] = true;
            truth_used[j] = true;
            pairs.push((i, j, d));
        }
    }
    MarkerComparison {
        missed: truth.len() - pairs.len(),
        spurious: found.len() - pairs.len(),
        pairs,
    }
}

/// The true marker centres (mm) that markers found in `frame` are compared
/// with. `reference` `mri_gel`: gel cores, for markers in `mri_lps`;
/// `world_gel` / `world_face`: gel cores / coloured face centres, for markers in
/// `world` or `camera_left` (the left camera of view `view`). Each centre comes
/// with whether it is expected to be found: always, except in `camera_left`,
/// where only markers whose face is visible in both images of the view are (a
/// partly hidden one that is found anyway is matched, not spurious). Any other
/// pairing is an error naming the frame.
pub fn true_marker_centres(
    truth: &GroundTruth,
    reference: &str,
    frame: &str,
    view: usize,
) -> Result<Vec<([f64; 3], bool)>, String> {
    let centre = |m: &MarkerTruth| match reference {
        "world_face" => m.face_center_world_mm,
        _ => m.center_world_mm,
    };
    match (reference, frame) {
        ("mri_gel", "mri_lps") => Ok(truth
            .markers
            .iter()
            .map(|m| (m.center_mri_mm, true))
            .collect()),
        ("mri_lesion", "mri_lps") => Ok(truth
            .lesions
            .iter()
            .map(|l| (l.center_mri_mm, true))
            .collect()),
        ("world_gel" | "world_face", "world") => {
            Ok(truth.markers.iter().map(|m| (centre(m), true)).collect())
        }
        ("world_gel" | "world_face", "camera_left") => {
            let world_to_camera = frame_to_world(truth, frame, view)?.inverse();
            let v = &truth.views[view];
            Ok(truth
                .markers
                .iter()
                .map(|m| {
                    let seen = v.markers_visible_left.contains(&m.id)
                        && v.markers_visible_right.contains(&m.id);
                    ((world_to_camera * Point3::from(centre(m))).into(), seen)
                })
                .collect())
        }
        ("mri_gel" | "mri_lesion", _) => Err(format!(
            "frame `{frame}`, but reference `{reference}` takes markers in mri_lps"
        )),
        ("world_gel" | "world_face", _) => Err(format!(
            "frame `{frame}`, but reference `{reference}` takes markers in world or camera_left"
        )),
        _ => Err(format!(
            "unknown reference `{reference}` (mri_gel, mri_lesion, world_gel or world_face)"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_without_order_and_counts_misses() {
        let truth = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]];
        let found = [[0.0, 10.1, 0.0], [50.0, 0.0, 0.0], [0.2, 0.0, 0.0]];
        let c = compare_markers(&found, &truth, 5.0);
        assert_eq!((c.pairs.len(), c.missed, c.spurious), (2, 1, 1));
        assert!((c.mean_error_mm() - 0.15).abs() < 1e-12);
        assert!((c.max_error_mm() - 0.2).abs() < 1e-12);
        assert!(compare_markers(&[], &truth, 5.0).mean_error_mm().is_nan());
    }

    #[test]
    fn camera_centres_are_the_visible_markers_in_the_view_camera() {
        let truth = crate::eval::frames::test_truth();
        let pose = crate::camera::isometry_from_matrix(&truth.views[0].left_camera_to_world);
        let faces = true_marker_centres(&truth, "world_face", "camera_left", 0).unwrap();
        // Every marker is there; markers 1, 2, 3 are visible in both images of
        // the test view, so only they are expected.
        assert_eq!(faces.len(), truth.markers.len());
        let expected: Vec<usize> = (0..faces.len()).filter(|&i| faces[i].1).collect();
        assert_eq!(expected, [1, 2, 3]);
        for ((c, _), m) in faces.iter().zip(&truth.markers) {
            let back = pose * Point3::from(*c);
            assert!((back - Point3::from(m.face_center_world_mm)).norm() < 1e-9);
        }
        // The gel core lies below the face, along the marker's axis.
        let gels = true_marker_centres(&truth, "world_gel", "camera_left", 0).unwrap();
        let m = &truth.markers[1];
        let depth = (Point3::from(m.face_center_world_mm) - Point3::from(m.center_world_mm)).norm();
        assert!(((Point3::from(faces[1].0) - Point3::from(gels[1].0)).norm() - depth).abs() < 1e-9);
        assert!(depth > 0.5);
        assert_eq!(
            true_marker_centres(&truth, "world_gel", "world", 0)
                .unwrap()
                .len(),
            truth.markers.len()
        );
    }

    #[test]
    fn mismatched_frames_and_views_are_errors() {
        let truth = crate::eval::frames::test_truth();
        let err = true_marker_centres(&truth, "mri_gel", "camera_left", 0).unwrap_err();
        assert!(err.contains("takes markers in mri_lps"), "{err}");
        let err = true_marker_centres(&truth, "world_face", "mri_lps", 0).unwrap_err();
        assert!(err.contains("world or camera_left"), "{err}");
        let err = true_marker_centres(&truth, "world_face", "camera_left", 2).unwrap_err();
        assert!(err.contains("view 2 does not exist"), "{err}");
    }
}

/// The true marker each of `found` is (the nearest of `truth`, if within
/// `max_distance_mm`), by index into `truth`.
pub fn identify_markers(
    found: &[[f64; 3]],
    truth: &[[f64; 3]],
    max_distance_mm: f64,
) -> Vec<Option<usize>> {
    found
        .iter()
        .map(|f| {
            truth
                .iter()
                .enumerate()
                .map(|(j, t)| {
                    let d = ((f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2) + (f[2] - t[2]).powi(2))
                        .sqrt();
                    (j, d)
                })
                .filter(|(_, d)| *d <= max_distance_mm)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(j, _)| j)
        })
        .collect()
}

#[cfg(test)]
mod identify_tests {
    use super::*;

    #[test]
    fn nearest_true_marker_within_reach() {
        let truth = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]];
        let found = [[9.0, 0.5, 0.0], [0.2, 0.0, 0.0], [50.0, 0.0, 0.0]];
        assert_eq!(
            identify_markers(&found, &truth, 3.0),
            [Some(1), Some(0), None]
        );
    }
}
