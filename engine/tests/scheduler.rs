//! The scheduler and cache, end to end on test ops: reuse, exact re-runs,
//! corruption, failures, panics, parallelism, concurrent runs, sinks, file sources.

mod common;

use common::{registry, run_file, statuses, with_status, write_graph};
use fusegraph_engine::NodeStatus::{Cached, Failed, Ran, Skipped};
use fusegraph_engine::cache::DiskCache;
use fusegraph_engine::cache::MemoryCache;
use fusegraph_engine::key::node_keys;
use fusegraph_engine::schedule::{RunOptions, RunOutcome};
use fusegraph_engine::session::{load_graph, run};

/// a -> b -> c, and an independent branch x -> d.
const DIAMOND: &str = r#"
[graph]
name = "diamond"

[node.a]
op = "test.source"
value = 2.0

[node.b]
op = "test.add"
in.a = "a.value"
in.b = "a.value"

[node.c]
op = "test.add"
in.a = "b.value"
in.b = "x.value"

[node.x]
op = "test.source"
value = 10.0

[node.d]
op = "test.add"
in.a = "x.value"
"#;

fn scalar(outcome: &fusegraph_engine::schedule::RunOutcome, node: usize, port: &str) -> f64 {
    let entry = outcome.results[node]
        .as_ref()
        .expect("node produced results");
    match &entry.outputs.0[port] {
        fusegraph_engine::Value::Scalar(v) => **v,
        other => panic!("{other:?}"),
    }
}

/// A run of `graph` with `sets`, a disk cache or none, and `keep_outputs`
/// as given, sharing `memory` with other runs.
fn run_with(
    reg: &fusegraph_engine::Registry,
    graph: &std::path::Path,
    sets: &[&str],
    cache: Option<&std::path::Path>,
    out: &std::path::Path,
    memory: &MemoryCache,
    keep_outputs: bool,
) -> RunOutcome {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let graph = load_graph(graph, &sets, reg).unwrap();
    let options = RunOptions {
        out_dir: out.to_path_buf(),
        cache: cache.map(|c| DiskCache::open(c).unwrap()),
        jobs: 2,
        progress: false,
        provenance: Default::default(),
        keep_outputs,
    };
    run(&graph, &options, memory).unwrap()
}

/// The diamond run with `keep_outputs` as given, without a disk cache,
/// sharing `memory` between runs.
fn run_in_memory(
    reg: &fusegraph_engine::Registry,
    graph: &std::path::Path,
    out: &std::path::Path,
    memory: &MemoryCache,
    keep_outputs: bool,
) -> RunOutcome {
    run_with(reg, graph, &[], None, out, memory, keep_outputs)
}

#[test]
fn released_outputs_are_gone_from_memory_and_the_outcome_only() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    let memory = MemoryCache::new();
    // Released as their last readers ran: the outcome holds none, and the
    // memory cache, which keeps nothing alive itself, cannot give them to
    // a second run.
    let released = run_in_memory(&reg, &g, &t.path().join("out"), &memory, false);
    assert!(released.report.succeeded());
    assert!(released.results.iter().all(Option::is_none));
    let again = run_in_memory(&reg, &g, &t.path().join("out"), &memory, true);
    assert_eq!(with_status(&again, Ran), ["a", "b", "c", "d", "x"]);
    assert_eq!(counters.total(), 10);
    // Kept: the outcome holds them all, and while it lives a second run
    // finds them in memory.
    assert_eq!(scalar(&again, 2, "value"), 14.0);
    let third = run_in_memory(&reg, &g, &t.path().join("out"), &memory, true);
    assert_eq!(with_status(&third, Cached), ["a", "b", "c", "d", "x"]);
    assert_eq!(counters.total(), 10);
    drop((again, third));
    let fourth = run_in_memory(&reg, &g, &t.path().join("out"), &memory, false);
    assert_eq!(with_status(&fourth, Ran), ["a", "b", "c", "d", "x"]);
}

#[test]
fn second_run_is_all_cached_and_runs_nothing() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    let cache = t.path().join("cache");
    let first = run_file(&reg, &g, &[], Some(&cache), &t.path().join("out")).unwrap();
    assert!(first.report.succeeded());
    assert_eq!(with_status(&first, Ran), ["a", "b", "c", "d", "x"]);
    assert_eq!(scalar(&first, 2, "value"), 14.0);
    assert_eq!(counters.total(), 5);

    let second = run_file(&reg, &g, &[], Some(&cache), &t.path().join("out")).unwrap();
    assert_eq!(with_status(&second, Cached), ["a", "b", "c", "d", "x"]);
    assert_eq!(counters.total(), 5, "a cached run must not run any op");
    assert_eq!(scalar(&second, 2, "value"), 14.0);
    assert_eq!(
        second.report.metrics()["c.sum"],
        14.0,
        "metrics come back from the cache"
    );
    for ((_, a), (_, b)) in first.report.nodes.iter().zip(&second.report.nodes) {
        assert_eq!(a.key, b.key);
    }
}

#[test]
fn changing_one_parameter_reruns_exactly_that_node_and_its_downstream() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    let changed = run_file(&reg, &g, &["a.value=3"], Some(&cache), &out).unwrap();
    assert_eq!(with_status(&changed, Ran), ["a", "b", "c"]);
    assert_eq!(with_status(&changed, Cached), ["d", "x"]);
    assert_eq!(scalar(&changed, 2, "value"), 16.0);
    assert_eq!(counters.runs("a"), 2);
    assert_eq!(counters.runs("x"), 1);

    // A parameter set to its default, or an integer for a float, is the same key.
    let same = run_file(
        &reg,
        &g,
        &["a.value=3.0", "x.repeat=1", "x.mode=\"fast\""],
        Some(&cache),
        &out,
    )
    .unwrap();
    assert_eq!(with_status(&same, Ran), Vec::<String>::new());
}

#[test]
fn corrupted_or_truncated_cache_entries_are_recomputed() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    run_file(&reg, &g, &[], Some(&cache), &out).unwrap();

    let graph = load_graph(&g, &[], &reg).unwrap();
    let keys = node_keys(&graph, &out).unwrap();
    let disk = DiskCache::open(&cache).unwrap();
    let b = graph.index_of("b").unwrap();
    let x = graph.index_of("x").unwrap();
    // Flip one byte of b's entry, truncate x's.
    let b_path = disk.entry_path(&keys[b]);
    let mut bytes = std::fs::read(&b_path).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    std::fs::write(&b_path, bytes).unwrap();
    let x_path = disk.entry_path(&keys[x]);
    let len = std::fs::metadata(&x_path).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&x_path)
        .unwrap()
        .set_len(len / 2)
        .unwrap();

    let again = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(with_status(&again, Ran), ["b", "x"]);
    assert_eq!(with_status(&again, Cached), ["a", "c", "d"]);
    assert_eq!(scalar(&again, 2, "value"), 14.0);
    assert_eq!(counters.runs("b"), 2);

    // The recomputed entries were rewritten whole.
    let third = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(with_status(&third, Cached).len(), 5);
}

/// The diamond graph run as the CLI runs it: outputs released as they are
/// read, with a disk cache.
fn run_released(
    reg: &fusegraph_engine::Registry,
    graph: &std::path::Path,
    sets: &[&str],
    cache: &std::path::Path,
    out: &std::path::Path,
) -> RunOutcome {
    run_with(
        reg,
        graph,
        sets,
        Some(cache),
        out,
        &MemoryCache::new(),
        false,
    )
}

#[test]
fn values_are_read_only_where_a_node_downstream_computes_and_checked_then() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    let first = run_released(&reg, &g, &[], &cache, &out);
    assert_eq!(with_status(&first, Ran).len(), 5);
    let metric = |o: &RunOutcome, id: &str| o.report.node(id).unwrap().metrics.clone();

    // Damage the last byte of a's and b's entries: their values, not their
    // metas.
    let graph = load_graph(&g, &[], &reg).unwrap();
    let keys = node_keys(&graph, &out).unwrap();
    let disk = DiskCache::open(&cache).unwrap();
    for id in ["a", "b"] {
        let path = disk.entry_path(&keys[graph.index_of(id).unwrap()]);
        let mut bytes = std::fs::read(&path).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        std::fs::write(&path, bytes).unwrap();
    }
    // Every node cached: no value is read, so none is found damaged; the
    // metrics come from the metas, checked.
    let cached = run_released(&reg, &g, &[], &cache, &out);
    assert_eq!(with_status(&cached, Cached).len(), 5);
    for id in ["a", "b", "c", "d", "x"] {
        assert_eq!(metric(&cached, id), metric(&first, id), "{id}");
    }

    // x changes: c computes and reads b's value, which fails its check, so
    // b computes and reads a's, which fails too: both computed again, in
    // this run, and c's sum is right.
    let changed = run_released(&reg, &g, &["x.value=11"], &cache, &out);
    assert_eq!(with_status(&changed, Ran), ["a", "b", "c", "d", "x"]);
    assert_eq!(counters.runs("a"), 2);
    assert_eq!(counters.runs("b"), 2);
    let c = changed.report.node("c").unwrap();
    assert_eq!(c.status, Ran);
    let again = run_released(&reg, &g, &["x.value=11"], &cache, &out);
    assert_eq!(with_status(&again, Cached).len(), 5);
}

#[test]
fn a_failing_node_stops_only_its_downstream() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let text = format!(
        "{DIAMOND}\n[node.bad]\nop = \"test.fail\"\nin.a = \"a.value\"\n\n[node.after_bad]\nop = \"test.add\"\nin.a = \"bad.value\"\n\n[node.after_after]\nop = \"test.add\"\nin.a = \"after_bad.value\"\nin.b = \"d.value\"\n"
    );
    let g = write_graph(t.path(), "g.toml", &text);
    let cache = t.path().join("cache");
    let o = run_file(&reg, &g, &[], Some(&cache), &t.path().join("out")).unwrap();
    let s = statuses(&o);
    assert!(!o.report.succeeded());
    assert_eq!(s["bad"], Failed);
    assert_eq!(s["after_bad"], Skipped);
    assert_eq!(s["after_after"], Skipped);
    for id in ["a", "b", "c", "x", "d"] {
        assert_eq!(s[id], Ran, "{id} is independent of the failure");
    }
    let bad = o.report.node("bad").unwrap();
    assert!(bad.error.as_deref().unwrap().contains("deliberate failure"));
    let skipped = o.report.node("after_bad").unwrap();
    assert!(skipped.error.as_deref().unwrap().contains("`bad`"));

    // A failure is not cached: the next run tries again.
    let again = run_file(&reg, &g, &[], Some(&cache), &t.path().join("out")).unwrap();
    assert_eq!(statuses(&again)["bad"], Failed);
    assert_eq!(statuses(&again)["d"], Cached);
}

#[test]
fn a_panicking_op_is_a_failed_node_not_a_crash() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let text = format!("{DIAMOND}\n[node.boom]\nop = \"test.panic\"\nin.a = \"a.value\"\n");
    let g = write_graph(t.path(), "g.toml", &text);
    let o = run_file(&reg, &g, &[], None, &t.path().join("out")).unwrap();
    let boom = o.report.node("boom").unwrap();
    assert_eq!(boom.status, Failed);
    let msg = boom.error.as_deref().unwrap();
    assert!(
        msg.contains("test.panic")
            && msg.contains("panicked")
            && msg.contains("index out of bounds"),
        "{msg}"
    );
    assert_eq!(statuses(&o)["c"], Ran);
}

#[test]
fn an_op_producing_the_wrong_type_fails_clearly() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let g = write_graph(t.path(), "g.toml", "[node.l]\nop = \"test.liar\"\n");
    let o = run_file(&reg, &g, &[], None, &t.path().join("out")).unwrap();
    let msg = o.report.node("l").unwrap().error.clone().unwrap();
    assert!(
        msg.contains("produced a Volume on output `value`, declared Scalar"),
        "{msg}"
    );
}

#[test]
fn independent_nodes_run_in_parallel() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let text: String = (0..4)
        .map(|i| format!("[node.s{i}]\nop = \"test.slow\"\nms = 100\n\n"))
        .collect();
    let g = write_graph(t.path(), "g.toml", &text);
    run_file(&reg, &g, &[], None, &t.path().join("out")).unwrap();
    assert_eq!(
        counters
            .max_running
            .load(std::sync::atomic::Ordering::SeqCst),
        2,
        "jobs = 2"
    );
}

#[test]
fn concurrent_runs_on_one_cache_both_succeed_and_leave_it_valid() {
    let t = tempfile::tempdir().unwrap();
    let text: String = DIAMOND.to_string()
        + &(0..40)
            .map(|i| {
                format!(
                    "\n[node.e{i}]\nop = \"test.add\"\nin.a = \"c.value\"\nin.b = \"d.value\"\n"
                )
            })
            .collect::<String>();
    let g = write_graph(t.path(), "g.toml", &text);
    let cache = t.path().join("cache");
    std::thread::scope(|s| {
        let runs: Vec<_> = (0..3)
            .map(|i| {
                let (g, cache, out) = (&g, &cache, t.path().join(format!("out{i}")));
                s.spawn(move || {
                    let (reg, _) = registry();
                    run_file(&reg, g, &[], Some(cache), &out).unwrap()
                })
            })
            .collect();
        for r in runs {
            assert!(r.join().unwrap().report.succeeded());
        }
    });
    let (reg, counters) = registry();
    let after = run_file(&reg, &g, &[], Some(&cache), &t.path().join("out")).unwrap();
    assert_eq!(with_status(&after, Cached).len(), 45);
    assert_eq!(counters.total(), 0);
    let leftovers: Vec<_> = walk(&cache)
        .into_iter()
        .filter(|p| p.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

fn walk(dir: &std::path::Path) -> Vec<String> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p.display().to_string());
        }
    }
    out
}

#[test]
fn no_cache_runs_everything_and_writes_no_entries() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    run_file(&reg, &g, &[], None, &t.path().join("out")).unwrap();
    let o = run_file(&reg, &g, &[], None, &t.path().join("out")).unwrap();
    assert_eq!(with_status(&o, Ran).len(), 5);
    assert_eq!(counters.total(), 10);
    assert!(!t.path().join("cache").exists());
}

#[test]
fn sinks_rerun_when_their_file_or_output_folder_changes() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let text = format!(
        "{DIAMOND}\n[node.w]\nop = \"test.write\"\nin.value = \"c.value\"\nfile = \"sub/c.txt\"\n"
    );
    let g = write_graph(t.path(), "g.toml", &text);
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(
        std::fs::read_to_string(out.join("sub/c.txt")).unwrap(),
        "14"
    );
    let status = |o: &fusegraph_engine::schedule::RunOutcome| statuses(o)["w"];
    assert_eq!(
        status(&run_file(&reg, &g, &[], Some(&cache), &out).unwrap()),
        Cached
    );

    std::fs::remove_file(out.join("sub/c.txt")).unwrap();
    assert_eq!(
        status(&run_file(&reg, &g, &[], Some(&cache), &out).unwrap()),
        Ran
    );
    assert!(out.join("sub/c.txt").exists());

    let other = t.path().join("other");
    assert_eq!(
        status(&run_file(&reg, &g, &[], Some(&cache), &other).unwrap()),
        Ran
    );
    assert!(other.join("sub/c.txt").exists());
    assert!(other.join("report.json").exists());

    // A file outside the output folder is refused before anything runs.
    let Err(escape) = run_file(&reg, &g, &["w.file=../x.txt"], Some(&cache), &out) else {
        panic!("a sink writing ../x.txt ran");
    };
    assert!(
        escape.to_string().contains("inside the output folder"),
        "{escape}"
    );
}

#[test]
fn file_sources_are_keyed_by_content() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    std::fs::write(t.path().join("data.bin"), b"12345").unwrap();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.f]\nop = \"test.file\"\npath = \"data.bin\"\n\n[node.g]\nop = \"test.add\"\nin.a = \"f.bytes\"\n",
    );
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    let status = |o: fusegraph_engine::schedule::RunOutcome| statuses(&o)["f"];
    assert_eq!(
        status(run_file(&reg, &g, &[], Some(&cache), &out).unwrap()),
        Ran
    );
    // Rewriting the same bytes (new mtime) keeps the key.
    std::fs::write(t.path().join("data.bin"), b"12345").unwrap();
    assert_eq!(
        status(run_file(&reg, &g, &[], Some(&cache), &out).unwrap()),
        Cached
    );
    // A copy of the same bytes elsewhere is the same key too.
    std::fs::copy(t.path().join("data.bin"), t.path().join("copy.bin")).unwrap();
    assert_eq!(
        status(run_file(&reg, &g, &["f.path=copy.bin"], Some(&cache), &out).unwrap()),
        Cached
    );
    std::fs::write(t.path().join("data.bin"), b"123456").unwrap();
    let changed = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(statuses(&changed)["f"], Ran);
    assert_eq!(scalar(&changed, 1, "value"), 6.0);
}

#[test]
fn the_report_file_holds_every_node() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let text = format!("{DIAMOND}\n[node.bad]\nop = \"test.fail\"\nin.a = \"a.value\"\n");
    let g = write_graph(t.path(), "g.toml", &text);
    let out = t.path().join("out");
    run_file(&reg, &g, &[], None, &out).unwrap();
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["graph"], "diamond");
    let ids: Vec<&str> = report["nodes"]
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(ids, ["a", "b", "c", "x", "d", "bad"], "file order");
    assert_eq!(report["nodes"]["c"]["status"], "ran");
    assert_eq!(report["nodes"]["c"]["op"], "test.add");
    assert_eq!(report["nodes"]["c"]["key"].as_str().unwrap().len(), 64);
    assert!(report["nodes"]["c"]["ms"].as_f64().unwrap() >= 0.0);
    assert_eq!(report["nodes"]["bad"]["status"], "failed");
    assert!(
        report["nodes"]["bad"]["error"]
            .as_str()
            .unwrap()
            .contains("deliberate")
    );
    assert_eq!(report["metrics"]["c.sum"], 14.0);
}

#[test]
fn generated_files_live_in_the_cache_under_the_node_key() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.gen]\nop = \"test.generate\"\nfiles = 4\n",
    );
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    let first = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    let dir = match &first.results[0].as_ref().unwrap().outputs.0["dir"] {
        fusegraph_engine::Value::Path(p) => p.path.clone(),
        other => panic!("{other:?}"),
    };
    let key = &first.report.node("gen").unwrap().key;
    assert_eq!(
        dir,
        std::path::absolute(
            cache
                .join(format!(
                    "v{}/files",
                    fusegraph_engine::cache::FORMAT_VERSION
                ))
                .join(key)
                .join("series")
        )
        .unwrap()
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("slice3.txt")).unwrap(),
        "slice 3"
    );
    let leftovers: Vec<_> = walk(&cache)
        .into_iter()
        .filter(|p| p.contains(".tmp-"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    assert_eq!(
        statuses(&run_file(&reg, &g, &[], Some(&cache), &out).unwrap())["gen"],
        Cached
    );
    // Edited or deleted files make the entry stale: the node runs again.
    std::fs::write(dir.join("slice0.txt"), "edited").unwrap();
    assert_eq!(
        statuses(&run_file(&reg, &g, &[], Some(&cache), &out).unwrap())["gen"],
        Ran
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("slice0.txt")).unwrap(),
        "slice 0"
    );
    std::fs::remove_dir_all(cache.join(format!(
        "v{}/files",
        fusegraph_engine::cache::FORMAT_VERSION
    )))
    .unwrap();
    assert_eq!(
        statuses(&run_file(&reg, &g, &[], Some(&cache), &out).unwrap())["gen"],
        Ran
    );
    assert!(dir.join("slice2.txt").exists());
    assert_eq!(counters.runs("gen"), 3);

    // Without a cache the files live under OUT/.work for the run only.
    let nc = run_file(&reg, &g, &[], None, &out).unwrap();
    assert!(nc.report.succeeded());
    assert!(
        !out.join(".work").exists(),
        "--no-cache leaves no files behind"
    );
}

#[test]
fn a_cached_nodes_files_are_checked_when_a_node_that_runs_reads_them() {
    // What a re-run after a late parameter does: the phantom's folders are
    // not read again while only nodes after their readers compute.
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.gen]\nop = \"test.generate\"\nfiles = 3\n\n\
         [node.count]\nop = \"test.count_bytes\"\nin.dir = \"gen.dir\"\n\n\
         [node.one]\nop = \"test.source\"\nvalue = 1.0\n\n\
         [node.add]\nop = \"test.add\"\nin.a = \"count.bytes\"\nin.b = \"one.value\"\n",
    );
    let (cache, out) = (t.path().join("cache"), t.path().join("out"));
    let run = |sets: &[&str]| {
        run_with(
            &reg,
            &g,
            sets,
            Some(&cache),
            &out,
            &MemoryCache::new(),
            false,
        )
    };
    let sum = |outcome: &RunOutcome| outcome.report.node("add").unwrap().metrics["sum"];
    let first = run(&[]);
    assert_eq!(sum(&first), 21.0 + 1.0, "3 x \"slice N\", and one");
    let dir = cache
        .join(format!(
            "v{}/files",
            fusegraph_engine::cache::FORMAT_VERSION
        ))
        .join(&first.report.node("gen").unwrap().key)
        .join("series");
    std::fs::write(dir.join("slice0.txt"), "edited, longer").unwrap();
    // Only a node after the folder's reader runs: the folder is not read.
    let later = run(&["one.value=2.0"]);
    assert_eq!(with_status(&later, Ran), ["add", "one"]);
    assert_eq!(sum(&later), 21.0 + 2.0);
    assert_eq!(counters.runs("gen"), 1);
    // Its reader runs: the edit is found, the folder made again, and the
    // reader sees what the key stands for.
    let read = run(&["one.value=2.0", "count.label=again"]);
    assert_eq!(with_status(&read, Ran), ["add", "count", "gen"]);
    assert_eq!(sum(&read), 21.0 + 2.0);
    assert_eq!(
        std::fs::read_to_string(dir.join("slice0.txt")).unwrap(),
        "slice 0"
    );
}

#[test]
fn a_moved_cache_reads_its_own_files_and_recomputes_nothing() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.gen]\nop = \"test.generate\"\nfiles = 3\n",
    );
    let (old, new) = (t.path().join("cache"), t.path().join("elsewhere/cache"));
    let out = t.path().join("out");
    run_file(&reg, &g, &[], Some(&old), &out).unwrap();
    std::fs::create_dir_all(new.parent().unwrap()).unwrap();
    std::fs::rename(&old, &new).unwrap();
    let moved = run_file(&reg, &g, &[], Some(&new), &out).unwrap();
    assert_eq!(statuses(&moved)["gen"], Cached);
    assert_eq!(counters.runs("gen"), 1, "nothing regenerated");
    let dir = match &moved.results[0].as_ref().unwrap().outputs.0["dir"] {
        fusegraph_engine::Value::Path(p) => p.path.clone(),
        other => panic!("{other:?}"),
    };
    assert!(
        dir.starts_with(std::path::absolute(&new).unwrap()),
        "{} is not in the moved cache",
        dir.display()
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("slice2.txt")).unwrap(),
        "slice 2"
    );
}

#[test]
fn a_sink_publishes_its_files_and_leaves_no_staging_folder() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.a]\nop = \"test.source\"\nvalue = 2.0\n\n\
         [node.w]\nop = \"test.write\"\nin.value = \"a.value\"\nfile = \"sub/value.txt\"\n",
    );
    let out = t.path().join("out");
    let r = run_file(&reg, &g, &[], None, &out).unwrap();
    assert!(r.report.succeeded());
    assert!(out.join("sub/value.txt").is_file());
    let staging: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with(".staging-"))
        .collect();
    assert!(staging.is_empty(), "staging folders left: {staging:?}");
    match &r.results[1].as_ref().unwrap().outputs.0["file"] {
        fusegraph_engine::Value::Path(p) => {
            assert_eq!(
                p.path,
                std::path::absolute(out.join("sub/value.txt")).unwrap()
            )
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn an_unwritable_files_folder_falls_back_to_the_output_folder_with_a_note() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.gen]\nop = \"test.generate\"\nfiles = 2\n",
    );
    let cache = t.path().join("cache");
    let versioned = cache.join(format!("v{}", fusegraph_engine::cache::FORMAT_VERSION));
    std::fs::create_dir_all(&versioned).unwrap();
    // A file where the files folder should be: it cannot be created (as a
    // read-only cache, which root would write anyway).
    std::fs::write(versioned.join("files"), "not a folder").unwrap();
    let out = t.path().join("out");
    let r = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert!(r.report.succeeded(), "{:?}", r.report);
    let notes = &r.report.node("gen").unwrap().notes;
    assert!(
        notes
            .iter()
            .any(|n| n.contains("cannot be written") && n.contains(".work")),
        "{notes:?}"
    );
    let dir = match &r.results[0].as_ref().unwrap().outputs.0["dir"] {
        fusegraph_engine::Value::Path(p) => p.path.clone(),
        other => panic!("{other:?}"),
    };
    assert!(
        dir.starts_with(std::path::absolute(out.join(".work")).unwrap()),
        "{}",
        dir.display()
    );
    assert!(dir.join("slice1.txt").is_file());
}

#[test]
fn a_result_read_from_files_deleted_during_the_node_is_not_cached() {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.gen]\nop = \"test.generate\"\nfiles = 4\n\n\
         [node.count]\nop = \"test.count_then_lose\"\nin.dir = \"gen.dir\"\n",
    );
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    // The first run loses a file after reading the folder: the node fails,
    // naming the input, and stores nothing.
    let first = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    let count = first.report.node("count").unwrap();
    assert_eq!(count.status, Failed);
    let why = count.error.as_deref().unwrap();
    assert!(
        why.contains("input `dir`") && why.contains("while the node ran"),
        "{why}"
    );
    // The next run regenerates the folder and counts all of it afresh.
    let second = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(statuses(&second)["gen"], Ran);
    assert_eq!(statuses(&second)["count"], Ran);
    assert_eq!(scalar(&second, 1, "files"), 4.0);
    assert_eq!(counters.runs("count"), 2);
    let third = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(statuses(&third)["count"], Cached);
}

#[test]
fn a_result_read_from_a_file_edited_during_the_node_is_not_cached() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    std::fs::write(t.path().join("data.bin"), b"12345").unwrap();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.f]\nop = \"test.read_then_touch\"\npath = \"data.bin\"\n",
    );
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    let first = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    let f = first.report.node("f").unwrap();
    assert_eq!(f.status, Failed);
    let why = f.error.as_deref().unwrap();
    assert!(why.contains("path parameter was modified"), "{why}");
    // The file as it is now: 14 bytes, computed, not a stale 5.
    let second = run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    assert_eq!(statuses(&second)["f"], Ran);
    assert_eq!(scalar(&second, 0, "bytes"), 14.0);
}

/// Entries that are no longer files of their declared size (grown to 3 GB, a
/// FIFO, a link to /dev/zero) are recomputed without being read: each run
/// finishes in a bounded time (a FIFO opened for reading would block, a
/// device never end) and memory (a 3 GB read).
#[test]
fn entries_of_the_wrong_kind_or_size_are_recomputed_without_reading_them() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let g = write_graph(t.path(), "g.toml", DIAMOND);
    let cache = t.path().join("cache");
    let out = t.path().join("out");
    run_file(&reg, &g, &[], Some(&cache), &out).unwrap();
    let graph = load_graph(&g, &[], &reg).unwrap();
    let keys = node_keys(&graph, &out).unwrap();
    let disk = DiskCache::open(&cache).unwrap();
    let path = |id: &str| disk.entry_path(&keys[graph.index_of(id).unwrap()]);
    // Grown (sparse, so the disk is not filled).
    std::fs::OpenOptions::new()
        .write(true)
        .open(path("a"))
        .unwrap()
        .set_len(3 << 30)
        .unwrap();
    // A FIFO, where mkfifo exists.
    std::fs::remove_file(path("b")).unwrap();
    let fifo = std::process::Command::new("mkfifo")
        .arg(path("b"))
        .status()
        .is_ok_and(|s| s.success());
    if !fifo {
        eprintln!("mkfifo is not available: the FIFO case is skipped");
    }
    // A link to a device that never ends.
    std::fs::remove_file(path("x")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", path("x")).unwrap();

    let (done, wait) = std::sync::mpsc::channel();
    let (reg2, g2, cache2, out2) = (reg, g.clone(), cache.clone(), out.clone());
    std::thread::spawn(move || {
        let o = run_file(&reg2, &g2, &[], Some(&cache2), &out2).unwrap();
        let _ = done.send(with_status(&o, Ran));
    });
    let ran = wait
        .recv_timeout(std::time::Duration::from_secs(60))
        .expect("the run finished: no entry was read whole");
    let mut expected = vec!["a", "x"];
    if fifo {
        expected.insert(1, "b");
    }
    // c depends on b and x, which ran again with the same result: c stays cached.
    assert_eq!(ran, expected);
    assert!(std::fs::metadata(path("a")).unwrap().len() < 4096);
}
