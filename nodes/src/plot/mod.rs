//! `plot.lines`: line plots of table columns as PNG, with plotters (text drawn
//! with the bundled DejaVu Sans, so no system font library is needed); and the
//! pictures other ops attach to the report.

pub mod ops;
mod overlay;
pub use overlay::{circles_over_slices, mask_over_slice, overlay_panels};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use fusegraph_engine::value::Table;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

/// Registers the `plot.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::Lines>()
}

/// What to draw.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    /// Column on the x axis.
    pub x: String,
    /// Columns drawn as lines.
    pub y: Vec<String>,
    /// Title.
    pub title: String,
    /// Axis labels.
    pub x_label: String,
    /// Axis labels.
    pub y_label: String,
    /// Logarithmic axes.
    pub log_x: bool,
    /// Logarithmic axes.
    pub log_y: bool,
    /// Image size, px.
    pub size_px: (u32, u32),
}

pub(crate) fn register_font() {
    static FONT: Once = Once::new();
    FONT.call_once(|| {
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            include_bytes!("../../assets/DejaVuSans.ttf"),
        );
    });
}

/// Draws `plot` of `table` into a PNG at `path`.
pub fn draw_lines(table: &Table, plot: &LinePlot, path: &Path) -> Result<(), String> {
    let png = lines_png(table, plot)?;
    std::fs::write(path, png).map_err(|e| format!("{}: {e}", path.display()))
}

/// 8-bit RGB pixels (`width x height`) as PNG file bytes.
pub fn png_bytes(rgb: &[u8], width: usize, height: usize) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(
            rgb,
            width as u32,
            height as u32,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| e.to_string())?;
    Ok(out)
}

/// `plot` of `table` as PNG file bytes.
pub fn lines_png(table: &Table, plot: &LinePlot) -> Result<Vec<u8>, String> {
    register_font();
    let column = |name: &str| {
        table
            .column(name)
            .ok_or_else(|| format!("no column `{name}`; columns: {}", table.columns.join(", ")))
    };
    let xs = column(&plot.x)?;
    let series: Vec<(String, Vec<f64>)> = plot
        .y
        .iter()
        .map(|n| Ok((n.clone(), column(n)?)))
        .collect::<Result<_, String>>()?;
    let all_y: Vec<f64> = series.iter().flat_map(|s| s.1.iter().copied()).collect();
    let range = |v: &[f64], log: bool| -> Result<(f64, f64), String> {
        let v: Vec<f64> = v
            .iter()
            .copied()
            .filter(|x| x.is_finite() && (!log || *x > 0.0))
            .collect();
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        if !lo.is_finite() {
            return Err("nothing to plot (no finite, and for log axes positive, values)".into());
        }
        let (lo, hi) = if lo == hi {
            (lo * 0.9 - 1e-9, hi * 1.1 + 1e-9)
        } else {
            (lo, hi)
        };
        Ok(if log {
            (lo / 1.2, hi * 1.2)
        } else {
            (lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        })
    };
    let (x_range, y_range) = (range(&xs, plot.log_x)?, range(&all_y, plot.log_y)?);
    let (w, h) = plot.size_px;
    let mut pixels = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, plot.size_px).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let colours = [BLUE, RED, GREEN, MAGENTA, CYAN, BLACK];
        macro_rules! draw {
            ($x:expr, $y:expr) => {{
                let mut chart = ChartBuilder::on(&root)
                    .caption(&plot.title, ("sans-serif", 22))
                    .margin(12)
                    .x_label_area_size(45)
                    .y_label_area_size(70)
                    .build_cartesian_2d($x, $y)
                    .map_err(|e| e.to_string())?;
                chart
                    .configure_mesh()
                    .x_desc(&plot.x_label)
                    .y_desc(&plot.y_label)
                    .label_style(("sans-serif", 14))
                    .draw()
                    .map_err(|e| e.to_string())?;
                for (i, (name, ys)) in series.iter().enumerate() {
                    let colour = colours[i % colours.len()];
                    let points: Vec<(f64, f64)> = xs
                        .iter()
                        .copied()
                        .zip(ys.iter().copied())
                        .filter(|(x, y)| x.is_finite() && y.is_finite())
                        .collect();
                    chart
                        .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                        .map_err(|e| e.to_string())?
                        .label(name.clone())
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                        });
                    chart
                        .draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                        .map_err(|e| e.to_string())?;
                }
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 14))
                    .draw()
                    .map_err(|e| e.to_string())?;
            }};
        }
        let (xr, yr) = (x_range.0..x_range.1, y_range.0..y_range.1);
        match (plot.log_x, plot.log_y) {
            (false, false) => draw!(xr, yr),
            (true, false) => draw!(xr.log_scale(), yr),
            (false, true) => draw!(xr, yr.log_scale()),
            (true, true) => draw!(xr.log_scale(), yr.log_scale()),
        }
        root.present().map_err(|e| e.to_string())?;
    }
    png_bytes(&pixels, w as usize, h as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_a_log_log_plot_and_names_missing_columns() {
        let t = Table::new(
            vec!["b".into(), "v".into()],
            vec![5.0, 11.9, 10.0, 2.8, 25.0, 0.38],
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        let plot = LinePlot {
            x: "b".into(),
            y: vec!["v".into()],
            title: "var".into(),
            x_label: "b".into(),
            y_label: "v".into(),
            log_x: true,
            log_y: true,
            size_px: (400, 300),
        };
        draw_lines(&t, &plot, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (400, 300));
        // Something other than white was drawn (axes, text, line).
        assert!(img.pixels().filter(|p| p.0 != [255, 255, 255]).count() > 1000);
        let bad = LinePlot {
            y: vec!["w".into()],
            ..plot
        };
        assert!(
            draw_lines(&t, &bad, &path)
                .unwrap_err()
                .contains("no column `w`")
        );
    }
}
