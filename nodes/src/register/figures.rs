//! Figures of the registration ops for the report: the ICP trace, the clouds
//! before and after ICP, and a 3D view of a fused result.

use crate::cloud::convert::cloud_points;
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::value::{Markers, PointCloud, Table};
use fusegraph_engine::{OpError, RunCtx};
use nalgebra::{Isometry3, Point3, Vector3};

/// The fused result in the source's frame (the camera's, for MRI onto camera)
/// as a 3D view for the report: the source cloud in its colours (grey
/// without), the target mapped into it in blue, targets as red balls.
pub(crate) fn fused_view(
    ctx: &mut RunCtx,
    source: &PointCloud,
    target: &PointCloud,
    source_to_target: &Isometry3<f64>,
    targets: Option<&Markers>,
) -> Result<(), OpError> {
    const MAX_POINTS: usize = 40_000;
    let (mut xyz, mut rgb) = (Vec::new(), Vec::new());
    let mut push = |p: &Point3<f64>, c: [u8; 3]| {
        xyz.extend([p.x as f32, p.y as f32, p.z as f32]);
        rgb.extend(c);
    };
    let step = (source.len() / MAX_POINTS).max(1);
    for (i, p) in cloud_points(source).iter().enumerate().step_by(step) {
        let c = source
            .colors
            .as_ref()
            .map_or([200, 200, 200], |c| [c[3 * i], c[3 * i + 1], c[3 * i + 2]]);
        push(p, c);
    }
    let back = source_to_target.inverse();
    let step = (target.len() / MAX_POINTS).max(1);
    for p in cloud_points(target).iter().step_by(step) {
        push(&(back * p), [70, 130, 255]);
    }
    if let Some(t) = targets {
        let into_source = if t.frame == target.frame {
            back
        } else {
            Isometry3::identity()
        };
        for c in t.positions_mm.chunks(3) {
            let centre = into_source * Point3::new(c[0], c[1], c[2]);
            // A ball of 2 mm radius on a 0.5 mm grid.
            for i in -4..=4 {
                for j in -4..=4 {
                    for k in -4..=4 {
                        let d = Vector3::new(i as f64, j as f64, k as f64) * 0.5;
                        if d.norm() <= 2.0 {
                            push(&(centre + d), [255, 40, 40]);
                        }
                    }
                }
            }
        }
    }
    ctx.figure(
        "fused",
        "The fused result in the source's frame: source cloud (its colours), target mapped onto it (blue), targets (red)",
        FigureData::Points3d { xyz, rgb },
    )
}

/// The ICP trace plot and the clouds before and after, for the report.
pub(crate) fn icp_figures(
    ctx: &mut RunCtx,
    trace: &Table,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: &Isometry3<f64>,
    fin: &Isometry3<f64>,
) -> Result<(), OpError> {
    let plot = crate::plot::LinePlot {
        x: "iteration".into(),
        y: vec!["rmse_mm".into()],
        title: "ICP: RMSE of the kept pairs".into(),
        x_label: "iteration (all voxel stages)".into(),
        y_label: "RMSE, mm".into(),
        log_x: false,
        log_y: false,
        size_px: (700, 380),
    };
    if let Ok(png) = crate::plot::lines_png(trace, &plot) {
        ctx.figure(
            "trace",
            "ICP: RMSE of the kept pairs by iteration",
            FigureData::Png(png),
        )?;
    }
    // At most 20,000 points of each cloud: enough to see the fit.
    let thin = |pts: &[Point3<f64>], iso: &Isometry3<f64>| -> Vec<Point3<f64>> {
        let step = (pts.len() / 20_000).max(1);
        pts.iter().step_by(step).map(|p| iso * p).collect()
    };
    let (before, after) = (thin(source, init), thin(source, fin));
    let target = thin(target, &Isometry3::identity());
    if let Some((rgb, w, h)) = crate::plot::overlay_panels(&target, &[&before, &after], 420)
        && let Ok(png) = crate::plot::png_bytes(&rgb, w, h)
    {
        ctx.figure(
            "before_after",
            "Side view: source (orange) over target (grey), from the initial transform (left) and after ICP (right)",
            FigureData::Png(png),
        )?;
    }
    Ok(())
}
