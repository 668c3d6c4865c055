//! `register.evaluate`: registration quality, with and without the truth.

use crate::cloud::convert::cloud_points;
use crate::eval::convert::load_truth;
use crate::eval::{overlap_errors, registration_errors, true_mri_to_camera};
use crate::register::convert::transform_isometry;
use crate::register::figures::fused_view;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue, PointCloud, Transform};

/// Registration quality: RMSE over the overlap, and with the truth, TRE at the lesions; a 3D view of the fused clouds for the report
#[derive(Op)]
// 3: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "register.evaluate", version = 3)]
pub struct Evaluate {
    /// Source points farther than this from the target are not overlap
    #[param(default = 10.0, unit = "mm", min = 0.0)]
    pub overlap_mm: f64,
    /// Pairs closer than this are inliers
    #[param(default = 2.0, unit = "mm", min = 0.0)]
    pub inlier_mm: f64,
    /// Phantom view whose left camera is camera_left
    #[param(default = 0, min = 0)]
    pub view: usize,
}

#[derive(Inputs)]
pub struct EvaluateInputs {
    /// Source -> target
    pub transform: Arc<Transform>,
    /// Source cloud
    pub source: Arc<PointCloud>,
    /// Target cloud
    pub target: Arc<PointCloud>,
    /// ground_truth.json (frames mri_lps and camera_left of `view`)
    pub truth: Option<Arc<PathValue>>,
    /// Targets to mark in the 3D view (in the source's or the target's frame)
    pub targets: Option<Arc<Markers>>,
}

#[derive(Outputs)]
pub struct EvaluateOutputs {
    /// RMSE of the inliers, mm
    pub rmse_mm: f64,
}

impl RunOp for Evaluate {
    type Inputs = EvaluateInputs;
    type Outputs = EvaluateOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (t, s, g) = (inputs.transform, inputs.source, inputs.target);
        let iso = transform_isometry(&t);
        let overlap = overlap_errors(
            &cloud_points(&s),
            &cloud_points(&g),
            &iso,
            self.overlap_mm,
            self.inlier_mm,
        )
        .ok_or_else(|| OpError::invalid("the target cloud is empty"))?;
        fused_view(ctx, &s, &g, &iso, inputs.targets.as_deref())?;
        ctx.metric("rmse_all_mm", overlap.rmse_all_mm);
        ctx.metric("rmse_mm", overlap.rmse_mm);
        ctx.metric("inlier_fraction", overlap.inlier_fraction);
        if let Some(file) = inputs.truth {
            let truth = load_truth(&file)?;
            let true_mc = true_mri_to_camera(&truth, self.view).map_err(OpError::invalid)?;
            let est_mc = match (t.from.as_str(), t.to.as_str()) {
                ("mri_lps", "camera_left") => iso,
                ("camera_left", "mri_lps") => iso.inverse(),
                (a, b) => {
                    return Err(OpError::invalid(format!(
                        "transform maps `{a}` -> `{b}`; the truth knows mri_lps <-> camera_left"
                    )));
                }
            };
            // Errors where the robot acts: positions in camera space.
            let e = registration_errors(&truth, &true_mc, &est_mc);
            ctx.metric("tre_mm", e.tre_mm);
            ctx.metric("tre_max_mm", e.tre_max_mm);
            ctx.metric("rotation_error_deg", e.rotation_error_deg);
            ctx.metric("translation_error_mm", e.translation_error_mm);
        }
        Ok(EvaluateOutputs {
            rmse_mm: overlap.rmse_mm,
        })
    }
}
