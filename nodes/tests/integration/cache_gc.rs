//! `fusegraph cache gc` while another run uses the cache loses nothing that
//! run needs, removes what nobody used, and `stats` then agrees with `du`.

use fusegraph_engine::cache::{DiskCache, FORMAT_VERSION, MemoryCache};
use fusegraph_engine::cache_admin::{GcLimits, gc, stats, verify};
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::session::{load_graph, run};
use fusegraph_engine::{NodeStatus, RunReport};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, SystemTime};

fn run_graph(graph: &str, sets: &[&str], cache: &Path, out: &Path) -> RunReport {
    let file = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../graphs")
        .join(graph);
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let registry = fusegraph_nodes::builtin_registry();
    let valid = load_graph(&file, &sets, &registry).expect("a valid graph");
    let options = RunOptions {
        out_dir: out.to_path_buf(),
        cache: Some(DiskCache::open(cache).expect("a cache")),
        jobs: 2,
        progress: false,
        provenance: Default::default(),
        keep_outputs: false,
    };
    run(&valid, &options, &MemoryCache::new())
        .expect("the run finishes")
        .report
}

/// Sets every entry's last use `by` into the past.
fn age_entries(cache: &Path, by: Duration) {
    let v = cache.join(format!("v{FORMAT_VERSION}"));
    for shard in std::fs::read_dir(&v).unwrap().flatten() {
        if shard.file_name().len() != 2 {
            continue;
        }
        for e in std::fs::read_dir(shard.path()).unwrap().flatten() {
            let f = std::fs::File::options().write(true).open(e.path()).unwrap();
            f.set_modified(SystemTime::now() - by).unwrap();
        }
    }
}

#[test]
fn gc_beside_a_running_job_keeps_what_it_uses_and_removes_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let small = ["phantom.size=\"small\""];
    // Entries of another graph nobody will use again, and the MRI branch's.
    assert!(run_graph("demo.toml", &[], &cache, &dir.path().join("demo")).succeeded());
    assert!(run_graph("mri.toml", &small, &cache, &dir.path().join("a")).succeeded());
    let before = stats(&cache).unwrap();
    let demo_entries = before.by_op["math.constant"].0
        + before.by_op["math.binary"].0
        + before.by_op["io.write_json"].0;
    age_entries(&cache, Duration::from_secs(2 * 86_400));

    // gc, again and again, while the MRI branch runs once more on the cache.
    let limits = GcLimits {
        older_than: Some(Duration::from_secs(86_400)),
        max_bytes: None,
        keep_recent: Duration::from_secs(600),
        dry_run: false,
    };
    let done = AtomicBool::new(false);
    let report = std::thread::scope(|s| {
        let collector = s.spawn(|| {
            let mut removed = 0;
            while !done.load(Ordering::Acquire) {
                removed += gc(&cache, limits, SystemTime::now()).unwrap().removed.len();
            }
            removed
        });
        let report = run_graph("mri.toml", &small, &cache, &dir.path().join("b"));
        done.store(true, Ordering::Release);
        assert!(collector.join().unwrap() >= demo_entries);
        report
    });
    // The run lost nothing: every node finished, from the cache or again.
    assert!(report.succeeded(), "{:?}", report.nodes);
    assert!(
        report
            .nodes
            .iter()
            .all(|(_, n)| matches!(n.status, NodeStatus::Ran | NodeStatus::Cached))
    );
    // What it used is marked used and stays; the other graph's entries are gone.
    let after = stats(&cache).unwrap();
    for op in ["math.constant", "math.binary", "io.write_json"] {
        assert!(
            !after.by_op.contains_key(op),
            "{op} entries left: {:?}",
            after.by_op
        );
    }
    for op in [
        "phantom.generate",
        "dicom.load_series",
        "mri.otsu",
        "mri.isosurface",
    ] {
        assert_eq!(after.by_op.get(op).map(|x| x.0), Some(1), "{op}");
    }
    let again = gc(&cache, limits, SystemTime::now()).unwrap();
    assert!(again.removed.is_empty(), "{:?}", again.removed);
    // A third run into the same folder (sinks' keys hold it) reuses every node.
    let third = run_graph("mri.toml", &small, &cache, &dir.path().join("b"));
    let computed: Vec<&str> = third
        .nodes
        .iter()
        .filter(|(_, n)| n.status != NodeStatus::Cached)
        .map(|(id, _)| id.as_str())
        .collect();
    assert!(computed.is_empty(), "computed again: {computed:?}");
    assert!(verify(&cache, false).unwrap().clean());

    // `stats` counts as `du -sb` does, where du is found.
    if let Ok(du) = std::process::Command::new("du")
        .arg("-sb")
        .arg(&cache)
        .output()
        && du.status.success()
    {
        let bytes: u64 = String::from_utf8_lossy(&du.stdout)
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert_eq!(stats(&cache).unwrap().total_bytes, bytes);
    }
}

#[test]
fn verify_finds_corrupt_entries_orphans_and_stale_leases_and_repairs_them() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    assert!(run_graph("demo.toml", &[], &cache, &dir.path().join("demo")).succeeded());
    let v = cache.join(format!("v{FORMAT_VERSION}"));
    assert!(verify(&cache, false).unwrap().clean());
    // One entry's last byte flipped, a files folder of no entry, a lease of
    // a process that cannot exist (pid above Linux's largest).
    let entry = std::fs::read_dir(&v)
        .unwrap()
        .flatten()
        .filter(|s| s.file_name().len() == 2)
        .flat_map(|s| std::fs::read_dir(s.path()).unwrap().flatten())
        .next()
        .unwrap()
        .path();
    let mut bytes = std::fs::read(&entry).unwrap();
    *bytes.last_mut().unwrap() ^= 0xff;
    std::fs::write(&entry, bytes).unwrap();
    std::fs::create_dir_all(v.join("files").join("ab".repeat(32))).unwrap();
    std::fs::create_dir_all(v.join("leases")).unwrap();
    let host = fusegraph_engine::process::host_name();
    std::fs::write(
        v.join("leases").join(format!("{}.lease", "cd".repeat(32))),
        format!("{host} 4194304\n"),
    )
    .unwrap();
    let found = verify(&cache, false).unwrap();
    assert_eq!(found.corrupt.len(), 1, "{found:?}");
    assert!(found.corrupt[0].1.contains("checksum"), "{found:?}");
    assert_eq!(
        (found.orphans.len(), found.stale_leases.len()),
        (1, 1),
        "{found:?}"
    );
    assert!(verify(&cache, true).unwrap().repaired);
    assert!(verify(&cache, false).unwrap().clean());
    // The corrupt entry is computed again on the next run (into the same
    // folder: sinks' keys hold it), and only it.
    let r = run_graph("demo.toml", &[], &cache, &dir.path().join("demo"));
    assert_eq!(
        r.nodes
            .iter()
            .filter(|(_, n)| n.status == NodeStatus::Ran)
            .count(),
        1
    );
}
