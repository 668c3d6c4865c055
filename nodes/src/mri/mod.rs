//! The MRI branch (the paper's module A): contrast stretch, Otsu threshold,
//! isosurface, connected components, marker selection and centroids, and
//! lesions found in the scan.

mod components;
mod filters;
mod intensity;
mod lesions;
mod marching_cubes;
mod markers;
pub mod ops;
mod self_intersection;

pub use components::{Connectivity, label_components};
pub use intensity::{otsu_threshold, percentiles, stretch};
pub use lesions::{FoundLesion, LesionParams, LesionSearch, Polarity, detect_lesions};
pub use marching_cubes::{TriangleMesh, marching_cubes};
pub use markers::{MarkerSelection, Weighting, centroids, select_components};
pub use self_intersection::{self_intersections, triangle_distance};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `mri.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::BrightStretch>()?;
    registry.add::<ops::Otsu>()?;
    registry.add::<ops::Isosurface>()?;
    registry.add::<ops::Components>()?;
    registry.add::<ops::SelectMarkers>()?;
    registry.add::<ops::Centroids>()?;
    registry.add::<ops::DetectLesions>()?;
    Ok(())
}
