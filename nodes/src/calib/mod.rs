//! Camera calibration: chessboard corners to sub-pixel accuracy, homographies,
//! Zhang's closed form, Levenberg-Marquardt refinement (written here, see
//! `lm.rs`), stereo calibration and rectification.

mod camera_calibration;
mod detect;
mod homography;
mod lm;
mod subpixel;
mod zhang;

pub use camera_calibration::{
    BoardView, CameraCalibration, DISTORTION_NAMES, calibrate_camera, rotation_error_deg,
};
pub use detect::find_chessboard;
pub use homography::homography;
pub use lm::{LeastSquares, LmReport, levenberg_marquardt};
pub use subpixel::{refine_corner, window_for_square};
pub use zhang::{intrinsics_from_homographies, pose_from_homography};
