//! `register.match_markers`: marker correspondences without assumed order.

use crate::register::convert::{marker_points, markers_value};
use crate::register::match_markers;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Markers;
use nalgebra::Point3;

/// Marker correspondences without assumed order (triplet consensus)
#[derive(Op)]
#[op(name = "register.match_markers", version = 1)]
pub struct MatchMarkers {
    /// Largest distance of a matched pair after the fit
    #[param(default = 3.0, unit = "mm", min = 0.01)]
    pub tolerance_mm: f64,
    /// Allow a uniform scale between the sets
    #[param(default = false)]
    pub scale: bool,
}

#[derive(Inputs)]
pub struct MatchMarkersInputs {
    /// Markers to map
    pub source: Arc<Markers>,
    /// Markers to map onto
    pub target: Arc<Markers>,
}

#[derive(Outputs)]
pub struct MatchMarkersOutputs {
    /// Matched source markers, in pair order
    pub source: Markers,
    /// Matched target markers, in the same order
    pub target: Markers,
}

impl RunOp for MatchMarkers {
    type Inputs = MatchMarkersInputs;
    type Outputs = MatchMarkersOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (s, t) = (inputs.source, inputs.target);
        let (sp, tp) = (marker_points(&s), marker_points(&t));
        let m = match_markers(&sp, &tp, self.tolerance_mm, self.scale).ok_or_else(|| {
            OpError::invalid(format!(
                "fewer than 3 of the {} source and {} target markers can be matched within the tolerance",
                sp.len(),
                tp.len()
            ))
        })?;
        ctx.metric("inliers", m.pairs.len() as f64);
        ctx.metric("rmse_mm", m.rmse_mm);
        let pick = |pts: &[Point3<f64>], markers: &Markers, which: fn(&(usize, usize)) -> usize| {
            let picked: Vec<Point3<f64>> = m.pairs.iter().map(|p| pts[which(p)]).collect();
            let ids: Vec<u32> = m.pairs.iter().map(|p| markers.ids[which(p)]).collect();
            markers_value(&picked, ids, &markers.frame)
        };
        Ok(MatchMarkersOutputs {
            source: pick(&sp, &s, |p| p.0)?,
            target: pick(&tp, &t, |p| p.1)?,
        })
    }
}
