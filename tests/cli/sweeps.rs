//! `fusegraph sweep` end to end on the small phantom's MRI branch: a grid of
//! Otsu bins x smoothing plus a failing variant, run in one process and as
//! three shard processes started at once on one cache folder, then merged.
//! The comparisons agree, no node key is computed twice across the
//! processes, and a failed variant is reported in its row while the others
//! finish. Bad sweeps are refused before anything runs.

use super::common::{chromium, fusegraph, stderr};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

const SWEEP: &str = r#"
[sweep]
graph = "mri.toml"
rank_by = "eval_surface.mean_mm"
metrics = ["surface.triangles", "eval_surface.p95_mm"]
set = { "phantom.size" = "small" }

[sweep.vary]
"otsu.bins" = [64, 256]
"surface.smooth_iterations" = [0, 5]

# No surface at level 2 of a volume stretched to [0, 1]: this one fails.
[variant.too_high]
"surface.in.level" = ""
"surface.level" = 2.0
"#;

fn setup(dir: &Path) {
    let graphs = Path::new(env!("CARGO_MANIFEST_DIR")).join("graphs");
    std::fs::copy(graphs.join("mri.toml"), dir.join("mri.toml")).unwrap();
    std::fs::write(dir.join("surface.toml"), SWEEP).unwrap();
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The comparison's rows without the columns that depend on who computed
/// what (times, computed and reused counts).
fn results(dir: &Path) -> Vec<String> {
    read(&dir.join("comparison.csv"))
        .lines()
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            // variant, overrides, status, 2 metrics | times and counts | error
            let mut kept = cells[..5].to_vec();
            kept.push(cells[cells.len() - 1]);
            kept.join(",")
        })
        .collect()
}

/// Node key -> how many times a variant's report says it ran.
fn computed_keys(dir: &Path, variants: &[&str]) -> BTreeMap<String, usize> {
    let mut counts = BTreeMap::new();
    for v in variants {
        let r: serde_json::Value =
            serde_json::from_str(&read(&dir.join(v).join("report.json"))).unwrap();
        for (_, n) in r["nodes"].as_object().unwrap() {
            if n["status"] == "ran" {
                *counts
                    .entry(n["key"].as_str().unwrap().to_string())
                    .or_insert(0) += 1;
            }
        }
    }
    counts
}

const VARIANTS: [&str; 5] = ["01_64_0", "02_64_5", "03_256_0", "04_256_5", "too_high"];

#[test]
fn shards_started_at_once_on_one_cache_merge_into_the_single_process_comparison() {
    let t = tempfile::tempdir().unwrap();
    setup(t.path());
    let variants = VARIANTS;

    // One process.
    let o = fusegraph(
        &[
            "sweep",
            "surface.toml",
            "--out",
            "single",
            "--cache",
            "single-cache",
        ],
        t.path(),
    );
    assert_eq!(o.status.code(), Some(1), "a variant failed: {}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("sweep `surface`: 5 variants, all valid"), "{e}");
    assert!(
        e.contains("1 of 5 variants did not finish: too_high (failed)"),
        "{e}"
    );
    let single = t.path().join("single");
    let md = read(&single.join("comparison.md"));
    assert!(
        md.contains("Best by `eval_surface.mean_mm` (lower is better): **"),
        "{md}"
    );
    assert!(md.contains("| too_high | surface.in.level=; surface.level=2.0 | failed: surface: no surface at level 2"), "{md}");
    let html = read(&single.join("comparison.html"));
    assert!(
        html.contains("<table id=\"comparison\">") && html.contains("<svg"),
        "table and plots"
    );
    // Every distinct node key computed once in the one process.
    let once = computed_keys(&single, &variants);
    assert!(once.values().all(|&n| n == 1), "{once:?}");

    // Three shard processes started at once on one cache folder.
    let at_once: Vec<_> = (1..=3)
        .map(|i| {
            Command::new(env!("CARGO_BIN_EXE_fusegraph"))
                .args([
                    "sweep",
                    "surface.toml",
                    "--out",
                    "at-once",
                    "--cache",
                    "at-once-cache",
                ])
                .args(["--shard", &format!("{i}/3")])
                .current_dir(t.path())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .expect("starts")
        })
        .collect();
    for child in at_once {
        let o = child.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            stderr(&o).contains("shard done; when every shard is: fusegraph sweep --merge"),
            "{}",
            stderr(&o)
        );
    }
    {
        let folder = "at-once";
        let o = fusegraph(&["sweep", "--merge", folder], t.path());
        assert_eq!(o.status.code(), Some(1), "too_high failed: {}", stderr(&o));
        let dir = t.path().join(folder);
        assert_eq!(results(&dir), results(&single), "{folder}");
        // No key computed twice across the processes, and every key the one
        // process computed was computed by some shard.
        let counts = computed_keys(&dir, &variants);
        let twice: Vec<_> = counts.iter().filter(|(_, n)| **n > 1).collect();
        assert!(twice.is_empty(), "{folder}: computed twice: {twice:?}");
        // As many distinct keys computed as by the one process (sinks' keys
        // hold their output folders, so the keys themselves differ there).
        assert_eq!(counts.len(), once.len(), "{folder}");
    }
    // A shard of another sweep refuses the folder, naming both plans.
    std::fs::copy(t.path().join("surface.toml"), t.path().join("other.toml")).unwrap();
    let o = fusegraph(
        &["sweep", "other.toml", "--out", "at-once", "--shard", "2/2"],
        t.path(),
    );
    let e = stderr(&o);
    assert_ne!(o.status.code(), Some(0), "{e}");
    assert!(
        e.contains("sweep.json holds sweep `surface` from") && e.contains("other.toml"),
        "{e}"
    );
}

#[test]
fn a_bad_variant_is_refused_before_anything_runs() {
    let t = tempfile::tempdir().unwrap();
    setup(t.path());
    std::fs::write(
        t.path().join("bad.toml"),
        "[sweep]\ngraph = \"mri.toml\"\n[sweep.vary]\n\"otsu.bins\" = [64, 0]\n[variant.typo]\n\"surfce.level\" = 0.5\n",
    )
    .unwrap();
    let o = fusegraph(&["sweep", "bad.toml", "--out", "bad-out"], t.path());
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("variant 02_0"), "{e}");
    assert!(e.contains("bins"), "{e}");
    assert!(
        e.contains("variant typo: no node with this id (did you mean `surface`?)"),
        "{e}"
    );
    assert!(!t.path().join("bad-out").exists(), "nothing ran");
    // Metrics of nodes the graph does not have.
    std::fs::write(
        t.path().join("metrics.toml"),
        "[sweep]\ngraph = \"mri.toml\"\nrank_by = \"surfce.area_mm2\"\nmetrics = [\"nowhere.x\"]\n[sweep.vary]\n\"otsu.bins\" = [64, 128]\n",
    )
    .unwrap();
    let o = fusegraph(&["sweep", "metrics.toml", "--out", "m-out"], t.path());
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        e.contains("\"surfce.area_mm2\" names node `surfce`, which the graph does not have (did you mean `surface`?)"),
        "{e}"
    );
    assert!(e.contains("\"nowhere.x\" names node `nowhere`"), "{e}");
    assert!(!t.path().join("m-out").exists(), "nothing ran");
    let o = fusegraph(&["sweep", "--merge", "nowhere"], t.path());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("sweep.json"), "{}", stderr(&o));
}

#[test]
fn the_shipped_sweeps_are_valid_in_every_variant() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("graphs/sweeps");
    let registry = fusegraph_nodes::builtin_registry();
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let file = entry.unwrap().path();
        if file.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let plan = fusegraph_engine::sweep::load_sweep(&file).unwrap_or_else(|e| panic!("{e}"));
        let graphs = fusegraph_engine::sweep::validate_variants(&plan, &registry)
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        assert_eq!(graphs.len(), plan.variants.len());
        assert!(plan.rank_by.is_some(), "{}: ranked", file.display());
        checked += 1;
    }
    assert!(checked >= 3, "ICP, matchers, MRI surface");
}

#[test]
fn the_comparison_page_sorts_in_a_real_browser() {
    let Some(browser) = chromium() else {
        eprintln!("skipped: no chromium installed (apt install chromium)");
        return;
    };
    let t = tempfile::tempdir().unwrap();
    setup(t.path());
    let o = fusegraph(
        &["sweep", "surface.toml", "--out", "s", "--no-cache"],
        t.path(),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let page = t.path().join("s/comparison.html");
    let dom = |hash: &str| {
        let profile = tempfile::tempdir().unwrap();
        let o = Command::new(browser)
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--virtual-time-budget=5000",
            ])
            .args([
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--no-first-run",
            ])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg("--dump-dom")
            .arg(format!("file://{}{hash}", page.display()))
            .output()
            .expect("run the browser");
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let order = |dom: &str| -> Vec<String> {
        let body = &dom[dom.find("<tbody>").expect("a table body")..];
        body.split("<tr class=")
            .skip(1)
            .map(|row| {
                row.split("<td>")
                    .nth(1)
                    .unwrap_or("")
                    .split('<')
                    .next()
                    .unwrap_or("")
                    .to_string()
            })
            .collect()
    };
    let as_written = order(&dom(""));
    assert_eq!(
        as_written,
        ["01_64_0", "02_64_5", "03_256_0", "04_256_5", "too_high"]
    );
    // Sorted by the skin distance, descending: unsmoothed first, the failed
    // variant (no value) last.
    let sorted = order(&dom("#sort=-eval_surface.mean_mm"));
    assert_eq!(sorted.len(), 5, "{sorted:?}");
    assert!(
        sorted[0].ends_with("_0") && sorted[1].ends_with("_0"),
        "{sorted:?}"
    );
    assert_eq!(sorted[4], "too_high", "{sorted:?}");
}
