//! Camera geometry shared by the phantom renderer, calibration and stereo: the
//! pinhole + lens distortion model and rigid frame conversions.

mod frames;
mod model;

pub use frames::{isometry_from_matrix, isometry_to_matrix, look_at};
pub use model::CameraModel;
