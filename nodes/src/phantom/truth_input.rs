//! The ground truth a `truth` port carries (the path of a phantom's
//! `ground_truth.json`), for the ops of every stage that compare with it.

use super::truth::GroundTruth;
use fusegraph_engine::value::PathValue;
use fusegraph_engine::{Inputs, OpError};

/// The ground truth in the `ground_truth.json` that `file` is.
pub(crate) fn load_truth(file: &PathValue) -> Result<GroundTruth, OpError> {
    GroundTruth::load(&file.path).map_err(OpError::invalid)
}

/// The ground truth on an optional `truth` input of an op not yet in the
/// typed form (a typed op declares `truth: Option<Arc<PathValue>>` and calls
/// [`load_truth`]); goes when the last such op does.
pub(crate) fn optional_truth_input(inputs: &Inputs) -> Result<Option<GroundTruth>, OpError> {
    match inputs.optional::<PathValue>("truth")? {
        Some(file) => load_truth(&file).map(Some),
        None => Ok(None),
    }
}

/// The ground truth on a required `truth` input of an op not yet in the
/// typed form (see [`optional_truth_input`]).
pub(crate) fn truth_input(inputs: &Inputs) -> Result<GroundTruth, OpError> {
    optional_truth_input(inputs)?
        .ok_or_else(|| OpError::Input("truth".into(), "not connected".into()))
}
