//! The `calib.*` ops: one file per op, each its declaration and thin adapter.

mod calibrate_camera;
mod cross_validate;
mod find_chessboard;
mod rectify;
mod remap;
mod stereo_calibrate;

pub use calibrate_camera::{CalibrateCamera, CalibrateCameraInputs, CalibrateCameraOutputs};
pub use cross_validate::{CrossValidate, CrossValidateInputs, CrossValidateOutputs};
pub use find_chessboard::{FindChessboard, FindChessboardInputs, FindChessboardOutputs};
pub use rectify::{Rectify, RectifyInputs, RectifyOutputs};
pub use remap::{Remap, RemapInputs, RemapOutputs, RemapSide};
pub use stereo_calibrate::{StereoCalibrate, StereoCalibrateInputs, StereoCalibrateOutputs};

use super::{DISTORTION_NAMES, Spread};
use fusegraph_engine::OpError;
use fusegraph_engine::typed::prelude::*;

/// The solver parameters shared by `calib.calibrate_camera` and
/// `calib.stereo_calibrate`.
#[derive(Params)]
pub struct SolverParams {
    /// Distortion coefficients to estimate (others 0)
    #[param(default = ["k1", "k2", "p1", "p2"])]
    pub free: Vec<String>,
    /// Fail when the RMS reprojection error exceeds this (a garbage calibration)
    #[param(default = 2.0, unit = "px", min = 0.0)]
    pub max_rms_px: f64,
}

impl SolverParams {
    /// The names in `free` that are no distortion coefficient, at validation.
    pub fn check(&self) -> Vec<(&'static str, String)> {
        self.unknown_coefficient()
            .map(|m| ("free", m))
            .into_iter()
            .collect()
    }

    fn unknown_coefficient(&self) -> Option<String> {
        let f = self
            .free
            .iter()
            .find(|f| !DISTORTION_NAMES.contains(&f.as_str()))?;
        Some(format!(
            "unknown coefficient {f:?}; use {}",
            DISTORTION_NAMES.join(", ")
        ))
    }

    /// Which of k1, k2, p1, p2, k3 are estimated; an unknown name is an error.
    pub fn distortion_mask(&self) -> Result<[bool; 5], OpError> {
        if let Some(m) = self.unknown_coefficient() {
            return Err(OpError::invalid(format!("free: {m}")));
        }
        Ok(std::array::from_fn(|i| {
            self.free.iter().any(|f| f == DISTORTION_NAMES[i])
        }))
    }

    /// Refuses a calibration whose reprojection error (`rms_px`, px) says it
    /// is garbage (a mispaired or mis-detected view), naming the worst of
    /// `views` by their `view_rms_px`.
    pub fn check_rms(
        &self,
        what: &str,
        rms_px: f64,
        views: &[u32],
        view_rms_px: &[f64],
    ) -> Result<(), OpError> {
        let max_rms_px = self.max_rms_px;
        if rms_px.is_finite() && rms_px <= max_rms_px {
            return Ok(());
        }
        let mut worst: Vec<(f64, u32)> = view_rms_px
            .iter()
            .copied()
            .zip(views.iter().copied())
            .collect();
        worst.sort_by(|a, b| b.0.total_cmp(&a.0));
        let listed: Vec<String> = worst
            .iter()
            .take(3)
            .map(|(e, v)| format!("view {v} {e:.2} px"))
            .collect();
        Err(OpError::invalid(format!(
            "{what} RMS reprojection error {rms_px:.3} px is above max_rms_px = {max_rms_px} px: \
             a view is probably mispaired or its board mis-detected (worst: {})",
            listed.join(", ")
        )))
    }
}

/// The metric names of the intrinsics' standard deviations, in solver order.
const INTRINSICS_SD_NAMES: [&str; 9] = [
    "fx_sd_px", "fy_sd_px", "cx_sd_px", "cy_sd_px", "k1_sd", "k2_sd", "p1_sd", "p2_sd", "k3_sd",
];

/// Reports the estimated intrinsics' standard deviations `sd` (solver
/// order) as metrics named with `prefix` (`fx_sd_px`, ..., `k1_sd`; none for
/// a coefficient held fixed), and the residuals' own standard deviation;
/// without a spread, a note saying why.
pub(crate) fn report_intrinsics_sd(
    ctx: &mut RunCtx,
    prefix: &str,
    spread: Option<&Spread>,
    sd: [f64; 9],
    estimated: &[usize],
) {
    let Some(spread) = spread else {
        ctx.note(format!(
            "{prefix}no standard deviations: the views leave a parameter undetermined (J^T J is \
             singular at the optimum)"
        ));
        return;
    };
    for &i in estimated {
        ctx.metric(&format!("{prefix}{}", INTRINSICS_SD_NAMES[i]), sd[i]);
    }
    if let Some(v) = super::residual_variance(spread.cost, spread.residuals, spread.parameters) {
        ctx.metric(&format!("{prefix}residual_sd_px"), v.sqrt());
    }
}
