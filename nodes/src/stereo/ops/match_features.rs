//! `stereo.match_features`: descriptor matches between the two images.

use super::shape_error;
use crate::stereo::{MatchParams, features_from_table, match_features};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Matches, Table};

/// Nearest-neighbour descriptor matches (ratio test, mutual check, same rows
/// if rectified)
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.match_features", version = 1)]
pub struct MatchFeatures {
    /// Lowe's ratio: nearest distance below this times the second nearest
    /// (1 = off)
    #[param(default = 0.8, min = 0.01, max = 1.0)]
    pub ratio: f64,
    /// Keep only matches that are each other's nearest
    #[param(default = true)]
    pub mutual: bool,
    /// Rectified pair: candidates only within row_tolerance_px rows
    #[param(default = true)]
    pub rectified: bool,
    /// Largest |y_left - y_right| of a match when rectified
    #[param(default = 2.0, unit = "px", min = 0.0)]
    pub row_tolerance_px: f64,
    /// [min, max] allowed x_left - x_right; empty: no bound
    #[param(default = [], unit = "px", lengths = [0, 2])]
    pub disparity_bounds_px: Vec<f64>,
}

/// The inputs of `stereo.match_features`.
#[derive(Inputs)]
pub struct MatchFeaturesInputs {
    /// Features of the left image (stereo.features)
    pub left: Arc<Table>,
    /// Features of the right image, same detector
    pub right: Arc<Table>,
}

/// The outputs of `stereo.match_features`.
#[derive(Outputs)]
pub struct MatchFeaturesOutputs {
    /// Matched positions (px) and descriptor distances
    pub matches: Matches,
    /// x_left_px, y_left_px, x_right_px, y_right_px, disparity_px, score
    pub table: Table,
}

/// Columns of the `table` output.
const MATCH_COLUMNS: [&str; 6] = [
    "x_left_px",
    "y_left_px",
    "x_right_px",
    "y_right_px",
    "disparity_px",
    "score",
];

impl MatchFeatures {
    /// The matcher's settings.
    pub fn params(&self) -> Result<MatchParams, OpError> {
        let bounds = &self.disparity_bounds_px;
        let disparity_bounds_px = match bounds.as_slice() {
            [] => None,
            [lo, hi] => Some((*lo as f32, *hi as f32)),
            _ => {
                return Err(OpError::invalid(format!(
                    "disparity_bounds_px: {} numbers; give none or [min, max]",
                    bounds.len()
                )));
            }
        };
        Ok(MatchParams {
            ratio: self.ratio as f32,
            mutual: self.mutual,
            rectified: self.rectified,
            row_tolerance_px: self.row_tolerance_px as f32,
            disparity_bounds_px,
        })
    }
}

impl RunOp for MatchFeatures {
    type Inputs = MatchFeaturesInputs;
    type Outputs = MatchFeaturesOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let left = features_from_table(&inputs.left, "input `left`").map_err(OpError::invalid)?;
        let right =
            features_from_table(&inputs.right, "input `right`").map_err(OpError::invalid)?;
        let found = match_features(&left, &right, &self.params()?).map_err(OpError::invalid)?;
        let mut left_px = Vec::with_capacity(2 * found.len());
        let mut right_px = Vec::with_capacity(2 * found.len());
        let mut rows = Vec::with_capacity(6 * found.len());
        for m in &found {
            left_px.extend([m.x_left_px, m.y_left_px]);
            right_px.extend([m.x_right_px, m.y_right_px]);
            rows.extend(
                [
                    m.x_left_px,
                    m.y_left_px,
                    m.x_right_px,
                    m.y_right_px,
                    m.disparity_px,
                    m.score,
                ]
                .map(f64::from),
            );
        }
        let scores: Vec<f32> = found.iter().map(|m| m.score).collect();
        let matches = Matches::new(left_px, right_px, scores).map_err(shape_error)?;
        let columns = MATCH_COLUMNS.iter().map(|c| c.to_string()).collect();
        let table = Table::new(columns, rows).map_err(shape_error)?;
        ctx.metric("matches", found.len() as f64);
        Ok(MatchFeaturesOutputs { matches, table })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::defaults;
    use super::*;

    #[test]
    fn the_defaults_are_the_matchers_defaults() {
        let op: MatchFeatures = defaults();
        assert_eq!(op.params().unwrap(), MatchParams::default());
        let bounded = MatchFeatures {
            disparity_bounds_px: vec![3.0, 40.0],
            ..op
        };
        assert_eq!(
            bounded.params().unwrap().disparity_bounds_px,
            Some((3.0, 40.0))
        );
    }
}
