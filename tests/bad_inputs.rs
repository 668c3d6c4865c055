//! Inputs a careless user or an unlucky machine brings: special files, an
//! output path that is a file, a closed pipe, out-of-range sizes, a tampered
//! cache. Each gets a clear error (exit 1 or 2) or the right result, never a
//! panic (exit 101) or a hang.

mod common;

use common::{fusegraph, stderr};
use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};

fn demo_copy(dir: &Path) {
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("graphs/demo.toml");
    std::fs::copy(demo, dir.join("demo.toml")).unwrap();
}

#[cfg(unix)]
#[test]
fn a_device_is_refused_as_a_graph_file() {
    let t = tempfile::tempdir().unwrap();
    let o = fusegraph(&["validate", "/dev/zero"], t.path());
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("/dev/zero: not a regular file"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn an_output_path_that_is_a_file_is_named() {
    let t = tempfile::tempdir().unwrap();
    demo_copy(t.path());
    std::fs::write(t.path().join("taken"), "x").unwrap();
    let o = fusegraph(&["run", "demo.toml", "--out", "taken"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--out taken: is a file, not a folder"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn sizes_out_of_range_are_refused_before_allocating() {
    let t = tempfile::tempdir().unwrap();
    for args in [
        &["bench", "icp", "--iterations", "0"][..],
        &["bench", "marching-cubes", "--size", "100000"][..],
        &["bench", "scheduler", "--nodes", "0"][..],
    ] {
        let o = fusegraph(args, t.path());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("is not within 1 to"),
            "{args:?}: {}",
            stderr(&o)
        );
    }
}

#[cfg(unix)]
#[test]
fn a_closed_output_pipe_ends_the_process_quietly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_fusegraph"))
        .args(["nodes", "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0u8; 10];
    child.stdout.take().unwrap().read_exact(&mut first).unwrap();
    // The pipe closes here, as `| head -c 10` closes it.
    let out = child.wait_with_output().unwrap();
    assert_ne!(out.status.code(), Some(101), "{}", stderr(&out));
    assert!(!stderr(&out).contains("panicked"), "{}", stderr(&out));
}

#[test]
fn a_cache_entry_copied_over_another_nodes_is_recomputed() {
    let t = tempfile::tempdir().unwrap();
    demo_copy(t.path());
    let o = fusegraph(&["run", "demo.toml"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let report = |dir: &Path| -> serde_json::Value {
        let text = std::fs::read_to_string(dir.join("out/demo/report.json")).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    let first = report(t.path());
    let key = |node: &str| first["nodes"][node]["key"].as_str().unwrap().to_string();
    let entry = |k: &str| {
        t.path().join(format!(
            ".fusegraph/cache/v{}/{}/{k}.entry",
            fusegraph_engine::cache::FORMAT_VERSION,
            &k[..2]
        ))
    };
    // Two nodes with the same output type: the focal length's entry over the
    // verging angle's.
    std::fs::copy(entry(&key("focal_mm")), entry(&key("verging_deg"))).unwrap();
    let o = fusegraph(&["run", "demo.toml"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let again = report(t.path());
    assert_eq!(again["nodes"]["verging_deg"]["status"], "ran");
    assert_eq!(again["metrics"], first["metrics"]);
}
