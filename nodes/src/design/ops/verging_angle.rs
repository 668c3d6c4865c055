//! `design.verging_angle`: the angle at which the optical axes cross.

use crate::design::verging_angle_deg;
use fusegraph_engine::typed::prelude::*;

/// Verging angle theta = atan(b / Dmin)
#[derive(Op)]
#[op(name = "design.verging_angle", version = 1)]
pub struct VergingAngle {
    /// Baseline b
    #[param(default = 55.0, unit = "mm", min = 0.0)]
    pub baseline_mm: f64,
    /// Distance Dmin where the axes cross
    #[param(default = 400.0, unit = "mm", min = 1.0)]
    pub min_distance_mm: f64,
}

#[derive(Inputs)]
pub struct VergingAngleInputs;

#[derive(Debug, Outputs)]
pub struct VergingAngleOutputs {
    /// Verging angle, deg
    pub theta_deg: f64,
}

impl RunOp for VergingAngle {
    type Inputs = VergingAngleInputs;
    type Outputs = VergingAngleOutputs;

    fn run(&self, _: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let theta = verging_angle_deg(self.baseline_mm, self.min_distance_mm);
        ctx.metric("theta_deg", theta);
        Ok(VergingAngleOutputs { theta_deg: theta })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_papers_rig_verges_by_7_8_degrees() {
        let op = VergingAngle {
            baseline_mm: 55.0,
            min_distance_mm: 400.0,
        };
        let mut ctx = RunCtx::new("verge", std::path::Path::new("."));
        let out = op.run(VergingAngleInputs, &mut ctx).unwrap();
        assert!((out.theta_deg - 7.82908).abs() < 1e-5, "{}", out.theta_deg);
        assert_eq!(ctx.metrics()["theta_deg"], out.theta_deg);
    }
}
