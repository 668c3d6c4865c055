//! Measurements against the phantom's ground truth: marker localisation errors
//! and surface distances.

mod calibration;
mod disparity;
mod frames;
mod markers;
mod ops;
mod surface;

pub use calibration::{CalibrationErrors, compare_calibration};
pub use disparity::{DisparityErrors, bad_metric_name, disparity_errors};
pub use frames::{EVAL_FRAMES, frame_to_world};
pub use markers::{MarkerComparison, compare_markers, identify_markers, true_marker_centres};
pub use surface::{SurfaceDistances, skin_distances};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `eval.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(ops::EvalMarkersOp::new()))?;
    registry.register(Arc::new(ops::EvalCorrespondencesOp::new()))?;
    registry.register(Arc::new(ops::EvalSkinOp::new()))?;
    registry.register(Arc::new(ops::EvalSurfaceOp::new()))?;
    registry.register(Arc::new(ops::EvalCalibrationOp::new()))?;
    registry.register(Arc::new(ops::EvalDisparityOp::new()))?;
    Ok(())
}
