//! `register.map_targets`: MRI targets into camera space.

use crate::eval::convert::load_truth;
use crate::eval::{target_errors, true_mri_to_camera};
use crate::register::convert::{marker_points, markers_value};
use crate::register::{map_targets, predict_marker_tre};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue, Transform};

/// Targets marked in MRI (lesions) mapped into camera (robot) space with a registration
#[derive(Op)]
#[op(name = "register.map_targets", version = 2)]
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
    /// Markers matched between the two frames (e.g. match_markers.source),
    /// with `landmarks_target` in the same order: the predicted error of a
    /// markers-only registration at each target (Fitzpatrick's formula, FLE
    /// from the markers' own residual)
    pub landmarks_source: Option<Arc<Markers>>,
    /// The same markers in the other frame
    pub landmarks_target: Option<Arc<Markers>>,
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
        if let (Some(a), Some(b)) = (&inputs.landmarks_source, &inputs.landmarks_target) {
            report_marker_prediction(ctx, &targets, &points, a, b)?;
        }
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

/// Reports the predicted TRE of a markers-only registration at each target
/// (`target_<id>_marker_tre_mm` and its 95 % bound), with the markers' FRE
/// and the FLE it implies; a note where it cannot be predicted.
fn report_marker_prediction(
    ctx: &mut RunCtx,
    targets: &Markers,
    points: &[nalgebra::Point3<f64>],
    a: &Markers,
    b: &Markers,
) -> Result<(), OpError> {
    // The markers in the targets' frame, and their matches.
    let (own, other) = if a.frame == targets.frame {
        (a, b)
    } else if b.frame == targets.frame {
        (b, a)
    } else {
        return Err(OpError::invalid(format!(
            "landmarks in `{}` and `{}`: one side must be in the targets' frame `{}`",
            a.frame, b.frame, targets.frame
        )));
    };
    let (own, other) = (marker_points(own), marker_points(other));
    if own.len() != other.len() {
        return Err(OpError::invalid(format!(
            "{} landmarks_source vs {} landmarks_target: they must correspond one to one",
            a.ids.len(),
            b.ids.len()
        )));
    }
    let Some(p) = predict_marker_tre(&own, &other, points) else {
        ctx.note(format!(
            "no predicted target error: {} matched markers (it needs 4 or more, not on one line)",
            own.len()
        ));
        return Ok(());
    };
    ctx.metric("marker_fre_mm", p.fre_mm);
    ctx.metric("marker_fle_mm", p.fle_mm);
    for (id, (rms, bound)) in targets.ids.iter().zip(&p.targets) {
        ctx.metric(&format!("target_{id}_marker_tre_mm"), *rms);
        ctx.metric(&format!("target_{id}_marker_tre_bound95_mm"), *bound);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn markers(positions: &[[f64; 3]], frame: &str) -> Arc<Markers> {
        let ids: Vec<u32> = (0..positions.len() as u32).collect();
        Arc::new(Markers::new(positions.concat(), ids, frame).unwrap())
    }

    const MRI_MARKERS: [[f64; 3]; 5] = [
        [40.0, 0.0, 0.0],
        [-40.0, 5.0, 0.0],
        [0.0, 40.0, 10.0],
        [0.0, -40.0, 5.0],
        [10.0, 10.0, 40.0],
    ];

    fn inputs(camera_frame: &str) -> MapTargetsInputs {
        // The camera's markers: the MRI's, each 1 mm off along some axis.
        let offsets = [
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let camera: Vec<[f64; 3]> = MRI_MARKERS
            .iter()
            .zip(offsets)
            .map(|(p, o)| [p[0] + o[0], p[1] + o[1], p[2] + o[2]])
            .collect();
        MapTargetsInputs {
            targets: markers(&[[0.0, 0.0, 20.0], [0.0, 0.0, 120.0]], "mri_lps"),
            transform: Arc::new(Transform::identity("mri_lps", "camera_left")),
            truth: None,
            landmarks_source: Some(markers(&camera, camera_frame)),
            landmarks_target: Some(markers(&MRI_MARKERS, "mri_lps")),
        }
    }

    #[test]
    fn matched_markers_give_each_target_its_predicted_error() {
        let mut ctx = RunCtx::new("targets", &std::env::temp_dir());
        MapTargets { view: 0 }
            .run(inputs("camera_left"), &mut ctx)
            .unwrap();
        let m = ctx.metrics();
        let (fre, fle) = (m["marker_fre_mm"], m["marker_fle_mm"]);
        assert!(fre > 0.3 && fre < 1.0, "{fre}");
        assert!((fle - fre * (5.0f64 / 3.0).sqrt()).abs() < 1e-9);
        // The far target is predicted worse, and its bound lies beyond its RMS.
        let (near, far) = (m["target_0_marker_tre_mm"], m["target_1_marker_tre_mm"]);
        assert!(near < far, "{near} {far}");
        assert!(m["target_1_marker_tre_bound95_mm"] > far);
    }

    #[test]
    fn landmarks_in_neither_frame_of_the_targets_are_refused() {
        let mut ctx = RunCtx::new("targets", &std::env::temp_dir());
        let mut i = inputs("camera_left");
        i.landmarks_target = Some(markers(&MRI_MARKERS, "world"));
        let e = MapTargets { view: 0 }
            .run(i, &mut ctx)
            .map(|_| ())
            .unwrap_err();
        assert!(
            e.to_string()
                .contains("one side must be in the targets' frame `mri_lps`"),
            "{e}"
        );
    }
}
