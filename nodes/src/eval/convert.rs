//! Conversions between the engine's values and the evaluation's types: the
//! ground truth behind a `truth` path, marker positions as arrays.

use fusegraph_engine::value::Markers;

pub(crate) use crate::phantom::load_truth;

/// Markers' positions, mm, in their frame.
pub(crate) fn marker_positions(m: &Markers) -> Vec<[f64; 3]> {
    m.positions_mm
        .chunks(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect()
}
