//! `cloud.remove_colour`: the points of a colour and their surroundings.

use super::MarkerColour;
use crate::cloud::away_from_colour;
use crate::cloud::convert::cloud_points;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PointCloud;

/// Removes the points of a colour (markers' faces) and every point within a radius of them (their walls)
#[derive(Op)]
#[op(name = "cloud.remove_colour", version = 1)]
pub struct RemoveColour {
    /// The markers' colour
    #[param(flatten)]
    pub colour: MarkerColour,
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
        let colour = self.colour.blob_params();
        let keep = away_from_colour(&cloud_points(&c), colors, &colour, self.radius_mm);
        let kept = keep.iter().filter(|k| **k).count();
        ctx.metric("removed", (keep.len() - kept) as f64);
        ctx.metric("points", kept as f64);
        Ok(RemoveColourOutputs {
            cloud: c.select(&keep).map_err(|e| OpError::invalid(e.0))?,
        })
    }
}
