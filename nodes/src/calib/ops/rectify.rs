//! `calib.rectify`: Bouguet rectification of a calibrated rig.

use crate::calib::conversions::{rectification_value, rig_isometry};
use crate::calib::rectify;
use crate::camera::CameraModel;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Rectification, StereoRig};

/// Bouguet rectification (R1, R2, P1, P2, Q) of a stereo rig
#[derive(Op)]
#[op(name = "calib.rectify", version = 1)]
pub struct Rectify {
    /// 0: only valid pixels; 1: every source pixel
    #[param(default = 0.0, min = 0.0, max = 1.0)]
    pub alpha: f64,
}

#[derive(Inputs)]
pub struct RectifyInputs {
    /// The rig
    pub rig: Arc<StereoRig>,
}

#[derive(Debug, Outputs)]
pub struct RectifyOutputs {
    /// Rotations and projections (px; P2 translation f Tx)
    pub rectification: Rectification,
}

impl RunOp for Rectify {
    type Inputs = RectifyInputs;
    type Outputs = RectifyOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let rig = inputs.rig;
        let (l, r) = (
            CameraModel::from_value(&rig.left),
            CameraModel::from_value(&rig.right),
        );
        let rect = rectify(&l, &r, &rig_isometry(&rig), self.alpha);
        ctx.metric("focal_px", rect.p1[(0, 0)]);
        ctx.metric("baseline_mm", -rect.p2[(0, 3)] / rect.p2[(0, 0)]);
        Ok(RectifyOutputs {
            rectification: rectification_value(&rect),
        })
    }
}
