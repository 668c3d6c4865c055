//! Registration (the paper's module D): marker correspondences, Procrustes,
//! ICP, several views into one, and targets carried through a registration.
//! The point cloud helpers are in [`crate::cloud`].

pub(crate) mod convert;
mod deformable;
pub(crate) mod figures;
mod frame_spread;
mod gicp;
mod icp;
mod marker_merge;
mod match_markers;
mod multiview;
pub mod ops;
mod pairs;
mod pose_spread;
mod procrustes;
mod target_error;
mod targets;

pub use deformable::synthetic as synthetic_breast;
pub use deformable::{
    DeformParams, Deformation, FIELD_COLUMNS, LandmarkPairs, Lattice, Support, base_on,
    displacement_stats, fit_deformation,
};
pub use frame_spread::{Sighting, markers_frame_covariance};
pub use gicp::GICP_NEIGHBOURS;
pub use icp::{
    Anchors, IcpMethod, IcpParams, IcpResult, IcpStep, Kernel, icp, icp_anchored, normals_near,
    relative_information,
};
pub use marker_merge::{
    DroppedSighting, MergeParams, MergedMarker, ViewMarkers, merge_markers, merge_markers_weighted,
};
pub use match_markers::{MarkerMatch, match_markers};
pub use multiview::{
    MarkerAnchoring, Multiview, View, first_view_spread, markers_frame_spread, poses_from_markers,
    register_views,
};
pub use pose_spread::{
    PoseSpread, ShiftField, ShiftedPoint, carried_pose_covariance, mapped_point_covariance,
    pose_spread,
};
pub use procrustes::{Similarity, umeyama};
pub use target_error::{
    FiducialConfiguration, MarkerPrediction, error_bound_mm, expected_fre, fle_from_fre,
    predict_marker_tre,
};
pub use targets::{map_targets, mapped_target_covariances};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `register.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::MatchMarkers>()?;
    registry.add::<ops::Procrustes>()?;
    registry.add::<ops::Icp>()?;
    registry.add::<ops::Deformable>()?;
    registry.add::<ops::Evaluate>()?;
    registry.add::<ops::MapTargets>()?;
    registry.add::<ops::Multiview>()?;
    Ok(())
}
