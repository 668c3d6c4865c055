//! Measurements against the phantom's ground truth: marker localisation errors,
//! surface distances, calibration, disparity and registration errors; and the
//! `eval.*` ops.

mod calibration;
pub(crate) mod convert;
mod disparity;
mod frames;
mod markers;
pub mod ops;
mod registration;
mod surface;

pub use calibration::{CalibrationErrors, compare_calibration};
pub use disparity::{DisparityErrors, bad_metric_name, disparity_errors};
pub use frames::{EVAL_FRAMES, frame_to_world};
pub use markers::{MarkerComparison, compare_markers, identify_markers, true_marker_centres};
pub use registration::{
    OverlapErrors, RegistrationErrors, TrueMapping, overlap_errors, registration_errors,
    target_errors, true_mri_to_camera,
};
pub use surface::{SurfaceDistances, skin_distances};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `eval.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::EvalMarkers>()?;
    registry.add::<ops::EvalCorrespondences>()?;
    registry.add::<ops::EvalSkinDistance>()?;
    registry.add::<ops::EvalSurface>()?;
    registry.add::<ops::EvalCalibration>()?;
    registry.add::<ops::EvalDisparity>()?;
    Ok(())
}
