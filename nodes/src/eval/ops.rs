//! Node adapters: `eval.markers` and `eval.skin_distance`.

use super::{
    bad_metric_name, compare_calibration, compare_markers, disparity_errors, skin_distances,
};
use crate::camera::isometry_from_matrix;
use crate::phantom::truth_input;
use fusegraph_engine::value::{Disparity, Image, Markers, Mesh, Rectification, StereoRig};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};
use std::sync::Arc;

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
        let truth = truth_input(inputs)?;
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
        let truth = truth_input(inputs)?;
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

pub(crate) struct EvalCalibrationOp(OpSpec);

impl EvalCalibrationOp {
    pub(crate) fn new() -> Self {
        EvalCalibrationOp(
            OpSpec::new(
                "eval.calibration",
                1,
                "A calibrated rig (and rectification) against the phantom's true cameras",
            )
            .input("rig", &[ValueType::StereoRig], "Estimated rig")
            .input("truth", &[ValueType::Path], "ground_truth.json")
            .optional_input(
                "rectification",
                &[ValueType::Rectification],
                "Estimated rectification (for epipolar_rms_px)",
            )
            .output(
                "epipolar_rms_px",
                ValueType::Scalar,
                "Row error of true correspondences after rectification (NaN without one)",
            ),
        )
    }
}

impl Op for EvalCalibrationOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, _: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let rig = inputs.get::<StereoRig>("rig")?;
        let truth = truth_input(inputs)?;
        let rect: Option<Arc<Rectification>> = inputs.optional("rectification")?;
        let rect = rect.map(|r| crate::calib::rectification_of(&r));
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
        for (name, v) in [
            "left_fx", "left_fy", "left_cx", "left_cy", "right_fx", "right_fy", "right_cx",
            "right_cy",
        ]
        .iter()
        .zip(e.intrinsic_rel)
        {
            ctx.metric(&format!("{name}_rel_error"), v);
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
        ctx.metric("rotation_error_deg", e.rotation_error_deg);
        let epipolar = e.epipolar_rms_px.unwrap_or(f64::NAN);
        ctx.metric("epipolar_rms_px", epipolar);
        Ok(Outputs::new().with("epipolar_rms_px", epipolar))
    }
}

pub(crate) struct EvalDisparityOp(OpSpec);

impl EvalDisparityOp {
    pub(crate) fn new() -> Self {
        EvalDisparityOp(
            OpSpec::new(
                "eval.disparity",
                1,
                "A disparity map against the true one: bad-N % (invalid counted bad), MAE, RMSE, coverage",
            )
            .input("disparity", &[ValueType::Disparity], "Estimated disparity, px")
            .input("truth", &[ValueType::Disparity], "True disparity, px (0, NaN or inf = unknown)")
            .optional_input(
                "mask",
                &[ValueType::Image],
                "Where to evaluate (nonzero pixels), same size",
            )
            .param(
                ParamSpec::float_list(
                    "thresholds_px",
                    &[0.5, 1.0, 2.0, 4.0],
                    "px",
                    "Error thresholds of the bad_N_pct metrics",
                )
                .at_least(0.0),
            )
            .output(
                "bad_2_pct",
                ValueType::Scalar,
                "Evaluated pixels off by more than 2 px or without an estimate, %",
            ),
        )
    }
}

impl Op for EvalDisparityOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let est = inputs.get::<Disparity>("disparity")?;
        let truth = inputs.get::<Disparity>("truth")?;
        if (est.width, est.height) != (truth.width, truth.height) {
            return Err(OpError::invalid(format!(
                "input `disparity` is {} x {} px but `truth` is {} x {} px",
                est.width, est.height, truth.width, truth.height
            )));
        }
        let mask: Option<Arc<Image>> = inputs.optional("mask")?;
        let mask = match mask {
            None => None,
            Some(m) if (m.width, m.height) != (truth.width, truth.height) => {
                return Err(OpError::invalid(format!(
                    "input `mask` is {} x {} px but `truth` is {} x {} px",
                    m.width, m.height, truth.width, truth.height
                )));
            }
            Some(m) => Some(
                crate::io::grey_of(&m)
                    .iter()
                    .map(|&v| v > 0.0)
                    .collect::<Vec<bool>>(),
            ),
        };
        let mut thresholds = params.float_list("thresholds_px")?;
        if !thresholds.contains(&2.0) {
            thresholds.push(2.0);
        }
        let e = disparity_errors(&est.data, &truth.data, mask.as_deref(), &thresholds)
            .map_err(OpError::invalid)?;
        if e.evaluated == 0 {
            return Err(OpError::invalid(
                "no pixel to evaluate: the truth is unknown everywhere (or the mask is empty)",
            ));
        }
        for (&t, &pct) in thresholds.iter().zip(&e.bad_pct) {
            ctx.metric(&bad_metric_name(t), pct);
        }
        ctx.metric("mae_px", e.mae_px);
        ctx.metric("rmse_px", e.rmse_px);
        ctx.metric("coverage_pct", e.coverage_pct);
        ctx.metric("evaluated", e.evaluated as f64);
        let bad2 = thresholds
            .iter()
            .position(|&t| t == 2.0)
            .map_or(f64::NAN, |k| e.bad_pct[k]);
        Ok(Outputs::new().with("bad_2_pct", bad2))
    }
}
