//! The `design.*` ops: one file per op, each its declaration and thin adapter.

mod baseline_monte_carlo;
mod depth_of_field;
mod focal_length;
mod verging_angle;

pub use baseline_monte_carlo::{
    BaselineMonteCarlo, BaselineMonteCarloInputs, BaselineMonteCarloOutputs,
};
pub use depth_of_field::{DepthOfField, DepthOfFieldInputs, DepthOfFieldOutputs};
pub use focal_length::{FocalLength, FocalLengthInputs, FocalLengthOutputs};
pub use verging_angle::{VergingAngle, VergingAngleInputs, VergingAngleOutputs};
