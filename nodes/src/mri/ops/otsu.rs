//! `mri.otsu`: Otsu's threshold over a whole volume.

use super::shape_error;
use crate::mri::otsu_threshold;
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Mask, Volume};

/// Otsu's threshold over the whole volume -> foreground mask
#[derive(Op)]
#[op(name = "mri.otsu", version = 2)]
pub struct Otsu {
    /// Histogram bins
    #[param(default = 256, min = 2, max = 65536)]
    pub bins: usize,
}

#[derive(Inputs)]
pub struct OtsuInputs {
    /// Volume
    pub volume: Arc<Volume>,
}

#[derive(Outputs)]
pub struct OtsuOutputs {
    /// 1 where the value is above the threshold
    pub mask: Mask,
    /// The threshold, in the volume's units
    pub threshold: f64,
}

impl RunOp for Otsu {
    type Inputs = OtsuInputs;
    type Outputs = OtsuOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let v = inputs.volume;
        let t = otsu_threshold(&v.data, self.bins).ok_or_else(|| {
            OpError::invalid("the volume is flat: no threshold separates anything")
        })?;
        let mask: Vec<u8> = v.data.iter().map(|&x| (x > t) as u8).collect();
        let fraction = mask.iter().filter(|&&m| m == 1).count() as f64 / mask.len() as f64;
        ctx.metric("threshold", t as f64);
        ctx.metric("foreground_fraction", fraction);
        // The middle slice for the report, foreground tinted.
        let dims = v.grid.dims;
        let rgb = crate::plot::mask_over_slice(&v.data, &mask, dims, dims[2] / 2);
        if let Ok(png) = crate::plot::png_bytes(&rgb, dims[0], dims[1]) {
            ctx.figure(
                "mask",
                &format!(
                    "Otsu foreground (red) over the middle slice {} of {}",
                    dims[2] / 2,
                    dims[2]
                ),
                FigureData::Png(png),
            )?;
        }
        Ok(OtsuOutputs {
            mask: Mask::new(v.grid.clone(), mask).map_err(shape_error)?,
            threshold: t as f64,
        })
    }
}
