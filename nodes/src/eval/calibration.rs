//! A calibrated rig against the phantom's true cameras.

use crate::calib::StereoRectification;
use crate::camera::{CameraModel, isometry_from_matrix};
use crate::phantom::GroundTruth;
use nalgebra::{Isometry3, Point3};

/// Errors of a stereo calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationErrors {
    /// |estimate - truth| / truth for fx, fy, cx, cy of the left then right camera.
    pub intrinsic_rel: [f64; 8],
    /// Largest difference between estimated and true lens distortion over the
    /// image, px (the displacement each model applies to the same ray).
    pub distortion_max_px: [f64; 2],
    /// Estimate - truth for fx, fy, cx, cy of the left then right camera,
    /// px (signed: their spread over phantom seeds is what a calibration's
    /// standard deviations predict).
    pub intrinsic_error_px: [f64; 8],
    /// |estimated baseline - true baseline|, mm.
    pub baseline_error_mm: f64,
    /// Estimated baseline - true baseline, mm.
    pub baseline_signed_error_mm: f64,
    /// The estimated left -> right rotation's small-angle error about the
    /// right camera's x, y, z axes (R_est = exp([e]x) R_true), deg.
    pub rotation_error_axes_deg: [f64; 3],
    /// Angle between the estimated and true left -> right rotations, deg.
    pub rotation_error_deg: f64,
    /// RMS row difference of true corresponding points after rectification
    /// with the estimate, px (when a rectification is given).
    pub epipolar_rms_px: Option<f64>,
}

fn distortion_difference_px(est: &CameraModel, truth: &CameraModel) -> f64 {
    let mut worst: f64 = 0.0;
    for v in (0..truth.height).step_by(20) {
        for u in (0..truth.width).step_by(20) {
            let (x, y) = truth.undistort(u as f64, v as f64);
            let (a, b) = (est.distort(x, y), truth.distort(x, y));
            worst = worst.max(((a.0 - b.0) * truth.fx).hypot((a.1 - b.1) * truth.fy));
        }
    }
    worst
}

/// Compares an estimated rig (and optionally its rectification) with the truth.
pub fn compare_calibration(
    left: &CameraModel,
    right: &CameraModel,
    left_to_right: &Isometry3<f64>,
    rect: Option<&StereoRectification>,
    truth: &GroundTruth,
) -> CalibrationErrors {
    let (tl, tr) = (&truth.rig.left, &truth.rig.right);
    let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
    let intrinsic_rel = [
        rel(left.fx, tl.fx),
        rel(left.fy, tl.fy),
        rel(left.cx, tl.cx),
        rel(left.cy, tl.cy),
        rel(right.fx, tr.fx),
        rel(right.fy, tr.fy),
        rel(right.cx, tr.cx),
        rel(right.cy, tr.cy),
    ];
    let intrinsic_error_px = [
        left.fx - tl.fx,
        left.fy - tl.fy,
        left.cx - tl.cx,
        left.cy - tl.cy,
        right.fx - tr.fx,
        right.fy - tr.fy,
        right.cx - tr.cx,
        right.cy - tr.cy,
    ];
    let true_rig = isometry_from_matrix(&truth.rig.left_to_right);
    let rotation_error = (left_to_right.rotation * true_rig.rotation.inverse()).scaled_axis();
    let baseline_signed_error_mm =
        left_to_right.translation.vector.norm() - true_rig.translation.vector.norm();
    let epipolar_rms_px = rect.map(|r| {
        let [cols, rows] = truth.chessboard.pattern;
        let mut sum2 = 0.0;
        let mut n = 0usize;
        for pair in &truth.calibration {
            let pose = isometry_from_matrix(&pair.board_to_left_camera);
            for k in 0..cols * rows {
                let b = crate::calib::board_corner_mm(k, cols, truth.chessboard.square_mm);
                let b = Point3::new(b.x, b.y, 0.0);
                let (pl, pr) = (
                    tl.project(&(pose * b)),
                    tr.project(&(true_rig * (pose * b))),
                );
                let (Some(pl), Some(pr)) = (pl, pr) else {
                    continue;
                };
                if !tl.contains(&pl, 0.0) || !tr.contains(&pr, 0.0) {
                    continue;
                }
                let a = StereoRectification::rectify_point(left, &r.r1, &r.p1, &pl);
                let c = StereoRectification::rectify_point(right, &r.r2, &r.p2, &pr);
                sum2 += (a.y - c.y).powi(2);
                n += 1;
            }
        }
        (sum2 / n.max(1) as f64).sqrt()
    });
    CalibrationErrors {
        intrinsic_rel,
        distortion_max_px: [
            distortion_difference_px(left, tl),
            distortion_difference_px(right, tr),
        ],
        intrinsic_error_px,
        baseline_error_mm: baseline_signed_error_mm.abs(),
        baseline_signed_error_mm,
        rotation_error_axes_deg: rotation_error.map(f64::to_degrees).into(),
        rotation_error_deg: left_to_right
            .rotation
            .angle_to(&true_rig.rotation)
            .to_degrees(),
        epipolar_rms_px,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::isometry_from_matrix;
    use crate::eval::frames::test_truth;
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn signed_errors_say_which_way_each_parameter_is_off() {
        let truth = test_truth();
        let (mut left, right) = (truth.rig.left.clone(), truth.rig.right.clone());
        left.fx += 1.5;
        left.cy -= 0.5;
        let true_rig = isometry_from_matrix(&truth.rig.left_to_right);
        // 0.01 deg about the right camera's y axis, and 0.2 mm longer.
        let turn = UnitQuaternion::from_scaled_axis(Vector3::y() * 0.01f64.to_radians());
        let mut rig = true_rig;
        rig.rotation = turn * rig.rotation;
        rig.translation.vector *= 1.0 + 0.2 / true_rig.translation.vector.norm();
        let e = compare_calibration(&left, &right, &rig, None, &truth);
        assert!((e.intrinsic_error_px[0] - 1.5).abs() < 1e-9);
        assert!((e.intrinsic_error_px[3] + 0.5).abs() < 1e-9);
        assert!(e.intrinsic_error_px[4..].iter().all(|v| v.abs() < 1e-9));
        assert!((e.baseline_signed_error_mm - 0.2).abs() < 1e-9);
        let [x, y, z] = e.rotation_error_axes_deg;
        assert!(
            x.abs() < 1e-9 && (y - 0.01).abs() < 1e-9 && z.abs() < 1e-9,
            "{x} {y} {z}"
        );
    }
}
