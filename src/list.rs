//! Text for people: the node type listing and the end-of-run summary.

use fusegraph_engine::report::{NodeStatus, RunReport};
use fusegraph_engine::{ParamSpec, Registry};
use std::fmt::Write;
use std::path::Path;

/// Every node type with its ports and parameters.
pub fn nodes_text(registry: &Registry) -> String {
    let mut s = String::new();
    for spec in registry.specs() {
        let _ = writeln!(s, "{} (v{}): {}", spec.name, spec.version, spec.doc);
        if let Some(origin) = &spec.origin {
            let _ = writeln!(s, "    from plugin {}", origin.file.display());
        }
        for p in &spec.inputs {
            let opt = if p.optional { ", optional" } else { "" };
            let _ = writeln!(s, "    in  {}: {}{opt}  {}", p.name, p.type_names(), p.doc);
        }
        for p in &spec.outputs {
            let _ = writeln!(s, "    out {}: {}  {}", p.name, p.type_names(), p.doc);
        }
        for p in &spec.params {
            let _ = writeln!(s, "    {}  {}", param_line(p), p.doc);
        }
        s.push('\n');
    }
    s
}

fn param_line(p: &ParamSpec) -> String {
    let mut line = format!("{}: {}", p.name, p.kind);
    match &p.default {
        Some(d) => {
            let _ = write!(line, " = {d}");
        }
        None => line.push_str(" (required)"),
    }
    if !p.unit.is_empty() {
        let _ = write!(line, " [{}]", p.unit);
    }
    match (p.min, p.max) {
        (Some(a), Some(b)) => {
            let _ = write!(line, " in {a}..={b}");
        }
        (Some(a), None) => {
            let _ = write!(line, " >= {a}");
        }
        (None, Some(b)) => {
            let _ = write!(line, " <= {b}");
        }
        (None, None) => {}
    }
    if !p.choices.is_empty() {
        let _ = write!(line, " one of {}", p.choices.join("|"));
    }
    line
}

/// One line per node (status, time, metrics) and where the report is.
pub fn summary(report: &RunReport, out_dir: &Path) -> String {
    let mut s = String::new();
    for (id, n) in &report.nodes {
        let status = match n.status {
            NodeStatus::Ran => "ran",
            NodeStatus::Cached => "cached",
            NodeStatus::Failed => "FAILED",
            NodeStatus::Skipped => "skipped",
        };
        let metrics: Vec<String> = n
            .metrics
            .iter()
            .map(|(k, v)| format!("{k}={v:.6}"))
            .collect();
        let _ = writeln!(
            s,
            "{status:>8} {id:<24} {:>9.1} ms  {}",
            n.ms,
            metrics.join(" ")
        );
        if let Some(e) = &n.error {
            let _ = writeln!(s, "{:>8} {e}", "");
            // A failed node's notes say why: shown here, not only in the report.
            const SHOWN: usize = 10;
            for note in n.notes.iter().take(SHOWN) {
                let _ = writeln!(s, "{:>8} note: {note}", "");
            }
            if n.notes.len() > SHOWN {
                let more = n.notes.len() - SHOWN;
                let _ = writeln!(s, "{:>8} ... and {more} more notes in report.json", "");
            }
        }
    }
    let counts = report.note_counts();
    if !counts.is_empty() {
        let total: usize = counts.iter().map(|(_, n)| n).sum();
        let by_node: Vec<String> = counts.iter().map(|(id, n)| format!("{id} {n}")).collect();
        let _ = writeln!(
            s,
            "{total} warning{} ({}): see `notes` in report.json",
            if total == 1 { "" } else { "s" },
            by_node.join(", ")
        );
    }
    let _ = write!(
        s,
        "graph `{}`: {} in {:.1} ms; report: {}",
        report.graph,
        if report.succeeded() { "done" } else { "FAILED" },
        report.total_ms,
        out_dir.join("report.json").display()
    );
    s
}
