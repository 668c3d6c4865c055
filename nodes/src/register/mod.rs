//! Registration (the paper's module D): marker correspondences, Procrustes,
//! point cloud helpers and ICP.

mod cloud;
mod icp;
mod match_markers;
mod procrustes;

pub use cloud::{Nearest, estimate_normals, sample_mesh, voxel_downsample};
pub use icp::{IcpMethod, IcpParams, IcpResult, IcpStep, Kernel, icp};
pub use match_markers::{MarkerMatch, match_markers};
pub use procrustes::{Similarity, umeyama};
