//! The `eval.*` ops: one file per op, each its declaration and thin adapter.

mod calibration;
mod correspondences;
mod disparity;
mod markers;
mod skin_distance;
mod surface;

pub use calibration::{EvalCalibration, EvalCalibrationInputs, EvalCalibrationOutputs};
pub use correspondences::{
    EvalCorrespondences, EvalCorrespondencesInputs, EvalCorrespondencesOutputs, SourceReference,
};
pub use disparity::{EvalDisparity, EvalDisparityInputs, EvalDisparityOutputs};
pub use markers::{EvalMarkers, EvalMarkersInputs, EvalMarkersOutputs, Reference};
pub use skin_distance::{EvalSkinDistance, EvalSkinDistanceInputs, EvalSkinDistanceOutputs};
pub use surface::{EvalSurface, EvalSurfaceInputs, EvalSurfaceOutputs};

/// The test truth written to a file of its own (tests run in parallel), as
/// a `truth` input.
#[cfg(test)]
pub(crate) fn truth_file(
    name: &str,
) -> (
    crate::phantom::GroundTruth,
    std::sync::Arc<fusegraph_engine::value::PathValue>,
) {
    let truth = crate::eval::frames::test_truth();
    let path =
        std::env::temp_dir().join(format!("fusegraph-eval-{}-{name}.json", std::process::id()));
    truth.save(&path).unwrap();
    let file = fusegraph_engine::value::PathValue {
        path,
        content_hash: String::new(),
    };
    (truth, std::sync::Arc::new(file))
}
