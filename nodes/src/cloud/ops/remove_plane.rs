//! `cloud.remove_plane`: the table under the object, and what lies beyond it.

use crate::cloud::convert::cloud_points;
use crate::cloud::{off_table, plane_table};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PointCloud, Table};

/// Removes the dominant plane (the table under the object) and what lies beyond it, by RANSAC
#[derive(Op)]
// 2: the table itself as an output.
#[op(name = "cloud.remove_plane", version = 2)]
pub struct RemovePlane {
    /// Points this close to the plane are on it
    #[param(default = 3.0, unit = "mm", min = 1e-3)]
    pub threshold_mm: f64,
    /// Remove the plane only if it holds at least this fraction of the points (else there is no table)
    #[param(default = 0.2, min = 0.0, max = 1.0)]
    pub min_fraction: f64,
    /// RANSAC trials
    #[param(default = 300, min = 1, max = 100000)]
    pub iterations: usize,
    /// RANSAC seed
    #[param(default = 1, min = 0)]
    pub seed: i64,
}

#[derive(Inputs)]
pub struct RemovePlaneInputs {
    /// The cloud (camera frame: the camera is at the origin)
    pub cloud: Arc<PointCloud>,
}

#[derive(Outputs)]
pub struct RemovePlaneOutputs {
    /// The points off the plane on the camera's side (normals and colours kept)
    pub cloud: PointCloud,
    /// The table, in the cloud's frame: one row (normal_x, normal_y, normal_z,
    /// offset_mm; the points p with normal . p = offset, the unit normal
    /// towards the camera), or none when no plane held min_fraction
    pub plane: Table,
}

impl RunOp for RemovePlane {
    type Inputs = RemovePlaneInputs;
    type Outputs = RemovePlaneOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let c = inputs.cloud;
        let (keep, table, plane_fraction) = off_table(
            &cloud_points(&c),
            self.threshold_mm,
            self.min_fraction,
            self.iterations,
            self.seed as u64,
        );
        ctx.metric("plane_fraction", plane_fraction);
        let kept = keep.iter().filter(|k| **k).count();
        ctx.metric("points", kept as f64);
        Ok(RemovePlaneOutputs {
            cloud: c.select(&keep).map_err(|e| OpError::invalid(e.0))?,
            plane: plane_table(table.as_ref()).map_err(|e| OpError::invalid(e.0))?,
        })
    }
}
