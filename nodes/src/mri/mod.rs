//! The MRI branch (the paper's module A): contrast stretch, Otsu threshold,
//! isosurface, connected components, marker selection and centroids.

mod components;
mod intensity;
mod marching_cubes;
mod markers;
mod ops;
mod self_intersection;

pub use components::{Connectivity, label_components};
pub use intensity::{otsu_threshold, percentiles, stretch};
pub use marching_cubes::{TriangleMesh, marching_cubes};
pub use markers::{MarkerSelection, Weighting, centroids, select_components};
pub use self_intersection::{self_intersections, triangle_distance};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `mri.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(ops::StretchOp::new()))?;
    registry.register(Arc::new(ops::OtsuOp::new()))?;
    registry.register(Arc::new(ops::IsosurfaceOp::new()))?;
    registry.register(Arc::new(ops::ComponentsOp::new()))?;
    registry.register(Arc::new(ops::SelectMarkersOp::new()))?;
    registry.register(Arc::new(ops::CentroidsOp::new()))?;
    Ok(())
}
