//! `design.baseline_monte_carlo`: triangulation variance against baseline.

use crate::design::figures::variance_png;
use crate::design::tables::table;
use crate::design::{StudyParams, baseline_study};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Table;

/// Triangulation variance against baseline: noisy projections of random
/// points, DLT, repeated
#[derive(Op)]
#[op(name = "design.baseline_monte_carlo", version = 2)]
pub struct BaselineMonteCarlo {
    /// Baselines
    #[param(default = [50.0, 100.0, 150.0, 200.0, 250.0], unit = "mm", min = 1.0)]
    pub baselines_mm: Vec<f64>,
    /// Focal length
    #[param(default = 8.0, unit = "mm", min = 0.1)]
    pub focal_mm: f64,
    /// Pixel pitch
    #[param(default = 0.006, unit = "mm", min = 1e-6)]
    pub pixel_mm: f64,
    /// Image width and height
    #[param(default = [800, 600], unit = "px", min = 1)]
    pub image_px: [usize; 2],
    /// Where the axes cross (verging by atan(b / Dmin))
    #[param(default = 400.0, unit = "mm", min = 1.0)]
    pub min_distance_mm: f64,
    /// Working range (near, far)
    #[param(default = [400.0, 700.0], unit = "mm", min = 1.0)]
    pub range_mm: [f64; 2],
    /// Random 3D points
    #[param(default = 100, min = 1, max = 1e6)]
    pub points: usize,
    /// Noisy repetitions per point (NMC)
    #[param(default = 200, min = 2, max = 1e6)]
    pub repetitions: usize,
    /// Image noise sigma
    #[param(default = 1.0, unit = "px", min = 1e-9)]
    pub noise_px: f64,
    /// Seed
    #[param(default = 1, min = 0)]
    pub seed: i64,
    /// The paper's z variances, for comparison (one per baseline, or empty)
    #[param(default = [11.86, 2.84, 1.19, 0.65, 0.38], unit = "mm2")]
    pub paper_var_z_mm2: Vec<f64>,
    /// Baseline whose paper row fixes the fitted noise
    #[param(default = 100.0, unit = "mm")]
    pub reference_baseline_mm: f64,
}

#[derive(Inputs)]
pub struct BaselineMonteCarloInputs {
    /// Focal length from another node (overrides focal_mm)
    pub lens_mm: Option<f64>,
}

#[derive(Debug, Outputs)]
pub struct BaselineMonteCarloOutputs {
    /// baseline_mm, verging_deg, var_x/y/z_mm2, fitted and paper z variances
    pub table: Table,
}

impl RunOp for BaselineMonteCarlo {
    type Inputs = BaselineMonteCarloInputs;
    type Outputs = BaselineMonteCarloOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let p = StudyParams {
            baselines_mm: self.baselines_mm.clone(),
            focal_mm: inputs.lens_mm.unwrap_or(self.focal_mm),
            pixel_mm: self.pixel_mm,
            image_px: self.image_px,
            converge_mm: self.min_distance_mm,
            range_mm: self.range_mm,
            points: self.points,
            repetitions: self.repetitions,
            noise_px: self.noise_px,
            seed: self.seed as u64,
        };
        let study = baseline_study(&p).map_err(OpError::invalid)?;
        let paper = &self.paper_var_z_mm2;
        let paper = (paper.len() == study.rows.len()).then_some(paper);
        // The noise at which the reference baseline's z variance equals the
        // paper's (variance scales with noise squared).
        let reference = self.reference_baseline_mm;
        let fit = paper.and_then(|paper| {
            let i = study
                .rows
                .iter()
                .position(|r| (r.baseline_mm - reference).abs() < 1e-9)?;
            Some((paper[i] / study.rows[i].variance_mm2[2]).sqrt())
        });
        if let Some(scale) = fit {
            ctx.metric("noise_px_fitting_paper", p.noise_px * scale);
        }
        let mut columns = vec![
            "baseline_mm",
            "verging_deg",
            "var_x_mm2",
            "var_y_mm2",
            "var_z_mm2",
        ];
        if fit.is_some() {
            columns.extend(["var_z_fitted_mm2", "paper_var_z_mm2"]);
        }
        let rows = study
            .rows
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let mut row = vec![
                    r.baseline_mm,
                    r.verging_deg,
                    r.variance_mm2[0],
                    r.variance_mm2[1],
                    r.variance_mm2[2],
                ];
                if let (Some(scale), Some(paper)) = (fit, paper) {
                    row.extend([r.variance_mm2[2] * scale * scale, paper[i]]);
                }
                ctx.metric(&format!("var_z_mm2_b{}", r.baseline_mm), r.variance_mm2[2]);
                row
            })
            .collect();
        if let Some(slope) = study.loglog_slope_z() {
            ctx.metric("loglog_slope_z", slope);
        }
        let out = table(&columns, rows)?;
        if let Ok(png) = variance_png(&out) {
            ctx.figure(
                "variance",
                "Variance of triangulated depth against baseline, log-log (the paper's values where fitted)",
                FigureData::Png(png),
            )?;
        }
        Ok(BaselineMonteCarloOutputs { table: out })
    }
}
