//! A registration measured: how well the clouds overlap (no truth needed),
//! and with the phantom's truth, how far off the lesions land in the camera
//! frame where the robot acts.

use crate::camera::isometry_from_matrix;
use crate::cloud::Nearest;
use crate::phantom::{GroundTruth, MotionField};
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

/// Where the truth puts MRI points in the left camera frame of one view: the
/// rigid MRI -> camera transform of the phantom as scanned, and, when the
/// tissue moved between the scan and the camera session, that motion.
#[derive(Debug, Clone)]
pub struct TrueMapping {
    /// `mri_lps` -> `camera_left` of the phantom as scanned, mm.
    pub rigid: Isometry3<f64>,
    /// The motion (phantom frame) with `mri_lps` -> phantom and phantom ->
    /// `camera_left`; `None` when nothing moved.
    motion: Option<(MotionField, Isometry3<f64>, Isometry3<f64>)>,
}

impl TrueMapping {
    /// Where MRI point `p` (`mri_lps`, mm) is in the camera session
    /// (`camera_left`, mm).
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        match &self.motion {
            None => self.rigid * p,
            Some((field, mri_to_phantom, phantom_to_camera)) => {
                phantom_to_camera * field.moved(&(mri_to_phantom * p))
            }
        }
    }
}

/// The true mapping of MRI points (`mri_lps`) into the left camera
/// (`camera_left`) of phantom view `view`, motion included; an unknown view is
/// an error naming it.
pub fn true_mri_to_camera(truth: &GroundTruth, view: usize) -> Result<TrueMapping, String> {
    let v = truth
        .views
        .get(view)
        .ok_or_else(|| format!("view {view} does not exist ({} views)", truth.views.len()))?;
    let world_to_camera = isometry_from_matrix(&v.left_camera_to_world).inverse();
    let motion = truth.motion.as_ref().filter(|m| !m.is_still()).map(|m| {
        (
            m.clone(),
            isometry_from_matrix(&truth.phantom_to_mri).inverse(),
            world_to_camera * isometry_from_matrix(&truth.phantom_to_world),
        )
    });
    Ok(TrueMapping {
        rigid: world_to_camera * isometry_from_matrix(&truth.mri_to_world),
        motion,
    })
}

/// How well a registered source cloud lies on its target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OverlapErrors {
    /// RMS distance of the source points within the overlap distance of the
    /// target, mm.
    pub rmse_all_mm: f64,
    /// RMS distance of the inliers (within the inlier distance), mm.
    pub rmse_mm: f64,
    /// Inliers as a fraction of all source points.
    pub inlier_fraction: f64,
}

/// Distances from every `source` point, moved by `source_to_target`, to the
/// nearest `target` point (target frame, mm), summarised over the points
/// within `overlap_mm` and within `inlier_mm`; `None` for an empty target.
pub fn overlap_errors(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    source_to_target: &Isometry3<f64>,
    overlap_mm: f64,
    inlier_mm: f64,
) -> Option<OverlapErrors> {
    let tree = Nearest::new(target)?;
    // In parallel, in order: the sums below run over the same sequence.
    let d: Vec<f64> = source
        .par_iter()
        .map(|p| tree.nearest(&(source_to_target * p)).1.sqrt())
        .collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let overlap: Vec<f64> = d.iter().copied().filter(|&x| x <= overlap_mm).collect();
    let inliers: Vec<f64> = overlap
        .iter()
        .copied()
        .filter(|&x| x <= inlier_mm)
        .collect();
    Some(OverlapErrors {
        rmse_all_mm: rms(&overlap),
        rmse_mm: rms(&inliers),
        inlier_fraction: inliers.len() as f64 / d.len().max(1) as f64,
    })
}

/// An estimated MRI -> camera registration against the true one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegistrationErrors {
    /// Mean target registration error over the lesion centres, mm (camera frame).
    pub tre_mm: f64,
    /// Largest target registration error over the lesion centres, mm.
    pub tre_max_mm: f64,
    /// Angle between the estimated and the true rotation, degrees.
    pub rotation_error_deg: f64,
    /// Error at the phantom's centre (25 mm above its base), mm.
    pub translation_error_mm: f64,
}

/// The errors of `estimated` (`mri_lps` -> `camera_left`, mm) against the
/// truth's mapping (see [`true_mri_to_camera`]) where the robot acts: at the
/// lesion centres as the camera session has them (moved, if the tissue
/// moved), in camera space. The rotation is compared with the rigid part.
pub fn registration_errors(
    truth: &GroundTruth,
    true_mc: &TrueMapping,
    estimated: &Isometry3<f64>,
) -> RegistrationErrors {
    let errors: Vec<f64> = truth
        .lesions
        .iter()
        .map(|l| {
            let p = Point3::from(l.center_mri_mm);
            (estimated * p - true_mc.apply(&p)).norm()
        })
        .collect();
    let (tre_mm, tre_max_mm) = mean_and_max(&errors);
    let centre = isometry_from_matrix(&truth.phantom_to_mri) * Point3::new(0.0, 0.0, 25.0);
    RegistrationErrors {
        tre_mm,
        tre_max_mm,
        rotation_error_deg: estimated
            .rotation
            .angle_to(&true_mc.rigid.rotation)
            .to_degrees(),
        translation_error_mm: (estimated * centre - true_mc.apply(&centre)).norm(),
    }
}

/// Mean and largest distance (mm) of `mapped` (in `camera_left`) from where
/// `true_mc` (the truth's `mri_lps` -> `camera_left`) puts `targets` (in
/// `mri_lps`), pair by pair; both 0 without targets.
pub fn target_errors(
    true_mc: &TrueMapping,
    targets: &[Point3<f64>],
    mapped: &[Point3<f64>],
) -> (f64, f64) {
    let errors: Vec<f64> = targets
        .iter()
        .zip(mapped)
        .map(|(p, m)| (true_mc.apply(p) - m).norm())
        .collect();
    mean_and_max(&errors)
}

/// Mean (0 for none) and largest (0 for none) of distances.
fn mean_and_max(errors: &[f64]) -> (f64, f64) {
    (
        errors.iter().sum::<f64>() / errors.len().max(1) as f64,
        errors.iter().copied().fold(0.0, f64::max),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::frames::test_truth;

    #[test]
    fn the_true_registration_has_no_error_and_a_shift_shows_as_such() {
        let mut truth = test_truth();
        for (id, centre) in [(1, [0.0, 10.0, 20.0]), (2, [-15.0, 5.0, 30.0])] {
            truth.lesions.push(crate::phantom::LesionTruth {
                id,
                center_mri_mm: centre,
                center_world_mm: [0.0; 3],
                diameter_mm: 8.0,
                scanned_world_mm: None,
            });
        }
        let exact = true_mri_to_camera(&truth, 0).unwrap();
        let e = registration_errors(&truth, &exact, &exact.rigid);
        assert!(e.tre_max_mm < 1e-9 && e.rotation_error_deg < 1e-6, "{e:?}");
        let shift = Isometry3::translation(0.0, 1.5, 0.0);
        let e = registration_errors(&truth, &exact, &(shift * exact.rigid));
        assert!((e.tre_mm - 1.5).abs() < 1e-9 && (e.tre_max_mm - 1.5).abs() < 1e-9);
        assert!((e.translation_error_mm - 1.5).abs() < 1e-9);
        let err = true_mri_to_camera(&truth, 3).unwrap_err();
        assert_eq!(err, "view 3 does not exist (1 views)");
        let p = [Point3::new(1.0, 2.0, 3.0)];
        let mapped = [shift * exact.rigid * p[0]];
        let (mean, max) = target_errors(&exact, &p, &mapped);
        assert!((mean - 1.5).abs() < 1e-9 && (max - 1.5).abs() < 1e-9);
    }

    #[test]
    fn overlap_counts_the_close_points() {
        let target: Vec<Point3<f64>> = (0..10).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        // 1 mm above, 3 mm above (outside the inliers) and 50 mm away.
        let source = [
            Point3::new(2.0, 0.0, 1.0),
            Point3::new(5.0, 0.0, 3.0),
            Point3::new(5.0, 50.0, 0.0),
        ];
        let e = overlap_errors(&source, &target, &Isometry3::identity(), 10.0, 2.0).unwrap();
        assert!((e.rmse_all_mm - 5f64.sqrt()).abs() < 1e-12);
        assert!((e.rmse_mm - 1.0).abs() < 1e-12);
        assert!((e.inlier_fraction - 1.0 / 3.0).abs() < 1e-12);
        let moved = Isometry3::translation(0.0, 0.0, -1.0);
        let e = overlap_errors(&source[..1], &target, &moved, 10.0, 2.0).unwrap();
        assert_eq!(e.rmse_mm, 0.0);
        assert!(overlap_errors(&source, &[], &moved, 10.0, 2.0).is_none());
    }
}
