//! `phantom.lesions`: the lesion centres as targets in MRI space.

use super::{TruthInput, shape_error};
use crate::phantom::load_truth;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Markers;

/// The phantom's lesion centres in MRI space: the targets a radiologist would
/// mark on the scan
#[derive(Debug, Clone, PartialEq, Op)]
// 2: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "phantom.lesions", version = 2)]
pub struct Lesions;

/// The output of `phantom.lesions`.
#[derive(Outputs)]
pub struct LesionsOutputs {
    /// Lesion centres, mm, frame mri_lps; ids the lesion numbers
    pub targets: Markers,
}

impl RunOp for Lesions {
    type Inputs = TruthInput;
    type Outputs = LesionsOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let truth = load_truth(&inputs.truth)?;
        let positions: Vec<f64> = truth.lesions.iter().flat_map(|l| l.center_mri_mm).collect();
        let ids: Vec<u32> = truth.lesions.iter().map(|l| l.id).collect();
        ctx.metric("targets", ids.len() as f64);
        let targets = Markers::new(positions, ids, "mri_lps").map_err(shape_error)?;
        Ok(LesionsOutputs { targets })
    }
}
