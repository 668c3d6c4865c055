//! The camera surface from images (the paper's module C, steps 3-5): feature
//! matches that bound the disparity range, dense matchers (block matching and
//! semi-global matching), triangulation into a metric cloud in the left camera
//! frame, and the coloured markers found in both images and triangulated.
//!
//! Frames: pixel coordinates are in the *rectified* images (px, integer values
//! at pixel centres, OpenCV); disparity is `x_left - x_right` in px; 3D points
//! are in mm in the original (unrectified) left camera frame `camera_left`.

mod feature_ops;
pub mod features;
#[cfg(test)]
mod features_eval;
mod matching;
mod range;
mod triangulate;

pub use feature_ops::{features_from_table, features_to_table};
pub use matching::{FeatureMatch, MatchParams, match_features};
pub use range::{RangeParams, disparity_range, percentile};
pub use triangulate::point_from_disparity;

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `stereo.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(feature_ops::FeaturesOp::new()))?;
    registry.register(Arc::new(feature_ops::MatchFeaturesOp::new()))?;
    registry.register(Arc::new(feature_ops::DisparityRangeOp::new()))?;
    Ok(())
}
