//! The whole path from a graph file to a report, as the CLI and tests use it:
//! load, apply `--set` overrides, validate, key, run, write `report.json`,
//! the figures and `report.html`.

use crate::cache::MemoryCache;
use crate::error::GraphErrors;
use crate::figure::FigureData;
use crate::graph::GraphDoc;
use crate::key::node_keys;
use crate::registry::Registry;
use crate::report::{RunReport, figure_refs};
use crate::report_html::{Reference, report_html};
use crate::schedule::{RunOptions, RunOutcome, run_graph};
use crate::validate::{ValidGraph, validate};
use std::path::Path;

/// Why a run could not start or finish.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The graph is invalid (exit code 2).
    #[error("{0}")]
    Graph(#[from] GraphErrors),
    /// The output or cache folder could not be written.
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// Loads `file`, applies `overrides` (`ID.KEY=VALUE`) and validates it.
pub fn load_graph(
    file: &Path,
    overrides: &[String],
    registry: &Registry,
) -> Result<ValidGraph, GraphErrors> {
    let mut doc = GraphDoc::load(file)?;
    let errors: Vec<_> = overrides
        .iter()
        .filter_map(|s| doc.apply_set(s).err())
        .collect();
    if !errors.is_empty() {
        return Err(GraphErrors(errors));
    }
    validate(&doc, registry)
}

/// Runs a validated graph and writes `report.json` into the output folder.
/// `memory` may be shared by several runs of one process.
pub fn run(
    graph: &ValidGraph,
    options: &RunOptions,
    memory: &MemoryCache,
) -> Result<RunOutcome, RunError> {
    let keys = node_keys(graph, &options.out_dir)?;
    let outcome = run_graph(graph, &keys, options, memory)?;
    write_report(&outcome.report, &graph.references, &options.out_dir)?;
    Ok(outcome)
}

/// Writes `report.json`, the nodes' figures under `figures/` and
/// `report.html` into `out_dir`.
pub fn write_report(
    report: &RunReport,
    references: &[Reference],
    out_dir: &Path,
) -> std::io::Result<()> {
    let write = |path: &Path, bytes: &[u8]| {
        std::fs::write(path, bytes)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))
    };
    let figures_dir = out_dir.join("figures");
    for (id, node) in &report.nodes {
        for (figure, place) in node.figures.iter().zip(figure_refs(id, node)) {
            match &figure.data {
                FigureData::Png(bytes) => {
                    std::fs::create_dir_all(&figures_dir)?;
                    write(&out_dir.join(&place.file), bytes)?;
                }
                FigureData::Svg(text) => {
                    std::fs::create_dir_all(&figures_dir)?;
                    write(&out_dir.join(&place.file), text.as_bytes())?;
                }
                // Drawn by the page itself, from data inside it.
                FigureData::Points3d { .. } => {}
            }
        }
    }
    let text = serde_json::to_string_pretty(&report.to_json()).expect("plain data");
    write(&out_dir.join("report.json"), (text + "\n").as_bytes())?;
    write(
        &out_dir.join("report.html"),
        report_html(report, references).as_bytes(),
    )
}
