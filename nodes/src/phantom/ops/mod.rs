//! The `phantom.*` ops: one file per op, each its declaration and thin adapter.

mod camera_surface;
mod generate;
mod lesions;
mod rig_pose;
mod true_disparity;
mod true_rig;

pub use camera_surface::{CameraSurface, CameraSurfaceOutputs};
pub use generate::{Generate, GenerateInputs, GenerateOutputs};
pub use lesions::{Lesions, LesionsOutputs};
pub use rig_pose::{RigPose, RigPoseOutputs};
pub use true_disparity::{TrueDisparity, TrueDisparityInputs, TrueDisparityOutputs};
pub use true_rig::{TrueRig, TrueRigOutputs};

use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, ValueError};

/// The input of the ops that read a phantom's truth alone.
#[derive(Inputs)]
pub struct TruthInput {
    /// ground_truth.json of a phantom
    pub truth: Arc<PathValue>,
}

/// A value whose shape does not fit its type, as the op's error.
pub(crate) fn shape_error(e: ValueError) -> OpError {
    OpError::invalid(e.0)
}
