//! `cloud.normals`: normals by local PCA.

use crate::cloud::convert::{cloud_points, make_cloud};
use crate::cloud::estimate_normals;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PointCloud;
use nalgebra::Point3;

/// Normals by PCA over the k nearest neighbours, oriented consistently
#[derive(Op)]
#[op(name = "cloud.normals", version = 1)]
pub struct Normals {
    /// Neighbours
    #[param(default = 16, min = 3, max = 1000)]
    pub k: usize,
    /// Towards the viewpoint, or away from the centroid
    #[param(default = Orient::Viewpoint)]
    pub orient: Orient,
    /// Viewpoint (the camera centre is the origin of camera frames)
    #[param(default = [0.0, 0.0, 0.0], unit = "mm")]
    pub viewpoint_mm: [f64; 3],
}

/// Which way normals face.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum Orient {
    /// Towards `viewpoint_mm`.
    Viewpoint,
    /// Away from the cloud's centroid.
    Outward,
}

#[derive(Inputs)]
pub struct NormalsInputs {
    /// The cloud
    pub cloud: Arc<PointCloud>,
}

#[derive(Outputs)]
pub struct NormalsOutputs {
    /// The cloud with unit normals
    pub cloud: PointCloud,
}

impl RunOp for Normals {
    type Inputs = NormalsInputs;
    type Outputs = NormalsOutputs;

    fn run(&self, inputs: Self::Inputs, _: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let c = inputs.cloud;
        let viewpoint = match self.orient {
            Orient::Viewpoint => Some(Point3::from(self.viewpoint_mm)),
            Orient::Outward => None,
        };
        let pts = cloud_points(&c);
        let normals = estimate_normals(&pts, self.k, viewpoint);
        Ok(NormalsOutputs {
            cloud: make_cloud(&pts, Some(&normals), c.colors.clone(), &c.frame)?,
        })
    }
}
