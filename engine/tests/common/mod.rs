//! Test node types for the engine's own tests: trivial arithmetic that counts
//! how often each node ran, a failing op, a panicking op, a slow op that records
//! how many ran at once, a file source and a file sink.

#![allow(dead_code)]

use fusegraph_engine::cache::{DiskCache, MemoryCache};
use fusegraph_engine::schedule::{RunOptions, RunOutcome};
use fusegraph_engine::session::{load_graph, run};
use fusegraph_engine::value::{Grid, Volume};
use fusegraph_engine::{
    GraphErrors, Inputs, NodeStatus, Op, OpError, OpSpec, Outputs, ParamSpec, Params, Registry,
    RunCtx, ValueType, path_value,
};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// How many times each node id ran, and the most nodes seen running at once.
#[derive(Default)]
pub struct Counters {
    runs: Mutex<HashMap<String, usize>>,
    running: AtomicUsize,
    pub max_running: AtomicUsize,
}

impl Counters {
    pub fn runs(&self, id: &str) -> usize {
        *self.runs.lock().unwrap().get(id).unwrap_or(&0)
    }
    pub fn total(&self) -> usize {
        self.runs.lock().unwrap().values().sum()
    }
    fn count(&self, id: &str) {
        *self.runs.lock().unwrap().entry(id.to_string()).or_default() += 1;
    }
}

type RunFn =
    dyn Fn(&Inputs, &Params, &mut RunCtx, &Counters) -> Result<Outputs, OpError> + Send + Sync;

struct TestOp {
    spec: OpSpec,
    counters: Arc<Counters>,
    run: Box<RunFn>,
}

impl Op for TestOp {
    fn spec(&self) -> &OpSpec {
        &self.spec
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        self.counters.count(ctx.node_id());
        (self.run)(inputs, params, ctx, &self.counters)
    }
}

fn scalar(inputs: &Inputs, port: &str) -> f64 {
    *inputs.get::<f64>(port).unwrap()
}

/// A registry of the test ops, all counting into one `Counters`.
pub fn registry() -> (Registry, Arc<Counters>) {
    let counters = Arc::new(Counters::default());
    let mut r = Registry::new();
    let mut add = |spec: OpSpec, run: Box<RunFn>| {
        r.register(Arc::new(TestOp {
            spec,
            counters: counters.clone(),
            run,
        }))
        .unwrap();
    };
    add(
        OpSpec::new("test.source", 1, "A number")
            .param(ParamSpec::float("value", 1.0, "mm", "The number").range(-1e6, 1e6))
            .param(ParamSpec::int("repeat", 1, "", "Unused integer").at_least(0.0))
            .param(ParamSpec::choice(
                "mode",
                &["fast", "slow"],
                "Unused choice",
            ))
            .output("value", ValueType::Scalar, "The number"),
        Box::new(|_, p, _, _| Ok(Outputs::new().with("value", p.float("value")?))),
    );
    add(
        OpSpec::new("test.add", 1, "a + b")
            .input("a", &[ValueType::Scalar], "First")
            .optional_input("b", &[ValueType::Scalar], "Second (0 when unconnected)")
            .output("value", ValueType::Scalar, "Sum"),
        Box::new(|i, _, ctx, _| {
            let v = scalar(i, "a") + i.optional::<f64>("b")?.map_or(0.0, |b| *b);
            ctx.metric("sum", v);
            Ok(Outputs::new().with("value", v))
        }),
    );
    add(
        OpSpec::new("test.fail", 1, "Always fails")
            .input("a", &[ValueType::Scalar], "Ignored")
            .output("value", ValueType::Scalar, "Never produced"),
        Box::new(|_, _, _, _| Err(OpError::invalid("deliberate failure: bad marker count"))),
    );
    add(
        OpSpec::new("test.panic", 1, "Always panics")
            .input("a", &[ValueType::Scalar], "Ignored")
            .output("value", ValueType::Scalar, "Never produced"),
        Box::new(|_, _, _, _| panic!("index out of bounds in test op")),
    );
    add(
        OpSpec::new("test.liar", 1, "Declares a Scalar, produces a Volume").output(
            "value",
            ValueType::Scalar,
            "Wrong type",
        ),
        Box::new(|_, _, _, _| {
            let v = Volume::new(
                Grid::axis_aligned([1, 1, 1], [1.0; 3], [0.0; 3]),
                vec![1.0f32],
            )
            .unwrap();
            Ok(Outputs::new().with("value", v))
        }),
    );
    add(
        OpSpec::new(
            "test.slow",
            1,
            "Sleeps, recording how many nodes run at once",
        )
        .param(ParamSpec::int("ms", 50, "ms", "Sleep"))
        .output("value", ValueType::Scalar, "1"),
        Box::new(|_, p, _, c| {
            let now = c.running.fetch_add(1, Ordering::SeqCst) + 1;
            c.max_running.fetch_max(now, Ordering::SeqCst);
            std::thread::sleep(std::time::Duration::from_millis(p.int("ms")? as u64));
            c.running.fetch_sub(1, Ordering::SeqCst);
            Ok(Outputs::new().with("value", 1.0))
        }),
    );
    add(
        OpSpec::new("test.volume", 1, "A volume")
            .param(ParamSpec::int("size", 2, "voxels", "Edge length").range(1.0, 64.0))
            .output("volume", ValueType::Volume, "Zeros"),
        Box::new(|_, p, _, _| {
            let n = p.count("size")?;
            let v = Volume::new(
                Grid::axis_aligned([n; 3], [1.0; 3], [0.0; 3]),
                vec![0.0f32; n * n * n],
            )
            .unwrap();
            Ok(Outputs::new().with("volume", v))
        }),
    );
    add(
        OpSpec::new("test.voxels", 1, "Counts voxels")
            .input("volume", &[ValueType::Volume, ValueType::Mask], "A grid")
            .output("count", ValueType::Scalar, "Voxels"),
        Box::new(|i, _, _, _| {
            let v = i.get::<Volume>("volume")?;
            Ok(Outputs::new().with("count", v.data.len() as f64))
        }),
    );
    add(
        OpSpec::new("test.file", 1, "Size of a file")
            .param(ParamSpec::path("path", "A file"))
            .output("bytes", ValueType::Scalar, "Its size"),
        Box::new(|_, p, _, _| {
            let path = p.path("path")?;
            let n = std::fs::read(&path)
                .map_err(|e| OpError::io(&path, e))?
                .len();
            Ok(Outputs::new().with("bytes", n as f64))
        }),
    );
    add(
        OpSpec::new("test.write", 1, "Writes a number to a file")
            .input("value", &[ValueType::Scalar], "The number")
            .param(ParamSpec::string("file", "value.txt", "Output file"))
            .output("file", ValueType::Path, "The file")
            .writes_output(),
        Box::new(|i, p, ctx, _| {
            let path = ctx.output_path(&p.string("file")?)?;
            std::fs::write(&path, scalar(i, "value").to_string())
                .map_err(|e| OpError::io(&path, e))?;
            Ok(Outputs::new().with("file", path_value(&path)?))
        }),
    );
    add(
        OpSpec::new(
            "test.generate",
            1,
            "Writes files into its content-addressed folder",
        )
        .param(ParamSpec::int("files", 3, "", "How many files"))
        .output("dir", ValueType::Path, "The folder"),
        Box::new(|_, p, ctx, _| {
            let dir = ctx.work_dir()?.join("series");
            std::fs::create_dir_all(&dir).map_err(|e| OpError::io(&dir, e))?;
            for i in 0..p.count("files")? {
                let f = dir.join(format!("slice{i}.txt"));
                std::fs::write(&f, format!("slice {i}")).map_err(|e| OpError::io(&f, e))?;
            }
            Ok(Outputs::new().with("dir", path_value(&dir)?))
        }),
    );
    add(
        OpSpec::new("test.count_bytes", 1, "The bytes in a folder's files")
            .input("dir", &[ValueType::Path], "The folder")
            .param(ParamSpec::string("label", "", "Changes the key alone"))
            .output("bytes", ValueType::Scalar, "Their bytes"),
        Box::new(|i, _, _, _| {
            let dir = &i.get::<fusegraph_engine::value::PathValue>("dir")?.path;
            let mut bytes = 0;
            for entry in std::fs::read_dir(dir).map_err(|e| OpError::io(dir, e))? {
                let path = entry.map_err(|e| OpError::io(dir, e))?.path();
                bytes += std::fs::read(&path)
                    .map_err(|e| OpError::io(&path, e))?
                    .len();
            }
            Ok(Outputs::new().with("bytes", bytes as f64))
        }),
    );
    add(
        OpSpec::new(
            "test.count_then_lose",
            1,
            "Counts a folder's files; on its first run, deletes one after reading (a cache cleared under a running job)",
        )
        .input("dir", &[ValueType::Path], "The folder")
        .output("files", ValueType::Scalar, "How many files it held"),
        Box::new(|i, _, ctx, counters| {
            let dir = &i.get::<fusegraph_engine::value::PathValue>("dir")?.path;
            let mut files: Vec<_> = std::fs::read_dir(dir)
                .map_err(|e| OpError::io(dir, e))?
                .map(|e| e.unwrap().path())
                .collect();
            files.sort();
            if counters.runs(ctx.node_id()) == 1 {
                std::fs::remove_file(&files[0]).unwrap();
            }
            Ok(Outputs::new().with("files", files.len() as f64))
        }),
    );
    add(
        OpSpec::new(
            "test.read_then_touch",
            1,
            "Size of a file; on its first run, appends to it after reading",
        )
        .param(ParamSpec::path("path", "A file"))
        .output("bytes", ValueType::Scalar, "Its size"),
        Box::new(|_, p, ctx, counters| {
            let path = p.path("path")?;
            let n = std::fs::read(&path)
                .map_err(|e| OpError::io(&path, e))?
                .len();
            if counters.runs(ctx.node_id()) == 1 {
                let mut text = std::fs::read(&path).unwrap();
                text.extend(b" and more");
                std::fs::write(&path, text).unwrap();
            }
            Ok(Outputs::new().with("bytes", n as f64))
        }),
    );
    (r, counters)
}

/// A graph file written into `dir`.
pub fn write_graph(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Loads (with overrides), validates and runs a graph against a disk cache in
/// `cache` (or none), with a fresh memory cache, writing into `out`.
pub fn run_file(
    registry: &Registry,
    file: &Path,
    sets: &[&str],
    cache: Option<&Path>,
    out: &Path,
) -> Result<RunOutcome, GraphErrors> {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let graph = load_graph(file, &sets, registry)?;
    let options = RunOptions {
        out_dir: out.to_path_buf(),
        cache: cache.map(|c| DiskCache::open(c).unwrap()),
        jobs: 2,
        progress: false,
        provenance: Default::default(),
        // The tests read every node's outputs from the outcome.
        keep_outputs: true,
    };
    match run(&graph, &options, &MemoryCache::new()) {
        Ok(o) => Ok(o),
        Err(fusegraph_engine::session::RunError::Graph(g)) => Err(g),
        Err(e) => panic!("{e}"),
    }
}

/// The status of every node, by id.
pub fn statuses(outcome: &RunOutcome) -> HashMap<String, NodeStatus> {
    outcome
        .report
        .nodes
        .iter()
        .map(|(id, n)| (id.clone(), n.status))
        .collect()
}

/// The ids whose status is `status`, sorted.
pub fn with_status(outcome: &RunOutcome, status: NodeStatus) -> Vec<String> {
    let mut ids: Vec<String> = outcome
        .report
        .nodes
        .iter()
        .filter(|(_, n)| n.status == status)
        .map(|(id, _)| id.clone())
        .collect();
    ids.sort();
    ids
}
