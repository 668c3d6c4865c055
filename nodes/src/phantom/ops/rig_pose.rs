//! `phantom.rig_pose`: a view's camera pose as a robot arm would report it.

use super::TruthInput;
use crate::camera::{isometry_from_matrix, isometry_to_matrix};
use crate::phantom::load_truth;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Transform;
use rand::{Rng, SeedableRng};

/// A phantom view's left camera pose, as a robot arm would report it (with
/// noise)
#[derive(Debug, Clone, PartialEq, Op)]
// 2: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "phantom.rig_pose", version = 2)]
pub struct RigPose {
    /// Which view pair
    #[param(default = 0, min = 0)]
    pub view: usize,
    /// Uniform position error, each axis
    #[param(default = 0.0, unit = "mm", min = 0.0, max = 1000.0)]
    pub noise_mm: f64,
    /// Uniform rotation error, each axis
    #[param(default = 0.0, unit = "deg", min = 0.0, max = 180.0)]
    pub noise_deg: f64,
    /// Seed of the noise
    #[param(default = 1, min = 0)]
    pub seed: u64,
}

/// The output of `phantom.rig_pose`.
#[derive(Outputs)]
pub struct RigPoseOutputs {
    /// camera_left -> world
    pub pose: Transform,
}

impl RunOp for RigPose {
    type Inputs = TruthInput;
    type Outputs = RigPoseOutputs;

    fn run(&self, inputs: Self::Inputs, _: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let truth = load_truth(&inputs.truth)?;
        let view = self.view;
        let v = truth.views.get(view).ok_or_else(|| {
            OpError::invalid(format!(
                "view {view} does not exist ({} views)",
                truth.views.len()
            ))
        })?;
        let (mm, deg) = (self.noise_mm, self.noise_deg.to_radians());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.seed ^ ((view as u64) << 32));
        let mut draw = |a: f64| {
            if a > 0.0 {
                rng.random_range(-a..a)
            } else {
                0.0
            }
        };
        let noise = nalgebra::Isometry3::new(
            nalgebra::Vector3::new(draw(mm), draw(mm), draw(mm)),
            nalgebra::Vector3::new(draw(deg), draw(deg), draw(deg)),
        );
        let pose = isometry_from_matrix(&v.left_camera_to_world) * noise;
        Ok(RigPoseOutputs {
            pose: Transform {
                matrix: isometry_to_matrix(&pose),
                from: "camera_left".into(),
                to: "world".into(),
            },
        })
    }
}
