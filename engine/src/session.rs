//! The whole path from a graph file to a report, as the CLI and tests use it:
//! load, apply `--set` overrides, validate, key, run, write `report.json`.

use crate::cache::MemoryCache;
use crate::error::GraphErrors;
use crate::graph::GraphDoc;
use crate::key::node_keys;
use crate::registry::Registry;
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
    let path = options.out_dir.join("report.json");
    let text = serde_json::to_string_pretty(&outcome.report.to_json()).expect("plain data");
    std::fs::write(&path, text + "\n")
        .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
    Ok(outcome)
}
