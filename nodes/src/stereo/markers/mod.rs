//! Coloured markers in a stereo pair: colour thresholds in HSV, blobs cleaned
//! by morphology and filtered by area and ellipse shape, sub-pixel centroids,
//! left-right pairs along the rectified rows, and their triangulation.

mod blobs;
mod figure;
mod hsv_markers;

pub use blobs::{MomentEllipse, components, dilate, ellipse_fit, erode, open_close, soft_centroid};
pub(crate) use figure::detections_png;
pub use hsv_markers::{
    Blob, BlobParams, GREY_CHROMA_LEVELS, MIN_PAIRS_FOR_NOISE, PairParams, StereoMarker,
    StereoMarkers, colour_mask, find_blobs, hsv, hue_score, localisation_noise_px, max_chroma,
    pair_blobs, stereo_markers, stereo_markers_unrectified,
};
