//! Camera setup design (the paper's module B): lens focal length, depth of
//! field, verging angle, and the Monte Carlo study of triangulation reliability
//! against baseline.

mod figures;
mod monte_carlo;
pub mod ops;
mod optics;
mod tables;

pub use monte_carlo::{BaselineStudy, StudyParams, VarianceRow, baseline_study, triangulate_dlt};
pub use optics::{
    blur_circle_mm, focal_length_mm, focus_for_range_mm, min_f_number, nearest_lens_mm,
    verging_angle_deg,
};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `design.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::FocalLength>()?;
    registry.add::<ops::DepthOfField>()?;
    registry.add::<ops::VergingAngle>()?;
    registry.add::<ops::BaselineMonteCarlo>()?;
    Ok(())
}
