//! `eval.surface`: a point cloud against the phantom's true skin.

use crate::camera::isometry_from_matrix;
use crate::eval::convert::load_truth;
use crate::eval::{frame_to_world, skin_distances};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, PointCloud};

/// Distances from a point cloud to the phantom's true skin (mean, 95th percentile, max)
#[derive(Op)]
// 4: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "eval.surface", version = 4)]
pub struct EvalSurface {
    /// Which view's left camera, for a cloud in camera_left
    #[param(default = 0, min = 0)]
    pub view: usize,
    /// Skip points this close to a marker or lesion
    #[param(default = 2.0, unit = "mm", min = 0.0)]
    pub marker_margin_mm: f64,
    /// Skip points this close to the base (or below it)
    #[param(default = 1.0, unit = "mm", min = 0.0)]
    pub base_margin_mm: f64,
}

#[derive(Inputs)]
pub struct EvalSurfaceInputs {
    /// Surface points, mm (frame camera_left, world or mri_lps)
    pub cloud: Arc<PointCloud>,
    /// ground_truth.json
    pub truth: Arc<PathValue>,
}

#[derive(Outputs)]
pub struct EvalSurfaceOutputs {
    /// Mean point-to-skin distance, mm
    pub mean_mm: f64,
}

impl RunOp for EvalSurface {
    type Inputs = EvalSurfaceInputs;
    type Outputs = EvalSurfaceOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let cloud = inputs.cloud;
        let truth = load_truth(&inputs.truth)?;
        let to_world = frame_to_world(&truth, &cloud.frame, self.view)
            .map_err(|e| OpError::invalid(format!("cloud: {e}")))?;
        let to_phantom = isometry_from_matrix(&truth.phantom_to_world).inverse() * to_world;
        let points = cloud
            .points
            .chunks(3)
            .map(|c| [c[0] as f64, c[1] as f64, c[2] as f64]);
        // Every frame but the MRI's sees the tissue as it moved.
        let motion = truth.motion_field();
        let moved = (cloud.frame != "mri_lps").then_some(&motion);
        let d = skin_distances(
            &truth.shape,
            moved,
            &to_phantom,
            points,
            self.marker_margin_mm,
            self.base_margin_mm,
        )
        .ok_or_else(|| {
            OpError::invalid(format!(
                "cloud: none of its {} points lies on the skin (away from markers and the base)",
                cloud.len()
            ))
        })?;
        ctx.metric("mean_mm", d.mean_mm);
        ctx.metric("mean_signed_mm", d.mean_signed_mm);
        ctx.metric("median_signed_mm", d.median_signed_mm);
        ctx.metric("rms_mm", d.rms_mm);
        ctx.metric("p95_mm", d.p95_mm);
        ctx.metric("max_mm", d.max_mm);
        ctx.metric("used", d.used as f64);
        ctx.metric("points", cloud.len() as f64);
        Ok(EvalSurfaceOutputs { mean_mm: d.mean_mm })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::ops::truth_file;
    use crate::phantom::GroundTruth;
    use nalgebra::{Isometry3, Point3};
    use std::collections::BTreeMap;

    /// Skin points of the truth well away from markers, lesions and the base,
    /// each moved a known distance along the skin normal, in world (mm); and
    /// those distances, signed (positive outwards).
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
            let delta = (0.2 + 0.2 * (i % 5) as f64) * if i % 3 == 0 { -1.0 } else { 1.0 };
            let normal = to_world.rotation * shape.skin_normal(&p);
            points.push(Point3::from(*x) + normal * delta);
            offsets.push(delta);
        }
        (points, offsets)
    }

    fn cloud(points: &[Point3<f64>], to_frame: &Isometry3<f64>, frame: &str) -> Arc<PointCloud> {
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
        Arc::new(PointCloud::new(flat, None, None, frame).unwrap())
    }

    #[test]
    fn surface_distances_are_the_known_offsets_along_the_normal() {
        let (truth, file) = truth_file("surface");
        let run = |cloud: Arc<PointCloud>, view: usize| {
            let op = EvalSurface {
                view,
                marker_margin_mm: 2.0,
                base_margin_mm: 1.0,
            };
            let inputs = EvalSurfaceInputs {
                cloud,
                truth: file.clone(),
            };
            let mut ctx = RunCtx::new("eval", &std::env::temp_dir());
            let out = op.run(inputs, &mut ctx)?;
            Ok::<(f64, BTreeMap<String, f64>), OpError>((out.mean_mm, ctx.into_metrics()))
        };
        let (mut points, offsets) = offset_skin(&truth);
        assert!(offsets.len() > 100, "{}", offsets.len());
        let n = offsets.len() as f64;
        let mean_signed = offsets.iter().sum::<f64>() / n;
        let mut signed = offsets.clone();
        signed.sort_by(f64::total_cmp);
        let median_signed = signed[signed.len() / 2];
        let offsets: Vec<f64> = offsets.iter().map(|d| d.abs()).collect();
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
        for (to_frame, frame) in [
            (world_to_camera, "camera_left"),
            (Isometry3::identity(), "world"),
        ] {
            let (out, m) = run(cloud(&points, &to_frame, frame), 0).unwrap();
            assert_eq!(out, m["mean_mm"]);
            assert_eq!(m["used"], n, "{frame}");
            assert_eq!(m["points"], n + truth.markers.len() as f64);
            for (name, expected) in [
                ("mean_mm", mean),
                ("mean_signed_mm", mean_signed),
                ("median_signed_mm", median_signed),
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
        let err = run(c, 4).unwrap_err();
        assert!(err.to_string().contains("view 4 does not exist"), "{err}");
        let c = cloud(&points, &world_to_camera, "camera_right");
        let err = run(c, 0).unwrap_err();
        assert!(err.to_string().contains("frame `camera_right`"), "{err}");
        let far = cloud(
            &[Point3::new(0.0, 0.0, -50.0)],
            &Isometry3::identity(),
            "world",
        );
        let err = run(far, 0).unwrap_err();
        assert!(err.to_string().contains("none of its 1 points"), "{err}");
        std::fs::remove_file(&file.path).unwrap();
    }
}
