//! Plugins end to end: the example census matcher swapped into the stereo
//! graph by config alone, cached and invalidated like a built-in op, loaded
//! from `--plugin`, `[graph] plugins` and FUSEGRAPH_PLUGIN_PATH; and bad
//! plugins (another ABI version, no symbols, not a library, ops that panic,
//! fail or return malformed outputs), each refused with a clear error while
//! the host survives and a graph's other branches finish.

use super::common::stderr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The plugin library `name` (crate name with `_`), built once per test run
/// into its own target folder (the outer `cargo test` does not build
/// cdylibs).
fn plugin(name: &str) -> PathBuf {
    static BUILT: OnceLock<PathBuf> = OnceLock::new();
    let dir = BUILT.get_or_init(|| {
        let target = root().join("target/test-plugins");
        let o = Command::new(env!("CARGO"))
            .args(["build", "--quiet"])
            .args(["-p", "census-matcher", "-p", "test-plugin-abi-mismatch"])
            .args([
                "-p",
                "test-plugin-no-symbols",
                "-p",
                "test-plugin-data-symbols",
                "-p",
                "test-plugin-misbehaving",
            ])
            .env("CARGO_TARGET_DIR", &target)
            .current_dir(root())
            .output()
            .expect("cargo runs");
        assert!(o.status.success(), "building the plugins: {}", stderr(&o));
        target.join("debug")
    });
    let file = dir.join(format!(
        "{}{name}{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    ));
    assert!(file.is_file(), "{}", file.display());
    file
}

fn fusegraph_env(args: &[&str], cwd: &Path, env: &[(&str, &Path)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_fusegraph"));
    cmd.args(args)
        .current_dir(cwd)
        .env_remove("FUSEGRAPH_PLUGIN_PATH");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("fusegraph runs")
}

fn fusegraph(args: &[&str], cwd: &Path) -> Output {
    fusegraph_env(args, cwd, &[])
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

#[test]
fn nodes_lists_a_plugins_ops_with_their_origin() {
    let t = tempfile::tempdir().unwrap();
    let lib = plugin("census_matcher");
    let o = fusegraph(&["nodes", "--plugin", lib.to_str().unwrap()], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("census.match (v1): Census transform"),
        "{text}"
    );
    assert!(text.contains(&format!(
        "from plugin {}",
        lib.canonicalize().unwrap().display()
    )));
    assert!(
        text.contains("aggregate_px: integer = 7 [px] in 1..=51"),
        "{text}"
    );
    let o = fusegraph(
        &["nodes", "--json", "--plugin", lib.to_str().unwrap()],
        t.path(),
    );
    let specs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let census = specs
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "census.match")
        .expect("listed");
    assert_eq!(census["origin"]["content_hash"].as_str().unwrap().len(), 64);
    assert!(
        specs
            .as_array()
            .unwrap()
            .iter()
            .any(|s| s["name"] == "stereo.sgm")
    );
}

#[test]
fn the_census_plugin_matches_the_phantom_and_is_cached_like_a_built_in_op() {
    let t = tempfile::tempdir().unwrap();
    std::fs::copy(
        root().join("graphs/stereo.toml"),
        t.path().join("stereo.toml"),
    )
    .unwrap();
    // A copy of the library: the test changes its content below.
    let lib = t.path().join(plugin("census_matcher").file_name().unwrap());
    std::fs::copy(plugin("census_matcher"), &lib).unwrap();
    let args = [
        "run",
        "stereo.toml",
        "--plugin",
        lib.to_str().unwrap(),
        "--set",
        "match.op=census.match",
        "--set",
        "phantom.size=small",
    ];
    let o = fusegraph(&args, t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let out = t.path().join("out/stereo");
    let r = report(&out);
    let m = |k: &str| {
        r["metrics"][k]
            .as_f64()
            .unwrap_or_else(|| panic!("no {k}: {r}"))
    };
    // Against the ray-cast true disparity over the skin.
    assert!(m("eval_disparity.bad_2_pct") < 6.0, "{}", r["metrics"]);
    assert!(m("eval_disparity.coverage_pct") > 90.0, "{}", r["metrics"]);
    assert!(m("match.coverage_pct") > 50.0, "{}", r["metrics"]);
    assert_eq!(r["nodes"]["match"]["op"], "census.match");

    // Again: every node cached, the plugin op too.
    let o = fusegraph(&args, t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&out);
    let ran: Vec<&String> = r["nodes"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(_, n)| n["status"] == "ran")
        .map(|(id, _)| id)
        .collect();
    assert!(ran.is_empty(), "re-ran: {ran:?}");

    // New content (as a rebuild gives): the plugin op and what follows re-run.
    let mut bytes = std::fs::read(&lib).unwrap();
    bytes.extend_from_slice(b"rebuilt");
    std::fs::write(&lib, bytes).unwrap();
    let o = fusegraph(&args, t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&out);
    let status = |id: &str| r["nodes"][id]["status"].as_str().unwrap().to_string();
    assert_eq!(status("match"), "ran");
    assert_eq!(status("eval_disparity"), "ran");
    assert_eq!(status("phantom"), "cached");
    assert_eq!(status("rectify"), "cached");
}

#[test]
fn plugins_named_by_the_graph_or_the_environment_are_loaded() {
    let t = tempfile::tempdir().unwrap();
    let libs = t.path().join("libs");
    std::fs::create_dir(&libs).unwrap();
    let lib = libs.join(plugin("test_plugin_misbehaving").file_name().unwrap());
    std::fs::copy(plugin("test_plugin_misbehaving"), &lib).unwrap();
    let graph = "[node.d]\nop = \"bad.good\"\n";
    std::fs::write(
        t.path().join("g.toml"),
        format!(
            "[graph]\nplugins = [\"libs/{}\"]\n{graph}",
            lib.file_name().unwrap().to_str().unwrap()
        ),
    )
    .unwrap();
    let o = fusegraph(&["run", "g.toml", "--no-cache"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let r = report(&t.path().join("out/g"));
    assert_eq!(r["metrics"]["d.ok_count"], 8.0);
    assert_eq!(r["nodes"]["d"]["notes"][0], "a note from the plugin");

    std::fs::write(t.path().join("h.toml"), graph).unwrap();
    let o = fusegraph(&["validate", "h.toml"], t.path());
    assert_eq!(o.status.code(), Some(2), "no plugin, no op: {}", stderr(&o));
    assert!(stderr(&o).contains("bad.good"), "{}", stderr(&o));
    // A folder on FUSEGRAPH_PLUGIN_PATH: its libraries are loaded.
    let o = fusegraph_env(
        &["validate", "h.toml"],
        t.path(),
        &[("FUSEGRAPH_PLUGIN_PATH", &libs)],
    );
    assert!(o.status.success(), "{}", stderr(&o));

    // A graph naming a plugin that is missing: exit 2, naming the key.
    std::fs::write(
        t.path().join("m.toml"),
        format!("[graph]\nplugins = [\"libs/nothing.so\"]\n{graph}"),
    )
    .unwrap();
    let o = fusegraph(&["validate", "m.toml"], t.path());
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("plugins") && stderr(&o).contains("nothing.so"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn bad_libraries_are_refused_naming_the_file() {
    let t = tempfile::tempdir().unwrap();
    let junk = t.path().join("libjunk.so");
    std::fs::write(&junk, "not a library\n").unwrap();
    let cases = [
        (
            plugin("test_plugin_abi_mismatch"),
            "built for plugin ABI version 999",
        ),
        (
            plugin("test_plugin_no_symbols"),
            "not a fusegraph plugin: it has no `fusegraph_plugin_abi_version` symbol",
        ),
        (
            plugin("test_plugin_data_symbols"),
            "its `fusegraph_plugin_abi_version` symbol is data, not a function",
        ),
        (junk, "not a loadable library: dlopen failed: "),
        (t.path().join("missing.so"), "missing.so"),
    ];
    for (lib, says) in cases {
        let o = fusegraph(&["nodes", "--plugin", lib.to_str().unwrap()], t.path());
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{}: {e}", lib.display());
        assert!(e.contains(says), "{}: {e}", lib.display());
        assert!(
            e.contains(lib.file_name().unwrap().to_str().unwrap()),
            "{e}"
        );
        assert!(!e.contains("panicked"), "{e}");
    }
}

#[test]
fn misbehaving_ops_fail_clearly_and_the_other_branches_finish() {
    let t = tempfile::tempdir().unwrap();
    let lib = plugin("test_plugin_misbehaving");
    let mut graph = String::from("[node.fine]\nop = \"math.constant\"\nvalue = 2.0\n");
    for op in ["panic", "fail", "short", "wrong_type", "undeclared", "good"] {
        graph += &format!("[node.{op}]\nop = \"bad.{op}\"\nin.x = \"fine.value\"\n");
    }
    std::fs::write(t.path().join("g.toml"), graph).unwrap();
    let o = fusegraph(
        &[
            "run",
            "g.toml",
            "--no-cache",
            "--plugin",
            lib.to_str().unwrap(),
        ],
        t.path(),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        !e.contains("panicked at"),
        "the plugin's panic is caught quietly: {e}"
    );
    let r = report(&t.path().join("out/g"));
    let node = |id: &str| &r["nodes"][id];
    assert_eq!(node("fine")["status"], "ran");
    assert_eq!(node("good")["status"], "ran");
    let shown = lib.canonicalize().unwrap().display().to_string();
    for (id, says) in [
        ("panic", "panicked: index 9 out of range in the matcher"),
        ("fail", "refused: the pair is not rectified"),
        (
            "short",
            "output `disparity`: 20 bytes of data for shape [2, 4]",
        ),
        (
            "wrong_type",
            "output `disparity`: a Scalar where the declaration says Disparity",
        ),
        ("undeclared", "produced an undeclared output `extra`"),
    ] {
        assert_eq!(node(id)["status"], "failed", "{id}: {}", node(id));
        let error = node(id)["error"].as_str().unwrap();
        assert!(
            error.contains(&format!("plugin {shown}: op `bad.{id}`")),
            "{id}: {error}"
        );
        assert!(error.contains(says), "{id}: {error}");
    }
}

#[test]
fn a_sweep_loads_its_plugins_once_for_every_variant() {
    let t = tempfile::tempdir().unwrap();
    let lib = plugin("test_plugin_misbehaving");
    std::fs::write(
        t.path().join("g.toml"),
        "[node.c]\nop = \"math.constant\"\nvalue = 1.0\n[node.d]\nop = \"bad.good\"\nin.x = \"c.value\"\n",
    )
    .unwrap();
    std::fs::write(
        t.path().join("s.toml"),
        format!(
            "[sweep]\ngraph = \"g.toml\"\nrank_by = \"d.ok_count\"\nplugins = [{:?}]\n[sweep.vary]\n\"c.value\" = [1.0, 2.0, 3.0]\n",
            lib.display().to_string()
        ),
    )
    .unwrap();
    let o = fusegraph(&["sweep", "s.toml", "--out", "sw", "--no-cache"], t.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(t.path().join("sw/comparison.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 3, "{csv}");
    assert!(rows.iter().all(|r| r.contains(",done,8,")), "{csv}");
}
