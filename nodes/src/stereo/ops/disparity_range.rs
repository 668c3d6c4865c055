//! `stereo.disparity_range`: the dense matchers' search range from matches.

use crate::stereo::{RangeParams, disparity_range};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Matches;

/// Disparity search range from matches: percentiles widened by a margin
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.disparity_range", version = 1)]
pub struct DisparityRange {
    /// Lower percentile of matched disparities
    #[param(default = 2.0, unit = "%", min = 0.0, max = 100.0)]
    pub low_percentile: f64,
    /// Upper percentile of matched disparities
    #[param(default = 98.0, unit = "%", min = 0.0, max = 100.0)]
    pub high_percentile: f64,
    /// Fixed margin added on both sides
    #[param(default = 16.0, unit = "px", min = 0.0)]
    pub margin_px: f64,
    /// Margin added on both sides, as a fraction of the percentile spread
    #[param(default = 0.1, min = 0.0)]
    pub margin_fraction: f64,
    /// Fewer matches is an error
    #[param(default = 10, min = 1)]
    pub min_matches: usize,
}

/// The input of `stereo.disparity_range`.
#[derive(Inputs)]
pub struct DisparityRangeInputs {
    /// Matches of a rectified pair
    pub matches: Arc<Matches>,
}

/// The outputs of `stereo.disparity_range`.
#[derive(Outputs)]
pub struct DisparityRangeOutputs {
    /// Smallest disparity to search, px
    pub min_disparity: f64,
    /// Largest disparity to search, px
    pub max_disparity: f64,
}

impl DisparityRange {
    /// The range's settings.
    pub fn params(&self) -> RangeParams {
        RangeParams {
            low_percentile: self.low_percentile,
            high_percentile: self.high_percentile,
            margin_px: self.margin_px,
            margin_fraction: self.margin_fraction,
            min_matches: self.min_matches,
        }
    }
}

impl RunOp for DisparityRange {
    type Inputs = DisparityRangeInputs;
    type Outputs = DisparityRangeOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let matches = inputs.matches;
        let disparities: Vec<f32> = matches
            .left_px
            .chunks(2)
            .zip(matches.right_px.chunks(2))
            .map(|(l, r)| l[0] - r[0])
            .collect();
        let (min, max) = disparity_range(&disparities, &self.params())
            .map_err(|e| OpError::invalid(format!("input `matches`: {e}")))?;
        ctx.metric("min_px", min as f64);
        ctx.metric("max_px", max as f64);
        ctx.metric("matches", disparities.len() as f64);
        Ok(DisparityRangeOutputs {
            min_disparity: min as f64,
            max_disparity: max as f64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{ctx, defaults};
    use super::*;

    #[test]
    fn the_defaults_are_the_ranges_defaults() {
        let op: DisparityRange = defaults();
        assert_eq!(op.params(), RangeParams::default());
    }

    #[test]
    fn too_few_matches_name_the_remedy() {
        let m = Matches::new(vec![10.0f32, 5.0], vec![2.0f32, 5.0], vec![0.1f32]).unwrap();
        let inputs = DisparityRangeInputs {
            matches: Arc::new(m),
        };
        let op: DisparityRange = defaults();
        let err = op.run(inputs, &mut ctx()).err().unwrap().to_string();
        assert!(
            err.contains("only 1 matches") && err.contains("parameters"),
            "{err}"
        );
    }
}
