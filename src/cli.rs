//! The `fusegraph` command line: parses arguments and hands them to the engine
//! with the built-in node types (and, run from the Python package, the ops
//! its Python files declare). It holds no algorithm.

use crate::{bench, list};
use anyhow::Context;
use clap::{Parser, Subcommand};
use fusegraph_engine::cache::{DiskCache, MemoryCache};
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::script::ScriptHost;
use fusegraph_engine::session::{RunError, load_graph, run};
use fusegraph_engine::{GraphErrors, Registry};
use std::ffi::OsString;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Exit code of an invalid graph or invalid arguments.
pub const EXIT_INVALID: u8 = 2;
/// Exit code of a run in which a node failed, or of an I/O failure.
pub const EXIT_FAILED: u8 = 1;

#[derive(Parser)]
#[command(
    name = "fusegraph",
    version,
    about = "MRI and stereo-vision surface reconstruction and fusion, as cached TOML dataflow graphs"
)]
struct Cli {
    /// More logging on stderr (-v: info, -vv: debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Load node types from a plugin library (repeatable; also from
    /// `[graph] plugins` and FUSEGRAPH_PLUGIN_PATH, files or folders as in PATH).
    #[arg(long = "plugin", global = true, value_name = "PATH")]
    plugins: Vec<PathBuf>,
    /// Load node types from a Python file (repeatable; also from `[graph]
    /// python`). Needs the fusegraph Python package: `python -m fusegraph`.
    #[arg(long = "python", global = true, value_name = "FILE")]
    python: Vec<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a graph: write its sinks' files and report.json under the output folder.
    Run {
        /// The graph file.
        graph: PathBuf,
        #[command(flatten)]
        edit: Edit,
        #[command(flatten)]
        running: Running,
    },
    /// Run every variant of a sweep against one cache and compare them:
    /// DIR/<variant>/report.json, DIR/comparison.{csv,md,html}.
    Sweep {
        /// The sweep file (not needed with --merge).
        #[arg(required_unless_present = "merge")]
        sweep: Option<PathBuf>,
        #[command(flatten)]
        running: Running,
        /// Run only the I-th of N slices of the variants (I from 1, as
        /// `#SBATCH --array=1-N` numbers them); merge the folder afterwards.
        #[arg(long, value_name = "I/N", value_parser = parse_shard)]
        shard: Option<(usize, usize)>,
        /// Build the comparison from a sweep folder the shards wrote.
        #[arg(long, value_name = "DIR", conflicts_with_all = ["sweep", "shard", "out", "cache", "no_cache"])]
        merge: Option<PathBuf>,
    },
    /// Check a graph without running it.
    Validate {
        /// The graph file.
        graph: PathBuf,
        #[command(flatten)]
        edit: Edit,
    },
    /// List the node types: ports, parameters (type, default, unit, range), docs.
    Nodes {
        /// Machine-readable JSON.
        #[arg(long)]
        json: bool,
    },
    /// Print a graph in Graphviz dot syntax.
    Dot {
        /// The graph file.
        graph: PathBuf,
        #[command(flatten)]
        edit: Edit,
    },
    /// Write the ground-truth phantom: DIR/mri/, DIR/calib/, DIR/views/, DIR/ground_truth.json, DIR/targets.mrk.json.
    Phantom {
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Seed of every random choice.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Resolution preset: full (0.6 x 0.6 x 1.0 mm voxels) or small (1.5 mm, fast).
        #[arg(long, default_value = "full", value_parser = ["full", "small"])]
        size: String,
        /// Any other parameter of `phantom.generate` (see `fusegraph nodes`), as
        /// KEY=VALUE in TOML syntax, e.g. `--set motion=\"sag\" --set motion_peak_mm=5`
        /// (repeatable). Checked as a graph's parameters are.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
    },
    /// Manage a cache folder: what it holds, removing old entries, checking it.
    Cache {
        #[command(subcommand)]
        what: CacheCommand,
    },
    /// Measure the engine: scheduler overhead per node, cold and cached.
    Bench {
        #[command(subcommand)]
        what: bench::BenchCommand,
    },
}

/// `fusegraph cache ...`. DIR is the cache folder [default: .fusegraph/cache;
/// the shipped graphs' is graphs/.fusegraph/cache].
#[derive(Subcommand)]
enum CacheCommand {
    /// Size, entries, entries and bytes by op, least and most recently used.
    Stats {
        /// The cache folder.
        dir: Option<PathBuf>,
    },
    /// Remove the least recently used entries (and their files): those not
    /// used for --older-than, then more until the cache is under --max-size.
    /// Safe while other runs use the cache: an entry being computed or used
    /// within --keep-recent is left alone.
    Gc {
        /// The cache folder.
        dir: Option<PathBuf>,
        /// Remove entries not used for this long (30d, 12h, 90m).
        #[arg(long, value_parser = fusegraph_engine::cache_admin::parse_age)]
        older_than: Option<std::time::Duration>,
        /// Remove least recently used entries until at most this size (10G, 500M).
        #[arg(long, value_parser = fusegraph_engine::cache_admin::parse_size)]
        max_size: Option<u64>,
        /// Never remove an entry used this recently.
        #[arg(long, default_value = "1h", value_parser = fusegraph_engine::cache_admin::parse_age)]
        keep_recent: std::time::Duration,
        /// Also remove the folders of older entry formats (v1, v2, ...
        /// below this build's), which this build never reads: only once no
        /// older fusegraph uses this cache.
        #[arg(long)]
        old_formats: bool,
        /// Only list what would be removed.
        #[arg(long)]
        dry_run: bool,
    },
    /// Check every entry's length, checksum and key; list files folders
    /// without an entry, leases of dead owners and temporaries of dead runs
    /// (exit 1 when anything is wrong).
    Verify {
        /// The cache folder.
        dir: Option<PathBuf>,
        /// Remove what was found wrong.
        #[arg(long)]
        repair: bool,
    },
}

fn cache_command(what: CacheCommand) -> anyhow::Result<u8> {
    use fusegraph_engine::cache_admin as admin;
    let dir_or_default =
        |d: Option<PathBuf>| d.unwrap_or_else(|| Path::new(".fusegraph").join("cache"));
    let age = |t: std::time::SystemTime| {
        let secs = std::time::SystemTime::now()
            .duration_since(t)
            .map_or(0, |d| d.as_secs());
        match secs {
            s if s < 3600 => format!("{} min ago", s / 60),
            s if s < 86_400 => format!("{:.1} h ago", s as f64 / 3600.0),
            s => format!("{:.1} days ago", s as f64 / 86_400.0),
        }
    };
    match what {
        CacheCommand::Stats { dir } => {
            let dir = dir_or_default(dir);
            let s = admin::stats(&dir)?;
            println!(
                "{}: {} in all (as du -sb counts), {} entries",
                dir.display(),
                admin::human_bytes(s.total_bytes),
                s.entries.len()
            );
            if let (Some(old), Some(new)) = (s.entries.first(), s.entries.last()) {
                println!(
                    "least recently used {} ({}), most recently {} ({})",
                    age(old.last_used),
                    old.op,
                    age(new.last_used),
                    new.op
                );
            }
            for (folder, bytes) in &s.older_formats {
                println!(
                    "{} {}: an older format this build does not read; `fusegraph cache gc \
                     --old-formats` removes it once no older fusegraph uses this cache",
                    folder.display(),
                    admin::human_bytes(*bytes)
                );
            }
            let mut ops: Vec<_> = s.by_op.iter().collect();
            ops.sort_by_key(|op| std::cmp::Reverse(op.1.1));
            println!("{:<32} {:>8} {:>12}", "op", "entries", "size");
            for (op, (n, bytes)) in ops {
                println!("{op:<32} {n:>8} {:>12}", admin::human_bytes(*bytes));
            }
            Ok(0)
        }
        CacheCommand::Gc {
            dir,
            older_than,
            max_size,
            keep_recent,
            old_formats,
            dry_run,
        } => {
            let dir = dir_or_default(dir);
            if older_than.is_none() && max_size.is_none() && !old_formats {
                anyhow::bail!(
                    "cache gc: give --older-than AGE, --max-size SIZE, --old-formats or several"
                );
            }
            if old_formats {
                for (folder, bytes) in admin::remove_older_formats(&dir, dry_run)? {
                    println!(
                        "{} older format {} ({})",
                        if dry_run { "would remove" } else { "removed" },
                        folder.display(),
                        admin::human_bytes(bytes)
                    );
                }
                if older_than.is_none() && max_size.is_none() {
                    return Ok(0);
                }
            }
            let limits = admin::GcLimits {
                older_than,
                max_bytes: max_size,
                keep_recent,
                dry_run,
            };
            let r = admin::gc(&dir, limits, std::time::SystemTime::now())?;
            println!(
                "{} {} entries ({}); left {} being computed and {} used within {}",
                if dry_run { "would remove" } else { "removed" },
                r.removed.len(),
                admin::human_bytes(r.removed_bytes),
                r.busy,
                r.recent,
                humantime(keep_recent)
            );
            Ok(0)
        }
        CacheCommand::Verify { dir, repair } => {
            let dir = dir_or_default(dir);
            let r = admin::verify(&dir, repair)?;
            println!("{}: {} entries checked", dir.display(), r.checked);
            for (p, why) in &r.corrupt {
                println!("corrupt: {}: {why}", p.display());
            }
            for (what, list) in [
                ("orphan files folder", &r.orphans),
                ("stale lease", &r.stale_leases),
                ("stale temporary", &r.stale_temporaries),
            ] {
                for p in list {
                    println!("{what}: {}", p.display());
                }
            }
            if r.clean() {
                println!("all well");
                Ok(0)
            } else if repair {
                println!("removed what was wrong");
                Ok(0)
            } else {
                println!("run `fusegraph cache verify --repair` to remove them");
                Ok(EXIT_FAILED)
            }
        }
    }
}

fn humantime(d: std::time::Duration) -> String {
    format!("{:.0} min", d.as_secs_f64() / 60.0)
}

/// The phantom `fusegraph phantom` writes: `phantom.generate`'s parameters,
/// `seed` and `size` and `KEY=VALUE` settings checked as in a graph (a one-node
/// graph is validated, so a misspelt key or a value out of range is named).
fn phantom_config(
    seed: u64,
    size: &str,
    sets: &[String],
    registry: &Registry,
) -> anyhow::Result<fusegraph_nodes::phantom::PhantomConfig> {
    use fusegraph_engine::typed::declaration::ParamSet;
    let file = std::path::Path::new("<fusegraph phantom>");
    let text = format!(
        "[graph]\nname = \"phantom\"\n[node.phantom]\nop = \"phantom.generate\"\nseed = {seed}\nsize = \"{size}\"\n"
    );
    let mut doc = fusegraph_engine::graph::GraphDoc::parse(&text, file)?;
    let mut errors: Vec<_> = sets
        .iter()
        .filter_map(|s| doc.apply_set(&format!("phantom.{s}")).err())
        .collect();
    let graph = match fusegraph_engine::validate::validate(&doc, registry) {
        Ok(graph) if errors.is_empty() => graph,
        Ok(_) => return Err(GraphErrors(errors).into()),
        Err(GraphErrors(more)) => {
            errors.extend(more);
            return Err(GraphErrors(errors).into());
        }
    };
    let op = fusegraph_nodes::phantom::ops::Generate::from_params(&graph.nodes[0].params)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(op.config())
}

/// Where a run writes and what it reuses (`run` and `sweep`).
#[derive(clap::Args)]
struct Running {
    /// Output folder [default: out/<graph or sweep name>].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Cache folder [default: .fusegraph/cache beside the (base) graph].
    #[arg(long, conflicts_with = "no_cache")]
    cache: Option<PathBuf>,
    /// Do not read or write the disk cache (a sweep's variants still share
    /// their results, in a cache of its own removed at the end).
    #[arg(long)]
    no_cache: bool,
    /// Worker threads of a run [default: one per core].
    #[arg(long, short = 'j', default_value_t = 0)]
    jobs: usize,
}

#[derive(clap::Args)]
struct Edit {
    /// Override a parameter (ID.KEY=VALUE, VALUE in TOML syntax), swap an op
    /// (ID.op=NAME) or rewire an input (ID.in.PORT=NODE.PORT). Repeatable.
    #[arg(long = "set", value_name = "ID.KEY=VALUE")]
    sets: Vec<String>,
}

/// Runs the command line `args` (the program name first) and returns the
/// exit code: 0 done, 1 a node or a file failed, 2 an invalid graph or
/// invalid arguments. `script_host` runs the Python files that `--python`
/// and graphs name (`None`: the plain binary, which refuses them).
pub fn main(
    args: impl IntoIterator<Item = OsString>,
    script_host: Option<Arc<dyn ScriptHost>>,
) -> u8 {
    let args: Vec<OsString> = args.into_iter().collect();
    let command_line: Vec<String> = args
        .iter()
        .map(|a| a.to_string_lossy().into_owned())
        .collect();
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() { EXIT_INVALID } else { 0 };
        }
    };
    init_logging(cli.verbose);
    let mut registry = fusegraph_nodes::builtin_registry();
    if let Some(host) = script_host {
        registry.set_script_host(host);
    }
    if let Err(why) = load_plugins(&cli.plugins, &cli.python, &mut registry) {
        eprintln!("error: {why}");
        return EXIT_INVALID;
    }
    match execute(cli, &registry, &command_line) {
        Ok(code) => code,
        Err(e) => {
            if let Some(errors) = e.downcast_ref::<GraphErrors>() {
                eprintln!("{errors}");
                EXIT_INVALID
            } else {
                eprintln!("error: {e:#}");
                EXIT_FAILED
            }
        }
    }
}

/// Adds the ops of FUSEGRAPH_PLUGIN_PATH's plugins, of `--plugin` ones and
/// of `--python` files.
fn load_plugins(
    flags: &[PathBuf],
    python: &[PathBuf],
    registry: &mut Registry,
) -> Result<(), String> {
    if let Some(path) = std::env::var_os("FUSEGRAPH_PLUGIN_PATH") {
        fusegraph_engine::plugin::load_plugin_path(&path, registry)?;
    }
    for p in flags {
        fusegraph_engine::plugin::load_plugin(p, registry).map_err(|e| format!("--plugin: {e}"))?;
    }
    let python: Vec<PathBuf> = python
        .iter()
        .map(|p| std::path::absolute(p).unwrap_or_else(|_| p.clone()))
        .collect();
    fusegraph_engine::script::load_scripts(&python, registry).map_err(|e| format!("--python {e}"))
}

/// Ends the process quietly when its output pipe closes (`fusegraph nodes
/// --json | head`), as other command-line tools do, instead of panicking in
/// `println!` with exit code 101. Rust ignores SIGPIPE by default. For a
/// program's `main`, before any thread exists.
pub fn quiet_on_broken_pipe() {
    #[cfg(unix)]
    // SAFETY: called first in main, before any thread exists; restoring the
    // default disposition of SIGPIPE touches no memory of ours.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// The folder a run or sweep writes into: `--out`, or out/NAME; refused
/// when it is a file.
pub fn out_folder(out: Option<PathBuf>, name: &str) -> anyhow::Result<PathBuf> {
    let dir = out.unwrap_or_else(|| Path::new("out").join(folder_name(name)));
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!(
            "--out {}: is a file, not a folder; give a folder for the report and files",
            dir.display()
        );
    }
    Ok(dir)
}

/// What this build of fusegraph was made from and how it was called, for
/// a report's provenance (the engine adds the host, time, graph and plugin
/// hashes): version, git commit and whether the tree was dirty, rustc,
/// target, the command line and its `--set` overrides.
pub fn provenance(
    command_line: &[String],
    overrides: &[String],
) -> serde_json::Map<String, serde_json::Value> {
    let mut p = serde_json::Map::new();
    let mut put = |k: &str, v: serde_json::Value| {
        p.insert(k.into(), v);
    };
    put("fusegraph_version", env!("CARGO_PKG_VERSION").into());
    put("git_commit", env!("FUSEGRAPH_GIT_COMMIT").into());
    put(
        "git_dirty",
        match env!("FUSEGRAPH_GIT_DIRTY") {
            "true" => true.into(),
            "false" => false.into(),
            _ => serde_json::Value::Null,
        },
    );
    put("rustc", env!("FUSEGRAPH_RUSTC").into());
    put("target", env!("FUSEGRAPH_TARGET").into());
    put("command_line", command_line.to_vec().into());
    put("overrides", overrides.to_vec().into());
    p
}

fn execute(cli: Cli, registry: &Registry, command_line: &[String]) -> anyhow::Result<u8> {
    match cli.command {
        Command::Run {
            graph,
            edit,
            running:
                Running {
                    out,
                    cache,
                    no_cache,
                    jobs,
                },
        } => {
            let valid = load_graph(&graph, &edit.sets, registry)?;
            let out_dir = out_folder(out, &valid.name)?;
            let cache = if no_cache {
                None
            } else {
                let dir = cache.unwrap_or_else(|| fusegraph_engine::cache::default_dir(&graph));
                Some(DiskCache::open(&dir)?)
            };
            let options = RunOptions {
                out_dir: out_dir.clone(),
                cache,
                jobs,
                progress: std::io::stderr().is_terminal() && cli.verbose == 0,
                provenance: provenance(command_line, &edit.sets),
                keep_outputs: false,
            };
            let outcome = run(&valid, &options, &MemoryCache::new()).map_err(|e| match e {
                RunError::Graph(g) => anyhow::Error::new(g),
                RunError::Io(io) => anyhow::Error::new(io).context("run failed"),
            })?;
            eprintln!("{}", list::summary(&outcome.report, &out_dir));
            Ok(if outcome.report.succeeded() {
                0
            } else {
                EXIT_FAILED
            })
        }
        Command::Sweep {
            sweep,
            running:
                Running {
                    out,
                    cache,
                    no_cache,
                    jobs,
                },
            shard,
            merge,
        } => {
            if let Some(dir) = merge {
                return compare_sweep(&dir);
            }
            let plan = fusegraph_engine::sweep::load_sweep(&sweep.expect("clap requires it"))?;
            let graphs = fusegraph_engine::sweep::validate_variants(&plan, registry)?;
            let out_dir = out_folder(out, &plan.name)?;
            let options = fusegraph_engine::sweep::SweepOptions {
                out_dir: out_dir.clone(),
                cache: (!no_cache).then(|| {
                    cache.unwrap_or_else(|| fusegraph_engine::sweep::default_cache(&plan))
                }),
                jobs,
                shard,
                provenance: provenance(command_line, &[]),
            };
            let mine = fusegraph_engine::sweep::shard_of(plan.variants.len(), shard).len();
            eprintln!(
                "sweep `{}`: {} variants{}, all valid",
                plan.name,
                plan.variants.len(),
                shard
                    .map(|(i, n)| format!(" ({mine} in shard {i}/{n})"))
                    .unwrap_or_default()
            );
            let runs = fusegraph_engine::sweep::run_sweep(&plan, &graphs, &options, |r| {
                eprintln!(
                    "{:>8} {:<40} {:>9.1} ms  {} computed, {} reused{}",
                    if r.succeeded { "done" } else { "FAILED" },
                    r.name,
                    r.ms,
                    r.ran,
                    r.cached,
                    r.error
                        .as_deref()
                        .map(|e| format!(": {e}"))
                        .unwrap_or_default()
                );
            })
            .with_context(|| format!("sweep into {}", out_dir.display()))?;
            let (ran, reused): (usize, usize) = runs
                .iter()
                .fold((0, 0), |a, r| (a.0 + r.ran, a.1 + r.cached));
            eprintln!(
                "{} node runs: {ran} computed, {reused} reused from other variants or earlier runs",
                ran + reused
            );
            if shard.is_some_and(|(_, n)| n > 1) {
                eprintln!(
                    "shard done; when every shard is: fusegraph sweep --merge {}",
                    out_dir.display()
                );
                return Ok(0);
            }
            compare_sweep(&out_dir)
        }
        Command::Validate { graph, edit } => {
            let valid = load_graph(&graph, &edit.sets, registry)?;
            println!(
                "{}: graph `{}` is valid ({} nodes)",
                graph.display(),
                valid.name,
                valid.nodes.len()
            );
            Ok(0)
        }
        Command::Nodes { json } => {
            if json {
                let specs: Vec<_> = registry.specs().collect();
                println!(
                    "{}",
                    serde_json::to_string_pretty(&specs).context("serialising node specs")?
                );
            } else {
                print!("{}", list::nodes_text(registry));
            }
            Ok(0)
        }
        Command::Dot { graph, edit } => {
            let valid = load_graph(&graph, &edit.sets, registry)?;
            print!("{}", fusegraph_engine::dot::to_dot(&valid));
            Ok(0)
        }
        Command::Phantom {
            out,
            seed,
            size,
            sets,
        } => {
            let config = phantom_config(seed, &size, &sets, registry)?;
            let started = std::time::Instant::now();
            let g =
                fusegraph_nodes::phantom::generate(&config, &out).map_err(anyhow::Error::msg)?;
            // The lesions as a radiologist would mark them on the scan: the
            // targets file `graphs/rig.toml` reads.
            let lesions = fusegraph_engine::value::Markers::new(
                g.truth
                    .lesions
                    .iter()
                    .flat_map(|l| l.center_mri_mm)
                    .collect::<Vec<f64>>(),
                g.truth.lesions.iter().map(|l| l.id).collect::<Vec<u32>>(),
                "mri_lps",
            )
            .map_err(|e| anyhow::anyhow!(e.0))?;
            let targets = out.join("targets.mrk.json");
            std::fs::write(
                &targets,
                serde_json::to_string_pretty(&fusegraph_nodes::io::slicer_markups(
                    &lesions, "lesion", None,
                ))?,
            )
            .with_context(|| targets.display().to_string())?;
            println!(
                "phantom ({size}, seed {seed}) in {:.2} s: {} MRI slices ({:.0} ms), {} calibration pairs ({:.0} ms), {} views ({:.0} ms); truth: {}",
                started.elapsed().as_secs_f64(),
                g.truth.mri.files,
                g.stage_ms[0],
                g.truth.calibration.len(),
                g.stage_ms[1],
                g.truth.views.len(),
                g.stage_ms[2],
                g.truth_file.display()
            );
            println!("targets (the lesions, MRI LPS): {}", targets.display());
            Ok(0)
        }
        Command::Cache { what } => cache_command(what),
        Command::Bench { what } => {
            bench::run_bench(what, registry)?;
            Ok(0)
        }
    }
}

/// `I/N` with 1 <= I <= N.
fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let (i, n) = s.split_once('/').ok_or("expected I/N, e.g. 3/8")?;
    let (i, n): (usize, usize) = (
        i.trim()
            .parse()
            .map_err(|_| format!("{i:?} is not a number"))?,
        n.trim()
            .parse()
            .map_err(|_| format!("{n:?} is not a number"))?,
    );
    if n == 0 || i == 0 || i > n || n > 100_000 {
        return Err(format!("{i}/{n}: need 1 <= I <= N <= 100000"));
    }
    Ok((i, n))
}

/// Builds and writes the comparison of the sweep folder `dir`; exit 1 when a
/// variant failed or is missing.
fn compare_sweep(dir: &Path) -> anyhow::Result<u8> {
    use fusegraph_engine::sweep::compare::{Status, comparison};
    use fusegraph_engine::sweep::write_comparison;
    let c = comparison(dir).map_err(anyhow::Error::msg)?;
    write_comparison(&c, dir)
        .with_context(|| format!("writing the comparison into {}", dir.display()))?;
    let bad: Vec<String> = c
        .rows
        .iter()
        .filter(|r| r.status != Status::Done)
        .map(|r| format!("{} ({})", r.variant, r.status.name()))
        .collect();
    match c.best() {
        Some(best) => eprintln!(
            "best by {}: {}",
            c.rank_by
                .as_ref()
                .map(|(m, b)| format!("{m} ({} is better)", b.name()))
                .unwrap_or_default(),
            best.variant
        ),
        None => eprintln!("no best variant (no rank metric, or no variant finished with it)"),
    }
    eprintln!("comparison: {}", dir.join("comparison.html").display());
    if bad.is_empty() {
        Ok(0)
    } else {
        eprintln!(
            "{} of {} variants did not finish: {}",
            bad.len(),
            c.rows.len(),
            bad.join(", ")
        );
        Ok(EXIT_FAILED)
    }
}

/// A graph name made safe as one folder name (no separators, no `..`).
fn folder_name(name: &str) -> String {
    let safe: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if safe.is_empty() {
        "graph".into()
    } else {
        safe
    }
}

fn init_logging(verbose: u8) {
    let level = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("FUSEGRAPH_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .try_init()
        // A second command line in one process (the Python package's) keeps
        // the first one's logging.
        .ok();
}
