//! `design.focal_length`: the lens for a field of view at a distance.

use crate::design::{focal_length_mm, nearest_lens_mm};
use fusegraph_engine::typed::prelude::*;

/// Lens focal length f = s * Dmin / FOV and the nearest standard lens
#[derive(Op)]
#[op(name = "design.focal_length", version = 1)]
pub struct FocalLength {
    /// Sensor width
    #[param(default = 4.8, unit = "mm", min = 0.1)]
    pub sensor_mm: f64,
    /// Closest working distance Dmin
    #[param(default = 400.0, unit = "mm", min = 1.0)]
    pub min_distance_mm: f64,
    /// Field of view wanted at Dmin
    #[param(default = 250.0, unit = "mm", min = 1.0)]
    pub fov_mm: f64,
    /// Standard lenses
    #[param(
        default = [4.0, 6.0, 8.0, 12.0, 16.0, 25.0, 35.0, 50.0],
        unit = "mm",
        min = 0.1
    )]
    pub lenses_mm: Vec<f64>,
}

#[derive(Inputs)]
pub struct FocalLengthInputs;

#[derive(Debug, Outputs)]
pub struct FocalLengthOutputs {
    /// The chosen lens, mm
    pub lens_mm: f64,
}

impl RunOp for FocalLength {
    type Inputs = FocalLengthInputs;
    type Outputs = FocalLengthOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        if self.lenses_mm.is_empty() {
            return vec![("lenses_mm", "give at least one lens".into())];
        }
        Vec::new()
    }

    fn run(&self, _: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (s, d, fov) = (self.sensor_mm, self.min_distance_mm, self.fov_mm);
        let f = focal_length_mm(s, d, fov);
        let lens = nearest_lens_mm(f, &self.lenses_mm)
            .ok_or_else(|| OpError::invalid("lenses_mm is empty"))?;
        ctx.metric("focal_mm", f);
        ctx.metric("lens_mm", lens);
        ctx.metric("fov_mm", s * d / lens);
        Ok(FocalLengthOutputs { lens_mm: lens })
    }
}
