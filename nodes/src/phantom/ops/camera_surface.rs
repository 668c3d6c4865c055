//! `phantom.camera_surface`: a simulated stereo reconstruction of one view.

use super::{TruthInput, shape_error};
use crate::phantom::{SurfaceSimParams, load_truth, simulate_camera_surface};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PointCloud};

/// Simulated stereo reconstruction of one phantom view, from the truth: noisy
/// visible surface and markers
#[derive(Debug, Clone, PartialEq, Op)]
// 2: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "phantom.camera_surface", version = 2)]
pub struct CameraSurface {
    /// The view, the noise and the marker errors.
    #[param(flatten)]
    pub sim: SurfaceSimParams,
}

/// The outputs of `phantom.camera_surface`.
#[derive(Outputs)]
pub struct CameraSurfaceOutputs {
    /// Visible surface, left camera frame (camera_left), mm
    pub cloud: PointCloud,
    /// Marker face centres, left camera frame, mm (ids are arbitrary)
    pub markers: Markers,
}

impl RunOp for CameraSurface {
    type Inputs = TruthInput;
    type Outputs = CameraSurfaceOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let truth = load_truth(&inputs.truth)?;
        let sim = simulate_camera_surface(&truth, &self.sim).map_err(OpError::invalid)?;
        ctx.metric("points", sim.points.len() as f64);
        ctx.metric("outliers", sim.outliers as f64);
        ctx.metric("markers", sim.markers.len() as f64);
        let flat: Vec<f32> = sim.points.iter().flatten().copied().collect();
        let cloud = PointCloud::new(flat, None, None, "camera_left").map_err(shape_error)?;
        let positions: Vec<f64> = sim.markers.iter().flatten().copied().collect();
        let ids: Vec<u32> = (0..sim.markers.len() as u32).collect();
        let markers = Markers::new(positions, ids, "camera_left").map_err(shape_error)?;
        Ok(CameraSurfaceOutputs { cloud, markers })
    }
}
