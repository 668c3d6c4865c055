//! Conversions between the engine's values and the evaluation's types: the
//! ground truth behind a `truth` path, marker positions as arrays.

use crate::phantom::GroundTruth;
use fusegraph_engine::OpError;
use fusegraph_engine::value::{Markers, PathValue};

/// The ground truth in the file a `truth` input names (ground_truth.json).
pub(crate) fn load_truth(file: &PathValue) -> Result<GroundTruth, OpError> {
    GroundTruth::load(&file.path).map_err(OpError::invalid)
}

/// Markers' positions, mm, in their frame.
pub(crate) fn marker_positions(m: &Markers) -> Vec<[f64; 3]> {
    m.positions_mm
        .chunks(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect()
}
