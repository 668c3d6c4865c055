//! The scheduler: runs a validated graph in dependency order, independent nodes in
//! parallel on a rayon pool, reusing cached results by key. A node that fails
//! (error or panic) stops only its downstream nodes, which are marked skipped;
//! every other branch finishes. Before any node runs, every node's cached
//! result is looked up by its key, and the values of the cached nodes a
//! computing node reads are read (see [`Executor::plan`]): the rest stay on
//! disk.

use crate::cache::{CacheEntry, DiskCache, Lookup, MemoryCache};
use crate::key::NodeKey;
use crate::op::{Inputs, OpError, RunCtx};
use crate::report::{NodeReport, NodeStatus, RunReport};
use crate::validate::{ValidGraph, ValidNode};
use crate::value::Value;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::collections::BTreeSet;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// How to run a graph.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Folder sinks write into (and `report.json`, written by the caller).
    pub out_dir: PathBuf,
    /// The disk cache, or `None` for `--no-cache`.
    pub cache: Option<DiskCache>,
    /// Worker threads; 0 = one per core.
    pub jobs: usize,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// What the program knows of where the run comes from (its build's git
    /// commit, rustc, the command line); the report's `provenance` adds the
    /// engine's part (see [`crate::provenance`]).
    pub provenance: serde_json::Map<String, serde_json::Value>,
    /// Keep every node's outputs in memory to the end of the run (in
    /// [`RunOutcome::results`]); otherwise each node's are released once
    /// the last node that reads them has run, so the run's peak memory is
    /// what is in flight, not everything it made (the disk cache keeps
    /// them all).
    pub keep_outputs: bool,
}

/// What a run produced: the report, and each node's outputs (`None` where it
/// failed or was skipped, or was released: see [`RunOptions::keep_outputs`]),
/// indexed like the graph's nodes.
pub struct RunOutcome {
    /// The report.
    pub report: RunReport,
    /// Each node's outputs and metrics.
    pub results: Vec<Option<Arc<CacheEntry>>>,
}

/// Runs `graph` whose node keys are `keys` (see [`crate::key::node_keys`]).
/// `memory` may be shared between runs of one process.
pub fn run_graph(
    graph: &ValidGraph,
    keys: &[NodeKey],
    options: &RunOptions,
    memory: &MemoryCache,
) -> Result<RunOutcome, std::io::Error> {
    std::fs::create_dir_all(&options.out_dir).map_err(|e| {
        std::io::Error::new(
            e.kind(),
            format!("output folder {}: {e}", options.out_dir.display()),
        )
    })?;
    crate::workdir::Staging::clean_stale(&options.out_dir);
    let start = Instant::now();
    let started = std::time::SystemTime::now();
    let n = graph.nodes.len();
    let mut successors: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); n];
    let mut predecessors: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); n];
    for (i, node) in graph.nodes.iter().enumerate() {
        for e in &node.inputs {
            successors[e.from].insert(i);
            predecessors[i].insert(e.from);
        }
    }
    let readers_left: Vec<AtomicUsize> = successors
        .iter()
        .map(|s| AtomicUsize::new(s.len()))
        .collect();
    let pending: Vec<AtomicUsize> = graph
        .nodes
        .iter()
        .map(|node| {
            AtomicUsize::new(
                node.inputs
                    .iter()
                    .map(|e| e.from)
                    .collect::<BTreeSet<_>>()
                    .len(),
            )
        })
        .collect();
    let progress = if options.progress {
        let bar = ProgressBar::with_draw_target(Some(n as u64), ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {wide_msg}",
            )
            .expect("valid template"),
        );
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        bar
    } else {
        ProgressBar::hidden()
    };
    let mut exec = Executor {
        graph,
        keys,
        options,
        memory,
        successors,
        predecessors,
        pending,
        readers_left,
        reports: (0..n).map(|_| OnceLock::new()).collect(),
        entries: (0..n).map(|_| Mutex::new(None)).collect(),
        planned: Vec::new(),
        running: Mutex::new(BTreeSet::new()),
        progress,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(options.jobs)
        .thread_name(|i| format!("fusegraph-{i}"))
        .build()
        .map_err(std::io::Error::other)?;
    exec.planned = pool
        .install(|| exec.plan())
        .into_iter()
        .map(Mutex::new)
        .collect();
    // The roots are chosen before any node runs: a node released by its
    // upstream while this loop still ran would otherwise be spawned twice,
    // and its second run would release its own successors early.
    let roots: Vec<usize> = (0..n)
        .filter(|&i| exec.pending[i].load(Ordering::Acquire) == 0)
        .collect();
    pool.install(|| {
        rayon::scope(|s| {
            for i in roots {
                let exec = &exec;
                s.spawn(move |s| exec.execute(i, s));
            }
        })
    });
    exec.progress.finish_and_clear();
    let reports: Vec<NodeReport> = exec
        .reports
        .into_iter()
        .map(|s| s.into_inner().expect("every node was executed"))
        .collect();
    let report = RunReport {
        graph: graph.name.clone(),
        file: graph.file.display().to_string(),
        nodes: graph
            .nodes
            .iter()
            .map(|node| node.id.clone())
            .zip(reports)
            .collect(),
        total_ms: start.elapsed().as_secs_f64() * 1e3,
        provenance: crate::provenance::provenance(graph, started, &options.provenance),
    };
    Ok(RunOutcome {
        report,
        results: exec
            .entries
            .into_iter()
            .map(|e| e.into_inner().unwrap_or_else(|p| p.into_inner()))
            .collect(),
    })
}

struct Slot {
    report: NodeReport,
    entry: Option<Arc<CacheEntry>>,
}

struct Executor<'a> {
    graph: &'a ValidGraph,
    keys: &'a [NodeKey],
    options: &'a RunOptions,
    memory: &'a MemoryCache,
    successors: Vec<BTreeSet<usize>>,
    predecessors: Vec<BTreeSet<usize>>,
    pending: Vec<AtomicUsize>,
    /// Each node's readers (distinct successors) that have not run yet.
    readers_left: Vec<AtomicUsize>,
    reports: Vec<OnceLock<NodeReport>>,
    /// Each node's outputs, set before its successors start; `None` where
    /// it produced none, or once released.
    entries: Vec<Mutex<Option<Arc<CacheEntry>>>>,
    /// Each node's cached result found before the run (see
    /// [`Executor::plan`]); `None` where it computes.
    planned: Vec<Mutex<Option<Arc<CacheEntry>>>>,
    running: Mutex<BTreeSet<String>>,
    progress: ProgressBar,
}

impl<'a> Executor<'a> {
    fn execute<'s>(&'s self, i: usize, scope: &rayon::Scope<'s>) {
        let slot = self.compute(i);
        let ms = slot.report.ms;
        *self.entry(i) = slot.entry;
        let _ = self.reports[i].set(slot.report);
        if !self.options.keep_outputs {
            // This node has read its inputs: an upstream node it was the
            // last reader of is released, and so is this one if none reads it.
            for &up in &self.predecessors[i] {
                if self.readers_left[up].fetch_sub(1, Ordering::AcqRel) == 1 {
                    self.entry(up).take();
                }
            }
            if self.successors[i].is_empty() {
                self.entry(i).take();
            }
            if ms >= crate::memory::TRIM_AFTER_MS {
                crate::memory::return_free_memory_if_large();
            }
        }
        self.progress.inc(1);
        for &next in &self.successors[i] {
            if self.pending[next].fetch_sub(1, Ordering::AcqRel) == 1 {
                scope.spawn(move |s| self.execute(next, s));
            }
        }
    }

    fn entry(&self, i: usize) -> std::sync::MutexGuard<'_, Option<Arc<CacheEntry>>> {
        self.entries[i].lock().unwrap_or_else(|p| p.into_inner())
    }

    fn set_running(&self, id: &str, running: bool) {
        let mut set = self.running.lock().unwrap_or_else(|p| p.into_inner());
        if running {
            set.insert(id.to_string());
        } else {
            set.remove(id);
        }
        self.progress
            .set_message(set.iter().cloned().collect::<Vec<_>>().join(", "));
    }

    fn compute(&self, i: usize) -> Slot {
        let node = &self.graph.nodes[i];
        let key = self.keys[i];
        let start = Instant::now();
        let report = |status, metrics, error| NodeReport {
            op: node.op.spec().name.clone(),
            status,
            ms: (start.elapsed().as_secs_f64() * 1e6).round() / 1e3,
            key: key.hex(),
            metrics,
            error,
            notes: Default::default(),
            figures: Default::default(),
        };

        let cached = |entry: Arc<CacheEntry>| {
            tracing::info!(node = %node.id, "cached");
            Slot {
                report: NodeReport {
                    figures: entry.figures.clone(),
                    notes: entry.notes.clone(),
                    ..report(NodeStatus::Cached, entry.metrics.clone(), None)
                },
                entry: Some(entry),
            }
        };
        // Taken, not cloned: the entry is released with the slot's.
        let planned = self.planned[i]
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        if let Some(entry) = planned {
            return cached(entry);
        }

        let mut inputs = Inputs::default();
        for e in &node.inputs {
            let upstream = self.entry(e.from).clone();
            let Some(entry) = &upstream else {
                let why = format!(
                    "upstream node `{}` did not produce results",
                    self.graph.nodes[e.from].id
                );
                return Slot {
                    report: report(NodeStatus::Skipped, Default::default(), Some(why)),
                    entry: None,
                };
            };
            let Some(value) = entry.outputs.0.get(&e.from_port) else {
                // Lookups check entries against their op's outputs, so this
                // is a bug, reported rather than panicking the run.
                let why = format!(
                    "upstream node `{}` has no output `{}`",
                    self.graph.nodes[e.from].id, e.from_port
                );
                return Slot {
                    report: report(NodeStatus::Skipped, Default::default(), Some(why)),
                    entry: None,
                };
            };
            inputs.0.insert(e.port.clone(), value.clone());
        }

        if let Some(entry) = self.lookup(&node.id, node.op.spec(), &key, PathCheck::Now) {
            return cached(entry);
        }
        // One process computes a key; others running the same key at the
        // same time wait for its entry. Held until this node's entry is stored.
        let _lease = match self.lease(&node.id, node.op.spec(), &key) {
            Ok(lease) => lease,
            Err(entry) => return cached(entry),
        };

        self.set_running(&node.id, true);
        let files_root = match &self.options.cache {
            Some(disk) => disk.files_root(),
            None => self.options.out_dir.join(".work"),
        };
        // Sinks write into a staging folder, published only on success.
        let staging = node
            .op
            .spec()
            .writes_output
            .then(|| crate::workdir::Staging::new(&self.options.out_dir, &key.hex()));
        let sink_dir = staging
            .as_ref()
            .map_or(self.options.out_dir.as_path(), |s| s.dir());
        let mut files = crate::workdir::WorkDir::new(&files_root, &key.hex())
            .with_fallback(&self.options.out_dir.join(".work"));
        let (outcome, mut results) = {
            let mut ctx = RunCtx::new(&node.id, sink_dir).with_files(|| files.create());
            let outcome = catch_unwind(AssertUnwindSafe(|| {
                node.op.run(&inputs, &node.params, &mut ctx)
            }));
            (outcome, ctx.into_results())
        };
        self.set_running(&node.id, false);
        if let Some(why) = files.fell_back() {
            results
                .notes
                .push(format!("the cache's files folder cannot be written: {why}"));
        }
        let spec = node.op.spec();
        let result = match outcome {
            Ok(Ok(outputs)) => check_outputs(spec, &outputs.0)
                .map_err(|e| e.to_string())
                .and_then(|()| self.inputs_unchanged(node, &inputs, key))
                .map(|()| outputs),
            Ok(Err(e)) => Err(e.to_string()),
            Err(panic) => Err(format!(
                "op `{}` panicked: {}",
                spec.name,
                crate::panics::message(panic.as_ref())
            )),
        };
        let result = crate::workdir::settle(result, Some(files));
        let result = crate::workdir::settle(result, staging);
        let outputs = match result {
            Ok(outputs) => outputs,
            Err(msg) => {
                return self.failure(
                    &node.id,
                    NodeReport {
                        notes: results.notes.into(),
                        ..report(NodeStatus::Failed, results.metrics, Some(msg))
                    },
                );
            }
        };
        let entry = Arc::new(CacheEntry {
            op: spec.name.clone(),
            outputs,
            metrics: results.metrics,
            figures: results.figures.into(),
            notes: results.notes.into(),
            on_disk: Vec::new(),
        });
        self.memory.insert(key, &entry);
        if let Some(disk) = &self.options.cache
            && let Err(e) = disk.store(&key, &entry)
        {
            tracing::warn!(node = %node.id, "could not write the cache entry: {e}");
        }
        tracing::info!(node = %node.id, ms = start.elapsed().as_secs_f64() * 1e3, "ran");
        Slot {
            report: NodeReport {
                figures: entry.figures.clone(),
                notes: entry.notes.clone(),
                ..report(NodeStatus::Ran, entry.metrics.clone(), None)
            },
            entry: Some(entry),
        }
    }

    fn failure(&self, id: &str, report: NodeReport) -> Slot {
        tracing::info!(node = %id, "failed: {}", report.error.as_deref().unwrap_or(""));
        self.progress.println(format!(
            "node `{id}` failed: {}",
            report.error.as_deref().unwrap_or("")
        ));
        Slot {
            report,
            entry: None,
        }
    }

    /// The lease on computing `key`, or the entry another process computed
    /// while this one waited for its lease. Without a disk cache, or where
    /// leases cannot be written (a read-only cache), no lease is needed.
    fn lease(
        &self,
        id: &str,
        spec: &crate::op::OpSpec,
        key: &NodeKey,
    ) -> Result<Option<crate::lease::Lease>, Arc<CacheEntry>> {
        let Some(disk) = &self.options.cache else {
            return Ok(None);
        };
        let path = disk.lease_path(key);
        let start = Instant::now();
        let mut told = false;
        loop {
            match crate::lease::try_acquire(&path) {
                Ok(crate::lease::Acquired::Held(lease)) => {
                    // The owner before us may have stored it just now.
                    return match self.lookup(id, spec, key, PathCheck::Now) {
                        Some(entry) => Err(entry),
                        None => Ok(Some(lease)),
                    };
                }
                Ok(crate::lease::Acquired::Busy) => {}
                Err(e) => {
                    tracing::debug!(node = %id, "no lease ({e}); computing without one");
                    return Ok(None);
                }
            }
            if let Some(entry) = self.lookup(id, spec, key, PathCheck::Now) {
                return Err(entry);
            }
            if !told {
                tracing::info!(node = %id, "another run is computing this key; waiting for it");
                told = true;
            }
            // A live owner that never finishes must not hang this run forever.
            if start.elapsed() > crate::lease::WAIT_LIMIT {
                tracing::warn!(node = %id, "gave up waiting for another run's lease");
                return Ok(None);
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
    }

    /// Each node's cached result, found before any node runs: from memory,
    /// or the meta of its disk entry; then the values of those a node that
    /// computes reads (every one's with `keep_outputs`), read and checked,
    /// and so are the files of the `Path` outputs it reads (see
    /// [`Executor::drop_stale_paths`]). One whose values or files fail
    /// their checks computes instead, and the nodes it reads then need
    /// theirs: until none changes. So a cached node whose readers are all
    /// cached too costs its meta alone, and every value a node receives was
    /// verified before the run began.
    fn plan(&self) -> Vec<Option<Arc<CacheEntry>>> {
        use rayon::prelude::*;
        let n = self.graph.nodes.len();
        let mut planned: Vec<Option<Arc<CacheEntry>>> = (0..n)
            .into_par_iter()
            .map(|i| self.lookup_meta(i))
            .collect();
        let mut checked = BTreeSet::new();
        loop {
            let unread: Vec<usize> = (0..n)
                .filter(|&i| planned[i].as_ref().is_some_and(|e| !e.on_disk.is_empty()))
                .filter(|&i| {
                    self.options.keep_outputs
                        || self.successors[i].iter().any(|&s| planned[s].is_none())
                })
                .collect();
            if unread.is_empty() {
                if self.drop_stale_paths(&mut planned, &mut checked) {
                    continue;
                }
                return planned;
            }
            let read: Vec<Option<Arc<CacheEntry>>> = unread
                .par_iter()
                .map(|&i| {
                    let node = &self.graph.nodes[i];
                    self.lookup(&node.id, node.op.spec(), &self.keys[i], PathCheck::Later)
                })
                .collect();
            for (i, entry) in unread.into_iter().zip(read) {
                planned[i] = entry;
            }
        }
    }

    /// Checks the files of planned entries' `Path` outputs that a node that
    /// computes reads (every one with `keep_outputs`) against the content
    /// they were recorded with, side by side; `checked` holds the (node,
    /// port)s already checked. An entry with one modified or deleted is
    /// dropped: its node computes again, regenerating its files. Whether
    /// any was. The others are left unread: a phantom's folders (46 MB)
    /// need no reading in a run where only nodes after them compute.
    fn drop_stale_paths(
        &self,
        planned: &mut [Option<Arc<CacheEntry>>],
        checked: &mut BTreeSet<(usize, String)>,
    ) -> bool {
        use rayon::prelude::*;
        let mut due: Vec<(usize, String)> = Vec::new();
        for (i, entry) in planned.iter().enumerate() {
            let Some(entry) = entry else { continue };
            for (port, value) in &entry.outputs.0 {
                let read = self.options.keep_outputs
                    || self.successors[i].iter().any(|&s| {
                        planned[s].is_none()
                            && self.graph.nodes[s]
                                .inputs
                                .iter()
                                .any(|e| e.from == i && &e.from_port == port)
                    });
                if matches!(value, crate::value::Value::Path(_))
                    && read
                    && checked.insert((i, port.clone()))
                {
                    due.push((i, port.clone()));
                }
            }
        }
        // One log line a node, whichever of its stale ports it names.
        let stale: std::collections::BTreeMap<usize, String> = due
            .par_iter()
            .filter_map(|(i, port)| {
                let entry = planned[*i].as_ref()?;
                let one = std::collections::BTreeMap::from([(
                    port.clone(),
                    entry.outputs.0[port].clone(),
                )]);
                crate::op::paths_intact(&one, "output")
                    .err()
                    .map(|why| (*i, why))
            })
            .collect();
        for (&i, why) in &stale {
            let id = &self.graph.nodes[i].id;
            tracing::info!(node = %id, "stale cache entry, recomputing: {why}");
            planned[i] = None;
        }
        !stale.is_empty()
    }

    /// Node `i`'s cached result with its values left on disk where the
    /// entry holds any: from memory, else its disk entry's meta. A corrupt
    /// or stale entry is logged, removed and treated as missing.
    fn lookup_meta(&self, i: usize) -> Option<Arc<CacheEntry>> {
        let (node, key) = (&self.graph.nodes[i], &self.keys[i]);
        if let Some(entry) = self.memory.get(key) {
            return Some(entry);
        }
        let disk = self.options.cache.as_ref()?;
        let entry = usable(&node.id, disk, key, disk.load_meta(key), PathCheck::Later)?;
        let spec = node.op.spec();
        let held = entry
            .outputs
            .0
            .keys()
            .chain(&entry.on_disk)
            .collect::<BTreeSet<_>>();
        let declared = spec
            .outputs
            .iter()
            .map(|p| &p.name)
            .collect::<BTreeSet<_>>();
        if held != declared {
            tracing::warn!(
                node = %node.id,
                "cache entry does not fit the op (outputs {held:?}, declared {declared:?}), recomputing"
            );
            disk.remove(key);
            return None;
        }
        Some(Arc::new(entry))
    }

    /// The cached result for `key`, from memory or disk; a corrupt or stale disk
    /// entry is logged, removed and treated as missing. `paths` says when
    /// its `Path` outputs' files are checked.
    fn lookup(
        &self,
        id: &str,
        spec: &crate::op::OpSpec,
        key: &NodeKey,
        paths: PathCheck,
    ) -> Option<Arc<CacheEntry>> {
        if let Some(entry) = self.memory.get(key) {
            return Some(entry);
        }
        let disk = self.options.cache.as_ref()?;
        let entry = usable(id, disk, key, disk.load(key), paths)?;
        if let Err(why) = check_outputs(spec, &entry.outputs.0) {
            tracing::warn!(node = %id, "cache entry does not fit the op, recomputing: {why}");
            disk.remove(key);
            return None;
        }
        let entry = Arc::new(entry);
        self.memory.insert(*key, &entry);
        Some(entry)
    }
}

/// When a cached entry's `Path` outputs are checked against the content
/// they were recorded with.
#[derive(Clone, Copy, PartialEq, Eq)]
enum PathCheck {
    /// On lookup: the entry is about to be used.
    Now,
    /// Before the run, those a node that computes reads
    /// ([`Executor::drop_stale_paths`]).
    Later,
}

/// The entry a disk lookup of `key` (node `id`) found, if it is whole and
/// (checked `Now`) its files are as recorded: a corrupt entry is logged and
/// removed, a stale one logged, and either treated as missing.
fn usable(
    id: &str,
    disk: &DiskCache,
    key: &NodeKey,
    found: Lookup,
    paths: PathCheck,
) -> Option<CacheEntry> {
    let entry = match found {
        Lookup::Hit(entry) => entry,
        Lookup::Miss => return None,
        Lookup::Corrupt(why) => {
            tracing::warn!(node = %id, "corrupt cache entry, recomputing: {why}");
            disk.remove(key);
            return None;
        }
    };
    if paths == PathCheck::Now
        && let Err(why) = entry.paths_intact()
    {
        tracing::info!(node = %id, "stale cache entry, recomputing: {why}");
        return None;
    }
    Some(entry)
}

/// An op must produce every declared output with its declared type.
impl Executor<'_> {
    /// Whether the files a node read (its path parameters and `Path` inputs)
    /// hold, after it ran, the content its key was made from. A file deleted
    /// or edited while the node ran (a cache folder cleared under a running
    /// job) would otherwise store a result of half a set under the key of the
    /// whole.
    fn inputs_unchanged(
        &self,
        node: &ValidNode,
        inputs: &Inputs,
        key: NodeKey,
    ) -> Result<(), String> {
        let changed =
            |why: String| format!("{why} while the node ran: its result is not kept; run again");
        crate::op::paths_intact(&inputs.0, "input").map_err(changed)?;
        match crate::key::node_key(node, |j| self.keys[j], &self.options.out_dir) {
            Ok(again) if again == key => Ok(()),
            Ok(_) => Err(changed(
                "a file named by a path parameter was modified".into(),
            )),
            Err(problems) => {
                let (name, e) = &problems[0];
                Err(changed(format!("parameter `{name}`: {e}")))
            }
        }
    }
}

fn check_outputs(
    spec: &crate::op::OpSpec,
    outputs: &std::collections::BTreeMap<String, Value>,
) -> Result<(), OpError> {
    for port in &spec.outputs {
        match outputs.get(&port.name) {
            None => {
                return Err(OpError::invalid(format!(
                    "op `{}` did not produce its output `{}`",
                    spec.name, port.name
                )));
            }
            Some(v) if !port.accepts(v.value_type()) => {
                return Err(OpError::invalid(format!(
                    "op `{}` produced a {} on output `{}`, declared {}",
                    spec.name,
                    v.value_type(),
                    port.name,
                    port.type_names()
                )));
            }
            Some(v) => {
                if let Some(what) = v.non_finite() {
                    return Err(OpError::invalid(format!(
                        "op `{}` produced a non-finite number in {what} of output `{}` (NaN or infinity): an input or parameter is out of its meaningful range",
                        spec.name, port.name
                    )));
                }
            }
        }
    }
    if let Some(extra) = outputs.keys().find(|k| spec.output_port(k).is_none()) {
        return Err(OpError::invalid(format!(
            "op `{}` produced an undeclared output `{extra}`",
            spec.name
        )));
    }
    Ok(())
}
