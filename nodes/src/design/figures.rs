//! The design stage's figures for the report.

use crate::plot::{LinePlot, lines_png};
use fusegraph_engine::value::Table;

/// The baseline study's plot (log-log: variance ~ 1 / b^2) of the z-variance
/// columns of `study` (`var_z*` and `paper*`) against `baseline_mm`, as PNG
/// file bytes.
pub(crate) fn variance_png(study: &Table) -> Result<Vec<u8>, String> {
    let y: Vec<String> = study
        .columns
        .iter()
        .filter(|c| c.starts_with("var_z") || c.starts_with("paper"))
        .cloned()
        .collect();
    let plot = LinePlot {
        x: "baseline_mm".into(),
        y,
        title: "Depth variance against baseline (Monte Carlo)".into(),
        x_label: "baseline, mm".into(),
        y_label: "variance of z, mm^2".into(),
        log_x: true,
        log_y: true,
        size_px: (700, 420),
    };
    lines_png(study, &plot)
}
