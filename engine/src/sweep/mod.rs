//! Variant sweeps: one base graph, many variants (lists of values, op swaps,
//! named override tables), every one validated before anything runs, all
//! run against one cache so that what variants share is computed once, and
//! compared in one table ([`compare`]).
//!
//! Sharding: `--shard I/N` runs the variants whose position (from 0) is
//! `I - 1` modulo N. Shards may run at once on several machines against one
//! cache on a shared filesystem: leases make each node key computed by one
//! process only, and entries are written to a temporary file and renamed
//! (see the README for what NFS and Lustre need). Each shard writes the
//! plan (`sweep.json`) and its variants' reports; `merge` builds the
//! comparison from the folder.

pub mod compare;
mod compare_html;
pub mod plan;

use crate::cache::{DiskCache, MemoryCache};
use crate::error::GraphErrors;
use crate::graph::GraphDoc;
use crate::registry::Registry;
use crate::report::NodeStatus;
use crate::schedule::RunOptions;
use crate::session::{RunError, run, with_graph_plugins, with_plugins, with_scripts};
use crate::validate::{ValidGraph, validate};
pub use plan::{Better, SweepPlan, Variant, load_sweep};
use std::path::{Path, PathBuf};

/// Every variant's graph, validated; errors name the variant, node and key.
pub fn validate_variants(
    plan: &SweepPlan,
    registry: &Registry,
) -> Result<Vec<ValidGraph>, GraphErrors> {
    let registry = with_plugins(&plan.plugins, &plan.file, registry)?;
    let registry = with_scripts(&plan.python, &plan.file, registry)?;
    let doc = GraphDoc::load(&plan.graph)?;
    let registry = with_graph_plugins(&doc, &registry)?;
    let mut graphs = Vec::new();
    let mut errors = Vec::new();
    for v in &plan.variants {
        let by = format!("variant {}", v.name);
        let mut d = doc.clone();
        let mut failed = false;
        for (k, value) in plan.common.iter().chain(&v.overrides) {
            let (id, key) = k.split_once('.').expect("checked NODE.KEY");
            if let Err(mut e) = d.set(id, key, value, &by) {
                e.file = plan.file.clone();
                errors.push(e);
                failed = true;
            }
        }
        if failed {
            continue;
        }
        match validate(&d, &registry) {
            Ok(g) => graphs.push(g),
            Err(GraphErrors(es)) => errors.extend(es.into_iter().map(|mut e| {
                e.message = format!("{by}: {}", e.message);
                e
            })),
        }
    }
    errors.extend(unknown_metric_nodes(plan, &graphs));
    if errors.is_empty() {
        Ok(graphs)
    } else {
        Err(GraphErrors(errors))
    }
}

/// `rank_by` and `metrics` entries (`NODE.METRIC`) whose node is in no
/// variant's graph: a typo that would leave a column empty and the ranking
/// unmade.
fn unknown_metric_nodes(plan: &SweepPlan, graphs: &[ValidGraph]) -> Vec<crate::GraphError> {
    let mut errors = Vec::new();
    let Some(first) = graphs.first() else {
        return errors; // every variant failed validation: already reported
    };
    let known = |node: &str| graphs.iter().any(|g| g.index_of(node).is_some());
    let ids = first.nodes.iter().map(|n| n.id.as_str());
    let named = plan
        .rank_by
        .iter()
        .map(|m| ("rank_by", m))
        .chain(plan.metrics.iter().map(|m| ("metrics", m)));
    let mut seen = std::collections::BTreeSet::new();
    for (key, metric) in named {
        let node = metric.split_once('.').map_or(metric.as_str(), |(n, _)| n);
        if known(node) || !seen.insert(metric.clone()) {
            continue;
        }
        let hint = match crate::error::closest(node, ids.clone()) {
            Some(c) => format!(" (did you mean `{c}`?)"),
            None => String::new(),
        };
        errors.push(
            crate::GraphError::file(
                crate::error::ErrorKind::UnknownSource,
                &plan.file,
                format!("{metric:?} names node `{node}`, which the graph does not have{hint}"),
            )
            .at_key(key),
        );
    }
    errors
}

/// How to run a sweep.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    /// The sweep's folder: `sweep.json`, one folder per variant, the comparison.
    pub out_dir: PathBuf,
    /// The shared disk cache (`None`: a cache of the sweep's own under
    /// `out_dir`, removed at the end).
    pub cache: Option<PathBuf>,
    /// Worker threads per variant's run (0 = one per core).
    pub jobs: usize,
    /// `(I, N)`: run the I-th of N slices (I from 1).
    pub shard: Option<(usize, usize)>,
    /// The program's part of each run's provenance (see
    /// [`RunOptions::provenance`]); the variant's name and overrides are added.
    pub provenance: serde_json::Map<String, serde_json::Value>,
}

/// What one variant's run did.
#[derive(Debug, Clone)]
pub struct VariantRun {
    /// The variant.
    pub name: String,
    /// Whether every node succeeded.
    pub succeeded: bool,
    /// Nodes computed by this run.
    pub ran: usize,
    /// Nodes reused from the cache (another variant's, or an earlier run's).
    pub cached: usize,
    /// Wall time, ms.
    pub ms: f64,
    /// Why the run could not finish (an I/O error), if it could not.
    pub error: Option<String>,
}

/// Refuses a sweep folder whose `sweep.json` holds another plan: shards of
/// two sweeps in one folder would replace each other's plan, and a merge
/// would drop one sweep's variants as missing. The same plan (another shard
/// of this sweep, or a rerun) is fine.
fn check_same_plan(
    plan_file: &Path,
    plan_json: &serde_json::Value,
    plan: &SweepPlan,
) -> std::io::Result<()> {
    let existing = match std::fs::read_to_string(plan_file) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => {
            return Err(std::io::Error::new(
                e.kind(),
                format!("{}: {e}", plan_file.display()),
            ));
        }
    };
    let theirs: Option<serde_json::Value> = serde_json::from_str(&existing).ok();
    if theirs.as_ref() == Some(plan_json) {
        return Ok(());
    }
    let described = theirs
        .as_ref()
        .map(|t| {
            format!(
                "sweep `{}` from {}",
                t["name"].as_str().unwrap_or("?"),
                t["file"].as_str().unwrap_or("?")
            )
        })
        .unwrap_or_else(|| "a plan that does not parse".into());
    Err(std::io::Error::other(format!(
        "{} holds {described}, not this plan (sweep `{}` from {}): shards of different sweeps, \
         or a changed sweep file, cannot share a folder; use another --out",
        plan_file.display(),
        plan.name,
        plan.file.display()
    )))
}

/// The variants shard `shard` of `n` runs (all with `None`).
pub fn shard_of(count: usize, shard: Option<(usize, usize)>) -> Vec<usize> {
    match shard {
        None => (0..count).collect(),
        Some((i, n)) => (0..count).filter(|v| v % n == i - 1).collect(),
    }
}

/// Runs the variants of this shard against one cache, each into
/// `OUT/<variant>/`, after writing the plan to `OUT/sweep.json`. A failed
/// variant is reported in its run; the others go on.
pub fn run_sweep(
    plan: &SweepPlan,
    graphs: &[ValidGraph],
    options: &SweepOptions,
    mut each: impl FnMut(&VariantRun),
) -> std::io::Result<Vec<VariantRun>> {
    std::fs::create_dir_all(&options.out_dir)?;
    let plan_file = options.out_dir.join("sweep.json");
    let plan_json = compare::plan_json(plan);
    check_same_plan(&plan_file, &plan_json, plan)?;
    crate::atomic::write_atomically(
        &plan_file,
        (serde_json::to_string_pretty(&plan_json).expect("plain data") + "\n").as_bytes(),
    )?;
    let memory = MemoryCache::new();
    // Without a disk cache the variants still share files that nodes made (a
    // generated phantom): they live in a cache of this sweep's own, removed
    // at the end, not in one variant's `.work` folder.
    let dir = match &options.cache {
        Some(dir) => dir.clone(),
        None => tempfile_dir(&options.out_dir)?,
    };
    let private = options.cache.is_none().then(|| dir.clone());
    // Opened once: opening cleans dead runs' temporary folders.
    let cache = DiskCache::open(&dir)?;
    let mut runs = Vec::new();
    for i in shard_of(plan.variants.len(), options.shard) {
        let variant = &plan.variants[i];
        let run_options = RunOptions {
            out_dir: options.out_dir.join(&variant.name),
            cache: Some(cache.clone()),
            jobs: options.jobs,
            progress: false,
            provenance: {
                let mut p = options.provenance.clone();
                p.insert("sweep_file".into(), plan.file.display().to_string().into());
                p.insert("sweep_variant".into(), variant.name.clone().into());
                let overrides: Vec<String> = variant
                    .overrides
                    .iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect();
                p.insert("overrides".into(), overrides.into());
                p
            },
            keep_outputs: false,
        };
        let start = std::time::Instant::now();
        let outcome = run(&graphs[i], &run_options, &memory);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let result = match outcome {
            Ok(o) => {
                let count =
                    |s: NodeStatus| o.report.nodes.iter().filter(|(_, n)| n.status == s).count();
                VariantRun {
                    name: variant.name.clone(),
                    succeeded: o.report.succeeded(),
                    ran: count(NodeStatus::Ran),
                    cached: count(NodeStatus::Cached),
                    ms,
                    error: None,
                }
            }
            Err(e) => VariantRun {
                name: variant.name.clone(),
                succeeded: false,
                ran: 0,
                cached: 0,
                ms,
                error: Some(match e {
                    RunError::Graph(g) => g.to_string(),
                    RunError::Io(io) => io.to_string(),
                }),
            },
        };
        each(&result);
        runs.push(result);
    }
    if let Some(dir) = private {
        let _ = std::fs::remove_dir_all(dir);
    }
    Ok(runs)
}

/// A fresh folder `OUT/.sweep-cache-<pid>` for a sweep run without a disk cache.
fn tempfile_dir(out: &Path) -> std::io::Result<PathBuf> {
    let dir = out.join(format!(".sweep-cache-{}", std::process::id()));
    if dir.exists() {
        std::fs::remove_dir_all(&dir)?;
    }
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// The default cache of a sweep: `.fusegraph/cache` beside its base graph,
/// as `fusegraph run` uses.
pub fn default_cache(plan: &SweepPlan) -> PathBuf {
    crate::cache::default_dir(&plan.graph)
}

/// Writes the comparison files into `dir`.
pub fn write_comparison(c: &compare::Comparison, dir: &Path) -> std::io::Result<()> {
    let write = |name: &str, text: String| {
        crate::atomic::write_atomically(&dir.join(name), text.as_bytes())
    };
    write("comparison.csv", compare::to_csv(c))?;
    write("comparison_nodes.csv", compare::nodes_csv(c))?;
    write("comparison.md", compare::to_markdown(c))?;
    write(
        "comparison.html",
        compare_html::to_html(c, &compare::best_line(c)),
    )?;
    let plots = compare_html::plot_files(c);
    if !plots.is_empty() {
        std::fs::create_dir_all(dir.join("plots"))?;
        for (name, svg) in plots {
            write(&format!("plots/{name}"), svg)?;
        }
    }
    Ok(())
}
