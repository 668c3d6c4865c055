//! `mri.select_markers`: keep the components whose size fits a marker.

use super::shape_error;
use crate::mri::{MarkerSelection, select_components};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Labels;
use rayon::prelude::*;

/// Keep the components whose size fits a marker
#[derive(Op)]
#[op(name = "mri.select_markers", version = 1)]
pub struct SelectMarkers {
    /// Smallest kept
    #[param(default = 10.0, unit = "mm3", min = 0.0)]
    pub min_volume_mm3: f64,
    /// Largest kept
    #[param(default = 1000.0, unit = "mm3", min = 0.0)]
    pub max_volume_mm3: f64,
    /// Keep at most this many, closest to target (0 = all)
    #[param(default = 0, min = 0)]
    pub expected: usize,
    /// Expected marker (gel) volume
    #[param(default = 56.5, unit = "mm3", min = 0.0)]
    pub target_volume_mm3: f64,
}

#[derive(Inputs)]
pub struct SelectMarkersInputs {
    /// Components
    pub labels: Arc<Labels>,
}

#[derive(Outputs)]
pub struct SelectMarkersOutputs {
    /// Kept components, renumbered 1..found
    pub labels: Labels,
}

impl RunOp for SelectMarkers {
    type Inputs = SelectMarkersInputs;
    type Outputs = SelectMarkersOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let l = inputs.labels;
        let count = l.data.par_iter().copied().max().unwrap_or(0) as usize;
        // Integer counts: any split of the work gives the same sums.
        let sizes = l
            .data
            .par_chunks(1 << 16)
            .map(|chunk| {
                let mut sizes = vec![0usize; count + 1];
                chunk.iter().for_each(|&x| sizes[x as usize] += 1);
                sizes
            })
            .reduce(
                || vec![0usize; count + 1],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let s = l.grid.spacing_mm();
        let selection = MarkerSelection {
            min_volume_mm3: self.min_volume_mm3,
            max_volume_mm3: self.max_volume_mm3,
            expected: self.expected,
            target_volume_mm3: self.target_volume_mm3,
        };
        let kept = select_components(&sizes, s[0] * s[1] * s[2], &selection);
        let mut renumber = vec![0u32; count + 1];
        for (new, &old) in kept.iter().enumerate() {
            renumber[old as usize] = new as u32 + 1;
        }
        ctx.metric("found", kept.len() as f64);
        let labels: Vec<u32> = l.data.par_iter().map(|&x| renumber[x as usize]).collect();
        Ok(SelectMarkersOutputs {
            labels: Labels::new(l.grid.clone(), labels).map_err(shape_error)?,
        })
    }
}
