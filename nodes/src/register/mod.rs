//! Registration (the paper's module D): marker correspondences, Procrustes,
//! point cloud helpers and ICP.

mod cloud;
mod colour_filter;
mod icp;
mod match_markers;
mod multiview;
mod ops;
mod plane;
mod procrustes;

pub use cloud::{Nearest, bumpy_ellipsoid, estimate_normals, sample_mesh, voxel_downsample};
pub use colour_filter::away_from_colour;
pub use icp::{IcpMethod, IcpParams, IcpResult, IcpStep, Kernel, icp};
pub use match_markers::{MarkerMatch, match_markers};
pub use multiview::{
    MergedMarker, Multiview, View, merge_markers, poses_from_markers, register_views,
};
pub use plane::{Plane, dominant_plane};
pub use procrustes::{Similarity, umeyama};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `register.*` and `cloud.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(ops::MatchMarkersOp::new()))?;
    registry.register(Arc::new(ops::ProcrustesOp::new()))?;
    registry.register(Arc::new(ops::FromMeshOp::new()))?;
    registry.register(Arc::new(ops::DownsampleOp::new()))?;
    registry.register(Arc::new(ops::RemovePlaneOp::new()))?;
    registry.register(Arc::new(ops::RemoveColourOp::new()))?;
    registry.register(Arc::new(ops::NormalsOp::new()))?;
    registry.register(Arc::new(ops::TransformCloudOp::new()))?;
    registry.register(Arc::new(ops::IcpOp::new()))?;
    registry.register(Arc::new(ops::EvaluateOp::new()))?;
    registry.register(Arc::new(ops::MapTargetsOp::new()))?;
    registry.register(Arc::new(ops::MultiviewOp::new()))?;
    Ok(())
}
