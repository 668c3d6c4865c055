//! `phantom.true_disparity`: the true disparity of a view as rectified with
//! an estimated rig.

use super::shape_error;
use crate::calib::rectification_of;
use crate::camera::CameraModel;
use crate::phantom::{ViewScene, load_truth, true_disparity};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Disparity, Image, PathValue, Pixels, Rectification, StereoRig};

/// True disparity of a view pair as rectified with an estimated rig
/// (calibration error included)
#[derive(Debug, Clone, PartialEq, Op)]
// 2: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "phantom.true_disparity", version = 2)]
pub struct TrueDisparity {
    /// Which view pair
    #[param(default = 0, min = 0)]
    pub view: usize,
}

/// The inputs of `phantom.true_disparity`.
#[derive(Inputs)]
pub struct TrueDisparityInputs {
    /// ground_truth.json of a phantom
    pub truth: Arc<PathValue>,
    /// The rig the images are rectified with (usually the estimated one)
    pub rig: Arc<StereoRig>,
    /// calib.rectify of that rig
    pub rectification: Arc<Rectification>,
}

/// The outputs of `phantom.true_disparity`.
#[derive(Outputs)]
pub struct TrueDisparityOutputs {
    /// x_left - x_right on the left rectified image, px; NaN where unknown
    /// (nothing hit, outside either image, hidden from the right camera)
    pub disparity: Disparity,
    /// Grey u8, left rectified: 255 where the pixel sees skin and the
    /// disparity is known
    pub mask: Image,
    /// Grey u8, left rectified: 0 nothing, 1 table, 2 skin, 3 marker side, 4
    /// marker face
    pub labels: Image,
}

impl RunOp for TrueDisparity {
    type Inputs = TrueDisparityInputs;
    type Outputs = TrueDisparityOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let truth = load_truth(&inputs.truth)?;
        let rig = inputs.rig;
        let rect = rectification_of(&inputs.rectification);
        let scene = ViewScene::from_truth(&truth, self.view).map_err(OpError::invalid)?;
        let (left, right) = (
            CameraModel::from_value(&rig.left),
            CameraModel::from_value(&rig.right),
        );
        let t = true_disparity(&scene, &left, &right, &rect).map_err(OpError::invalid)?;
        let total = (t.width * t.height) as f64;
        ctx.metric("known_pct", 100.0 * t.known as f64 / total);
        ctx.metric("skin_pct", 100.0 * t.skin as f64 / total);
        ctx.metric("row_error_px", t.row_error_px);
        ctx.metric("min_px", t.min_px);
        ctx.metric("max_px", t.max_px);
        let (w, h) = (t.width, t.height);
        let grey =
            |data: Vec<u8>| Image::new(w, h, 1, Pixels::U8(data.into())).map_err(shape_error);
        Ok(TrueDisparityOutputs {
            disparity: Disparity::new(w, h, t.disparity_px).map_err(shape_error)?,
            mask: grey(t.mask)?,
            labels: grey(t.labels)?,
        })
    }
}
