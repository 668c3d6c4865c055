//! `calib.cross_validate`: two calibrations from disjoint halves of one
//! camera's views, compared in projection across the image.

use super::SolverParams;
use super::calibrate_camera::{DistinctViews, distinct_views};
use crate::calib::{CrossValidation, cross_validate};
use crate::io::viridis;
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Table;
use std::fmt::Write as _;

/// Cross-validation as mrcal does it: the views split into two halves
/// (alternate views), each calibrated alone, and how far apart the two
/// models project the same rays across the image (a rotation between them
/// fitted away); a model its views do not pin down shows it here, not in
/// its RMS -> Table
#[derive(Op)]
#[op(name = "calib.cross_validate", version = 1)]
pub struct CrossValidate {
    #[param(flatten)]
    pub solver: SolverParams,
    /// Grid cells across the image (rows in proportion)
    #[param(default = 32, min = 2, max = 400)]
    pub columns: usize,
    /// Fit away a rotation between the two models' camera frames (the
    /// extrinsics absorb it)
    #[param(default = true)]
    pub fit_rotation: bool,
}

#[derive(Inputs)]
pub struct CrossValidateInputs {
    /// find_chessboard's corners of one camera (6 or more distinct views)
    pub corners: Arc<Table>,
}

#[derive(Outputs)]
pub struct CrossValidateOutputs {
    /// u_px, v_px (grid cell centres) and difference_px between the two
    /// models' projections there
    pub differences: Table,
}

impl RunOp for CrossValidate {
    type Inputs = CrossValidateInputs;
    type Outputs = CrossValidateOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        self.solver.check()
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let DistinctViews {
            ids,
            views,
            size: (w, h),
        } = distinct_views(&inputs.corners, ctx)?;
        let c = cross_validate(
            &views,
            w,
            h,
            self.solver.distortion_mask()?,
            self.columns,
            self.fit_rotation,
        )
        .map_err(OpError::invalid)?;
        ctx.metric("mean_px", c.mean_px);
        ctx.metric("p95_px", c.p95_px);
        ctx.metric("max_px", c.max_px);
        for (half, name) in c.halves.iter().zip(["even", "odd"]) {
            ctx.metric(&format!("{name}_rms_px"), half.rms_px);
            ctx.metric(&format!("{name}_fx_px"), half.camera.fx);
        }
        let split = |parity: usize| {
            ids.iter()
                .skip(parity)
                .step_by(2)
                .map(u32::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        };
        ctx.note(format!("halves: views {} and views {}", split(0), split(1)));
        ctx.figure(
            "difference",
            "How far apart the two halves' models project the same rays, px, across the image",
            FigureData::Svg(heat_map_svg(&c, w, h)),
        )?;
        let data: Vec<f64> = c
            .differences
            .iter()
            .flat_map(|&(u, v, d)| [u, v, d])
            .collect();
        let differences = Table::new(
            ["u_px", "v_px", "difference_px"].map(String::from).to_vec(),
            data,
        )
        .map_err(|e| OpError::invalid(e.0))?;
        Ok(CrossValidateOutputs { differences })
    }
}

/// The differences as an SVG heat map over the `w x h` px image (viridis
/// from 0 to the largest), with a colour bar.
fn heat_map_svg(c: &CrossValidation, w: usize, h: usize) -> String {
    let (cols, rows) = (c.columns, c.differences.len() / c.columns.max(1));
    let scale = 640.0 / w as f64;
    let (pw, ph) = (640.0, h as f64 * scale);
    let (cw, ch) = (pw / cols as f64, ph / rows.max(1) as f64);
    // Up to the 95th percentile (above it saturated): one wild corner of
    // the image would leave the rest one colour.
    let top = c.p95_px.max(1e-9);
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" font-family=\"sans-serif\" font-size=\"12\">\n",
        pw + 90.0,
        ph + 10.0
    );
    for (k, d) in c.differences.iter().enumerate() {
        let [r, g, b] = viridis((d.2 / top).clamp(0.0, 1.0));
        let _ = writeln!(
            svg,
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.2}\" height=\"{:.2}\" fill=\"rgb({r},{g},{b})\"/>",
            (k % cols) as f64 * cw,
            (k / cols) as f64 * ch,
            cw + 0.5,
            ch + 0.5
        );
    }
    for i in 0..=20 {
        let t = i as f64 / 20.0;
        let [r, g, b] = viridis(t);
        let _ = writeln!(
            svg,
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"16\" height=\"{:.2}\" fill=\"rgb({r},{g},{b})\"/>",
            pw + 12.0,
            ph * (1.0 - t) - ph / 21.0 + 5.0,
            ph / 21.0 + 0.5
        );
    }
    let _ = writeln!(
        svg,
        "<text x=\"{:.1}\" y=\"16\">&#8805; {:.2} px</text>\n<text x=\"{:.1}\" y=\"{:.1}\">0 px</text>\n</svg>",
        pw + 32.0,
        top,
        pw + 32.0,
        ph + 4.0
    );
    svg
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::camera_calibration::tests::{true_camera, true_poses, views_of, with_noise};
    use crate::calib::tables::corners_table;
    use crate::stereo::ops::testing::{ctx, defaults};

    /// The corners table of `n` noisy views of the true camera (the five
    /// test poses, then again turned a little).
    fn corners(n: usize) -> Arc<Table> {
        let mut poses = true_poses();
        let turned: Vec<_> = poses
            .iter()
            .map(|p| {
                let mut q = *p;
                q.rotation =
                    nalgebra::UnitQuaternion::from_euler_angles(0.1, -0.08, 0.3) * q.rotation;
                q
            })
            .collect();
        poses.extend(turned);
        let views = with_noise(views_of(&true_camera(), &poses[..n]), 0.2, 9);
        let found: Vec<_> = views
            .into_iter()
            .enumerate()
            .map(|(i, v)| (i as u32, v.image_px, 800, 600))
            .collect();
        Arc::new(corners_table(&found, 9, 25.0).unwrap())
    }

    #[test]
    fn ten_views_give_the_differences_a_table_and_a_figure() {
        let op: CrossValidate = defaults();
        let mut c = ctx();
        let out = op
            .run(
                CrossValidateInputs {
                    corners: corners(10),
                },
                &mut c,
            )
            .unwrap();
        assert_eq!(out.differences.row_count(), 32 * 24);
        assert_eq!(c.figures().len(), 1);
        let m = c.into_metrics();
        assert!(m["mean_px"] > 0.0 && m["mean_px"] <= m["p95_px"] && m["p95_px"] <= m["max_px"]);
    }

    #[test]
    fn too_few_views_are_an_error_saying_how_many() {
        let op: CrossValidate = defaults();
        let e = op
            .run(
                CrossValidateInputs {
                    corners: corners(5),
                },
                &mut ctx(),
            )
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("5 views: cross-validation calibrates two disjoint halves"),
            "{e}"
        );
    }
}
