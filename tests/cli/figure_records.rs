//! Every shipped graph's figures are the ones recorded in
//! `tests/data/figures/<graph>.json`: every metric of its report but the
//! timings (`_ms`), to the bit. A speed-up must leave them as they were
//! (the ops give the same bits on any thread count and instruction set,
//! which other tests hold them to), so a figure that moves is a result that
//! changed.
//!
//! After a deliberate change (an op's new version, a new phantom), rewrite
//! the records with
//! `FUSEGRAPH_BLESS=1 cargo test --test cli -- every_shipped_graph main_job_gives`
//! and review their diff.

use serde_json::{Map, Value};
use std::path::{Path, PathBuf};

fn record_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/figures")
        .join(format!("{name}.json"))
}

/// A report's figures: its flat `metrics` without the timings. NaN and the
/// infinities are written as JSON `null`, so they compare alike.
fn figures(report: &Value) -> Map<String, Value> {
    report["metrics"]
        .as_object()
        .expect("a report has metrics")
        .iter()
        .filter(|(k, _)| !k.ends_with("_ms"))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect()
}

/// The figures of `report` (the run of graph `name`) are the recorded ones;
/// with `FUSEGRAPH_BLESS` set, they are recorded first.
pub fn assert_figures_as_recorded(name: &str, report: &Value) {
    let path = record_path(name);
    let now = figures(report);
    if std::env::var_os("FUSEGRAPH_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).expect("the records' folder");
        let text = serde_json::to_string_pretty(&now).expect("JSON") + "\n";
        std::fs::write(&path, text).expect("writing the record");
    }
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (record it with FUSEGRAPH_BLESS=1)", path.display()));
    let recorded: Map<String, Value> =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let differ = differences(&recorded, &now);
    assert!(
        differ.is_empty(),
        "{name}: {} of {} figures differ from {} (after a deliberate change, \
         bless them: see tests/cli/figure_records.rs):\n{}",
        differ.len(),
        recorded.len().max(now.len()),
        path.display(),
        differ.join("\n")
    );
}

/// One line per figure that is missing, added, or not the same number.
fn differences(recorded: &Map<String, Value>, now: &Map<String, Value>) -> Vec<String> {
    let mut lines = Vec::new();
    for (k, before) in recorded {
        match now.get(k) {
            None => lines.push(format!("  {k}: missing (recorded {before})")),
            Some(after) if !same_number(before, after) => {
                lines.push(format!("  {k}: {before} recorded, {after} now"))
            }
            Some(_) => {}
        }
    }
    for (k, after) in now {
        if !recorded.contains_key(k) {
            lines.push(format!("  {k}: added ({after})"));
        }
    }
    lines
}

/// Equal as numbers (`1` and `1.0` alike), or both the same non-number.
fn same_number(a: &Value, b: &Value) -> bool {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => x.to_bits() == y.to_bits(),
        _ => a == b,
    }
}

#[test]
fn a_changed_missing_or_added_figure_is_a_difference() {
    let map = |pairs: &[(&str, Value)]| -> Map<String, Value> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.clone()))
            .collect()
    };
    let recorded = map(&[
        ("a.x_mm", 1.25.into()),
        ("a.n", 3.into()),
        ("b.nan", Value::Null),
    ]);
    assert!(differences(&recorded, &recorded).is_empty());
    assert!(
        differences(
            &recorded,
            &map(&[
                ("a.x_mm", 1.25.into()),
                ("a.n", 3.0.into()),
                ("b.nan", Value::Null)
            ])
        )
        .is_empty()
    );
    let moved = map(&[
        ("a.x_mm", 1.2500000000000002.into()),
        ("a.n", 3.into()),
        ("c.new", 0.into()),
    ]);
    let lines = differences(&recorded, &moved);
    assert_eq!(lines.len(), 3, "{lines:?}");
    assert!(lines[0].contains("a.x_mm") && lines[0].contains("1.2500000000000002"));
    assert!(lines[1].contains("b.nan: missing"));
    assert!(lines[2].contains("c.new: added"));
}
