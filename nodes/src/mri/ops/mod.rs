//! The `mri.*` ops: one file per op, each its declaration and thin adapter.

mod bright_stretch;
mod centroids;
mod components;
mod detect_lesions;
mod isosurface;
mod otsu;
mod select_markers;

pub use bright_stretch::{BrightStretch, BrightStretchInputs, BrightStretchOutputs};
pub use centroids::{CentroidWeighting, Centroids, CentroidsInputs, CentroidsOutputs};
pub use components::{Components, ComponentsInputs, ComponentsOutputs};
pub use detect_lesions::{
    DetectLesions, DetectLesionsInputs, DetectLesionsOutputs, LesionPolarity,
};
pub use isosurface::{Isosurface, IsosurfaceInputs, IsosurfaceOutputs};
pub use otsu::{Otsu, OtsuInputs, OtsuOutputs};
pub use select_markers::{SelectMarkers, SelectMarkersInputs, SelectMarkersOutputs};

use fusegraph_engine::OpError;
use fusegraph_engine::value::ValueError;

/// A value whose shape does not fit its type, as the op's error.
pub(crate) fn shape_error(e: ValueError) -> OpError {
    OpError::invalid(e.0)
}
