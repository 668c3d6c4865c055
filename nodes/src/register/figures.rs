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

/// Each target (dot, id) with the ellipse 95 % of its predicted errors fall
/// within (chi-square(2) quantile 5.991 of the marginal covariance), in
/// three panels: the frame's x-y, x-z and y-z planes, each scaled to its
/// largest ellipse and centred on each target in turn. An SVG document.
pub(crate) fn error_ellipses_svg(
    ids: &[u32],
    points: &[Point3<f64>],
    covariances: &[nalgebra::Matrix3<f64>],
    frame: &str,
) -> String {
    use std::fmt::Write;
    const PANEL: f64 = 220.0;
    const CHI2_2_95: f64 = 5.991;
    let planes = [
        (0usize, 1usize, "x", "y"),
        (0, 2, "x", "z"),
        (1, 2, "y", "z"),
    ];
    let rows = ids.len().max(1);
    let (width, height) = (3.0 * PANEL + 40.0, rows as f64 * PANEL + 60.0);
    let mut svg = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" font-size="12">"#
    );
    let _ = write!(
        svg,
        r#"<text x="10" y="18">Predicted 95 % error ellipse of each target ({frame}, mm); grid step in each panel</text>"#
    );
    for (row, ((id, p), c)) in ids.iter().zip(points).zip(covariances).enumerate() {
        for (col, &(a, b, la, lb)) in planes.iter().enumerate() {
            let (x0, y0) = (20.0 + col as f64 * PANEL, 30.0 + row as f64 * PANEL);
            let (cx, cy) = (x0 + PANEL / 2.0, y0 + PANEL / 2.0);
            let m = nalgebra::Matrix2::new(c[(a, a)], c[(a, b)], c[(b, a)], c[(b, b)]);
            let e = m.symmetric_eigen();
            let radii = e.eigenvalues.map(|l| (l.max(0.0) * CHI2_2_95).sqrt());
            // The panel spans twice the largest semi-axis (at least 0.5 mm).
            let scale = 0.45 * PANEL / radii.max().max(0.25);
            let angle = e.eigenvectors[(1, 0)]
                .atan2(e.eigenvectors[(0, 0)])
                .to_degrees();
            let _ = write!(
                svg,
                r##"<rect x="{x0}" y="{y0}" width="{w}" height="{w}" fill="none" stroke="#ccc"/>"##,
                w = PANEL - 10.0
            );
            // A grid of a round step, 25 px or more apart.
            let step_mm = [0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0]
                .into_iter()
                .find(|mm| mm * scale >= 25.0)
                .unwrap_or(20.0);
            let step = step_mm * scale;
            let mut k = -((PANEL / 2.0 / step).floor());
            while k * step <= PANEL / 2.0 - 10.0 {
                let (gx, gy) = (cx + k * step, cy + k * step);
                if gx > x0 && gx < x0 + PANEL - 10.0 {
                    let _ = write!(
                        svg,
                        r##"<line x1="{gx:.1}" y1="{y0}" x2="{gx:.1}" y2="{:.1}" stroke="#eee"/>"##,
                        y0 + PANEL - 10.0
                    );
                }
                if gy > y0 && gy < y0 + PANEL - 10.0 {
                    let _ = write!(
                        svg,
                        r##"<line x1="{x0}" y1="{gy:.1}" x2="{:.1}" y2="{gy:.1}" stroke="#eee"/>"##,
                        x0 + PANEL - 10.0
                    );
                }
                k += 1.0;
            }
            let _ = write!(
                svg,
                r##"<ellipse cx="{cx:.1}" cy="{cy:.1}" rx="{:.1}" ry="{:.1}" transform="rotate({angle:.2} {cx:.1} {cy:.1})" fill="rgba(220,40,40,0.15)" stroke="#c22"/><circle cx="{cx:.1}" cy="{cy:.1}" r="3" fill="#c22"/>"##,
                radii[0] * scale,
                radii[1] * scale
            );
            let _ = write!(
                svg,
                r#"<text x="{:.1}" y="{:.1}">target {id} ({:.1}, {:.1}, {:.1}): {la} right, {lb} down</text><text x="{:.1}" y="{:.1}">grid {step_mm} mm</text>"#,
                x0 + 4.0,
                y0 + 14.0,
                p.x,
                p.y,
                p.z,
                x0 + 4.0,
                y0 + PANEL - 16.0
            );
        }
    }
    svg.push_str("</svg>");
    svg
}

/// The skin's samples seen along each axis of their frame, each coloured by
/// how far a deformation moved it (white none, dark red the peak), with a
/// tick every `step` of the colour scale.
pub(crate) fn field_on_skin_svg(
    points: &[Point3<f64>],
    displacements: &[Vector3<f64>],
    frame: &str,
) -> String {
    use std::fmt::Write;
    const PANEL: f64 = 260.0;
    let peak = displacements.iter().map(|u| u.norm()).fold(0.0, f64::max);
    let (width, height) = (3.0 * PANEL + 40.0, PANEL + 70.0);
    let mut svg = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" font-size="12">"#
    );
    let _ = write!(
        svg,
        r#"<text x="10" y="18">The deformation's displacement on the skin both see ({frame}, mm): white 0, dark red {peak:.2} mm</text>"#
    );
    let mut lo = Point3::from([f64::INFINITY; 3]);
    let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let span = (hi - lo).max().max(1e-9);
    let scale = (PANEL - 20.0) / span;
    // At most about 4,000 dots: every k-th sample.
    let every = points.len().div_ceil(4000).max(1);
    for (col, (a, b, la, lb)) in [
        (0usize, 1usize, "x", "y"),
        (0, 2, "x", "z"),
        (1, 2, "y", "z"),
    ]
    .into_iter()
    .enumerate()
    {
        let x0 = 20.0 + col as f64 * PANEL;
        let _ = write!(
            svg,
            r##"<rect x="{x0}" y="30" width="{w}" height="{w}" fill="none" stroke="#ccc"/><text x="{tx}" y="{ty}">{la} right, {lb} down</text>"##,
            w = PANEL - 10.0,
            tx = x0 + 4.0,
            ty = PANEL + 40.0
        );
        for (p, u) in points.iter().zip(displacements).step_by(every) {
            let t = if peak > 0.0 { u.norm() / peak } else { 0.0 };
            let (r, g) = (255.0 - 115.0 * t, 255.0 * (1.0 - t));
            let _ = write!(
                svg,
                r#"<circle cx="{:.1}" cy="{:.1}" r="1.6" fill="rgb({:.0},{:.0},{:.0})"/>"#,
                x0 + 5.0 + (p[a] - lo[a]) * scale,
                35.0 + (p[b] - lo[b]) * scale,
                r,
                g,
                g
            );
        }
    }
    svg.push_str("</svg>");
    svg
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_target_gets_an_ellipse_in_three_planes_sized_by_its_covariance() {
        // Two targets, one spread 4 times wider along x: three ellipses
        // each, and in the x-y panel the wide one's x semi-axis is the
        // panel's 0.45 (scaled to its own largest axis), its y one a quarter.
        let covariances = [
            nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(0.16, 0.01, 0.01)),
            nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(0.01, 0.01, 0.01)),
        ];
        let points = [Point3::new(1.0, 2.0, 500.0), Point3::new(-3.0, 0.0, 510.0)];
        let svg = error_ellipses_svg(&[4, 9], &points, &covariances, "camera_left");
        assert!(svg.starts_with("<svg") && svg.ends_with("</svg>"));
        assert_eq!(svg.matches("<ellipse").count(), 6);
        assert!(svg.contains("target 4 (1.0, 2.0, 500.0)") && svg.contains("target 9"));
        let first = &svg[svg.find("<ellipse").unwrap()..];
        let attribute = |name: &str| -> f64 {
            let start = first.find(&format!("{name}=\"")).unwrap() + name.len() + 2;
            first[start..].split('"').next().unwrap().parse().unwrap()
        };
        assert!((attribute("rx") - 99.0).abs() < 0.1, "{}", attribute("rx"));
        assert!((attribute("ry") - 24.75).abs() < 0.1, "{}", attribute("ry"));
    }
}
