//! `eval.disparity`: a disparity map against the true one.

use crate::eval::{bad_metric_name, disparity_errors};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Disparity, Image};

/// A disparity map against the true one: bad-N % (invalid counted bad), MAE, RMSE, coverage
#[derive(Op)]
#[op(name = "eval.disparity", version = 2)]
pub struct EvalDisparity {
    /// Error thresholds of the bad_N_pct metrics
    #[param(default = [0.5, 1.0, 2.0, 4.0], unit = "px", min = 0.0)]
    pub thresholds_px: Vec<f64>,
}

#[derive(Inputs)]
pub struct EvalDisparityInputs {
    /// Estimated disparity, px
    pub disparity: Arc<Disparity>,
    /// True disparity, px (0, NaN or inf = unknown)
    pub truth: Arc<Disparity>,
    /// Where to evaluate (nonzero pixels), same size
    pub mask: Option<Arc<Image>>,
}

#[derive(Outputs)]
pub struct EvalDisparityOutputs {
    /// Evaluated pixels off by more than 2 px or without an estimate, %
    pub bad_2_pct: f64,
}

impl RunOp for EvalDisparity {
    type Inputs = EvalDisparityInputs;
    type Outputs = EvalDisparityOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (est, truth) = (inputs.disparity, inputs.truth);
        if (est.width, est.height) != (truth.width, truth.height) {
            return Err(OpError::invalid(format!(
                "input `disparity` is {} x {} px but `truth` is {} x {} px",
                est.width, est.height, truth.width, truth.height
            )));
        }
        let mask = match inputs.mask {
            None => None,
            Some(m) if (m.width, m.height) != (truth.width, truth.height) => {
                return Err(OpError::invalid(format!(
                    "input `mask` is {} x {} px but `truth` is {} x {} px",
                    m.width, m.height, truth.width, truth.height
                )));
            }
            Some(m) => Some(
                crate::io::grey_of(&m)
                    .iter()
                    .map(|&v| v > 0.0)
                    .collect::<Vec<bool>>(),
            ),
        };
        let mut thresholds = self.thresholds_px.clone();
        if !thresholds.contains(&2.0) {
            thresholds.push(2.0);
        }
        let e = disparity_errors(&est.data, &truth.data, mask.as_deref(), &thresholds)
            .map_err(OpError::invalid)?;
        if e.evaluated == 0 {
            return Err(OpError::invalid(
                "no pixel to evaluate: the truth is unknown everywhere (or the mask is empty)",
            ));
        }
        for (&t, &pct) in thresholds.iter().zip(&e.bad_pct) {
            ctx.metric(&bad_metric_name(t), pct);
        }
        ctx.metric("mae_px", e.mae_px);
        ctx.metric("mean_signed_px", e.mean_signed_px);
        ctx.metric("median_signed_px", e.median_signed_px);
        ctx.metric("rmse_px", e.rmse_px);
        ctx.metric("coverage_pct", e.coverage_pct);
        ctx.metric("evaluated", e.evaluated as f64);
        let bad2 = thresholds
            .iter()
            .position(|&t| t == 2.0)
            .map_or(f64::NAN, |k| e.bad_pct[k]);
        Ok(EvalDisparityOutputs { bad_2_pct: bad2 })
    }
}
