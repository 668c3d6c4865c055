//! `cloud.keep_connected`: a cloud's main connected surfaces, without the
//! patches floating apart from them.

use crate::cloud::convert::cloud_points;
use crate::cloud::keep_main_surfaces;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PointCloud;

/// Keeps the cloud's main connected surfaces (points within link_mm of one
/// another are one surface): patches matched at a wrong disparity, floating
/// apart from the skin, go
#[derive(Op)]
#[op(name = "cloud.keep_connected", version = 1)]
pub struct KeepConnected {
    /// Points this close are one surface: a few times the cloud's spacing
    /// (1 mm voxels: 3 mm), well under the gap to a floating patch
    #[param(default = 3.0, unit = "mm", min = 1e-3)]
    pub link_mm: f64,
    /// A surface is kept with at least this share of the largest one's
    /// points: 0.1 keeps skin cut in two by a tool's shadow, and removes
    /// patches of a few hundred points against a skin of thousands
    #[param(default = 0.1, min = 0.0, max = 1.0)]
    pub min_share: f64,
}

#[derive(Inputs)]
pub struct KeepConnectedInputs {
    /// A cloud (any frame, mm)
    pub cloud: Arc<PointCloud>,
}

#[derive(Outputs)]
pub struct KeepConnectedOutputs {
    /// Its points on the surfaces kept
    pub cloud: PointCloud,
}

impl RunOp for KeepConnected {
    type Inputs = KeepConnectedInputs;
    type Outputs = KeepConnectedOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let c = inputs.cloud;
        let keep = keep_main_surfaces(&cloud_points(&c), self.link_mm, self.min_share);
        let kept = keep.iter().filter(|k| **k).count();
        ctx.metric("removed", (keep.len() - kept) as f64);
        ctx.metric("points", kept as f64);
        Ok(KeepConnectedOutputs {
            cloud: c.select(&keep).map_err(|e| OpError::invalid(e.0))?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::ops::test_cloud;

    fn run(op: KeepConnected, points: &[[f32; 3]]) -> Result<(PointCloud, f64), OpError> {
        let mut ctx = RunCtx::new("keep", &std::env::temp_dir());
        let cloud = Arc::new(test_cloud(points, "camera_left"));
        let out = op.run(KeepConnectedInputs { cloud }, &mut ctx)?;
        Ok((out.cloud, ctx.metrics()["removed"]))
    }

    #[test]
    fn a_far_point_goes_and_the_frame_stays() {
        let mut points: Vec<[f32; 3]> = (0..40).map(|k| [k as f32, 0.0, 500.0]).collect();
        points.push([10.0, 0.0, 440.0]);
        let op = KeepConnected {
            link_mm: 3.0,
            min_share: 0.1,
        };
        let (cloud, removed) = run(op, &points).unwrap();
        assert_eq!((cloud.len(), removed), (40, 1.0));
        assert_eq!(cloud.frame, "camera_left");
        assert!(cloud.points.chunks(3).all(|p| p[2] == 500.0));
    }

    #[test]
    fn a_link_of_zero_is_refused_and_an_empty_cloud_stays_empty() {
        let spec = fusegraph_engine::typed::spec_of::<KeepConnected>().unwrap();
        let link = spec.params.iter().find(|p| p.name == "link_mm").unwrap();
        let e = link
            .parse(&toml::Value::Float(0.0), std::path::Path::new("."))
            .unwrap_err();
        assert!(e.contains("0 is below the minimum 0.001 mm"), "{e}");
        let op = KeepConnected {
            link_mm: 3.0,
            min_share: 0.1,
        };
        let (cloud, removed) = run(op, &[]).unwrap();
        assert_eq!((cloud.len(), removed), (0, 0.0));
    }
}
