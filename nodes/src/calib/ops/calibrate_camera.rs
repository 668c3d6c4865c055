//! `calib.calibrate_camera`: one camera from the boards of its photos.

use super::{SolverParams, report_intrinsics_sd};
use crate::calib::tables::boards_from_table;
use crate::calib::{BoardView, calibrate_camera, repeated_poses, usual_size};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Camera, Table};

/// Zhang calibration refined by Levenberg-Marquardt -> Camera
#[derive(Op)]
// 3: analytic Jacobians, stopped on the exact minimum.
// 5: standard deviations of every intrinsic in the metrics.
#[op(name = "calib.calibrate_camera", version = 5)]
pub struct CalibrateCamera {
    #[param(flatten)]
    pub solver: SolverParams,
}

#[derive(Inputs)]
pub struct CalibrateCameraInputs {
    /// Corners from calib.find_chessboard
    pub corners: Arc<Table>,
}

#[derive(Debug, Outputs)]
pub struct CalibrateCameraOutputs {
    /// Intrinsics (px) and distortion
    pub camera: Camera,
}

/// One camera's boards, ready to calibrate.
pub(crate) struct DistinctViews {
    /// The views' numbers.
    pub ids: Vec<u32>,
    /// Their boards, in the same order.
    pub views: Vec<BoardView>,
    /// The photos' width and height, px.
    pub size: (usize, usize),
}

/// One camera's boards from a corners table: views of another photo size
/// than most and repeated board poses left out, each with a note. Fewer
/// than 3 poses left by repeats is an error naming them.
pub(crate) fn distinct_views(corners: &Table, ctx: &mut RunCtx) -> Result<DistinctViews, OpError> {
    let mut boards = boards_from_table(corners)?;
    let sizes = boards.iter().map(|(v, b)| (*v, b.1)).collect();
    let ((w, h), odd) = usual_size(&sizes);
    for v in odd {
        let (ow, oh) = sizes[&v];
        ctx.note(format!(
            "view {v}: the photo is {ow} x {oh} px, the others {w} x {h}: left out"
        ));
        boards.remove(&v);
    }
    let mut ids: Vec<u32> = boards.keys().copied().collect();
    let mut views: Vec<BoardView> = boards.into_values().map(|b| b.0).collect();
    let poses: Vec<Vec<&BoardView>> = views.iter().map(|v| vec![v]).collect();
    let repeats = repeated_poses(&poses);
    for (i, first, shift) in &repeats {
        ctx.note(format!(
            "view {}: the same board pose as view {} (corners within {shift:.2} px): a repeated photo, left out",
            ids[*i], ids[*first]
        ));
    }
    for (i, _, _) in repeats.iter().rev() {
        ids.remove(*i);
        views.remove(*i);
    }
    if views.len() < 3 && !repeats.is_empty() {
        return Err(OpError::invalid(format!(
            "{} distinct board poses ({} photos repeated others); calibration needs at least 3",
            views.len(),
            repeats.len()
        )));
    }
    Ok(DistinctViews {
        ids,
        views,
        size: (w, h),
    })
}

impl RunOp for CalibrateCamera {
    type Inputs = CalibrateCameraInputs;
    type Outputs = CalibrateCameraOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        self.solver.check()
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let DistinctViews {
            ids,
            views,
            size: (w, h),
        } = distinct_views(&inputs.corners, ctx)?;
        let c = calibrate_camera(&views, w, h, self.solver.distortion_mask()?)
            .map_err(OpError::invalid)?;
        ctx.metric("rms_px", c.rms_px);
        ctx.metric("views", views.len() as f64);
        ctx.metric("iterations", c.iterations as f64);
        if !c.converged {
            ctx.note(format!(
                "the solver stopped after {} iterations short of the minimum: check the corners",
                c.iterations
            ));
        }
        report_intrinsics_sd(ctx, "", c.spread.as_ref(), c.intrinsics_sd(), &c.estimated);
        for (id, e) in ids.iter().zip(&c.view_rms_px) {
            ctx.metric(&format!("view_{id}_rms_px"), *e);
        }
        self.solver
            .check_rms("camera", c.rms_px, &ids, &c.view_rms_px)?;
        Ok(CalibrateCameraOutputs {
            camera: c.camera.to_value(),
        })
    }
}
