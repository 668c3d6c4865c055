//! Ops written in Python: their declarations (made by the package's
//! `@fusegraph.op` decorator), the node type that calls them, and the
//! [`ScriptHost`] that runs the Python files graphs name.
//!
//! A Python op's cache key holds its name, version, declaration and the
//! source of its function (blake3, as the spec's origin hash): editing the
//! function re-runs its nodes and nothing else. The GIL is taken only while
//! the function (and the conversion of its values) runs; Rust nodes go on
//! beside it.

use crate::values::{from_py, param_to_py, to_py};
use fusegraph_engine::op::{Origin, RunCtx};
use fusegraph_engine::registry::Registry;
use fusegraph_engine::script::ScriptHost;
use fusegraph_engine::{Inputs, Op, OpError, OpSpec, Outputs, Params};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// An op declared in Python.
pub struct PyOp {
    spec: OpSpec,
    /// `invoke(inputs, params) -> {"outputs", "metrics", "notes"} | {"error"}`,
    /// made by the package around the user's function.
    invoke: Py<PyAny>,
}

/// The origin file of an op declared where Python has no source file (a REPL).
pub const PYTHON_ORIGIN: &str = "<python>";

/// Every op Python declared in this process, by name, in declaration order.
static DECLARED: Mutex<Vec<Arc<PyOp>>> = Mutex::new(Vec::new());

fn declared() -> std::sync::MutexGuard<'static, Vec<Arc<PyOp>>> {
    // A panic while the list was held cannot leave it half-written.
    DECLARED.lock().unwrap_or_else(|e| e.into_inner())
}

/// Declares (or declares again, replacing) the op `declaration` (JSON, see
/// `fusegraph_engine::plugin::script_op_spec`) whose function lives in
/// `file` with `source`; returns its name.
pub fn declare(
    declaration: &str,
    invoke: Py<PyAny>,
    file: &Path,
    source: &str,
) -> Result<String, String> {
    let mut hasher = blake3::Hasher::new();
    for part in [declaration, source] {
        hasher.update(&(part.len() as u64).to_le_bytes());
        hasher.update(part.as_bytes());
    }
    let origin = Origin {
        file: file.to_path_buf(),
        content_hash: hasher.finalize().to_hex().to_string(),
    };
    let spec = fusegraph_engine::plugin::script_op_spec(declaration, &origin)?;
    let name = spec.name.clone();
    let mut ops = declared();
    ops.retain(|op| op.spec.name != name);
    ops.push(Arc::new(PyOp { spec, invoke }));
    Ok(name)
}

/// Adds every op Python declared to `registry`: a Python op already there
/// is replaced by its latest declaration; a built-in or plugin op of the
/// same name is an error.
pub fn add_declared(registry: &mut Registry) -> Result<Vec<String>, String> {
    let ops: Vec<Arc<PyOp>> = declared().clone();
    let mut names = Vec::new();
    for op in ops {
        let name = op.spec.name.clone();
        if let Some(there) = registry.get(&name) {
            let python = there.spec().origin.as_ref().is_some_and(|o| {
                o.file.extension().is_some_and(|e| e == "py") || o.file == Path::new(PYTHON_ORIGIN)
            });
            if !python {
                return Err(format!(
                    "Python op `{name}` ({}): a built-in or plugin op has that name",
                    op.spec
                        .origin
                        .as_ref()
                        .map_or(String::new(), |o| o.file.display().to_string())
                ));
            }
            registry.unregister(&name);
        }
        registry.register(op).map_err(|e| e.to_string())?;
        names.push(name);
    }
    Ok(names)
}

/// The registry a run from Python uses: the built-in ops, the Python ops
/// declared so far, and a host for the Python files graphs name.
pub fn registry() -> Result<Registry, String> {
    let mut registry = fusegraph_nodes::builtin_registry();
    registry.set_script_host(Arc::new(PythonHost));
    add_declared(&mut registry)?;
    Ok(registry)
}

/// Runs the Python files graphs and `--python` name.
pub struct PythonHost;

impl ScriptHost for PythonHost {
    fn load(&self, file: &Path, registry: &mut Registry) -> Result<Vec<String>, String> {
        if !file.is_file() {
            return Err("no such Python file".into());
        }
        Python::attach(|py| -> Result<(), String> {
            let runpy = py.import("runpy").map_err(|e| e.to_string())?;
            // The package first, so `import fusegraph` in the file finds the
            // one that is running it.
            py.import("fusegraph").map_err(|e| e.to_string())?;
            runpy
                .call_method1("run_path", (file.to_string_lossy().into_owned(),))
                .map(|_| ())
                .map_err(|e| last_line(py, &e))
        })?;
        add_declared(registry)
    }
}

/// The last line of a Python exception's traceback, with the innermost
/// frame's file and line: `ValueError: ... (ops.py, line 12)`.
pub fn last_line(py: Python<'_>, e: &PyErr) -> String {
    let message = e.to_string();
    let place = e.traceback(py).and_then(|tb| {
        let mut tb = tb;
        while let Ok(Some(next)) = tb.getattr("tb_next").map(|n| (!n.is_none()).then_some(n)) {
            tb = next.cast_into().ok()?;
        }
        let line: usize = tb.getattr("tb_lineno").ok()?.extract().ok()?;
        let file: String = tb
            .getattr("tb_frame")
            .and_then(|f| f.getattr("f_code"))
            .and_then(|c| c.getattr("co_filename"))
            .ok()?
            .extract()
            .ok()?;
        let name = PathBuf::from(&file)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or(file);
        Some(format!(" ({name}, line {line})"))
    });
    message + &place.unwrap_or_default()
}

impl Op for PyOp {
    fn spec(&self) -> &OpSpec {
        &self.spec
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let name = &self.spec.name;
        let fail = |why: String| OpError::invalid(format!("Python op `{name}`: {why}"));
        Python::attach(|py| {
            let py_inputs = PyDict::new(py);
            for (port, value) in &inputs.0 {
                let v = to_py(py, value).map_err(|e| fail(e.to_string()))?;
                py_inputs
                    .set_item(port, v)
                    .map_err(|e| fail(e.to_string()))?;
            }
            let py_params = PyDict::new(py);
            for (key, value) in &params.0 {
                let v = param_to_py(py, value).map_err(|e| fail(e.to_string()))?;
                py_params
                    .set_item(key, v)
                    .map_err(|e| fail(e.to_string()))?;
            }
            let answer = self
                .invoke
                .call1(py, (py_inputs, py_params))
                .map_err(|e| fail(last_line(py, &e)))?;
            let answer = answer
                .bind(py)
                .cast::<PyDict>()
                .map_err(|_| fail("the package's invoker returned no dict".into()))?
                .clone();
            let get = |key: &str| answer.get_item(key).ok().flatten().filter(|v| !v.is_none());
            if let Some(error) = get("error") {
                return Err(fail(error.to_string()));
            }
            if let Some(metrics) = get("metrics") {
                let metrics = metrics
                    .cast_into::<PyDict>()
                    .map_err(|_| fail("metrics must be a dict".into()))?;
                for (k, v) in metrics.iter() {
                    let (Ok(k), Ok(v)) = (k.extract::<String>(), v.extract::<f64>()) else {
                        return Err(fail(format!("metric {k}: must be a name and a number")));
                    };
                    ctx.metric(&k, v);
                }
            }
            if let Some(notes) = get("notes") {
                let notes = notes
                    .cast_into::<PyList>()
                    .map_err(|_| fail("notes must be a list".into()))?;
                for n in notes.iter() {
                    ctx.note(n.to_string());
                }
            }
            let outputs = get("outputs").ok_or_else(|| fail("no outputs".into()))?;
            let outputs = outputs
                .cast_into::<PyDict>()
                .map_err(|_| fail("outputs must be a dict".into()))?;
            let mut out = Outputs::new();
            for port in &self.spec.outputs {
                let value = outputs
                    .get_item(&port.name)
                    .ok()
                    .flatten()
                    .filter(|v| !v.is_none())
                    .ok_or_else(|| fail(format!("returned no output `{}`", port.name)))?;
                let value = from_py(&value, port.types[0])
                    .map_err(|why| fail(format!("output `{}`: {why}", port.name)))?;
                out = out.with(&port.name, value);
            }
            Ok(out)
        })
    }
}
