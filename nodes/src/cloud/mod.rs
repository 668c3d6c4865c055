//! Point clouds (helpers of the paper's module D): nearest-neighbour search,
//! sampling a mesh, voxel downsampling, normals by local PCA, removing the
//! table under an object and the points near a colour, telling markers on
//! the skin from things off it, keeping a cloud's main connected surfaces;
//! and the `cloud.*` ops.

mod colour_filter;
mod connected;
pub(crate) mod convert;
mod nearest;
mod normals;
mod on_surface;
pub mod ops;
mod plane;
mod sample;
mod voxel;

pub use colour_filter::away_from_colour;
pub use connected::{connected_surfaces, keep_main_surfaces};
pub use nearest::Nearest;
pub use normals::{
    PLANE_COVARIANCE_EPSILON, estimate_normals, plane_covariance, plane_covariances,
};
pub use on_surface::{OnSurface, SurfaceTest, markers_on_surface};
pub use plane::{PLANE_COLUMNS, Plane, dominant_plane, off_table, plane_from_table, plane_table};
pub use sample::{bumpy_ellipsoid, sample_mesh, sample_mesh_with_normals};
pub use voxel::voxel_downsample;

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `cloud.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::FromMesh>()?;
    registry.add::<ops::Downsample>()?;
    registry.add::<ops::RemovePlane>()?;
    registry.add::<ops::RemoveColour>()?;
    registry.add::<ops::KeepConnected>()?;
    registry.add::<ops::MarkersOnSurface>()?;
    registry.add::<ops::Normals>()?;
    registry.add::<ops::TransformCloud>()?;
    Ok(())
}
