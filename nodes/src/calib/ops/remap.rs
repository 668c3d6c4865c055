//! `calib.remap`: one image of a pair undistorted and rectified.

use crate::calib::conversions::rectification_of;
use crate::calib::remap;
use crate::camera::CameraModel;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Image, Pixels, Rectification, StereoRig};

/// Undistort and rectify one image of a pair (bilinear)
#[derive(Op)]
#[op(name = "calib.remap", version = 1)]
pub struct Remap {
    /// Which camera took the image
    #[param(default = RemapSide::Left)]
    pub side: RemapSide,
}

/// The camera of the rig that took an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum RemapSide {
    /// The left camera (R1, P1).
    Left,
    /// The right camera (R2, P2).
    Right,
}

#[derive(Inputs)]
pub struct RemapInputs {
    /// Image from the `side` camera
    pub image: Arc<Image>,
    /// The rig
    pub rig: Arc<StereoRig>,
    /// calib.rectify's output
    pub rectification: Arc<Rectification>,
}

#[derive(Debug, Outputs)]
pub struct RemapOutputs {
    /// Rectified image
    pub image: Image,
}

impl RunOp for Remap {
    type Inputs = RemapInputs;
    type Outputs = RemapOutputs;

    fn run(&self, inputs: Self::Inputs, _: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (img, rig) = (inputs.image, inputs.rig);
        let rect = rectification_of(&inputs.rectification);
        let (camera, r, p) = match self.side {
            RemapSide::Left => (&rig.left, &rect.r1, &rect.p1),
            RemapSide::Right => (&rig.right, &rect.r2, &rect.p2),
        };
        let camera = CameraModel::from_value(camera);
        if (img.width, img.height) != (camera.width, camera.height) {
            return Err(OpError::invalid(format!(
                "image is {} x {} px but the camera is {} x {}",
                img.width, img.height, camera.width, camera.height
            )));
        }
        let Pixels::U8(src) = &img.pixels else {
            return Err(OpError::invalid("calib.remap takes 8-bit images"));
        };
        let out = remap(src, img.channels, &camera, r, p, rect.size);
        let image = Image::new(
            rect.size.0,
            rect.size.1,
            img.channels,
            Pixels::U8(out.into()),
        )
        .map_err(|e| OpError::invalid(e.0))?;
        Ok(RemapOutputs { image })
    }
}
