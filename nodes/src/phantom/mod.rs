//! The ground-truth phantom: a synthetic breast phantom with MRI-bright markers,
//! imaged by MRI (a DICOM series) and by a verging stereo rig (calibration and
//! phantom image pairs), with `ground_truth.json` holding every true position.
//!
//! The renderer, MRI simulator and geometry are our own: no crate simulates
//! partial-volume MRI or renders through an OpenCV-exact distortion model.

mod camera_surface;
mod dicom_series;
mod generate;
mod mri;
mod ops;
mod render;
mod rig;
mod scenes;
mod shape;
mod texture;
mod true_disparity;
mod truth;

pub use camera_surface::{SimulatedSurface, SurfaceSimParams, simulate_camera_surface};
pub use generate::{Generated, PhantomConfig, PhantomSize, generate};
pub(crate) use ops::{optional_truth_input, truth_input};
pub use rig::Rig;
pub use scenes::MARKER_GREEN;
pub use shape::{Lesion, Marker, Material, PhantomShape, ShapeParams};
pub use true_disparity::{SceneLabel, TrueDisparity, ViewScene, true_disparity};
pub use truth::*;

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `phantom.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(ops::GenerateOp::new()))?;
    registry.register(Arc::new(ops::CameraSurfaceOp::new()))?;
    registry.register(Arc::new(ops::RigPoseOp::new()))?;
    registry.register(Arc::new(ops::LesionsOp::new()))?;
    registry.register(Arc::new(ops::TrueDisparityOp::new()))?;
    Ok(())
}
