//! `register.map_targets`: MRI targets into camera space.

use crate::eval::convert::load_truth;
use crate::eval::{target_errors, true_mri_to_camera};
use crate::register::convert::{marker_points, markers_value};
use crate::register::map_targets;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue, Transform};

/// Targets marked in MRI (lesions) mapped into camera (robot) space with a registration
#[derive(Op)]
#[op(name = "register.map_targets", version = 1)]
pub struct MapTargets {
    /// Phantom view whose left camera is camera_left
    #[param(default = 0, min = 0)]
    pub view: usize,
}

#[derive(Inputs)]
pub struct MapTargetsInputs {
    /// Targets, mm, in one frame of the transform (e.g. mri_lps)
    pub targets: Arc<Markers>,
    /// The registration, either way between the targets' frame and the camera's
    pub transform: Arc<Transform>,
    /// ground_truth.json: the targets' true camera positions (targets in mri_lps, camera_left of `view`)
    pub truth: Option<Arc<PathValue>>,
}

#[derive(Outputs)]
pub struct MapTargetsOutputs {
    /// The targets in the transform's other frame (camera_left), same ids
    pub targets: Markers,
}

impl RunOp for MapTargets {
    type Inputs = MapTargetsInputs;
    type Outputs = MapTargetsOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (targets, transform) = (inputs.targets, inputs.transform);
        let points = marker_points(&targets);
        let (mapped, frame) =
            map_targets(&points, &targets.frame, &transform).map_err(OpError::invalid)?;
        ctx.metric("targets", mapped.len() as f64);
        if let Some(file) = inputs.truth {
            let truth = load_truth(&file)?;
            if targets.frame != "mri_lps" || frame != "camera_left" {
                return Err(OpError::invalid(format!(
                    "with a truth, targets map mri_lps -> camera_left, not `{}` -> `{frame}`",
                    targets.frame
                )));
            }
            let true_mc = true_mri_to_camera(&truth, self.view).map_err(OpError::invalid)?;
            let (mean, max) = target_errors(&true_mc, &points, &mapped);
            ctx.metric("target_error_mm", mean);
            ctx.metric("target_error_max_mm", max);
        }
        Ok(MapTargetsOutputs {
            targets: markers_value(&mapped, targets.ids.to_vec(), &frame)?,
        })
    }
}
