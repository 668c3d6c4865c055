//! What a node type is: its declaration ([`OpSpec`]) and its behaviour ([`Op`]),
//! with the inputs, outputs and context it runs with.

use crate::param::{ParamError, ParamSpec, Params};
use crate::value::{FromValue, PathValue, Value, ValueType};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One input or output port.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PortSpec {
    /// Port name, as written after the dot in `node.port`.
    pub name: String,
    /// Types accepted (inputs) or the one type produced (outputs).
    pub types: Vec<ValueType>,
    /// Whether an input may be left unconnected.
    pub optional: bool,
    /// One-line description, with units and frame.
    pub doc: String,
}

impl PortSpec {
    /// Whether a value of type `t` fits this port.
    pub fn accepts(&self, t: ValueType) -> bool {
        self.types.contains(&t)
    }

    /// The accepted types as text: `Volume` or `Volume | Mask`.
    pub fn type_names(&self) -> String {
        self.types
            .iter()
            .map(|t| t.name())
            .collect::<Vec<_>>()
            .join(" | ")
    }
}

/// The declaration of a node type: everything validation, `fusegraph nodes` and
/// the cache key need, without running it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OpSpec {
    /// Op name, `stage.action` (e.g. `mri.otsu`).
    pub name: String,
    /// Bumped whenever the op's outputs change for the same inputs; part of the
    /// cache key, so old cached results are not reused.
    pub version: u32,
    /// One-line description.
    pub doc: String,
    /// Input ports.
    pub inputs: Vec<PortSpec>,
    /// Output ports.
    pub outputs: Vec<PortSpec>,
    /// Parameters.
    pub params: Vec<ParamSpec>,
    /// Whether the op writes files under the run's output folder (an `io.*`
    /// sink). Its cache key then includes that folder, and its cached result is
    /// reused only while the files it wrote still hold the same content.
    pub writes_output: bool,
    /// The plugin library that declared the op (`None` for built-in ops). Its
    /// content hash is part of the op's cache key.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub origin: Option<Origin>,
    /// A fingerprint of the op's implementation (built-in ops: a hash of
    /// the source files it runs, made by `fusegraph-nodes`' build script).
    /// Part of the cache key, so editing an op re-runs its nodes; not part
    /// of the declaration (`fusegraph nodes`).
    #[serde(skip)]
    pub code: Option<String>,
}

/// Where a plugin's op comes from.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Origin {
    /// The library file (absolute).
    pub file: PathBuf,
    /// Hex blake3 hash of its content.
    pub content_hash: String,
}

impl OpSpec {
    /// A spec with no ports or parameters yet.
    pub fn new(name: &str, version: u32, doc: &str) -> Self {
        OpSpec {
            name: name.into(),
            version,
            doc: doc.into(),
            inputs: Vec::new(),
            outputs: Vec::new(),
            params: Vec::new(),
            writes_output: false,
            origin: None,
            code: None,
        }
    }

    /// Adds a required input accepting any of `types`.
    pub fn input(mut self, name: &str, types: &[ValueType], doc: &str) -> Self {
        self.inputs.push(PortSpec {
            name: name.into(),
            types: types.to_vec(),
            optional: false,
            doc: doc.into(),
        });
        self
    }

    /// Adds an input that may be left unconnected.
    pub fn optional_input(mut self, name: &str, types: &[ValueType], doc: &str) -> Self {
        self = self.input(name, types, doc);
        self.inputs.last_mut().expect("just pushed").optional = true;
        self
    }

    /// Adds an output.
    pub fn output(mut self, name: &str, ty: ValueType, doc: &str) -> Self {
        self.outputs.push(PortSpec {
            name: name.into(),
            types: vec![ty],
            optional: false,
            doc: doc.into(),
        });
        self
    }

    /// Adds a parameter.
    pub fn param(mut self, p: ParamSpec) -> Self {
        self.params.push(p);
        self
    }

    /// Marks the op as writing files under the run's output folder.
    pub fn writes_output(mut self) -> Self {
        self.writes_output = true;
        self
    }

    /// Checks the declaration: a `stage.action` name, unique non-empty port and
    /// parameter names (`op` and `in` are reserved), one type per output, and
    /// defaults that satisfy their own parameter's kind and range.
    pub fn check(&self) -> Result<(), String> {
        let valid_name =
            |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        match self.name.split_once('.') {
            Some((stage, action)) if valid_name(stage) && valid_name(action) => {}
            _ => return Err("op names are `stage.action` (letters, digits, '_')".into()),
        }
        for (what, names) in [
            (
                "input",
                self.inputs
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>(),
            ),
            (
                "output",
                self.outputs.iter().map(|p| p.name.as_str()).collect(),
            ),
            (
                "parameter",
                self.params.iter().map(|p| p.name.as_str()).collect(),
            ),
        ] {
            for (i, n) in names.iter().enumerate() {
                if !valid_name(n) || names[..i].contains(n) {
                    return Err(format!("{what} name `{n}` is empty, malformed or repeated"));
                }
            }
        }
        if let Some(p) = self
            .params
            .iter()
            .find(|p| p.name == "op" || p.name == "in")
        {
            return Err(format!("parameter name `{}` is reserved", p.name));
        }
        if let Some(p) = self.inputs.iter().find(|p| p.types.is_empty()) {
            return Err(format!("input `{}` accepts no type", p.name));
        }
        if let Some(p) = self.outputs.iter().find(|p| p.types.len() != 1) {
            return Err(format!("output `{}` must have exactly one type", p.name));
        }
        for p in &self.params {
            if let Some(d) = &p.default {
                let as_toml = toml::Value::try_from(d).map_err(|e| e.to_string())?;
                if d.kind() != p.kind {
                    return Err(format!(
                        "parameter `{}`: default is a {}, declared {}",
                        p.name,
                        d.kind(),
                        p.kind
                    ));
                }
                if p.kind != crate::param::ParamKind::Path {
                    p.parse(&as_toml, Path::new(""))
                        .map_err(|e| format!("parameter `{}`: default {e}", p.name))?;
                }
            }
        }
        Ok(())
    }

    /// The input port called `name`.
    pub fn input_port(&self, name: &str) -> Option<&PortSpec> {
        self.inputs.iter().find(|p| p.name == name)
    }

    /// The output port called `name`.
    pub fn output_port(&self, name: &str) -> Option<&PortSpec> {
        self.outputs.iter().find(|p| p.name == name)
    }

    /// The parameter called `name`.
    pub fn param_spec(&self, name: &str) -> Option<&ParamSpec> {
        self.params.iter().find(|p| p.name == name)
    }
}

/// Why an op failed. The message is shown to the user with the node id.
#[derive(Debug, thiserror::Error)]
pub enum OpError {
    /// Bad or unexpected input data (a corrupt file, too few points, ...).
    #[error("{0}")]
    Invalid(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A declared parameter could not be read (a bug in the op).
    #[error(transparent)]
    Param(#[from] ParamError),
    /// A declared input is missing or has another type (a bug in the op).
    #[error("input `{0}`: {1}")]
    Input(String, String),
}

impl OpError {
    /// An [`OpError::Invalid`] from any message.
    pub fn invalid(msg: impl Into<String>) -> Self {
        OpError::Invalid(msg.into())
    }

    /// An [`OpError::Io`] naming `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        OpError::Io {
            path: path.as_ref().to_path_buf(),
            source,
        }
    }
}

/// The values on a node's connected input ports.
#[derive(Debug, Clone, Default)]
pub struct Inputs(pub BTreeMap<String, Value>);

impl Inputs {
    /// The raw value on `port`, if connected.
    pub fn value(&self, port: &str) -> Option<&Value> {
        self.0.get(port)
    }

    /// The value on a required `port`, as type `T`.
    pub fn get<T: FromValue>(&self, port: &str) -> Result<Arc<T>, OpError> {
        self.optional(port)?
            .ok_or_else(|| OpError::Input(port.into(), "not connected".into()))
    }

    /// The value on an optional `port`, as type `T`, or `None` when unconnected.
    pub fn optional<T: FromValue>(&self, port: &str) -> Result<Option<Arc<T>>, OpError> {
        match self.0.get(port) {
            None => Ok(None),
            Some(v) => T::from_value(v).cloned().map(Some).ok_or_else(|| {
                OpError::Input(
                    port.into(),
                    format!("is a {}, expected {}", v.value_type(), T::TYPE),
                )
            }),
        }
    }
}

/// The values an op produced, by output port name.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Outputs(pub BTreeMap<String, Value>);

impl Outputs {
    /// No outputs yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds the value of output `port`.
    pub fn with(mut self, port: &str, value: impl Into<Value>) -> Self {
        self.0.insert(port.into(), value.into());
        self
    }

    /// Whether every `Path` output still holds the content it was recorded
    /// with (one that was edited or deleted makes a cached result stale).
    pub fn paths_intact(&self) -> Result<(), String> {
        paths_intact(&self.0, "output")
    }
}

/// Whether every `Path` among `values` (ports by name) still holds the
/// content it was recorded with; the error names the `what` ("input",
/// "output") port and the file.
pub fn paths_intact(values: &BTreeMap<String, Value>, what: &str) -> Result<(), String> {
    for (port, value) in values {
        if let Value::Path(p) = value {
            match crate::hash::hash_path(&p.path) {
                Ok(h) if h.to_hex().as_str() == p.content_hash => {}
                Ok(_) => {
                    return Err(format!(
                        "{what} `{port}`: {} was modified",
                        p.path.display()
                    ));
                }
                Err(e) => return Err(format!("{what} `{port}`: {e}")),
            }
        }
    }
    Ok(())
}

/// Makes (once) and returns the private folder an op writes its files into;
/// the engine's scheduler gives one (see [`RunCtx::work_dir`]).
pub type FilesFolder<'a> = Box<dyn FnMut() -> Result<PathBuf, OpError> + Send + 'a>;

/// What an op may use while it runs besides its inputs and parameters.
pub struct RunCtx<'a> {
    node_id: String,
    out_dir: PathBuf,
    metrics: BTreeMap<String, f64>,
    figures: Vec<crate::figure::Figure>,
    notes: Vec<String>,
    files: Option<FilesFolder<'a>>,
}

impl std::fmt::Debug for RunCtx<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunCtx")
            .field("node_id", &self.node_id)
            .field("out_dir", &self.out_dir)
            .field("metrics", &self.metrics)
            .field("notes", &self.notes)
            .field("files", &self.files.is_some())
            .finish_non_exhaustive()
    }
}

/// What a run of an op recorded besides its outputs.
#[derive(Debug, Default)]
pub struct RunResults {
    /// Metrics by name.
    pub metrics: BTreeMap<String, f64>,
    /// Figures for the report.
    pub figures: Vec<crate::figure::Figure>,
    /// Warnings for the user (inputs refused or skipped, and why).
    pub notes: Vec<String>,
}

impl<'a> RunCtx<'a> {
    /// A context for node `node_id` whose sinks write under `out_dir`.
    pub fn new(node_id: &str, out_dir: &Path) -> Self {
        RunCtx {
            node_id: node_id.into(),
            out_dir: out_dir.to_path_buf(),
            metrics: BTreeMap::new(),
            figures: Vec::new(),
            notes: Vec::new(),
            files: None,
        }
    }

    /// Lets the op write files into the folder that `make` creates (once);
    /// the scheduler moves it into the cache under the node's key when the
    /// op succeeds (see [`RunCtx::work_dir`]).
    pub fn with_files(
        mut self,
        make: impl FnMut() -> Result<PathBuf, OpError> + Send + 'a,
    ) -> Self {
        self.files = Some(Box::new(make));
        self
    }

    /// A folder for files the op produces as `Path` outputs (e.g. a generated
    /// DICOM series). It is private to this run of the node; when the op succeeds
    /// the engine moves it into the cache under the node's key and rewrites the
    /// `Path` outputs that point into it. Only ops run by the scheduler have one.
    pub fn work_dir(&mut self) -> Result<PathBuf, OpError> {
        let make = self
            .files
            .as_mut()
            .ok_or_else(|| OpError::invalid("this context has no folder for output files"))?;
        make()
    }

    /// The id of the node being run.
    pub fn node_id(&self) -> &str {
        &self.node_id
    }

    /// Records a named metric (put the unit in the name: `rmse_mm`).
    pub fn metric(&mut self, name: &str, value: f64) {
        self.metrics.insert(name.into(), value);
    }

    /// The metrics recorded so far.
    pub fn metrics(&self) -> &BTreeMap<String, f64> {
        &self.metrics
    }

    /// Takes the recorded metrics.
    pub fn into_metrics(self) -> BTreeMap<String, f64> {
        self.metrics
    }

    /// Attaches a figure to the run's report (a figure of the same name
    /// replaces the earlier one). `name` (letters, digits, `_`, `-`) names its
    /// file; `caption` says what it shows.
    pub fn figure(
        &mut self,
        name: &str,
        caption: &str,
        data: crate::figure::FigureData,
    ) -> Result<(), OpError> {
        crate::figure::check_figure_name(name).map_err(OpError::invalid)?;
        self.figures.retain(|f| f.name != name);
        self.figures.push(crate::figure::Figure {
            name: name.to_string(),
            caption: caption.to_string(),
            data,
        });
        Ok(())
    }

    /// The figures attached so far.
    pub fn figures(&self) -> &[crate::figure::Figure] {
        &self.figures
    }

    /// Records a warning for the user: an input that was refused, skipped or
    /// repaired, and why (`"left_07.png: refused: no complete 9 x 6 grid"`).
    /// Notes land in the node's `notes` in report.json, are kept in the cache
    /// with its outputs (a cached re-run shows them too) and are counted in
    /// the CLI's summary.
    pub fn note(&mut self, text: impl Into<String>) {
        let text = text.into();
        tracing::info!(node = %self.node_id, "note: {text}");
        self.notes.push(text);
    }

    /// The notes recorded so far.
    pub fn notes(&self) -> &[String] {
        &self.notes
    }

    /// Takes the recorded metrics, figures and notes.
    pub fn into_results(self) -> RunResults {
        RunResults {
            metrics: self.metrics,
            figures: self.figures,
            notes: self.notes,
        }
    }

    /// Where a sink writes `relative` under the run's output folder; creates the
    /// parent folders. Refuses absolute paths and `..`, so a graph cannot write
    /// outside the output folder.
    pub fn output_path(&self, relative: &str) -> Result<PathBuf, OpError> {
        if let Some(problem) = output_path_problem(relative) {
            return Err(OpError::invalid(problem));
        }
        let path = self.out_dir.join(relative);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| OpError::io(parent, e))?;
        }
        Ok(path)
    }
}

/// Why `relative` cannot name a file under the output folder (absolute, empty,
/// or climbing out with `..`), or `None` when it can. Validation checks sinks'
/// `file` parameters with it before anything runs; [`RunCtx::output_path`]
/// checks again.
pub fn output_path_problem(relative: &str) -> Option<String> {
    let rel = Path::new(relative);
    let escapes = rel.is_absolute()
        || rel.has_root()
        || rel.components().any(|c| {
            matches!(
                c,
                std::path::Component::ParentDir | std::path::Component::Prefix(_)
            )
        });
    (escapes || relative.trim().is_empty()).then(|| {
        format!("output file {relative:?} must be a relative path inside the output folder")
    })
}

/// A node type: its declaration and how it runs.
///
/// `run` must be a function of its inputs and parameters only (it is cached by
/// them), must not write outside [`RunCtx::output_path`], and reports bad data as
/// an [`OpError`] rather than panicking (a panic is caught and reported, but an
/// error message is clearer).
pub trait Op: Send + Sync {
    /// The declaration.
    fn spec(&self) -> &OpSpec;
    /// Computes the outputs.
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError>;
    /// Checks what the declaration cannot say about parameters that each
    /// pass it (a pattern no board can have, a source given twice or not at
    /// all), at validation, before anything runs; `params` hold every
    /// declared parameter and `wired` names the input ports the graph
    /// connects. Every problem found is returned, keyed by the parameter or
    /// by `in.<port>`.
    fn check(&self, params: &Params, wired: Wired) -> Vec<crate::param::ParamError> {
        let _ = (params, wired);
        Vec::new()
    }
}

/// The input ports a node's graph entry connects, as [`Op::check`] sees them.
#[derive(Debug, Clone, Copy)]
pub struct Wired<'a> {
    ports: &'a [&'a str],
}

impl<'a> Wired<'a> {
    /// The connected ports, by name.
    pub fn new(ports: &'a [&'a str]) -> Self {
        Wired { ports }
    }

    /// Whether the graph connects input `port`.
    pub fn has(&self, port: &str) -> bool {
        self.ports.contains(&port)
    }
}

/// The problem, if any, when not exactly one of a node's alternative sources
/// is given: `sources` pairs each graph key (`dir`, `in.dir`) with whether it
/// is given. The problem is keyed by the second source given, or by the
/// first source when none is.
pub fn exactly_one_source(sources: &[(&'static str, bool)]) -> Option<(&'static str, String)> {
    let names = || {
        sources
            .iter()
            .map(|(k, _)| format!("`{k}`"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let given: Vec<&str> = sources.iter().filter(|s| s.1).map(|s| s.0).collect();
    match given.as_slice() {
        [_] => None,
        [] => Some((sources[0].0, format!("give one of {}", names()))),
        [first, second, ..] => Some((
            second,
            format!(
                "`{first}` and `{second}` are both given: give one of {}",
                names()
            ),
        )),
    }
}

/// A `Path` value for `path`, hashed by content (for ops that write files;
/// a typed op's `Path` output is a `PathValue` field).
pub fn path_value(path: &std::path::Path) -> Result<PathValue, OpError> {
    let hash = crate::hash::hash_path(path).map_err(|e| OpError::io(path, e))?;
    let abs = std::path::absolute(path).map_err(|e| OpError::io(path, e))?;
    Ok(PathValue {
        path: abs,
        content_hash: hash.to_hex().to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exactly_one_source_names_what_is_missing_or_doubled() {
        assert_eq!(
            exactly_one_source(&[("path", true), ("in.dir", false)]),
            None
        );
        assert_eq!(
            exactly_one_source(&[("path", false), ("in.dir", true)]),
            None
        );
        let (key, none) = exactly_one_source(&[("path", false), ("in.dir", false)]).unwrap();
        assert_eq!(
            (key, none.as_str()),
            ("path", "give one of `path`, `in.dir`")
        );
        let (key, both) =
            exactly_one_source(&[("dir", true), ("in.dir", false), ("in.image", true)]).unwrap();
        assert_eq!(key, "in.image");
        assert_eq!(
            both,
            "`dir` and `in.image` are both given: give one of `dir`, `in.dir`, `in.image`"
        );
        let wired = Wired::new(&["left", "dir"]);
        assert!(wired.has("dir") && !wired.has("image"));
    }
}
