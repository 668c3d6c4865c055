//! Node adapters of the camera design stage.

use super::*;
use fusegraph_engine::value::Table;
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};

fn table(columns: &[&str], rows: Vec<Vec<f64>>) -> Result<Table, OpError> {
    Table::new(
        columns.iter().map(|c| c.to_string()).collect(),
        rows.concat(),
    )
    .map_err(|e| OpError::invalid(e.0))
}

/// The lens from the `lens_mm` input if connected, else the `param` parameter.
fn lens_mm(inputs: &Inputs, params: &Params, param: &str) -> Result<f64, OpError> {
    Ok(match inputs.optional::<f64>("lens_mm")? {
        Some(l) => *l,
        None => params.float(param)?,
    })
}

pub(crate) struct FocalLengthOp(OpSpec);

impl FocalLengthOp {
    pub(crate) fn new() -> Self {
        FocalLengthOp(
            OpSpec::new(
                "design.focal_length",
                1,
                "Lens focal length f = s * Dmin / FOV and the nearest standard lens",
            )
            .param(ParamSpec::float("sensor_mm", 4.8, "mm", "Sensor width").at_least(0.1))
            .param(
                ParamSpec::float(
                    "min_distance_mm",
                    400.0,
                    "mm",
                    "Closest working distance Dmin",
                )
                .at_least(1.0),
            )
            .param(
                ParamSpec::float("fov_mm", 250.0, "mm", "Field of view wanted at Dmin")
                    .at_least(1.0),
            )
            .param(
                ParamSpec::float_list(
                    "lenses_mm",
                    &[4.0, 6.0, 8.0, 12.0, 16.0, 25.0, 35.0, 50.0],
                    "mm",
                    "Standard lenses",
                )
                .at_least(0.1),
            )
            .output("lens_mm", ValueType::Scalar, "The chosen lens, mm"),
        )
    }
}

impl Op for FocalLengthOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, _: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (s, d, fov) = (
            params.float("sensor_mm")?,
            params.float("min_distance_mm")?,
            params.float("fov_mm")?,
        );
        let f = focal_length_mm(s, d, fov);
        let lens = nearest_lens_mm(f, &params.float_list("lenses_mm")?)
            .ok_or_else(|| OpError::invalid("lenses_mm is empty"))?;
        ctx.metric("focal_mm", f);
        ctx.metric("lens_mm", lens);
        ctx.metric("fov_mm", s * d / lens);
        Ok(Outputs::new().with("lens_mm", lens))
    }
}

pub(crate) struct DepthOfFieldOp(OpSpec);

impl DepthOfFieldOp {
    pub(crate) fn new() -> Self {
        DepthOfFieldOp(
            OpSpec::new(
                "design.depth_of_field",
                1,
                "Blur circle c = A f (D1 - D2) / ((D1 - f) D2) over the working range",
            )
            .optional_input(
                "lens_mm",
                &[ValueType::Scalar],
                "Focal length from another node (overrides focal_mm)",
            )
            .param(ParamSpec::float("focal_mm", 8.0, "mm", "Focal length").at_least(0.1))
            .param(
                ParamSpec::float("f_number", 8.0, "", "Aperture f-number N (A = f / N)")
                    .at_least(0.5),
            )
            .param(
                ParamSpec::float("near_mm", 400.0, "mm", "Near end of the working range")
                    .at_least(1.0),
            )
            .param(
                ParamSpec::float("far_mm", 700.0, "mm", "Far end of the working range")
                    .at_least(1.0),
            )
            .param(
                ParamSpec::float(
                    "focus_mm",
                    0.0,
                    "mm",
                    "Focus distance D1 (0 = the one balancing the range)",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "circle_mm",
                    0.006,
                    "mm",
                    "Acceptable circle of confusion (one 6 um pixel)",
                )
                .at_least(1e-6),
            )
            .param(ParamSpec::float("pixel_mm", 0.006, "mm", "Pixel pitch").at_least(1e-6))
            .param(ParamSpec::int("steps", 31, "", "Distances tabulated").range(2.0, 10000.0))
            .output("table", ValueType::Table, "distance_mm, blur_um, blur_px"),
        )
    }
}

impl Op for DepthOfFieldOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let f = lens_mm(inputs, params, "focal_mm")?;
        let (near, far) = (params.float("near_mm")?, params.float("far_mm")?);
        if near >= far || near <= f {
            return Err(OpError::invalid(format!(
                "need focal {f} < near {near} < far {far} (mm)"
            )));
        }
        let focus = match params.float("focus_mm")? {
            d if d > 0.0 => d,
            _ => focus_for_range_mm(near, far),
        };
        if focus <= f {
            return Err(OpError::invalid(format!(
                "focus {focus} mm must be beyond the focal length {f} mm"
            )));
        }
        let aperture = f / params.float("f_number")?;
        let pixel = params.float("pixel_mm")?;
        let steps = params.count("steps")?;
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
            min_f_number(f, focus, near, far, params.float("circle_mm")?),
        );
        Ok(Outputs::new().with(
            "table",
            table(&["distance_mm", "blur_um", "blur_px"], rows)?,
        ))
    }
}

pub(crate) struct VergingAngleOp(OpSpec);

impl VergingAngleOp {
    pub(crate) fn new() -> Self {
        VergingAngleOp(
            OpSpec::new(
                "design.verging_angle",
                1,
                "Verging angle theta = atan(b / Dmin)",
            )
            .param(ParamSpec::float("baseline_mm", 55.0, "mm", "Baseline b").at_least(0.0))
            .param(
                ParamSpec::float(
                    "min_distance_mm",
                    400.0,
                    "mm",
                    "Distance Dmin where the axes cross",
                )
                .at_least(1.0),
            )
            .output("theta_deg", ValueType::Scalar, "Verging angle, deg"),
        )
    }
}

impl Op for VergingAngleOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, _: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let theta = verging_angle_deg(
            params.float("baseline_mm")?,
            params.float("min_distance_mm")?,
        );
        ctx.metric("theta_deg", theta);
        Ok(Outputs::new().with("theta_deg", theta))
    }
}

pub(crate) struct MonteCarloOp(OpSpec);

impl MonteCarloOp {
    pub(crate) fn new() -> Self {
        MonteCarloOp(
            OpSpec::new(
                "design.baseline_monte_carlo",
                2,
                "Triangulation variance against baseline: noisy projections of random points, DLT, repeated",
            )
            .optional_input("lens_mm", &[ValueType::Scalar], "Focal length from another node (overrides focal_mm)")
            .param(ParamSpec::float_list("baselines_mm", &[50.0, 100.0, 150.0, 200.0, 250.0], "mm", "Baselines").at_least(1.0))
            .param(ParamSpec::float("focal_mm", 8.0, "mm", "Focal length").at_least(0.1))
            .param(ParamSpec::float("pixel_mm", 0.006, "mm", "Pixel pitch").at_least(1e-6))
            .param(ParamSpec::int_list("image_px", &[800, 600], "px", "Image width and height").at_least(1.0).length(2))
            .param(ParamSpec::float("min_distance_mm", 400.0, "mm", "Where the axes cross (verging by atan(b / Dmin))").at_least(1.0))
            .param(ParamSpec::float_list("range_mm", &[400.0, 700.0], "mm", "Working range (near, far)").at_least(1.0).length(2))
            .param(ParamSpec::int("points", 100, "", "Random 3D points").range(1.0, 1e6))
            .param(ParamSpec::int("repetitions", 200, "", "Noisy repetitions per point (NMC)").range(2.0, 1e6))
            .param(ParamSpec::float("noise_px", 1.0, "px", "Image noise sigma").at_least(1e-9))
            .param(ParamSpec::int("seed", 1, "", "Seed").at_least(0.0))
            .param(ParamSpec::float_list(
                "paper_var_z_mm2",
                &[11.86, 2.84, 1.19, 0.65, 0.38],
                "mm2",
                "The paper's z variances, for comparison (one per baseline, or empty)",
            ))
            .param(ParamSpec::float("reference_baseline_mm", 100.0, "mm", "Baseline whose paper row fixes the fitted noise"))
            .output("table", ValueType::Table, "baseline_mm, verging_deg, var_x/y/z_mm2, fitted and paper z variances"),
        )
    }
}

impl Op for MonteCarloOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let image = params.int_list("image_px")?;
        let range = params.float_list("range_mm")?;
        let (&[w, h], &[near, far]) = (image.as_slice(), range.as_slice()) else {
            return Err(OpError::invalid(
                "image_px and range_mm take two numbers each",
            ));
        };
        let p = StudyParams {
            baselines_mm: params.float_list("baselines_mm")?,
            focal_mm: lens_mm(inputs, params, "focal_mm")?,
            pixel_mm: params.float("pixel_mm")?,
            image_px: [w as usize, h as usize],
            converge_mm: params.float("min_distance_mm")?,
            range_mm: [near, far],
            points: params.count("points")?,
            repetitions: params.count("repetitions")?,
            noise_px: params.float("noise_px")?,
            seed: params.int("seed")? as u64,
        };
        let study = baseline_study(&p).map_err(OpError::invalid)?;
        let paper = params.float_list("paper_var_z_mm2")?;
        let paper = (paper.len() == study.rows.len()).then_some(paper);
        // The noise at which the reference baseline's z variance equals the
        // paper's (variance scales with noise squared).
        let reference = params.float("reference_baseline_mm")?;
        let fit = paper.as_ref().and_then(|paper| {
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
                if let (Some(scale), Some(paper)) = (fit, &paper) {
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
        // The study's plot for the report (log-log: variance ~ 1 / b^2).
        let y: Vec<String> = columns
            .iter()
            .filter(|c| c.starts_with("var_z") || c.starts_with("paper"))
            .map(|c| c.to_string())
            .collect();
        let plot = crate::plot::LinePlot {
            x: "baseline_mm".into(),
            y,
            title: "Depth variance against baseline (Monte Carlo)".into(),
            x_label: "baseline, mm".into(),
            y_label: "variance of z, mm^2".into(),
            log_x: true,
            log_y: true,
            size_px: (700, 420),
        };
        if let Ok(png) = crate::plot::lines_png(&out, &plot) {
            ctx.figure(
                "variance",
                "Variance of triangulated depth against baseline, log-log (the paper's values where fitted)",
                fusegraph_engine::figure::FigureData::Png(png),
            )?;
        }
        Ok(Outputs::new().with("table", out))
    }
}
