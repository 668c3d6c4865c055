//! `fusegraph._native`: the Rust side of the `fusegraph` Python package.
//! It runs, validates and sweeps graphs with the engine (the GIL released
//! while they run), hands their values to Python as numpy views
//! ([`values`]) and registers ops written in Python ([`host`]). The Python
//! side (`python/fusegraph/`) wraps it in the package's classes.

mod host;
mod values;

use fusegraph_engine::cache::{DiskCache, MemoryCache};
use fusegraph_engine::graph::GraphDoc;
use fusegraph_engine::schedule::RunOptions;
use fusegraph_engine::session::RunError;
use fusegraph_engine::{GraphErrors, Registry, Value, ValueType};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::{Path, PathBuf};
use std::sync::Arc;

pyo3::create_exception!(
    _native,
    GraphError,
    PyValueError,
    "An invalid graph or sweep: `errors` holds each problem (file, node, key, message)."
);

/// A GraphErrors as a Python GraphError with an `errors` list.
fn graph_error(py: Python<'_>, errors: &GraphErrors) -> PyErr {
    let err = GraphError::new_err(errors.to_string());
    let list = PyList::empty(py);
    for e in &errors.0 {
        let d = PyDict::new(py);
        let _ = d.set_item("kind", format!("{:?}", e.kind));
        let _ = d.set_item("file", e.file.to_string_lossy().into_owned());
        let _ = d.set_item("node", e.node.clone());
        let _ = d.set_item("key", e.key.clone());
        let _ = d.set_item("message", e.message.clone());
        let _ = list.append(d);
    }
    let _ = err.value(py).setattr("errors", list);
    err
}

/// The registry of a call: the built-in ops and every Python op declared.
fn registry() -> PyResult<Registry> {
    host::registry().map_err(PyValueError::new_err)
}

/// Where a run or sweep keeps its cache: `cache`, none, or `.fusegraph/cache`
/// beside `file` (as the command line does).
fn cache_dir(file: &Path, cache: Option<PathBuf>, no_cache: bool) -> Option<PathBuf> {
    (!no_cache).then(|| cache.unwrap_or_else(|| fusegraph_engine::cache::default_dir(file)))
}

/// Puts `given` (`"node.port"` -> value in the plain Python form) in place
/// of those nodes' outputs: each such node becomes a node of its own op that
/// returns the values (its key: their content), its parameters and inputs
/// dropped. A node or port the graph has not, or a value that does not
/// convert, is an error naming it.
fn replace_outputs(
    doc: &mut GraphDoc,
    given: Vec<(String, String, Value)>,
    registry: &mut Registry,
) -> Result<(), String> {
    let mut by_node: std::collections::BTreeMap<String, Vec<(String, Value)>> = Default::default();
    for (node, port, value) in given {
        by_node.entry(node).or_default().push((port, value));
    }
    for (node, values) in by_node {
        let decl = doc
            .nodes
            .iter_mut()
            .find(|n| n.id == node)
            .ok_or_else(|| format!("inputs: the graph has no node `{node}`"))?;
        let op = GivenValues::new(&node, values);
        decl.op = op.spec.name.clone();
        decl.params.clear();
        decl.inputs.clear();
        if registry.get(&op.spec.name).is_none() {
            registry.register(Arc::new(op)).map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}

/// A node whose outputs were given from Python.
struct GivenValues {
    spec: fusegraph_engine::OpSpec,
    values: Vec<(String, Value)>,
}

impl GivenValues {
    fn new(node: &str, values: Vec<(String, Value)>) -> Self {
        let mut hasher = blake3::Hasher::new();
        let mut bytes = Vec::new();
        for (port, value) in &values {
            bytes.clear();
            fusegraph_engine::value::encode_value(value, &mut bytes);
            hasher.update(port.as_bytes());
            hasher.update(&[0]);
            hasher.update(&bytes);
        }
        let hash = hasher.finalize().to_hex().to_string();
        let mut spec = fusegraph_engine::OpSpec::new(
            &format!("given.v{}", &hash[..16]),
            1,
            &format!("the outputs of node `{node}`, given from Python"),
        );
        for (port, value) in &values {
            spec = spec.output(port, value.value_type(), "given from Python");
        }
        spec.origin = Some(fusegraph_engine::op::Origin {
            file: PathBuf::from("<python>"),
            content_hash: hash,
        });
        GivenValues { spec, values }
    }
}

impl fusegraph_engine::Op for GivenValues {
    fn spec(&self) -> &fusegraph_engine::OpSpec {
        &self.spec
    }

    fn run(
        &self,
        _: &fusegraph_engine::Inputs,
        _: &fusegraph_engine::Params,
        _: &mut fusegraph_engine::RunCtx,
    ) -> Result<fusegraph_engine::Outputs, fusegraph_engine::OpError> {
        Ok(self
            .values
            .iter()
            .fold(fusegraph_engine::Outputs::new(), |o, (p, v)| {
                o.with(p, v.clone())
            }))
    }
}

/// Reads `inputs` (`{"node.port": (type name, plain value)}`) as engine values.
fn given_values(inputs: Option<Bound<'_, PyDict>>) -> PyResult<Vec<(String, String, Value)>> {
    let mut out = Vec::new();
    for (k, v) in inputs.iter().flat_map(|d| d.iter()) {
        let key: String = k.extract()?;
        let (node, port) = key
            .split_once('.')
            .ok_or_else(|| PyValueError::new_err(format!("inputs: `{key}` is not NODE.PORT")))?;
        let (ty, value): (String, Bound<'_, PyAny>) = v.extract()?;
        let ty = ValueType::from_name(&ty).ok_or_else(|| {
            PyValueError::new_err(format!("inputs[`{key}`]: unknown type `{ty}`"))
        })?;
        let value = values::from_py(&value, ty)
            .map_err(|why| PyValueError::new_err(format!("inputs[`{key}`]: {why}")))?;
        out.push((node.to_string(), port.to_string(), value));
    }
    Ok(out)
}

/// Loads `graph` with the overrides `sets` and the `given` outputs, and
/// validates it.
fn load(
    graph: &Path,
    sets: &[String],
    given: Vec<(String, String, Value)>,
    registry: &Registry,
) -> Result<fusegraph_engine::validate::ValidGraph, GraphErrors> {
    let mut doc = GraphDoc::load(graph)?;
    let mut registry = registry.clone();
    let as_error = |why: String| {
        GraphErrors(vec![fusegraph_engine::GraphError::file(
            fusegraph_engine::ErrorKind::BadOverride,
            graph,
            why,
        )])
    };
    replace_outputs(&mut doc, given, &mut registry).map_err(as_error)?;
    fusegraph_engine::session::validate_doc(doc, sets, &registry)
}

/// The build's provenance (see `fusegraph::cli::provenance`), the command
/// line being Python's own (`sys.argv`), with the Python version.
fn python_provenance(
    py: Python<'_>,
    sets: &[String],
) -> serde_json::Map<String, serde_json::Value> {
    let sys = py.import("sys").ok();
    let argv: Vec<String> = sys
        .as_ref()
        .and_then(|s| s.getattr("argv").ok()?.extract().ok())
        .unwrap_or_default();
    let mut p = fusegraph::cli::provenance(&argv, sets);
    let version: Option<String> = sys.and_then(|s| s.getattr("version").ok()?.extract().ok());
    p.insert("python".into(), version.unwrap_or_default().into());
    p
}

/// Runs a graph; see `fusegraph.run`.
#[pyfunction]
#[pyo3(signature = (graph, sets, out=None, cache=None, no_cache=false, jobs=0, inputs=None))]
#[allow(clippy::too_many_arguments)]
fn run<'py>(
    py: Python<'py>,
    graph: PathBuf,
    sets: Vec<String>,
    out: Option<PathBuf>,
    cache: Option<PathBuf>,
    no_cache: bool,
    jobs: usize,
    inputs: Option<Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let registry = registry()?;
    let given = given_values(inputs)?;
    let loaded = py.detach(|| load(&graph, &sets, given, &registry));
    let valid = loaded.map_err(|e| graph_error(py, &e))?;
    let out_dir = fusegraph::cli::out_folder(out, &valid.name)
        .map_err(|e| PyOSError::new_err(e.to_string()))?;
    let cache = match cache_dir(&graph, cache, no_cache) {
        Some(dir) => Some(
            DiskCache::open(&dir)
                .map_err(|e| PyOSError::new_err(format!("cache {}: {e}", dir.display())))?,
        ),
        None => None,
    };
    let options = RunOptions {
        out_dir: out_dir.clone(),
        cache,
        jobs,
        progress: false,
        provenance: python_provenance(py, &sets),
        keep_outputs: true,
    };
    let outcome = py
        .detach(|| fusegraph_engine::session::run(&valid, &options, &MemoryCache::new()))
        .map_err(|e| match e {
            RunError::Graph(g) => graph_error(py, &g),
            RunError::Io(io) => PyOSError::new_err(format!("run failed: {io}")),
        })?;
    let result = PyDict::new(py);
    let report = serde_json::to_string(&outcome.report.to_json()).expect("plain data");
    result.set_item("report", report)?;
    result.set_item("succeeded", outcome.report.succeeded())?;
    result.set_item("out_dir", out_dir.to_string_lossy().into_owned())?;
    let outputs = PyDict::new(py);
    for (node, entry) in valid.nodes.iter().zip(&outcome.results) {
        let Some(entry) = entry else { continue };
        for (port, value) in &entry.outputs.0 {
            outputs.set_item(format!("{}.{port}", node.id), values::to_py(py, value)?)?;
        }
    }
    result.set_item("outputs", outputs)?;
    Ok(result)
}

/// Validates a graph; see `fusegraph.validate`.
#[pyfunction]
#[pyo3(signature = (graph, sets))]
fn validate<'py>(
    py: Python<'py>,
    graph: PathBuf,
    sets: Vec<String>,
) -> PyResult<Bound<'py, PyDict>> {
    let registry = registry()?;
    let valid = py
        .detach(|| fusegraph_engine::session::load_graph(&graph, &sets, &registry))
        .map_err(|e| graph_error(py, &e))?;
    let d = PyDict::new(py);
    d.set_item("name", &valid.name)?;
    d.set_item(
        "nodes",
        valid.nodes.iter().map(|n| n.id.clone()).collect::<Vec<_>>(),
    )?;
    Ok(d)
}

/// Every op's declaration, as JSON (as `fusegraph nodes --json`).
#[pyfunction]
fn nodes() -> PyResult<String> {
    let registry = registry()?;
    let specs: Vec<_> = registry.specs().collect();
    Ok(serde_json::to_string(&specs).expect("plain data"))
}

/// Runs a sweep and writes its comparison; see `fusegraph.sweep`.
#[pyfunction]
#[pyo3(signature = (sweep, out=None, cache=None, no_cache=false, jobs=0))]
fn sweep<'py>(
    py: Python<'py>,
    sweep: PathBuf,
    out: Option<PathBuf>,
    cache: Option<PathBuf>,
    no_cache: bool,
    jobs: usize,
) -> PyResult<Bound<'py, PyDict>> {
    use fusegraph_engine::sweep as sw;
    let registry = registry()?;
    let plan = sw::load_sweep(&sweep).map_err(|e| graph_error(py, &e))?;
    let graphs = py
        .detach(|| sw::validate_variants(&plan, &registry))
        .map_err(|e| graph_error(py, &e))?;
    let out_dir = fusegraph::cli::out_folder(out, &plan.name)
        .map_err(|e| PyOSError::new_err(e.to_string()))?;
    let options = sw::SweepOptions {
        out_dir: out_dir.clone(),
        cache: (!no_cache).then(|| cache.unwrap_or_else(|| sw::default_cache(&plan))),
        jobs,
        shard: None,
        provenance: python_provenance(py, &[]),
    };
    let runs = py
        .detach(|| -> Result<_, String> {
            let runs = sw::run_sweep(&plan, &graphs, &options, |_| {})
                .map_err(|e| format!("sweep into {}: {e}", out_dir.display()))?;
            let c = sw::compare::comparison(&out_dir)?;
            sw::write_comparison(&c, &out_dir)
                .map_err(|e| format!("writing the comparison into {}: {e}", out_dir.display()))?;
            Ok(runs)
        })
        .map_err(PyOSError::new_err)?;
    let d = PyDict::new(py);
    d.set_item("out_dir", out_dir.to_string_lossy().into_owned())?;
    let list = PyList::empty(py);
    for r in runs {
        let v = PyDict::new(py);
        v.set_item("name", r.name)?;
        v.set_item("succeeded", r.succeeded)?;
        v.set_item("ms", r.ms)?;
        v.set_item("ran", r.ran)?;
        v.set_item("cached", r.cached)?;
        v.set_item("error", r.error)?;
        list.append(v)?;
    }
    d.set_item("variants", list)?;
    Ok(d)
}

/// Declares a Python op; see `fusegraph.op`.
#[pyfunction]
fn declare(declaration: &str, invoke: Py<PyAny>, file: PathBuf, source: &str) -> PyResult<String> {
    host::declare(declaration, invoke, &file, source).map_err(PyValueError::new_err)
}

/// The `fusegraph` command line with Python ops; returns its exit code.
#[pyfunction]
fn cli(py: Python<'_>, argv: Vec<String>) -> u8 {
    let host: Arc<dyn fusegraph_engine::script::ScriptHost> = Arc::new(host::PythonHost);
    py.detach(|| fusegraph::cli::main(argv.into_iter().map(Into::into), Some(host)))
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("GraphError", m.py().get_type::<GraphError>())?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(validate, m)?)?;
    m.add_function(wrap_pyfunction!(nodes, m)?)?;
    m.add_function(wrap_pyfunction!(sweep, m)?)?;
    m.add_function(wrap_pyfunction!(declare, m)?)?;
    m.add_function(wrap_pyfunction!(cli, m)?)?;
    Ok(())
}
