//! `design.depth_of_field`: the blur circle over the working range.

use crate::design::tables::table;
use crate::design::{blur_circle_mm, focus_for_range_mm, min_f_number};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Table;

/// Blur circle c = A f (D1 - D2) / ((D1 - f) D2) over the working range
#[derive(Op)]
#[op(name = "design.depth_of_field", version = 1)]
pub struct DepthOfField {
    /// Focal length
    #[param(default = 8.0, unit = "mm", min = 0.1)]
    pub focal_mm: f64,
    /// Aperture f-number N (A = f / N)
    #[param(default = 8.0, min = 0.5)]
    pub f_number: f64,
    /// Near end of the working range
    #[param(default = 400.0, unit = "mm", min = 1.0)]
    pub near_mm: f64,
    /// Far end of the working range
    #[param(default = 700.0, unit = "mm", min = 1.0)]
    pub far_mm: f64,
    /// Focus distance D1 (0 = the one balancing the range)
    #[param(default = 0.0, unit = "mm", min = 0.0)]
    pub focus_mm: f64,
    /// Acceptable circle of confusion (one 6 um pixel)
    #[param(default = 0.006, unit = "mm", min = 1e-6)]
    pub circle_mm: f64,
    /// Pixel pitch
    #[param(default = 0.006, unit = "mm", min = 1e-6)]
    pub pixel_mm: f64,
    /// Distances tabulated
    #[param(default = 31, min = 2, max = 10000)]
    pub steps: usize,
}

#[derive(Inputs)]
pub struct DepthOfFieldInputs {
    /// Focal length from another node (overrides focal_mm)
    pub lens_mm: Option<f64>,
}

#[derive(Debug, Outputs)]
pub struct DepthOfFieldOutputs {
    /// distance_mm, blur_um, blur_px
    pub table: Table,
}

impl RunOp for DepthOfField {
    type Inputs = DepthOfFieldInputs;
    type Outputs = DepthOfFieldOutputs;

    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        let (near, far) = (self.near_mm, self.far_mm);
        let mut problems = Vec::new();
        if near >= far {
            problems.push(("far_mm", format!("need near {near} < far {far} (mm)")));
        }
        // With the lens from another node, its focal length is known at run time.
        if !wired.has("lens_mm") {
            let f = self.focal_mm;
            if near <= f {
                problems.push(("near_mm", format!("need focal {f} < near {near} (mm)")));
            }
            if self.focus_mm > 0.0 && self.focus_mm <= f {
                problems.push((
                    "focus_mm",
                    format!(
                        "focus {} mm must be beyond the focal length {f} mm",
                        self.focus_mm
                    ),
                ));
            }
        }
        problems
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let f = inputs.lens_mm.unwrap_or(self.focal_mm);
        let (near, far) = (self.near_mm, self.far_mm);
        if near >= far || near <= f {
            return Err(OpError::invalid(format!(
                "need focal {f} < near {near} < far {far} (mm)"
            )));
        }
        let focus = match self.focus_mm {
            d if d > 0.0 => d,
            _ => focus_for_range_mm(near, far),
        };
        if focus <= f {
            return Err(OpError::invalid(format!(
                "focus {focus} mm must be beyond the focal length {f} mm"
            )));
        }
        let aperture = f / self.f_number;
        let pixel = self.pixel_mm;
        let steps = self.steps;
        let rows: Vec<Vec<f64>> = (0..steps)
            .map(|i| {
                let d = near + (far - near) * i as f64 / (steps - 1) as f64;
                let c = blur_circle_mm(aperture, f, focus, d);
                vec![d, c * 1e3, c / pixel]
            })
            .collect();
        let worst = rows.iter().map(|r| r[1]).fold(0.0, f64::max);
        ctx.metric("focus_mm", focus);
        ctx.metric("max_blur_um", worst);
        ctx.metric("max_blur_px", worst / 1e3 / pixel);
        ctx.metric(
            "min_f_number",
            min_f_number(f, focus, near, far, self.circle_mm),
        );
        Ok(DepthOfFieldOutputs {
            table: table(&["distance_mm", "blur_um", "blur_px"], rows)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn op() -> DepthOfField {
        DepthOfField {
            focal_mm: 8.0,
            f_number: 8.0,
            near_mm: 400.0,
            far_mm: 700.0,
            focus_mm: 0.0,
            circle_mm: 0.006,
            pixel_mm: 0.006,
            steps: 4,
        }
    }

    #[test]
    fn the_lens_input_overrides_focal_mm_and_the_range_is_tabulated() {
        let mut ctx = RunCtx::new("dof", std::path::Path::new("."));
        let inputs = DepthOfFieldInputs {
            lens_mm: Some(12.0),
        };
        let out = op().run(inputs, &mut ctx).unwrap();
        assert_eq!(
            out.table.column("distance_mm").unwrap(),
            [400.0, 500.0, 600.0, 700.0]
        );
        // Focused at the harmonic mean of the range, the blur is equal at both ends.
        let blur = out.table.column("blur_um").unwrap();
        assert!((blur[0] - blur[3]).abs() < 1e-9 && blur[0] > blur[1]);
        assert!((ctx.metrics()["focus_mm"] - 2.0 * 400.0 * 700.0 / 1100.0).abs() < 1e-9);
        let e = DepthOfField {
            far_mm: 300.0,
            ..op()
        }
        .run(DepthOfFieldInputs { lens_mm: None }, &mut ctx)
        .unwrap_err();
        assert!(
            e.to_string().contains("need focal 8 < near 400 < far 300"),
            "{e}"
        );
    }
}
