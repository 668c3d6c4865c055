//! The camera surface from images (the paper's module C, steps 3-5): feature
//! matches that bound the disparity range, dense matchers (block matching and
//! semi-global matching), triangulation into a metric cloud in the left camera
//! frame, and the coloured markers found in both images and triangulated.
//!
//! - `dense`: costs, semi-global aggregation, block matching, selection and
//!   the filters after it (every item re-exported here);
//! - [`features`]: keypoints and descriptors, their matches, and the disparity
//!   range the matches bound;
//! - `markers`: coloured blobs paired across the images (re-exported here);
//! - `triangulate`: pixels with disparities to points (re-exported here);
//! - [`ops`]: the `stereo.*` ops, one file each.
//!
//! Frames: pixel coordinates are in the *rectified* images (px, integer values
//! at pixel centres, OpenCV); disparity is `x_left - x_right` in px; 3D points
//! are in mm in the original (unrectified) left camera frame `camera_left`.

mod dense;
pub mod features;
mod markers;
pub mod ops;
mod triangulate;

pub use dense::{
    Aggregated, BlockCost, CensusCosts, CostRows, CostVolume, DisparityRange, FillParams,
    GreyImage, Isa, MAX_SIDE, MatchCost, Paths, RefineParams, SelectParams, SgmConfig, SgmParams,
    SlantedParams, WindowShape, aggregate, block_match, bt_costs, census_costs, census_transform,
    check_bt_window, check_census_window, check_pair, check_penalties, fill_disparity,
    filter_speckles, flat_windows, noise_sigma, refine_disparity, refine_slanted, select,
    sgm_disparity, speckle_size_px,
};
pub use features::{
    FeatureMatch, MatchParams, RangeParams, core_disparities, disparity_range, features_from_table,
    features_to_table, match_features, percentile, supported_disparities,
};
pub use markers::{
    Blob, BlobParams, GREY_CHROMA_LEVELS, MomentEllipse, PairParams, StereoMarker, StereoMarkers,
    colour_mask, components, dilate, ellipse_fit, erode, find_blobs, hsv, hue_score,
    localisation_noise_px, max_chroma, open_close, pair_blobs, soft_centroid, stereo_markers,
    stereo_markers_unrectified,
};
pub use ops::BLOB_COLUMNS;
pub use triangulate::{point_from_disparity, triangulate_disparity};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `stereo.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::Sgm>()?;
    registry.add::<ops::BlockMatch>()?;
    registry.add::<ops::FillDisparity>()?;
    registry.add::<ops::RefineSlanted>()?;
    registry.add::<ops::Triangulate>()?;
    registry.add::<ops::HsvMarkers>()?;
    registry.add::<ops::Features>()?;
    registry.add::<ops::MatchFeatures>()?;
    registry.add::<ops::DisparityRange>()?;
    Ok(())
}
