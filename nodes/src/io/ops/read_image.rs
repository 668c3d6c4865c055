//! `io.read_image`: an image file (PNG or JPEG) as 8-bit RGB.

use crate::io::{ImageSizeLimit, SourceDir, SourceFile, load_image_within};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Image;

/// Read an image file (PNG or JPEG) as 8-bit RGB
#[derive(Op)]
#[op(name = "io.read_image", version = 3)]
pub struct ReadImage {
    /// Which file: `file` in the `dir` input, or `path`.
    #[param(flatten)]
    pub source: SourceFile,
    /// The largest image decoded.
    #[param(flatten)]
    pub limit: ImageSizeLimit,
}

#[derive(Outputs)]
pub struct ReadImageOutputs {
    /// The image
    pub image: Image,
}

impl RunOp for ReadImage {
    type Inputs = SourceDir;
    type Outputs = ReadImageOutputs;

    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        self.source.check(wired)
    }

    fn run(&self, inputs: Self::Inputs, _: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let path = self.source.resolve(inputs.dir.as_deref())?;
        Ok(ReadImageOutputs {
            image: load_image_within(&path, self.limit.max_pixels())?,
        })
    }
}
