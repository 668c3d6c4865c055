//! The markers' colour as the `cloud.*` ops that tell marker points from skin
//! points take it: a group of parameters flattened into each.

use crate::stereo::BlobParams;
use fusegraph_engine::typed::prelude::*;

/// HSV thresholds of the markers' colour (defaults: the phantom's green, as
/// `stereo.hsv_markers` finds it).
#[derive(Debug, Clone, PartialEq, Params)]
pub struct MarkerColour {
    /// Hue range [min, max] of the markers' colour; min > max wraps through 0 (default: the markers' green, as stereo.hsv_markers)
    #[param(
        default = [BlobParams::default().hue_deg.0, BlobParams::default().hue_deg.1],
        unit = "deg",
        min = 0.0,
        max = 360.0
    )]
    pub hue_deg: [f64; 2],
    /// Smallest saturation of the markers' colour (0..1)
    #[param(default = BlobParams::default().min_saturation, min = 0.0, max = 1.0)]
    pub min_saturation: f64,
    /// Smallest value (brightness) of the markers' colour (0..1)
    #[param(default = BlobParams::default().min_value, min = 0.0, max = 1.0)]
    pub min_value: f64,
}

impl MarkerColour {
    /// The colour test of [`crate::stereo::colour_mask`].
    pub fn blob_params(&self) -> BlobParams {
        BlobParams {
            hue_deg: (self.hue_deg[0], self.hue_deg[1]),
            min_saturation: self.min_saturation,
            min_value: self.min_value,
            ..Default::default()
        }
    }
}
