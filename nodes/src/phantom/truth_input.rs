//! The ground truth a `truth` port carries (the path of a phantom's
//! `ground_truth.json`), for the ops of every stage that compare with it.

use super::truth::GroundTruth;
use fusegraph_engine::OpError;
use fusegraph_engine::value::PathValue;

/// The ground truth in the `ground_truth.json` that `file` is.
pub(crate) fn load_truth(file: &PathValue) -> Result<GroundTruth, OpError> {
    GroundTruth::load(&file.path).map_err(OpError::invalid)
}
