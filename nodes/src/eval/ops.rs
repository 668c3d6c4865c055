//! Node adapters: `eval.markers`, `eval.skin_distance`, `eval.surface`,
//! `eval.calibration` and `eval.disparity`.

use super::{
    bad_metric_name, compare_calibration, compare_markers, disparity_errors, frame_to_world,
    identify_markers, skin_distances, true_marker_centres,
};
use crate::camera::isometry_from_matrix;
use crate::phantom::truth_input;
use fusegraph_engine::value::{
    Disparity, Image, Markers, Mesh, PointCloud, Rectification, StereoRig,
};
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
                4,
                "Found marker centres against the phantom's true ones (no assumed order)",
            )
            .input(
                "markers",
                &[ValueType::Markers],
                "Found centres, mm (frame mri_lps, world or camera_left)",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json")
            .param(ParamSpec::choice(
                "reference",
                &["mri_gel", "world_gel", "world_face"],
                "Which true centres: gel cores in MRI LPS (markers in mri_lps), or gel cores / coloured faces (markers in world, or in camera_left: then only those visible in both images of `view`)",
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
            .param(
                ParamSpec::int(
                    "view",
                    0,
                    "",
                    "Which view's left camera, for markers in camera_left",
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
        let centres =
            true_marker_centres(&truth, &reference, &markers.frame, params.count("view")?)
                .map_err(|e| OpError::invalid(format!("markers: {e}")))?;
        let found: Vec<[f64; 3]> = markers
            .positions_mm
            .chunks(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let points: Vec<[f64; 3]> = centres.iter().map(|c| c.0).collect();
        let c = compare_markers(&found, &points, params.float("max_distance_mm")?);
        let missed = centres
            .iter()
            .enumerate()
            .filter(|(j, t)| t.1 && !c.pairs.iter().any(|p| p.1 == *j))
            .count();
        // Errors of the markers expected to be found, and apart from them
        // those of markers partly hidden from one camera but found anyway
        // (measured on a sliver of their face, they are not held to the same
        // standard, and not counted as spurious either).
        let (expected, partly_hidden): (Vec<_>, Vec<_>) =
            c.pairs.iter().partition(|p| centres[p.1].1);
        let stats = |pairs: &[&(usize, usize, f64)]| {
            let errors: Vec<f64> = pairs.iter().map(|p| p.2).collect();
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            (mean, errors.iter().copied().fold(f64::NAN, f64::max))
        };
        let (mean, max) = stats(&expected);
        ctx.metric("expected", centres.iter().filter(|c| c.1).count() as f64);
        ctx.metric("found", expected.len() as f64);
        ctx.metric("missed", missed as f64);
        ctx.metric("spurious", c.spurious as f64);
        ctx.metric("mean_error_mm", mean);
        ctx.metric("max_error_mm", max);
        ctx.metric("partly_hidden_found", partly_hidden.len() as f64);
        ctx.metric("partly_hidden_max_error_mm", stats(&partly_hidden).1);
        Ok(Outputs::new().with("found", c.pairs.len() as f64))
    }
}

pub(crate) struct EvalCorrespondencesOp(OpSpec);

impl EvalCorrespondencesOp {
    pub(crate) fn new() -> Self {
        EvalCorrespondencesOp(
            OpSpec::new(
                "eval.correspondences",
                1,
                "Whether matched marker pairs (e.g. camera -> MRI) are the same true markers",
            )
            .input(
                "source",
                &[ValueType::Markers],
                "Matched markers, in pair order (frame mri_lps, world or camera_left)",
            )
            .input(
                "target",
                &[ValueType::Markers],
                "Their partners, in the same order",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json")
            .param(ParamSpec::choice(
                "source_reference",
                &["world_face", "world_gel", "mri_gel"],
                "The true centres the source markers are measured at (faces for camera markers)",
            ))
            .param(ParamSpec::choice(
                "target_reference",
                &["mri_gel", "world_gel", "world_face"],
                "The true centres the target markers are measured at (gel cores for MRI markers)",
            ))
            .param(
                ParamSpec::float(
                    "max_distance_mm",
                    5.0,
                    "mm",
                    "Farther from every true marker is unknown",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::int(
                    "view",
                    0,
                    "",
                    "Which view's left camera, for markers in camera_left",
                )
                .at_least(0.0),
            )
            .output(
                "wrong",
                ValueType::Scalar,
                "Pairs of two different (or unknown) markers",
            ),
        )
    }
}

impl Op for EvalCorrespondencesOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let truth = truth_input(inputs)?;
        let view = params.count("view")?;
        let reach = params.float("max_distance_mm")?;
        let mut ids = Vec::new();
        for (port, reference) in [
            ("source", "source_reference"),
            ("target", "target_reference"),
        ] {
            let m = inputs.get::<Markers>(port)?;
            let centres = true_marker_centres(&truth, &params.string(reference)?, &m.frame, view)
                .map_err(|e| OpError::invalid(format!("{port}: {e}")))?;
            let points: Vec<[f64; 3]> = centres.iter().map(|c| c.0).collect();
            let found: Vec<[f64; 3]> = m
                .positions_mm
                .chunks(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect();
            ids.push(identify_markers(&found, &points, reach));
        }
        if ids[0].len() != ids[1].len() {
            return Err(OpError::invalid(format!(
                "{} source markers but {} targets: pairs must come in the same order",
                ids[0].len(),
                ids[1].len()
            )));
        }
        let right = ids[0]
            .iter()
            .zip(&ids[1])
            .filter(|(a, b)| a.is_some() && a == b)
            .count();
        let wrong = ids[0].len() - right;
        ctx.metric("pairs", ids[0].len() as f64);
        ctx.metric("right", right as f64);
        ctx.metric("wrong", wrong as f64);
        Ok(Outputs::new().with("wrong", wrong as f64))
    }
}

pub(crate) struct EvalSkinOp(OpSpec);

impl EvalSkinOp {
    pub(crate) fn new() -> Self {
        EvalSkinOp(
            OpSpec::new(
                "eval.skin_distance",
                3,
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

pub(crate) struct EvalSurfaceOp(OpSpec);

impl EvalSurfaceOp {
    pub(crate) fn new() -> Self {
        EvalSurfaceOp(
            OpSpec::new(
                "eval.surface",
                2,
                "Distances from a point cloud to the phantom's true skin (mean, 95th percentile, max)",
            )
            .input(
                "cloud",
                &[ValueType::PointCloud],
                "Surface points, mm (frame camera_left, world or mri_lps)",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json")
            .param(
                ParamSpec::int(
                    "view",
                    0,
                    "",
                    "Which view's left camera, for a cloud in camera_left",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "marker_margin_mm",
                    2.0,
                    "mm",
                    "Skip points this close to a marker or lesion",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "base_margin_mm",
                    1.0,
                    "mm",
                    "Skip points this close to the base (or below it)",
                )
                .at_least(0.0),
            )
            .output(
                "mean_mm",
                ValueType::Scalar,
                "Mean point-to-skin distance, mm",
            ),
        )
    }
}

impl Op for EvalSurfaceOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let cloud = inputs.get::<PointCloud>("cloud")?;
        let truth = truth_input(inputs)?;
        let to_world = frame_to_world(&truth, &cloud.frame, params.count("view")?)
            .map_err(|e| OpError::invalid(format!("cloud: {e}")))?;
        let to_phantom = isometry_from_matrix(&truth.phantom_to_world).inverse() * to_world;
        let points = cloud
            .points
            .chunks(3)
            .map(|c| [c[0] as f64, c[1] as f64, c[2] as f64]);
        let d = skin_distances(
            &truth.shape,
            &to_phantom,
            points,
            params.float("marker_margin_mm")?,
            params.float("base_margin_mm")?,
        )
        .ok_or_else(|| {
            OpError::invalid(format!(
                "cloud: none of its {} points lies on the skin (away from markers and the base)",
                cloud.len()
            ))
        })?;
        ctx.metric("mean_mm", d.mean_mm);
        ctx.metric("rms_mm", d.rms_mm);
        ctx.metric("p95_mm", d.p95_mm);
        ctx.metric("max_mm", d.max_mm);
        ctx.metric("used", d.used as f64);
        ctx.metric("points", cloud.len() as f64);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::frames::test_truth;
    use crate::phantom::GroundTruth;
    use fusegraph_engine::ParamValue;
    use fusegraph_engine::value::{PathValue, Value};
    use nalgebra::{Isometry3, Point3, Vector3};
    use std::path::PathBuf;

    /// The test truth written to a file of its own (tests run in parallel).
    fn truth_file(name: &str) -> (GroundTruth, PathBuf) {
        let truth = test_truth();
        let path =
            std::env::temp_dir().join(format!("fusegraph-eval-{}-{name}.json", std::process::id()));
        truth.save(&path).unwrap();
        (truth, path)
    }

    fn run(
        op: &dyn Op,
        truth: &std::path::Path,
        port: &str,
        value: Value,
        set: &[(&str, ParamValue)],
    ) -> Result<std::collections::BTreeMap<String, f64>, OpError> {
        let mut inputs = Inputs::default();
        inputs.0.insert(port.into(), value);
        let path = PathValue {
            path: truth.to_path_buf(),
            content_hash: String::new(),
        };
        inputs.0.insert("truth".into(), path.into());
        let mut params = Params::default();
        for p in &op.spec().params {
            params.0.insert(p.name.clone(), p.default.clone().unwrap());
        }
        for (k, v) in set {
            params.0.insert(k.to_string(), v.clone());
        }
        let mut ctx = RunCtx::new("eval", &std::env::temp_dir());
        op.run(&inputs, &params, &mut ctx)?;
        Ok(ctx.into_metrics())
    }

    /// Skin points of the truth well away from markers, lesions and the base,
    /// each moved a known distance along the skin normal, in world (mm); and
    /// those distances.
    fn offset_skin(truth: &GroundTruth) -> (Vec<Point3<f64>>, Vec<f64>) {
        let to_world = isometry_from_matrix(&truth.phantom_to_world);
        let shape = &truth.shape;
        let (mut points, mut offsets) = (Vec::new(), Vec::new());
        for x in &truth.skin_world_mm {
            let p = to_world.inverse() * Point3::from(*x);
            let clear = p.z > 6.0
                && shape
                    .markers
                    .iter()
                    .all(|m| (p - Point3::from(m.skin_point_mm)).norm() > m.radius_mm + 12.0)
                && shape
                    .lesions
                    .iter()
                    .all(|l| (p - Point3::from(l.center_mm)).norm() > l.radius_mm + 6.0);
            if !clear {
                continue;
            }
            let i = points.len();
            let delta = (0.2 + 0.2 * (i % 5) as f64) * if i % 2 == 0 { 1.0 } else { -1.0 };
            let normal = to_world.rotation * shape.skin_normal(&p);
            points.push(Point3::from(*x) + normal * delta);
            offsets.push(delta.abs());
        }
        (points, offsets)
    }

    fn cloud(points: &[Point3<f64>], to_frame: &Isometry3<f64>, frame: &str) -> Value {
        let flat: Vec<f32> = points
            .iter()
            .flat_map(|p| {
                (to_frame * p)
                    .coords
                    .iter()
                    .map(|&c| c as f32)
                    .collect::<Vec<_>>()
            })
            .collect();
        PointCloud::new(flat, None, None, frame).unwrap().into()
    }

    #[test]
    fn surface_distances_are_the_known_offsets_along_the_normal() {
        let (truth, file) = truth_file("surface");
        let (mut points, offsets) = offset_skin(&truth);
        assert!(offsets.len() > 100, "{}", offsets.len());
        let n = offsets.len() as f64;
        let mean = offsets.iter().sum::<f64>() / n;
        let rms = (offsets.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
        let mut sorted = offsets.clone();
        sorted.sort_by(f64::total_cmp);
        let p95 = sorted[(0.95 * (n - 1.0)).round() as usize];
        // Points on marker faces are not skin: skipped.
        points.extend(
            truth
                .markers
                .iter()
                .map(|m| Point3::from(m.face_center_world_mm)),
        );
        let world_to_camera = isometry_from_matrix(&truth.views[0].left_camera_to_world).inverse();
        let op = EvalSurfaceOp::new();
        for (to_frame, frame) in [
            (world_to_camera, "camera_left"),
            (Isometry3::identity(), "world"),
        ] {
            let m = run(&op, &file, "cloud", cloud(&points, &to_frame, frame), &[]).unwrap();
            assert_eq!(m["used"], n, "{frame}");
            assert_eq!(m["points"], n + truth.markers.len() as f64);
            for (name, expected) in [
                ("mean_mm", mean),
                ("rms_mm", rms),
                ("p95_mm", p95),
                ("max_mm", 1.0),
            ] {
                assert!(
                    (m[name] - expected).abs() < 1e-3,
                    "{frame} {name}: {} vs {expected}",
                    m[name]
                );
            }
        }
        // The camera cloud measured as if taken from a view it was not: a clear
        // error, not a number.
        let c = cloud(&points, &world_to_camera, "camera_left");
        let err = run(&op, &file, "cloud", c, &[("view", ParamValue::Int(4))]).unwrap_err();
        assert!(err.to_string().contains("view 4 does not exist"), "{err}");
        let c = cloud(&points, &world_to_camera, "camera_right");
        let err = run(&op, &file, "cloud", c, &[]).unwrap_err();
        assert!(err.to_string().contains("frame `camera_right`"), "{err}");
        let far = cloud(
            &[Point3::new(0.0, 0.0, -50.0)],
            &Isometry3::identity(),
            "world",
        );
        let err = run(&op, &file, "cloud", far, &[]).unwrap_err();
        assert!(err.to_string().contains("none of its 1 points"), "{err}");
        std::fs::remove_file(file).unwrap();
    }

    #[test]
    fn camera_markers_are_compared_in_the_view_camera() {
        let (truth, file) = truth_file("markers");
        let to_camera = isometry_from_matrix(&truth.views[0].left_camera_to_world).inverse();
        let shift = Vector3::new(0.3, 0.0, -0.4);
        // Faces of markers 1 and 2 (visible in both images) 0.5 mm off, and a
        // spurious one; marker 3 is missed; marker 0 is seen by the left camera
        // only, so it is not expected, but found 1.3 mm off it counts apart.
        let face = |i: usize| to_camera * Point3::from(truth.markers[i].face_center_world_mm);
        let found: Vec<f64> = [1usize, 2]
            .iter()
            .map(|&i| face(i) + shift)
            .chain([
                Point3::new(0.0, 0.0, 300.0),
                face(0) + Vector3::new(0.0, 1.2, -0.5),
            ])
            .flat_map(|p| p.coords.iter().copied().collect::<Vec<_>>())
            .collect();
        let markers = Markers::new(found, vec![7, 8, 9, 10], "camera_left").unwrap();
        let face = [("reference", ParamValue::String("world_face".into()))];
        let m = run(
            &EvalMarkersOp::new(),
            &file,
            "markers",
            markers.clone().into(),
            &face,
        )
        .unwrap();
        assert_eq!(
            (m["expected"], m["found"], m["missed"], m["spurious"]),
            (3.0, 2.0, 1.0, 1.0)
        );
        assert!((m["mean_error_mm"] - 0.5).abs() < 1e-9);
        assert!((m["max_error_mm"] - 0.5).abs() < 1e-9);
        assert_eq!(m["partly_hidden_found"], 1.0);
        assert!((m["partly_hidden_max_error_mm"] - 1.3).abs() < 1e-9);
        let err = run(&EvalMarkersOp::new(), &file, "markers", markers.into(), &[]).unwrap_err();
        assert!(
            err.to_string().contains("takes markers in mri_lps"),
            "{err}"
        );
        std::fs::remove_file(file).unwrap();
    }
}
