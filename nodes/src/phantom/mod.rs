//! The ground-truth phantom: a synthetic breast phantom with MRI-bright markers,
//! imaged by MRI (a DICOM series) and by a verging stereo rig (calibration and
//! phantom image pairs), with `ground_truth.json` holding every true position.
//!
//! The renderer, MRI simulator and geometry are our own: no crate simulates
//! partial-volume MRI or renders through an OpenCV-exact distortion model.

mod board_rays;
mod camera_surface;
mod conditions;
mod defocus;
mod dicom_series;
mod footprint;
mod generate;
mod lighting;
mod motion;
mod moved_shape;
mod mri;
pub mod ops;
mod props;
mod render;
mod rig;
mod row_materials;
mod scenes;
mod sensor;
mod shape;
mod shape_near;
mod texture;
mod true_disparity;
mod truth;
mod truth_input;

pub use camera_surface::{SimulatedSurface, SurfaceSimParams, simulate_camera_surface};
pub use conditions::{Conditions, ConditionsPreset};
pub use generate::{Generated, PhantomConfig, PhantomSize, generate};
pub use motion::{MotionField, MotionKind};
pub use moved_shape::{MovedHit, MovedShape};
pub use props::Prop;
pub use rig::Rig;
pub use scenes::MARKER_GREEN;
pub use shape::{Lesion, Marker, Material, PhantomShape, ShapeParams, Triples};
pub use true_disparity::{SceneLabel, TrueDisparity, ViewScene, true_disparity};
pub use truth::*;
pub(crate) use truth_input::load_truth;

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `phantom.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::Generate>()?;
    registry.add::<ops::CameraSurface>()?;
    registry.add::<ops::RigPose>()?;
    registry.add::<ops::Lesions>()?;
    registry.add::<ops::TrueRig>()?;
    registry.add::<ops::TrueDisparity>()?;
    Ok(())
}
