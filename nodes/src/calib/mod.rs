//! Camera calibration: chessboard corners to sub-pixel accuracy, homographies,
//! Zhang's closed form, Levenberg-Marquardt refinement (written here, see
//! `lm.rs`), stereo calibration and rectification.

mod camera_calibration;
mod conversions;
mod cross_validation;
mod detect;
mod homography;
mod lm;
mod normal_equations;
pub mod ops;
mod rectify;
mod reprojection;
mod rig_parameters;
mod stereo;
mod subpixel;
mod tables;
mod uncertainty;
mod views;
mod zhang;

pub use camera_calibration::{
    BoardView, CameraCalibration, DISTORTION_NAMES, board_corner_mm, calibrate_camera,
    rotation_error_deg,
};
pub use cross_validation::{CrossValidation, cross_validate};
pub use detect::{Refusal, find_chessboard};
pub use homography::homography;
pub use lm::{LeastSquares, LmReport, levenberg_marquardt};
pub use normal_equations::{BlockNormal, DampedSystem, DenseNormal};
pub use rectify::{StereoRectification, rectify, remap};
pub use rig_parameters::{
    COVARIANCE_COLUMNS, INTRINSIC_NAMES, POSE_NAMES, ParameterCovariance, RigModel,
    columns_with_covariance, covariance_entries, covariance_from_entries, covariances_for_ids,
    disparity_offset_rigs, parameter_names, perturbed_rigs, perturbed_rigs_from_table,
    triangulated_covariance, triangulation_shifts,
};
pub use stereo::{RigSpread, StereoCalibration, calibrate_stereo};
pub use subpixel::{refine_corner, window_for_square};
pub use uncertainty::{Spread, block3, intrinsics_sd, residual_variance};
pub use views::{
    IMAGE_EXTENSIONS, NumberedPhotos, Pairing, PhotoRecord, SAME_POSE_PX, Side,
    max_corner_shift_px, numbered_photos, pair_views, repeated_poses, usual_size, view_number,
};
pub use zhang::{intrinsics_from_homographies, pose_from_homography};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

pub(crate) use conversions::{rectification_of, rig_isometry, stereo_rig_value};

/// Registers the `calib.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::FindChessboard>()?;
    registry.add::<ops::CalibrateCamera>()?;
    registry.add::<ops::CrossValidate>()?;
    registry.add::<ops::StereoCalibrate>()?;
    registry.add::<ops::Rectify>()?;
    registry.add::<ops::Remap>()?;
    Ok(())
}

/// A test rig: two 800 x 600 cameras (f 1300 px, principal point at the
/// centre, no distortion), parallel, 80 mm apart along x.
#[cfg(test)]
pub(crate) fn parallel_test_rig() -> fusegraph_engine::value::StereoRig {
    let camera = fusegraph_engine::value::Camera {
        width: 800,
        height: 600,
        k: [[1300.0, 0.0, 400.0], [0.0, 1300.0, 300.0], [0.0, 0.0, 1.0]],
        distortion: [0.0; 5],
    };
    fusegraph_engine::value::StereoRig {
        left: camera.clone(),
        right: camera,
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation_mm: [-80.0, 0.0, 0.0],
    }
}
