//! `eval.calibration`: a calibrated rig against the true cameras.

use crate::eval::compare_calibration;
use crate::eval::convert::load_truth;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, Rectification, StereoRig};

/// A calibrated rig (and rectification) against the phantom's true cameras
#[derive(Op)]
// 2: signed errors (fx .. cy in px, the baseline, the rotation about each axis).
// 3: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "eval.calibration", version = 3)]
pub struct EvalCalibration;

#[derive(Inputs)]
pub struct EvalCalibrationInputs {
    /// Estimated rig
    pub rig: Arc<StereoRig>,
    /// ground_truth.json
    pub truth: Arc<PathValue>,
    /// Estimated rectification (for epipolar_rms_px)
    pub rectification: Option<Arc<Rectification>>,
}

#[derive(Outputs)]
pub struct EvalCalibrationOutputs {
    /// Row error of true correspondences after rectification (NaN without one)
    pub epipolar_rms_px: f64,
}

impl RunOp for EvalCalibration {
    type Inputs = EvalCalibrationInputs;
    type Outputs = EvalCalibrationOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let rig = inputs.rig;
        let truth = load_truth(&inputs.truth)?;
        let rect = inputs
            .rectification
            .map(|r| crate::calib::rectification_of(&r));
        let (l, r) = (
            crate::camera::CameraModel::from_value(&rig.left),
            crate::camera::CameraModel::from_value(&rig.right),
        );
        let e = compare_calibration(
            &l,
            &r,
            &crate::calib::rig_isometry(&rig),
            rect.as_ref(),
            &truth,
        );
        for (name, (rel, px)) in [
            "left_fx", "left_fy", "left_cx", "left_cy", "right_fx", "right_fy", "right_cx",
            "right_cy",
        ]
        .iter()
        .zip(e.intrinsic_rel.iter().zip(e.intrinsic_error_px))
        {
            ctx.metric(&format!("{name}_rel_error"), *rel);
            ctx.metric(&format!("{name}_error_px"), px);
        }
        ctx.metric(
            "focal_rel_error_max",
            e.intrinsic_rel[0]
                .max(e.intrinsic_rel[1])
                .max(e.intrinsic_rel[4])
                .max(e.intrinsic_rel[5]),
        );
        ctx.metric(
            "centre_rel_error_max",
            e.intrinsic_rel[2]
                .max(e.intrinsic_rel[3])
                .max(e.intrinsic_rel[6])
                .max(e.intrinsic_rel[7]),
        );
        ctx.metric("left_distortion_max_px", e.distortion_max_px[0]);
        ctx.metric("right_distortion_max_px", e.distortion_max_px[1]);
        ctx.metric("baseline_error_mm", e.baseline_error_mm);
        ctx.metric("baseline_signed_error_mm", e.baseline_signed_error_mm);
        ctx.metric("rotation_error_deg", e.rotation_error_deg);
        for (axis, v) in ["x", "y", "z"].iter().zip(e.rotation_error_axes_deg) {
            ctx.metric(&format!("rotation_{axis}_error_deg"), v);
        }
        let epipolar = e.epipolar_rms_px.unwrap_or(f64::NAN);
        ctx.metric("epipolar_rms_px", epipolar);
        Ok(EvalCalibrationOutputs {
            epipolar_rms_px: epipolar,
        })
    }
}
