//! `mri.bright_stretch`: percentile contrast stretch.

use super::shape_error;
use crate::mri::{percentiles, stretch};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Volume;

/// Percentile contrast stretch to [0, 1] (imadjust(V, stretchlim(V)))
#[derive(Op)]
#[op(name = "mri.bright_stretch", version = 1)]
pub struct BrightStretch {
    /// Percentile mapped to 0
    #[param(default = 1.0, unit = "%", min = 0.0, max = 100.0)]
    pub low_percentile: f64,
    /// Percentile mapped to 1
    #[param(default = 99.0, unit = "%", min = 0.0, max = 100.0)]
    pub high_percentile: f64,
}

#[derive(Inputs)]
pub struct BrightStretchInputs {
    /// MR volume
    pub volume: Arc<Volume>,
}

#[derive(Outputs)]
pub struct BrightStretchOutputs {
    /// Stretched volume, values in [0, 1]
    pub volume: Volume,
}

impl RunOp for BrightStretch {
    type Inputs = BrightStretchInputs;
    type Outputs = BrightStretchOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let v = inputs.volume;
        let (low, high) = (self.low_percentile, self.high_percentile);
        if low >= high {
            return Err(OpError::invalid(format!(
                "low_percentile {low} must be below high_percentile {high}"
            )));
        }
        let (lo, hi) = percentiles(&v.data, low, high)
            .ok_or_else(|| OpError::invalid("the volume has no numbers"))?;
        if hi <= lo {
            return Err(OpError::invalid(format!(
                "the volume is flat between the {low} and {high} percentiles (both {lo}); nothing to stretch"
            )));
        }
        ctx.metric("low_value", lo as f64);
        ctx.metric("high_value", hi as f64);
        let volume = Volume::new(v.grid.clone(), stretch(&v.data, lo, hi)).map_err(shape_error)?;
        Ok(BrightStretchOutputs { volume })
    }
}
