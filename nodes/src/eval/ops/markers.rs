//! `eval.markers`: found marker centres against the true ones.

use crate::eval::convert::{load_truth, marker_positions};
use crate::eval::{compare_markers, true_marker_centres};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue};

/// Found marker centres against the phantom's true ones (no assumed order)
#[derive(Op)]
// 6: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "eval.markers", version = 6)]
pub struct EvalMarkers {
    /// Which true centres: gel cores in MRI LPS (markers in mri_lps), or gel cores / coloured faces (markers in world, or in camera_left: then only those visible in both images of `view`), or lesion centres in MRI LPS (lesions found in the scan)
    #[param(default = Reference::MriGel)]
    pub reference: Reference,
    /// Farther than this is no match
    #[param(default = 5.0, unit = "mm", min = 0.0)]
    pub max_distance_mm: f64,
    /// Which view's left camera, for markers in camera_left
    #[param(default = 0, min = 0)]
    pub view: usize,
}

/// The true marker centres found markers are measured against (see
/// [`true_marker_centres`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum Reference {
    /// Gel cores in MRI LPS, for markers in `mri_lps`.
    MriGel,
    /// Gel cores in world, for markers in `world` or `camera_left`.
    WorldGel,
    /// Coloured face centres in world, for markers in `world` or `camera_left`.
    WorldFace,
    /// Lesion centres in MRI LPS, for lesions found in the scan (`mri_lps`).
    MriLesion,
}

#[derive(Inputs)]
pub struct EvalMarkersInputs {
    /// Found centres, mm (frame mri_lps, world or camera_left)
    pub markers: Arc<Markers>,
    /// ground_truth.json
    pub truth: Arc<PathValue>,
}

#[derive(Outputs)]
pub struct EvalMarkersOutputs {
    /// Number of matched markers
    pub found: f64,
}

impl RunOp for EvalMarkers {
    type Inputs = EvalMarkersInputs;
    type Outputs = EvalMarkersOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let markers = inputs.markers;
        let truth = load_truth(&inputs.truth)?;
        let centres = true_marker_centres(&truth, self.reference.name(), &markers.frame, self.view)
            .map_err(|e| OpError::invalid(format!("markers: {e}")))?;
        let found = marker_positions(&markers);
        let points: Vec<[f64; 3]> = centres.iter().map(|c| c.0).collect();
        let c = compare_markers(&found, &points, self.max_distance_mm);
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
        Ok(EvalMarkersOutputs {
            found: c.pairs.len() as f64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::isometry_from_matrix;
    use crate::eval::ops::truth_file;
    use nalgebra::{Point3, Vector3};

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
        let markers = Arc::new(Markers::new(found, vec![7, 8, 9, 10], "camera_left").unwrap());
        let run = |reference: Reference| {
            let op = EvalMarkers {
                reference,
                max_distance_mm: 5.0,
                view: 0,
            };
            let inputs = EvalMarkersInputs {
                markers: markers.clone(),
                truth: file.clone(),
            };
            let mut ctx = RunCtx::new("eval", &std::env::temp_dir());
            op.run(inputs, &mut ctx)
                .map(|out| (out, ctx.into_metrics()))
        };
        let (out, m) = run(Reference::WorldFace).unwrap();
        assert_eq!(
            (m["expected"], m["found"], m["missed"], m["spurious"]),
            (3.0, 2.0, 1.0, 1.0)
        );
        assert_eq!(out.found, 3.0, "the partly hidden one is matched too");
        assert!((m["mean_error_mm"] - 0.5).abs() < 1e-9);
        assert!((m["max_error_mm"] - 0.5).abs() < 1e-9);
        assert_eq!(m["partly_hidden_found"], 1.0);
        assert!((m["partly_hidden_max_error_mm"] - 1.3).abs() < 1e-9);
        let err = run(Reference::MriGel).map(|_| ()).unwrap_err();
        assert!(
            err.to_string().contains("takes markers in mri_lps"),
            "{err}"
        );
        std::fs::remove_file(&file.path).unwrap();
    }
}
