//! Cache keys that know the code: an edited op (simulated through its code
//! fingerprint, the input the build script computes from its source files)
//! re-runs its own nodes and what follows them, nothing else; unchanged
//! code keeps the whole cache.

use fusegraph_engine::cache::{DiskCache, MemoryCache};
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::session::{load_graph, run};
use fusegraph_engine::{NodeStatus, Registry};
use std::collections::BTreeMap;
use std::path::Path;

fn statuses(registry: &Registry, dir: &Path) -> BTreeMap<String, NodeStatus> {
    let graph = Path::new(env!("CARGO_MANIFEST_DIR")).join("../graphs/demo.toml");
    let valid = load_graph(&graph, &[], registry).expect("the demo graph is valid");
    let options = RunOptions {
        out_dir: dir.join("out"),
        cache: Some(DiskCache::open(&dir.join("cache")).expect("a cache")),
        jobs: 1,
        progress: false,
        provenance: Default::default(),
        keep_outputs: false,
    };
    let outcome = run(&valid, &options, &MemoryCache::new()).expect("the run finishes");
    assert!(outcome.report.succeeded());
    outcome
        .report
        .nodes
        .into_iter()
        .map(|(id, n)| (id, n.status))
        .collect()
}

#[test]
fn every_built_in_op_carries_its_code_fingerprint() {
    let registry = fusegraph_nodes::builtin_registry();
    let missing: Vec<&str> = registry
        .specs()
        .filter(|s| s.code.as_deref().is_none_or(|c| c.len() != 64))
        .map(|s| s.name.as_str())
        .collect();
    assert!(missing.is_empty(), "no code fingerprint: {missing:?}");
}

#[test]
fn an_edited_op_re_runs_its_nodes_and_what_follows_only() {
    let dir = tempfile::tempdir().unwrap();
    let built_in = fusegraph_nodes::builtin_registry();
    let first = statuses(&built_in, dir.path());
    assert!(first.values().all(|s| *s == NodeStatus::Ran), "{first:?}");
    // The same code (a rebuild that changed nothing): everything reused.
    let again = statuses(&fusegraph_nodes::builtin_registry(), dir.path());
    assert!(
        again.values().all(|s| *s == NodeStatus::Cached),
        "{again:?}"
    );

    let mut edited = fusegraph_nodes::builtin_registry();
    assert!(edited.set_code("math.binary", &"e".repeat(64)));
    let after = statuses(&edited, dir.path());
    let ran: Vec<&str> = after
        .iter()
        .filter(|(_, s)| **s == NodeStatus::Ran)
        .map(|(id, _)| id.as_str())
        .collect();
    // The three math.binary nodes and the two sinks that follow them.
    assert_eq!(
        ran,
        [
            "focal_mm",
            "s_times_dmin",
            "verging_deg",
            "write_focal",
            "write_verging"
        ]
    );
    for constant in ["sensor_mm", "dmin_mm", "fov_mm", "baseline_mm"] {
        assert_eq!(after[constant], NodeStatus::Cached, "{constant}");
    }
}
