//! `io.write_stereo_pair`: a rectified pair side by side as PNG, with
//! horizontal lines to check rectification by eye.

use crate::io::side_by_side;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Image, PathValue};

/// Write two images side by side as PNG, with horizontal lines
#[derive(Op)]
#[op(name = "io.write_stereo_pair", version = 1, writes_output)]
pub struct WriteStereoPair {
    /// Line spacing (0 = none)
    #[param(default = 40, unit = "px", min = 0)]
    pub lines_every_px: usize,
    /// PNG file, relative to the output folder
    #[param(default = "pair.png")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteStereoPairInputs {
    /// Left image
    pub left: Arc<Image>,
    /// Right image
    pub right: Arc<Image>,
}

#[derive(Outputs)]
pub struct WriteStereoPairOutputs {
    /// The PNG
    pub file: PathValue,
}

impl RunOp for WriteStereoPair {
    type Inputs = WriteStereoPairInputs;
    type Outputs = WriteStereoPairOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (rgb, w, h) = side_by_side(&inputs.left, &inputs.right, self.lines_every_px)
            .map_err(OpError::invalid)?;
        let path = ctx.output_path(&self.file)?;
        image::save_buffer(
            &path,
            &rgb,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| OpError::invalid(format!("{}: {e}", path.display())))?;
        Ok(WriteStereoPairOutputs {
            file: path_value(&path)?,
        })
    }
}
