//! The camera surface from images (the paper's module C, steps 3-5): feature
//! matches that bound the disparity range, dense matchers (block matching and
//! semi-global matching), triangulation into a metric cloud in the left camera
//! frame, and the coloured markers found in both images and triangulated.
//!
//! Frames: pixel coordinates are in the *rectified* images (px, integer values
//! at pixel centres, OpenCV); disparity is `x_left - x_right` in px; 3D points
//! are in mm in the original (unrectified) left camera frame `camera_left`.

mod blobs;
mod block_match;
mod cost;
mod dense;
mod dense_ops;
mod feature_ops;
pub mod features;
#[cfg(test)]
mod features_eval;
mod filter;
mod hsv_markers;
mod markers_op;
mod matching;
mod pair;
mod range;
mod refine;
mod select;
mod sgm;
mod simd;
mod texture;
mod triangulate;

pub use blobs::{MomentEllipse, components, dilate, ellipse_fit, erode, open_close, soft_centroid};
pub use block_match::{BlockCost, block_match};
pub use cost::{CensusCosts, CostRows, CostVolume, bt_costs, census_costs, census_transform};
pub use dense::{MatchCost, SgmConfig, sgm_disparity, speckle_size_px};
pub use dense_ops::triangulate_disparity;
pub use feature_ops::{features_from_table, features_to_table};
pub use filter::filter_speckles;
pub use hsv_markers::{
    Blob, BlobParams, PairParams, StereoMarker, StereoMarkers, colour_mask, find_blobs, hsv,
    hue_score, pair_blobs, stereo_markers,
};
pub use markers_op::BLOB_COLUMNS;
pub(crate) use markers_op::hue_range;
pub use matching::{FeatureMatch, MatchParams, match_features};
pub use pair::{DisparityRange, GreyImage, check_pair};
pub use range::{RangeParams, disparity_range, percentile};
pub use refine::{MAX_SIDE, RefineParams, refine_disparity};
pub use select::{SelectParams, select};
pub use sgm::{Aggregated, Paths, SgmParams, aggregate};
pub use simd::Isa;
pub use texture::{flat_windows, noise_sigma};
pub use triangulate::point_from_disparity;

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `stereo.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(dense_ops::SgmOp::new()))?;
    registry.register(Arc::new(dense_ops::BlockMatchOp::new()))?;
    registry.register(Arc::new(dense_ops::TriangulateOp::new()))?;
    registry.register(Arc::new(markers_op::HsvMarkersOp::new()))?;
    registry.register(Arc::new(feature_ops::FeaturesOp::new()))?;
    registry.register(Arc::new(feature_ops::MatchFeaturesOp::new()))?;
    registry.register(Arc::new(feature_ops::DisparityRangeOp::new()))?;
    Ok(())
}
