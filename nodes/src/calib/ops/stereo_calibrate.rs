//! `calib.stereo_calibrate`: both cameras and the rig from paired boards.

use super::{SolverParams, report_intrinsics_sd};
use crate::calib::conversions::rig_value;
use crate::calib::tables::{boards_from_table, photos_from_table};
use crate::calib::{ParameterCovariance, Side, calibrate_stereo, pair_views, parameter_names};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{StereoRig, Table};

/// Both cameras and the rig extrinsics, refined jointly -> StereoRig
#[derive(Op)]
// 3: analytic Jacobians, stopped on the exact minimum.
// 5: standard deviations of every parameter, and each pair's RMS, in the metrics.
// 6: the shared parameters' covariance as an output.
#[op(name = "calib.stereo_calibrate", version = 6)]
pub struct StereoCalibrate {
    #[param(flatten)]
    pub solver: SolverParams,
}

#[derive(Inputs)]
pub struct StereoCalibrateInputs {
    /// Left corners (calib.find_chessboard)
    pub left: Arc<Table>,
    /// Right corners; views pair by number (left_07 with right_07)
    pub right: Arc<Table>,
    /// The left find_chessboard's `views`: tells a refused photo from a missing one
    pub left_views: Option<Arc<Table>>,
    /// The right find_chessboard's `views`
    pub right_views: Option<Arc<Table>>,
}

#[derive(Debug, Outputs)]
pub struct StereoCalibrateOutputs {
    /// Cameras and R, T (left -> right, mm)
    pub rig: StereoRig,
    /// The covariance of the estimated parameters (each camera's free
    /// intrinsics, `left_fx_px` ..., then the rig's `rotation_vector_*_rad`
    /// and `translation_*_mm`): one column and one row per parameter, in
    /// their units squared; empty (no rows) where the views leave one
    /// undetermined
    pub covariance: Table,
}

/// One side's boards, and its photos' records when the views table is given.
fn side(corners: &Table, views: Option<&Table>) -> Result<Side, OpError> {
    Ok(Side {
        boards: boards_from_table(corners)?,
        photos: views.map(photos_from_table).transpose()?,
    })
}

impl RunOp for StereoCalibrate {
    type Inputs = StereoCalibrateInputs;
    type Outputs = StereoCalibrateOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        self.solver.check()
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let left = side(&inputs.left, inputs.left_views.as_deref())?;
        let right = side(&inputs.right, inputs.right_views.as_deref())?;
        let pairing = pair_views(&left, &right, 3).map_err(OpError::invalid)?;
        for dropped in &pairing.dropped {
            ctx.note(format!("{dropped}: pair left out"));
        }
        let s = calibrate_stereo(
            &pairing.pairs,
            pairing.sizes,
            self.solver.distortion_mask()?,
        )
        .map_err(OpError::invalid)?;
        ctx.metric("pairs", pairing.pairs.len() as f64);
        ctx.metric("iterations", s.iterations as f64);
        if !s.converged {
            ctx.note(format!(
                "the solver stopped after {} iterations short of the minimum: check the corners",
                s.iterations
            ));
        }
        ctx.metric("pairs_left_out", pairing.dropped.len() as f64);
        ctx.metric("rms_px", s.rms_px);
        ctx.metric("rms_left_px", s.rms_left_right_px[0]);
        ctx.metric("rms_right_px", s.rms_left_right_px[1]);
        ctx.metric("baseline_mm", s.left_to_right.translation.vector.norm());
        ctx.metric("verging_deg", s.left_to_right.rotation.angle().to_degrees());
        for (side, prefix) in ["left_", "right_"].into_iter().enumerate() {
            report_intrinsics_sd(
                ctx,
                prefix,
                s.spread.as_ref(),
                s.intrinsics_sd(side),
                &s.estimated,
            );
        }
        if let Some(rig) = s.rig_spread() {
            ctx.metric("baseline_sd_mm", rig.baseline_sd_mm);
            for (axis, (r, t)) in ["x", "y", "z"]
                .iter()
                .zip(rig.rotation_sd_deg().iter().zip(rig.translation_sd_mm()))
            {
                ctx.metric(&format!("rotation_{axis}_sd_deg"), *r);
                ctx.metric(&format!("translation_{axis}_sd_mm"), t);
            }
        }
        for (id, e) in pairing.views.iter().zip(&s.pair_rms_px) {
            ctx.metric(&format!("pair_{id}_rms_px"), *e);
        }
        self.solver
            .check_rms("stereo", s.rms_px, &pairing.views, &s.pair_rms_px)?;
        let names = parameter_names(&s.estimated);
        let covariance = match s.spread.as_ref().and_then(|spread| spread.covariance()) {
            Some(matrix) => ParameterCovariance { names, matrix }.to_table(),
            None => Table::new(names, Vec::new()).map_err(|e| OpError::invalid(e.0))?,
        };
        Ok(StereoCalibrateOutputs {
            rig: rig_value(&s),
            covariance,
        })
    }
}
