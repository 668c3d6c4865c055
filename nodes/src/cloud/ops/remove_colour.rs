//! `cloud.remove_colour`: the points of a colour and their surroundings.

use crate::cloud::away_from_colour;
use crate::cloud::convert::cloud_points;
use crate::stereo::BlobParams;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PointCloud;

/// Removes the points of a colour (markers' faces) and every point within a radius of them (their walls)
#[derive(Op)]
#[op(name = "cloud.remove_colour", version = 1)]
pub struct RemoveColour {
    /// Hue range [min, max]; min > max wraps through 0 (default: the markers' green, as stereo.hsv_markers)
    #[param(
        default = [BlobParams::default().hue_deg.0, BlobParams::default().hue_deg.1],
        unit = "deg",
        min = 0.0,
        max = 360.0
    )]
    pub hue_deg: [f64; 2],
    /// Smallest saturation (0..1)
    #[param(default = BlobParams::default().min_saturation, min = 0.0, max = 1.0)]
    pub min_saturation: f64,
    /// Smallest value (0..1)
    #[param(default = BlobParams::default().min_value, min = 0.0, max = 1.0)]
    pub min_value: f64,
    /// Points this close to a coloured one go too (a marker's 5 mm wall)
    #[param(default = 6.0, unit = "mm", min = 0.0)]
    pub radius_mm: f64,
}

#[derive(Inputs)]
pub struct RemoveColourInputs {
    /// A cloud with colours
    pub cloud: Arc<PointCloud>,
}

#[derive(Outputs)]
pub struct RemoveColourOutputs {
    /// The cloud without them
    pub cloud: PointCloud,
}

impl RunOp for RemoveColour {
    type Inputs = RemoveColourInputs;
    type Outputs = RemoveColourOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let c = inputs.cloud;
        let Some(colors) = &c.colors else {
            return Err(OpError::invalid("the cloud has no colours to select by"));
        };
        let colour = BlobParams {
            hue_deg: (self.hue_deg[0], self.hue_deg[1]),
            min_saturation: self.min_saturation,
            min_value: self.min_value,
            ..Default::default()
        };
        let keep = away_from_colour(&cloud_points(&c), colors, &colour, self.radius_mm);
        let kept = keep.iter().filter(|k| **k).count();
        ctx.metric("removed", (keep.len() - kept) as f64);
        ctx.metric("points", kept as f64);
        Ok(RemoveColourOutputs {
            cloud: c.select(&keep).map_err(|e| OpError::invalid(e.0))?,
        })
    }
}
