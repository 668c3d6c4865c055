//! `io.read_disparity`: a disparity map from PFM, or from 8/16-bit PGM or PNG
//! holding disparity times a scale.

use crate::io::{SourceDir, SourceFile, read_disparity};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Disparity;

/// Read a disparity map: PFM (inf = unknown), or 8/16-bit PGM or PNG divided by `scale`
#[derive(Op)]
#[op(name = "io.read_disparity", version = 1)]
pub struct ReadDisparity {
    /// Which file: `file` in the `dir` input, or `path`.
    #[param(flatten)]
    pub source: SourceFile,
    /// Stored value / scale = disparity in px (Middlebury 2003 disp2.pgm: 4; KITTI: 256)
    #[param(default = 1.0, min = 1e-9)]
    pub scale: f64,
    /// In PGM and PNG files, a stored 0 means no disparity (NaN)
    #[param(default = true)]
    pub zero_is_unknown: bool,
}

#[derive(Outputs)]
pub struct ReadDisparityOutputs {
    /// The disparity map, px
    pub disparity: Disparity,
}

impl RunOp for ReadDisparity {
    type Inputs = SourceDir;
    type Outputs = ReadDisparityOutputs;

    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        self.source.check(wired)
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let path = self.source.resolve(inputs.dir.as_deref())?;
        let d =
            read_disparity(&path, self.scale, self.zero_is_unknown).map_err(OpError::invalid)?;
        let known = d.data.iter().filter(|v| v.is_finite()).count();
        ctx.metric("known_pct", 100.0 * known as f64 / d.data.len() as f64);
        Ok(ReadDisparityOutputs { disparity: d })
    }
}
