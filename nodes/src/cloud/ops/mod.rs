//! The `cloud.*` ops: one file per op, each its declaration and thin adapter.

mod downsample;
mod from_mesh;
mod keep_connected;
mod marker_colour;
mod markers_on_surface;
mod normals;
mod remove_colour;
mod remove_plane;
mod transform;

pub use downsample::{Downsample, DownsampleInputs, DownsampleOutputs};
pub use from_mesh::{FromMesh, FromMeshInputs, FromMeshOutputs, SampleMode};
pub use keep_connected::{KeepConnected, KeepConnectedInputs, KeepConnectedOutputs};
pub use marker_colour::MarkerColour;
pub use markers_on_surface::{MarkersOnSurface, MarkersOnSurfaceInputs, MarkersOnSurfaceOutputs};
pub use normals::{Normals, NormalsInputs, NormalsOutputs, Orient};
pub use remove_colour::{RemoveColour, RemoveColourInputs, RemoveColourOutputs};
pub use remove_plane::{RemovePlane, RemovePlaneInputs, RemovePlaneOutputs};
pub use transform::{TransformCloud, TransformCloudInputs, TransformCloudOutputs};

/// A single-cloud input or output, for the ops' tests.
#[cfg(test)]
pub(crate) fn test_cloud(points: &[[f32; 3]], frame: &str) -> fusegraph_engine::value::PointCloud {
    fusegraph_engine::value::PointCloud::new(points.concat(), None, None, frame).unwrap()
}
