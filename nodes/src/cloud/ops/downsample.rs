//! `cloud.downsample`: voxel-grid downsampling.

use crate::cloud::convert::{cloud_points, make_cloud};
use crate::cloud::voxel_downsample;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PointCloud;

/// Voxel-grid downsampling: one mean point per occupied cube
#[derive(Op)]
#[op(name = "cloud.downsample", version = 1)]
pub struct Downsample {
    /// Cube side
    #[param(default = 2.0, unit = "mm", min = 1e-6)]
    pub voxel_mm: f64,
}

#[derive(Inputs)]
pub struct DownsampleInputs {
    /// The cloud
    pub cloud: Arc<PointCloud>,
}

#[derive(Outputs)]
pub struct DownsampleOutputs {
    /// Downsampled cloud (no normals or colours)
    pub cloud: PointCloud,
}

impl RunOp for Downsample {
    type Inputs = DownsampleInputs;
    type Outputs = DownsampleOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let c = inputs.cloud;
        let pts = voxel_downsample(&cloud_points(&c), self.voxel_mm);
        ctx.metric("points", pts.len() as f64);
        Ok(DownsampleOutputs {
            cloud: make_cloud(&pts, None, None, &c.frame)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::ops::test_cloud;

    #[test]
    fn the_cloud_keeps_its_frame_and_loses_close_points() {
        let cloud = test_cloud(
            &[[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [9.0, 0.0, 0.0]],
            "world",
        );
        let mut ctx = RunCtx::new("down", &std::env::temp_dir());
        let out = Downsample { voxel_mm: 2.0 }
            .run(
                DownsampleInputs {
                    cloud: Arc::new(cloud),
                },
                &mut ctx,
            )
            .unwrap();
        assert_eq!(&out.cloud.points[..], [0.25, 0.0, 0.0, 9.0, 0.0, 0.0]);
        assert_eq!(out.cloud.frame, "world");
        assert_eq!(ctx.metrics()["points"], 2.0);
    }
}
