//! Where a run's figures come from, recorded in every report: the engine's
//! version, the host, when the run started (UTC), the graph file and its
//! content hash, and each plugin library's and Python file's hash; the
//! program adds what only it knows (its build's git commit, rustc, target,
//! the command line) through [`crate::schedule::RunOptions::provenance`].

use crate::validate::ValidGraph;
use serde_json::{Map, Value, json};
use std::collections::BTreeMap;
use std::time::{SystemTime, UNIX_EPOCH};

/// `t` as `YYYY-MM-DDTHH:MM:SSZ` (UTC).
pub fn utc_iso(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rest) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rest / 3600,
        rest % 3600 / 60,
        rest % 60
    )
}

/// The engine's part of a run's provenance, merged with the program's
/// `extra` (which wins on a shared key).
pub fn provenance(
    graph: &ValidGraph,
    started: SystemTime,
    extra: &Map<String, Value>,
) -> Map<String, Value> {
    let mut p = Map::new();
    p.insert("engine_version".into(), json!(env!("CARGO_PKG_VERSION")));
    p.insert("host".into(), json!(crate::process::host_name()));
    p.insert("started_utc".into(), json!(utc_iso(started)));
    p.insert("graph_file".into(), json!(graph.file.display().to_string()));
    let graph_hash = crate::hash::hash_path(&graph.file).map(|h| h.to_hex().to_string());
    p.insert(
        "graph_blake3".into(),
        graph_hash.map_or(Value::Null, Value::String),
    );
    // Each plugin library and Python file whose ops the graph uses, once.
    let origins: BTreeMap<String, String> = graph
        .nodes
        .iter()
        .filter_map(|n| n.op.spec().origin.as_ref())
        .map(|o| (o.file.display().to_string(), o.content_hash.clone()))
        .collect();
    let origins: Vec<Value> = origins
        .into_iter()
        .map(|(file, hash)| json!({"file": file, "blake3": hash}))
        .collect();
    p.insert("plugins".into(), Value::Array(origins));
    for (k, v) in extra {
        p.insert(k.clone(), v.clone());
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn utc_times_are_civil_dates() {
        assert_eq!(utc_iso(UNIX_EPOCH), "1970-01-01T00:00:00Z");
        // 2000-02-29 (a leap day) 12:34:56 and 2026-12-05 11:13:51, by hand.
        assert_eq!(
            utc_iso(UNIX_EPOCH + Duration::from_secs(951_827_696)),
            "2000-02-29T12:34:56Z"
        );
        assert_eq!(
            utc_iso(UNIX_EPOCH + Duration::from_secs(1_796_469_231)),
            "2026-12-05T11:13:51Z"
        );
    }
}
