//! `eval.correspondences`: whether matched marker pairs are the same markers.

use super::Reference;
use crate::eval::convert::{load_truth, marker_positions};
use crate::eval::{identify_markers, true_marker_centres};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue};

/// Whether matched marker pairs (e.g. camera -> MRI) are the same true markers
#[derive(Op)]
// 2: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "eval.correspondences", version = 2)]
pub struct EvalCorrespondences {
    /// The true centres the source markers are measured at (faces for camera markers)
    #[param(default = SourceReference::WorldFace)]
    pub source_reference: SourceReference,
    /// The true centres the target markers are measured at (gel cores for MRI markers)
    #[param(default = Reference::MriGel)]
    pub target_reference: Reference,
    /// Farther from every true marker is unknown
    #[param(default = 5.0, unit = "mm", min = 0.0)]
    pub max_distance_mm: f64,
    /// Which view's left camera, for markers in camera_left
    #[param(default = 0, min = 0)]
    pub view: usize,
}

/// The true centres of the source markers: [`Reference`]'s choices with the
/// camera's first (`world_face`, `world_gel`, `mri_gel`), as declared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum SourceReference {
    /// Coloured face centres in world, for markers in `world` or `camera_left`.
    WorldFace,
    /// Gel cores in world, for markers in `world` or `camera_left`.
    WorldGel,
    /// Gel cores in MRI LPS, for markers in `mri_lps`.
    MriGel,
}

#[derive(Inputs)]
pub struct EvalCorrespondencesInputs {
    /// Matched markers, in pair order (frame mri_lps, world or camera_left)
    pub source: Arc<Markers>,
    /// Their partners, in the same order
    pub target: Arc<Markers>,
    /// ground_truth.json
    pub truth: Arc<PathValue>,
}

#[derive(Outputs)]
pub struct EvalCorrespondencesOutputs {
    /// Pairs of two different (or unknown) markers
    pub wrong: f64,
}

impl RunOp for EvalCorrespondences {
    type Inputs = EvalCorrespondencesInputs;
    type Outputs = EvalCorrespondencesOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let truth = load_truth(&inputs.truth)?;
        let mut ids = Vec::new();
        for (port, m, reference) in [
            ("source", &inputs.source, self.source_reference.name()),
            ("target", &inputs.target, self.target_reference.name()),
        ] {
            let centres = true_marker_centres(&truth, reference, &m.frame, self.view)
                .map_err(|e| OpError::invalid(format!("{port}: {e}")))?;
            let points: Vec<[f64; 3]> = centres.iter().map(|c| c.0).collect();
            ids.push(identify_markers(
                &marker_positions(m),
                &points,
                self.max_distance_mm,
            ));
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
        Ok(EvalCorrespondencesOutputs {
            wrong: wrong as f64,
        })
    }
}
