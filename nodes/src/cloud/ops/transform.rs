//! `cloud.transform`: a cloud into another frame.

use crate::camera::isometry_from_matrix;
use crate::cloud::convert::{cloud_normals, cloud_points, make_cloud};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PointCloud, Transform};
use nalgebra::Point3;

/// Move a cloud by a transform (or its inverse) into another frame
#[derive(Op)]
#[op(name = "cloud.transform", version = 1)]
pub struct TransformCloud {
    /// Apply the inverse (to -> from)
    #[param(default = false)]
    pub invert: bool,
}

#[derive(Inputs)]
pub struct TransformCloudInputs {
    /// The cloud
    pub cloud: Arc<PointCloud>,
    /// The transform
    pub transform: Arc<Transform>,
}

#[derive(Outputs)]
pub struct TransformCloudOutputs {
    /// The moved cloud, in the transform's other frame
    pub cloud: PointCloud,
}

impl RunOp for TransformCloud {
    type Inputs = TransformCloudInputs;
    type Outputs = TransformCloudOutputs;

    fn run(&self, inputs: Self::Inputs, _: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (c, t) = (inputs.cloud, inputs.transform);
        let iso = isometry_from_matrix(&t.matrix);
        let (iso, from, to) = if self.invert {
            (iso.inverse(), &t.to, &t.from)
        } else {
            (iso, &t.from, &t.to)
        };
        if &c.frame != from {
            return Err(OpError::invalid(format!(
                "the cloud is in frame `{}`, the transform maps from `{from}`",
                c.frame
            )));
        }
        let pts: Vec<Point3<f64>> = cloud_points(&c).iter().map(|p| iso * p).collect();
        let normals =
            cloud_normals(&c).map(|n| n.iter().map(|v| iso.rotation * v).collect::<Vec<_>>());
        Ok(TransformCloudOutputs {
            cloud: make_cloud(&pts, normals.as_deref(), c.colors.clone(), to)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::isometry_to_matrix;
    use crate::cloud::ops::test_cloud;
    use nalgebra::Isometry3;

    #[test]
    fn the_cloud_moves_either_way_and_its_frame_must_fit() {
        let iso = Isometry3::translation(10.0, 0.0, 0.0);
        let t = Arc::new(Transform {
            matrix: isometry_to_matrix(&iso),
            from: "a".into(),
            to: "b".into(),
        });
        let run = |invert: bool, frame: &str| {
            let inputs = TransformCloudInputs {
                cloud: Arc::new(test_cloud(&[[1.0, 2.0, 3.0]], frame)),
                transform: t.clone(),
            };
            let mut ctx = RunCtx::new("move", &std::env::temp_dir());
            TransformCloud { invert }.run(inputs, &mut ctx)
        };
        let out = run(false, "a").unwrap().cloud;
        assert_eq!(
            (&out.points[..], out.frame.as_str()),
            (&[11.0, 2.0, 3.0][..], "b")
        );
        let out = run(true, "b").unwrap().cloud;
        assert_eq!(
            (&out.points[..], out.frame.as_str()),
            (&[-9.0, 2.0, 3.0][..], "a")
        );
        let e = run(false, "b").map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("the cloud is in frame `b`"), "{e}");
    }
}
