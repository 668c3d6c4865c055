//! `eval.skin_distance`: a mesh against the phantom's true skin.

use crate::camera::isometry_from_matrix;
use crate::eval::convert::load_truth;
use crate::eval::skin_distances;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Mesh, PathValue};

/// Distances from a surface's vertices to the phantom's true skin
#[derive(Op)]
// 5: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "eval.skin_distance", version = 5)]
pub struct EvalSkinDistance {
    /// Skip vertices this close to a marker
    #[param(default = 2.0, unit = "mm", min = 0.0)]
    pub marker_margin_mm: f64,
    /// Skip vertices this close to the base
    #[param(default = 1.0, unit = "mm", min = 0.0)]
    pub base_margin_mm: f64,
}

#[derive(Inputs)]
pub struct EvalSkinDistanceInputs {
    /// Surface (frame mri_lps or world)
    pub mesh: Arc<Mesh>,
    /// ground_truth.json
    pub truth: Arc<PathValue>,
}

#[derive(Outputs)]
pub struct EvalSkinDistanceOutputs {
    /// Mean vertex-to-skin distance, mm
    pub mean_mm: f64,
}

impl RunOp for EvalSkinDistance {
    type Inputs = EvalSkinDistanceInputs;
    type Outputs = EvalSkinDistanceOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let mesh = inputs.mesh;
        let truth = load_truth(&inputs.truth)?;
        let to_phantom = match mesh.frame.as_str() {
            "mri_lps" => isometry_from_matrix(&truth.phantom_to_mri).inverse(),
            "world" => isometry_from_matrix(&truth.phantom_to_world).inverse(),
            other => {
                return Err(OpError::invalid(format!(
                    "mesh frame `{other}`: expected mri_lps or world"
                )));
            }
        };
        let vertices = mesh
            .vertices
            .chunks(3)
            .map(|c| [c[0] as f64, c[1] as f64, c[2] as f64]);
        let motion = truth.motion_field();
        let moved = (mesh.frame == "world").then_some(&motion);
        let d = skin_distances(
            &truth.shape,
            moved,
            &to_phantom,
            vertices,
            self.marker_margin_mm,
            self.base_margin_mm,
        )
        .ok_or_else(|| OpError::invalid("no mesh vertex lies on the skin"))?;
        ctx.metric("mean_mm", d.mean_mm);
        ctx.metric("mean_signed_mm", d.mean_signed_mm);
        ctx.metric("median_signed_mm", d.median_signed_mm);
        ctx.metric("rms_mm", d.rms_mm);
        ctx.metric("p95_mm", d.p95_mm);
        ctx.metric("max_mm", d.max_mm);
        ctx.metric("vertices_used", d.used as f64);
        Ok(EvalSkinDistanceOutputs { mean_mm: d.mean_mm })
    }
}
