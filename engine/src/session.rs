//! The whole path from a graph file to a report, as the CLI and tests use it:
//! load, apply `--set` overrides, validate, key, run, write `report.json`,
//! the figures and `report.html`.

use crate::cache::MemoryCache;
use crate::error::{ErrorKind, GraphError, GraphErrors};
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

/// Loads `file`, loads the plugins its `[graph] plugins` names (on top of
/// `registry`'s ops), applies `overrides` (`ID.KEY=VALUE`) and validates it.
pub fn load_graph(
    file: &Path,
    overrides: &[String],
    registry: &Registry,
) -> Result<ValidGraph, GraphErrors> {
    validate_doc(GraphDoc::load(file)?, overrides, registry)
}

/// [`load_graph`] on a graph already read (and perhaps edited).
pub fn validate_doc(
    mut doc: GraphDoc,
    overrides: &[String],
    registry: &Registry,
) -> Result<ValidGraph, GraphErrors> {
    let mut errors = Vec::new();
    // A script that cannot be loaded leaves its ops unknown: validation goes
    // on, so the error names each node's op as well as the file.
    let registry = match with_graph_plugins(&doc, registry) {
        Ok(r) => r,
        Err(GraphErrors(e)) if e.iter().all(|e| e.key.as_deref() == Some("python")) => {
            errors.extend(e);
            std::borrow::Cow::Borrowed(registry)
        }
        Err(e) => return Err(e),
    };
    errors.extend(overrides.iter().filter_map(|s| doc.apply_set(s).err()));
    // The graph with the overrides that did apply is still validated, so one
    // pass reports every problem, not the overrides' first.
    match validate(&doc, &registry) {
        Ok(graph) if errors.is_empty() => Ok(graph),
        Ok(_) => Err(GraphErrors(errors)),
        Err(GraphErrors(more)) => {
            errors.extend(more);
            Err(GraphErrors(errors))
        }
    }
}

/// `registry` with the plugins `doc`'s `[graph] plugins` names and the
/// Python files its `[graph] python` names loaded (the same registry when it
/// names none). A script's error is keyed `python`.
pub fn with_graph_plugins<'a>(
    doc: &GraphDoc,
    registry: &'a Registry,
) -> Result<std::borrow::Cow<'a, Registry>, GraphErrors> {
    let registry = with_plugins(&doc.plugins, &doc.file, registry)?;
    with_scripts(&doc.python, &doc.file, registry)
}

/// `registry` with the Python files `files` loaded by its script host;
/// errors name `named_by` (the graph or sweep file) and its key `python`.
pub fn with_scripts<'a>(
    files: &[std::path::PathBuf],
    named_by: &Path,
    mut registry: std::borrow::Cow<'a, Registry>,
) -> Result<std::borrow::Cow<'a, Registry>, GraphErrors> {
    if !files.is_empty() {
        crate::script::load_scripts(files, registry.to_mut())
            .map_err(|why| GraphError::file(ErrorKind::Plugin, named_by, why).at_key("python"))?;
    }
    Ok(registry)
}

/// `registry` with the plugin libraries `files` loaded; errors name
/// `named_by` (the graph or sweep file) and its key `plugins`.
pub fn with_plugins<'a>(
    files: &[std::path::PathBuf],
    named_by: &Path,
    registry: &'a Registry,
) -> Result<std::borrow::Cow<'a, Registry>, GraphErrors> {
    if files.is_empty() {
        return Ok(std::borrow::Cow::Borrowed(registry));
    }
    let mut r = registry.clone();
    for p in files {
        crate::plugin::load_plugin(p, &mut r)
            .map_err(|why| GraphError::file(ErrorKind::Plugin, named_by, why).at_key("plugins"))?;
    }
    Ok(std::borrow::Cow::Owned(r))
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
    if options.cache.is_none() {
        // Without a cache, files nodes produced (a generated phantom) live
        // under OUT/.work for the run only.
        let work = options.out_dir.join(".work");
        if work.exists()
            && let Err(e) = std::fs::remove_dir_all(&work)
        {
            tracing::warn!("could not remove {}: {e}", work.display());
        }
    }
    write_report(&outcome.report, &graph.references, &options.out_dir)?;
    Ok(outcome)
}

/// Writes `report.json`, the nodes' figures under `figures/` and
/// `report.html` into `out_dir`, each file whole or not at all (see
/// [`crate::atomic::write_atomically`]). Figures are written side by side,
/// and one whose file already holds its bytes (a cached node's, re-run) is
/// left as it is. A file that cannot be written does not stop the others;
/// the error names every one that failed.
pub fn write_report(
    report: &RunReport,
    references: &[Reference],
    out_dir: &Path,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    let figures: Vec<(std::path::PathBuf, &[u8])> = report
        .nodes
        .iter()
        .flat_map(|(id, node)| node.figures.iter().zip(figure_refs(id, node)))
        .filter_map(|(figure, place)| {
            let bytes = match &figure.data {
                FigureData::Png(bytes) => bytes.as_slice(),
                FigureData::Svg(text) => text.as_bytes(),
                // Drawn by the page itself, from data inside it.
                FigureData::Points3d { .. } => return None,
            };
            Some((out_dir.join(&place.file), bytes))
        })
        .collect();
    // The page and the JSON are composed while the figures are written.
    let (mut failures, (json, html)): (Vec<std::io::Error>, _) = rayon::join(
        || {
            figures
                .par_iter()
                .filter_map(|(path, bytes)| crate::atomic::write_if_changed(path, bytes).err())
                .collect()
        },
        || {
            let text = serde_json::to_string_pretty(&report.to_json()).expect("plain data");
            (text + "\n", report_html(report, references))
        },
    );
    for (name, text) in [("report.json", json), ("report.html", html)] {
        if let Err(e) = crate::atomic::write_atomically(&out_dir.join(name), text.as_bytes()) {
            failures.push(e);
        }
    }
    match failures.len() {
        0 => Ok(()),
        _ => {
            let kind = failures[0].kind();
            let all: Vec<String> = failures.iter().map(|e| e.to_string()).collect();
            Err(std::io::Error::new(kind, all.join("; ")))
        }
    }
}
