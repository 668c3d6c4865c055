//! Node adapters: `eval.markers` and `eval.skin_distance`.

use super::{compare_markers, skin_distances};
use crate::camera::isometry_from_matrix;
use crate::phantom::GroundTruth;
use fusegraph_engine::value::{Markers, Mesh, PathValue};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};
use std::sync::Arc;

fn truth(inputs: &Inputs) -> Result<GroundTruth, OpError> {
    let file: Arc<PathValue> = inputs.get("truth")?;
    GroundTruth::load(&file.path).map_err(OpError::invalid)
}

pub(crate) struct EvalMarkersOp(OpSpec);

impl EvalMarkersOp {
    pub(crate) fn new() -> Self {
        EvalMarkersOp(
            OpSpec::new(
                "eval.markers",
                1,
                "Found marker centres against the phantom's true ones (no assumed order)",
            )
            .input("markers", &[ValueType::Markers], "Found centres")
            .input("truth", &[ValueType::Path], "ground_truth.json")
            .param(ParamSpec::choice(
                "reference",
                &["mri_gel", "world_gel", "world_face"],
                "Which true centres: gel cores in MRI LPS, or gel cores / coloured faces in world",
            ))
            .param(
                ParamSpec::float(
                    "max_distance_mm",
                    5.0,
                    "mm",
                    "Farther than this is no match",
                )
                .at_least(0.0),
            )
            .output("found", ValueType::Scalar, "Number of matched markers"),
        )
    }
}

impl Op for EvalMarkersOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let markers = inputs.get::<Markers>("markers")?;
        let truth = truth(inputs)?;
        let reference = params.string("reference")?;
        let (expected_frame, centres): (&str, Vec<[f64; 3]>) = match reference.as_str() {
            "mri_gel" => (
                "mri_lps",
                truth.markers.iter().map(|m| m.center_mri_mm).collect(),
            ),
            "world_gel" => (
                "world",
                truth.markers.iter().map(|m| m.center_world_mm).collect(),
            ),
            _ => (
                "world",
                truth
                    .markers
                    .iter()
                    .map(|m| m.face_center_world_mm)
                    .collect(),
            ),
        };
        if markers.frame != expected_frame {
            return Err(OpError::invalid(format!(
                "markers are in frame `{}`, but reference `{reference}` is in `{expected_frame}`",
                markers.frame
            )));
        }
        let found: Vec<[f64; 3]> = markers
            .positions_mm
            .chunks(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let c = compare_markers(&found, &centres, params.float("max_distance_mm")?);
        ctx.metric("found", c.pairs.len() as f64);
        ctx.metric("missed", c.missed as f64);
        ctx.metric("spurious", c.spurious as f64);
        ctx.metric("mean_error_mm", c.mean_error_mm());
        ctx.metric("max_error_mm", c.max_error_mm());
        Ok(Outputs::new().with("found", c.pairs.len() as f64))
    }
}

pub(crate) struct EvalSkinOp(OpSpec);

impl EvalSkinOp {
    pub(crate) fn new() -> Self {
        EvalSkinOp(
            OpSpec::new(
                "eval.skin_distance",
                2,
                "Distances from a surface's vertices to the phantom's true skin",
            )
            .input(
                "mesh",
                &[ValueType::Mesh],
                "Surface (frame mri_lps or world)",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json")
            .param(
                ParamSpec::float(
                    "marker_margin_mm",
                    2.0,
                    "mm",
                    "Skip vertices this close to a marker",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "base_margin_mm",
                    1.0,
                    "mm",
                    "Skip vertices this close to the base",
                )
                .at_least(0.0),
            )
            .output(
                "mean_mm",
                ValueType::Scalar,
                "Mean vertex-to-skin distance, mm",
            ),
        )
    }
}

impl Op for EvalSkinOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let mesh = inputs.get::<Mesh>("mesh")?;
        let truth = truth(inputs)?;
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
        let d = skin_distances(
            &truth.shape,
            &to_phantom,
            vertices,
            params.float("marker_margin_mm")?,
            params.float("base_margin_mm")?,
        )
        .ok_or_else(|| OpError::invalid("no mesh vertex lies on the skin"))?;
        ctx.metric("mean_mm", d.mean_mm);
        ctx.metric("rms_mm", d.rms_mm);
        ctx.metric("p95_mm", d.p95_mm);
        ctx.metric("max_mm", d.max_mm);
        ctx.metric("vertices_used", d.used as f64);
        Ok(Outputs::new().with("mean_mm", d.mean_mm))
    }
}
