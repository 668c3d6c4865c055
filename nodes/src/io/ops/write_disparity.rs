//! `io.write_disparity`: a disparity map as a colour-mapped PNG with a legend
//! in px, and as PFM.

use crate::io::{disparity_png, encode_pfm, finite_percentiles};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Disparity, PathValue};

/// Write a disparity map as a colour-mapped PNG with a legend in px, and as PFM
#[derive(Op)]
#[op(name = "io.write_disparity", version = 1, writes_output)]
pub struct WriteDisparity {
    /// File stem, relative to the output folder: STEM.png and STEM.pfm
    #[param(default = "disparity")]
    pub file: String,
    /// Disparity at the low end of the colour map (when max_px <= min_px, as by default: the 1st percentile)
    #[param(default = 0.0, unit = "px")]
    pub min_px: f64,
    /// Disparity at the high end (when max_px <= min_px: the 99th percentile)
    #[param(default = 0.0, unit = "px")]
    pub max_px: f64,
}

#[derive(Inputs)]
pub struct WriteDisparityInputs {
    /// The disparity map, px
    pub disparity: Arc<Disparity>,
}

#[derive(Outputs)]
pub struct WriteDisparityOutputs {
    /// The colour-mapped PNG (unknown = black)
    pub png: PathValue,
    /// The PFM (little endian, unknown = inf)
    pub pfm: PathValue,
}

impl RunOp for WriteDisparity {
    type Inputs = WriteDisparityInputs;
    type Outputs = WriteDisparityOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (d, stem) = (inputs.disparity, &self.file);
        let (lo, hi) = (self.min_px, self.max_px);
        let range = if hi > lo {
            (lo, hi)
        } else {
            let (a, b) = finite_percentiles(&d.data, 1.0, 99.0).unwrap_or((0.0, 1.0));
            if b > a { (a, b) } else { (a - 0.5, a + 0.5) }
        };
        let (rgb, w, h) = disparity_png(&d, range).map_err(OpError::invalid)?;
        let png = ctx.output_path(&format!("{stem}.png"))?;
        image::save_buffer(
            &png,
            &rgb,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| OpError::invalid(format!("{}: {e}", png.display())))?;
        let pfm = ctx.output_path(&format!("{stem}.pfm"))?;
        std::fs::write(&pfm, encode_pfm(d.width, d.height, &d.data))
            .map_err(|e| OpError::io(&pfm, e))?;
        ctx.metric("min_px", range.0);
        ctx.metric("max_px", range.1);
        Ok(WriteDisparityOutputs {
            png: path_value(&png)?,
            pfm: path_value(&pfm)?,
        })
    }
}
