//! `stereo.disparity_range`: the dense matchers' search range from matches.

use crate::stereo::{RangeParams, core_disparities, disparity_range};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Matches, Rectification};

/// Disparity search range from matches: those nearby matches agree with and
/// those near them (all that the rig's geometry allows), their percentiles
/// widened by a margin
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.disparity_range", version = 3)]
pub struct DisparityRange {
    /// A match counts when at least `min_support` others within this radius
    /// (left image) agree on its disparity (0 = every match counts)
    #[param(default = 48.0, unit = "px", min = 0.0)]
    pub support_radius_px: f64,
    /// Largest disparity difference of agreeing matches
    #[param(default = 3.0, unit = "px", min = 0.0)]
    pub support_tolerance_px: f64,
    /// Agreeing neighbours a match needs
    #[param(default = 1, min = 1)]
    pub min_support: usize,
    /// Without a `rectification` input: the pair is rectified so a point at
    /// infinity has disparity 0 (Middlebury, most stereo cameras' rectified
    /// output), so negative disparities are impossible
    #[param(default = false)]
    pub zero_at_infinity: bool,
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

/// The inputs of `stereo.disparity_range`.
#[derive(Inputs)]
pub struct DisparityRangeInputs {
    /// Matches of a rectified pair
    pub matches: Arc<Matches>,
    /// The pair's rectification: a point in front of the rig has at least
    /// the disparity of a point at infinity (cx1 - cx2), so smaller matched
    /// disparities are impossible and the range starts there at the least
    pub rectification: Option<Arc<Rectification>>,
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
        let located: Vec<(f32, f32, f32)> = matches
            .left_px
            .chunks(2)
            .zip(matches.right_px.chunks(2))
            .map(|(l, r)| (l[0], l[1], l[0] - r[0]))
            .collect();
        // Disparity of a point at infinity, less a pixel for rounding.
        let at_infinity = inputs
            .rectification
            .as_deref()
            .map(|r| r.p1[0][2] - r.p2[0][2])
            .or(self.zero_at_infinity.then_some(0.0));
        let lowest = at_infinity.map(|d| d - 1.0);
        let support = (
            self.support_radius_px,
            self.support_tolerance_px,
            self.min_support,
        );
        let disparities = core_disparities(&located, support, lowest, &self.params());
        let dropped = located.len() - disparities.len();
        if dropped > 0 {
            ctx.note(format!(
                "{dropped} of {} matches left out: no {} neighbours within {} px agree on their \
                 disparity and it lies beyond the margin of those that have{}",
                located.len(),
                self.min_support,
                self.support_radius_px,
                lowest.map_or(String::new(), |l| format!(
                    ", or it is below {l:.1} px (a point behind the rig)"
                ))
            ));
        }
        let raw: Vec<f32> = located.iter().map(|m| m.2).collect();
        if raw.iter().filter(|d| d.is_finite()).count() < self.min_matches {
            // Too few before any is left out: the range's own error says so.
            disparity_range(&raw, &self.params())
                .map_err(|e| OpError::invalid(format!("input `matches`: {e}")))?;
        }
        if disparities.len() < self.min_matches {
            return Err(OpError::invalid(format!(
                "input `matches`: only {} of {} matches have {} neighbours within {} px agreeing \
                 on their disparity (min_matches = {}): too few to bound the disparity range; \
                 set the dense matcher's range by its parameters instead, or lower min_support",
                disparities.len(),
                located.len(),
                self.min_support,
                self.support_radius_px,
                self.min_matches
            )));
        }
        let (mut min, max) = disparity_range(&disparities, &self.params())
            .map_err(|e| OpError::invalid(format!("input `matches`: {e}")))?;
        if let Some(low) = lowest {
            min = min.max(low.floor() as i32).min(max);
        }
        ctx.metric("min_px", min as f64);
        ctx.metric("max_px", max as f64);
        ctx.metric("matches", located.len() as f64);
        ctx.metric("matches_used", disparities.len() as f64);
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
            rectification: None,
        };
        let op: DisparityRange = defaults();
        let err = op.run(inputs, &mut ctx()).err().unwrap().to_string();
        assert!(
            err.contains("only 1 matches") && err.contains("parameters"),
            "{err}"
        );
    }
}
