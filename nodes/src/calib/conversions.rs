//! Conversions between the engine's rig and rectification values and the
//! solvers' types.

use super::{StereoCalibration, StereoRectification};
use crate::camera::{CameraModel, isometry_from_matrix, isometry_to_matrix};
use fusegraph_engine::value::{Rectification, StereoRig};
use nalgebra::{Matrix3, Matrix3x4, Matrix4};

/// The rig's left -> right isometry (mm).
pub(crate) fn rig_isometry(rig: &StereoRig) -> nalgebra::Isometry3<f64> {
    let mut m = [[0.0; 4]; 4];
    for (r, row) in m.iter_mut().take(3).enumerate() {
        row[..3].copy_from_slice(&rig.rotation[r]);
        row[3] = rig.translation_mm[r];
    }
    m[3][3] = 1.0;
    isometry_from_matrix(&m)
}

/// A stereo calibration as the rig value: both cameras and R, T (left ->
/// right, mm).
pub(crate) fn rig_value(s: &StereoCalibration) -> StereoRig {
    stereo_rig_value(&s.left, &s.right, &isometry_to_matrix(&s.left_to_right))
}

/// Two cameras and the left -> right camera frame transform (4 x 4, mm) as
/// the rig value.
pub(crate) fn stereo_rig_value(
    left: &CameraModel,
    right: &CameraModel,
    left_to_right: &[[f64; 4]; 4],
) -> StereoRig {
    let m = left_to_right;
    StereoRig {
        left: left.to_value(),
        right: right.to_value(),
        rotation: std::array::from_fn(|r| std::array::from_fn(|c| m[r][c])),
        translation_mm: [m[0][3], m[1][3], m[2][3]],
    }
}

/// A rectification value as the solver's type.
pub(crate) fn rectification_of(v: &Rectification) -> StereoRectification {
    StereoRectification {
        size: (v.width, v.height),
        r1: Matrix3::from_fn(|r, c| v.r1[r][c]),
        r2: Matrix3::from_fn(|r, c| v.r2[r][c]),
        p1: Matrix3x4::from_fn(|r, c| v.p1[r][c]),
        p2: Matrix3x4::from_fn(|r, c| v.p2[r][c]),
        q: Matrix4::from_fn(|r, c| v.q[r][c]),
    }
}

/// The solver's rectification as the engine's value.
pub(crate) fn rectification_value(rect: &StereoRectification) -> Rectification {
    let mat3 = |m: &Matrix3<f64>| std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
    let m34 = |m: &Matrix3x4<f64>| std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
    Rectification {
        width: rect.size.0,
        height: rect.size.1,
        r1: mat3(&rect.r1),
        r2: mat3(&rect.r2),
        p1: m34(&rect.p1),
        p2: m34(&rect.p2),
        q: std::array::from_fn(|r| std::array::from_fn(|c| rect.q[(r, c)])),
    }
}
