//! Node types from dynamic libraries: the host side of the plugin C ABI
//! (`fusegraph-plugin-api`), loaded with libloading.
//!
//! Loading a plugin checks, in order, and names the file in every refusal:
//! that it is a regular file; that it loads as a library; that it exports
//! the ABI-version symbol and speaks this ABI version; that its table and
//! declaration are well formed; and that every op it declares is a valid,
//! new op name. Its ops then validate, cache and run as built-in ones do; the
//! cache key of each holds the library's content hash, so rebuilding a plugin
//! invalidates its results and nothing else.
//!
//! Running a plugin op lends it the input buffers (no copies), and checks
//! every output (declared port, type, dtype, shape against length) before
//! copying it into an engine value. A panic inside the op is caught on the
//! plugin's side and comes back as an error; the host never unwinds across
//! the boundary.

use crate::op::{Inputs, Op, OpError, OpSpec, Origin, Outputs, PortSpec, RunCtx};
use crate::param::{ListLength, ParamKind, ParamSpec, ParamValue, Params};
use crate::registry::Registry;
use crate::value::{Disparity, Grid, Image, Labels, Mask, Pixels, Table, Value, ValueType, Volume};
use fusegraph_plugin_api::abi::{
    self, FgArray, FgInput, FgParam, FgPlugin, FgResult, FgStr, dtype, param_kind, value_type,
};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A loaded library and its table; kept alive by every op it declared.
struct Loaded {
    file: PathBuf,
    table: *const FgPlugin,
    // Dropped last: the table and its functions live inside the library.
    _library: libloading::Library,
}

// SAFETY: the table is immutable static data of the library, and the ABI
// requires `run` and `free` to be callable from any thread.
unsafe impl Send for Loaded {}
// SAFETY: as above.
unsafe impl Sync for Loaded {}

impl Loaded {
    fn table(&self) -> &FgPlugin {
        // SAFETY: checked non-null at load; valid while the library is loaded.
        unsafe { &*self.table }
    }
}

/// An error and its sources: libloading says only "dlopen failed" and keeps
/// the loader's reason (a missing dependency, a wrong architecture, an
/// undefined symbol) as the source.
fn with_sources(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text = format!("{text}: {s}");
        source = s.source();
    }
    text
}

/// Refuses a symbol that is not code (a variable exported under a plugin
/// symbol's name): calling it would crash the process with no message. On
/// Linux the address is looked up in `/proc/self/maps`; elsewhere, and if
/// the maps cannot be read, the symbol is trusted.
fn check_code(address: usize, symbol: &str, shown: &impl std::fmt::Display) -> Result<(), String> {
    match executable(address) {
        Some(false) => Err(format!(
            "plugin {shown}: its `{symbol}` symbol is data, not a function: not a fusegraph plugin \
             (or one built wrongly); it was not called"
        )),
        _ => Ok(()),
    }
}

/// Whether `address` lies in an executable mapping of this process, if the
/// system says.
fn executable(address: usize) -> Option<bool> {
    let maps = std::fs::read_to_string("/proc/self/maps").ok()?;
    for line in maps.lines() {
        let mut parts = line.split_whitespace();
        let (range, perms) = (parts.next()?, parts.next()?);
        let (lo, hi) = range.split_once('-')?;
        let (lo, hi) = (
            usize::from_str_radix(lo, 16).ok()?,
            usize::from_str_radix(hi, 16).ok()?,
        );
        if (lo..hi).contains(&address) {
            return Some(perms.as_bytes().get(2) == Some(&b'x'));
        }
    }
    Some(false)
}

/// Loads the plugin at `path` and registers its ops; returns their names.
/// Errors name the file (and the op, where one is at fault).
pub fn load_plugin(path: &Path, registry: &mut Registry) -> Result<Vec<String>, String> {
    let shown = path.display();
    let file = std::fs::canonicalize(path).map_err(|e| format!("plugin {shown}: {e}"))?;
    if let Some(ops) = registry.plugin_ops(&file) {
        return Ok(ops.to_vec()); // named twice (flag, graph, environment)
    }
    let meta = std::fs::metadata(&file).map_err(|e| format!("plugin {shown}: {e}"))?;
    crate::hash::check_readable_kind(&file, &meta).map_err(|e| format!("plugin {shown}: {e}"))?;
    if !meta.is_file() {
        return Err(format!("plugin {shown}: a folder, not a library file"));
    }
    let content_hash = crate::hash::hash_path(&file)
        .map_err(|e| format!("plugin {shown}: {e}"))?
        .to_hex()
        .to_string();
    // SAFETY: loading a library runs its initialisers; that is what loading a
    // plugin means, and the user named this file.
    tracing::info!(plugin = %shown, "loading");
    let library = unsafe { libloading::Library::new(&file) }.map_err(|e| {
        format!(
            "plugin {shown}: not a loadable library: {}",
            with_sources(&e)
        )
    })?;
    let version = {
        // SAFETY: the symbol's type is fixed by every version of the ABI.
        let f = unsafe { library.get::<extern "C" fn() -> u32>(abi::ABI_VERSION_SYMBOL.as_bytes()) }
            .map_err(|e| {
                format!(
                    "plugin {shown}: not a fusegraph plugin: it has no `{}` symbol (export it with fusegraph_plugin_api::export_plugin!): {}",
                    abi::ABI_VERSION_SYMBOL,
                    with_sources(&e)
                )
            })?;
        check_code(*f as usize, abi::ABI_VERSION_SYMBOL, &shown)?;
        f()
    };
    if version != abi::ABI_VERSION {
        return Err(format!(
            "plugin {shown}: built for plugin ABI version {version}, but this fusegraph speaks version {}: rebuild it against this fusegraph's fusegraph-plugin-api",
            abi::ABI_VERSION
        ));
    }
    let table = {
        // SAFETY: ABI version 1 fixes this symbol's type.
        let f = unsafe {
            library.get::<extern "C" fn() -> *const FgPlugin>(abi::PLUGIN_SYMBOL.as_bytes())
        }
        .map_err(|e| {
            format!(
                "plugin {shown}: it has no `{}` symbol: {}",
                abi::PLUGIN_SYMBOL,
                with_sources(&e)
            )
        })?;
        check_code(*f as usize, abi::PLUGIN_SYMBOL, &shown)?;
        f()
    };
    if table.is_null() {
        return Err(format!(
            "plugin {shown}: its ops could not be declared (the plugin failed while declaring them)"
        ));
    }
    let loaded = Arc::new(Loaded {
        file: file.clone(),
        table,
        _library: library,
    });
    if loaded.table().abi_version != abi::ABI_VERSION {
        return Err(format!(
            "plugin {shown}: its table says ABI version {}, its symbol {}",
            loaded.table().abi_version,
            abi::ABI_VERSION
        ));
    }
    // SAFETY: the declaration lives in the library's static data.
    let text = unsafe { loaded.table().declaration.as_str() }
        .ok_or_else(|| format!("plugin {shown}: its declaration is not UTF-8"))?;
    let declaration: Declaration =
        toml::from_str(text).map_err(|e| format!("plugin {shown}: its declaration: {e}"))?;
    let origin = Origin { file, content_hash };
    let mut ops = Vec::new();
    for (index, decl) in declaration.op.iter().enumerate() {
        let spec = decl
            .to_spec(&origin, abi_type)
            .map_err(|e| format!("plugin {shown}: op `{}`: {e}", decl.name))?;
        ops.push(PluginOp {
            spec,
            index,
            loaded: loaded.clone(),
        });
    }
    let mut names = Vec::new();
    for op in ops {
        let name = op.spec.name.clone();
        registry
            .register(Arc::new(op))
            .map_err(|e| format!("plugin {shown}: {e}"))?;
        names.push(name);
    }
    registry.add_plugin(origin.file, names.clone());
    Ok(names)
}

/// Loads every plugin that `FUSEGRAPH_PLUGIN_PATH` names: entries separated
/// as in `PATH`, each a library file or a folder whose libraries (files
/// ending in this system's library suffix, `.so` on Linux) are loaded in name
/// order.
pub fn load_plugin_path(value: &std::ffi::OsStr, registry: &mut Registry) -> Result<(), String> {
    for entry in std::env::split_paths(value) {
        if entry.as_os_str().is_empty() {
            continue;
        }
        if entry.is_dir() {
            let mut libs: Vec<PathBuf> = std::fs::read_dir(&entry)
                .map_err(|e| format!("FUSEGRAPH_PLUGIN_PATH: {}: {e}", entry.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.to_string_lossy().ends_with(std::env::consts::DLL_SUFFIX))
                .collect();
            libs.sort();
            for lib in libs {
                load_plugin(&lib, registry).map_err(|e| format!("FUSEGRAPH_PLUGIN_PATH: {e}"))?;
            }
        } else {
            load_plugin(&entry, registry).map_err(|e| format!("FUSEGRAPH_PLUGIN_PATH: {e}"))?;
        }
    }
    Ok(())
}

/// The declaration's TOML (see `fusegraph_plugin_api::declare`).
#[derive(Debug, Deserialize)]
struct Declaration {
    #[serde(default)]
    op: Vec<OpDecl>,
}

#[derive(Debug, Deserialize)]
struct OpDecl {
    name: String,
    version: u32,
    #[serde(default)]
    doc: String,
    #[serde(default)]
    inputs: Vec<InputDecl>,
    #[serde(default)]
    outputs: Vec<OutputDecl>,
    #[serde(default)]
    params: Vec<ParamDecl>,
}

#[derive(Debug, Deserialize)]
struct InputDecl {
    name: String,
    types: Vec<String>,
    #[serde(default)]
    optional: bool,
    #[serde(default)]
    doc: String,
}

#[derive(Debug, Deserialize)]
struct OutputDecl {
    name: String,
    #[serde(rename = "type")]
    ty: String,
    #[serde(default)]
    doc: String,
}

#[derive(Debug, Deserialize)]
struct ParamDecl {
    name: String,
    kind: String,
    default: Option<toml::Value>,
    #[serde(default)]
    unit: String,
    #[serde(default)]
    doc: String,
    min: Option<f64>,
    max: Option<f64>,
    #[serde(default)]
    choices: Vec<String>,
    #[serde(default)]
    lengths: Vec<usize>,
    length_multiple_of: Option<usize>,
}

/// An engine value type that the ABI carries.
fn abi_type(name: &str) -> Result<ValueType, String> {
    let ty = ValueType::from_name(name).ok_or_else(|| format!("unknown value type `{name}`"))?;
    value_type::code(name)
        .map(|_| ty)
        .ok_or_else(|| format!("value type `{name}` does not cross the plugin ABI (yet)"))
}

/// The spec of one op declared in JSON, in the form of a plugin's
/// declaration (`name`, `version`, `doc`, `inputs`, `outputs`, `params`;
/// see `fusegraph_plugin_api::declare`), by a script from `origin`: every
/// value type is allowed, since a script's values do not cross the C ABI.
pub fn script_op_spec(json: &str, origin: &Origin) -> Result<OpSpec, String> {
    let decl: OpDecl =
        serde_json::from_str(json).map_err(|e| format!("the op's declaration: {e}"))?;
    let any_type = |name: &str| {
        ValueType::from_name(name).ok_or_else(|| {
            let all: Vec<&str> = ValueType::ALL.iter().map(|t| t.name()).collect();
            format!("unknown value type `{name}` (one of {})", all.join(", "))
        })
    };
    decl.to_spec(origin, any_type)
        .map_err(|e| format!("op `{}`: {e}", decl.name))
}

impl OpDecl {
    fn to_spec(
        &self,
        origin: &Origin,
        port_type: impl Fn(&str) -> Result<ValueType, String>,
    ) -> Result<OpSpec, String> {
        let mut spec = OpSpec::new(&self.name, self.version, &self.doc);
        for p in &self.inputs {
            let types = p
                .types
                .iter()
                .map(|t| port_type(t))
                .collect::<Result<Vec<_>, _>>()?;
            spec.inputs.push(PortSpec {
                name: p.name.clone(),
                types,
                optional: p.optional,
                doc: p.doc.clone(),
            });
        }
        for p in &self.outputs {
            spec.outputs.push(PortSpec {
                name: p.name.clone(),
                types: vec![port_type(&p.ty)?],
                optional: false,
                doc: p.doc.clone(),
            });
        }
        for p in &self.params {
            let kind = match p.kind.as_str() {
                "int" => ParamKind::Int,
                "float" => ParamKind::Float,
                "bool" => ParamKind::Bool,
                "string" => ParamKind::String,
                "int_list" => ParamKind::IntList,
                "float_list" => ParamKind::FloatList,
                "string_list" => ParamKind::StringList,
                other => return Err(format!("parameter `{}`: unknown kind `{other}`", p.name)),
            };
            let mut param = ParamSpec {
                name: p.name.clone(),
                kind,
                default: None,
                unit: p.unit.clone(),
                min: p.min,
                max: p.max,
                choices: p.choices.clone(),
                length: if p.lengths.is_empty() {
                    p.length_multiple_of.map(ListLength::MultipleOf)
                } else {
                    Some(ListLength::OneOf(p.lengths.clone()))
                },
                doc: p.doc.clone(),
            };
            if let Some(d) = &p.default {
                param.default = Some(
                    param
                        .parse(d, Path::new(""))
                        .map_err(|e| format!("parameter `{}`: default {e}", p.name))?,
                );
            }
            spec.params.push(param);
        }
        spec.origin = Some(origin.clone());
        spec.check()?;
        Ok(spec)
    }
}

/// One op of a loaded plugin.
struct PluginOp {
    spec: OpSpec,
    index: usize,
    loaded: Arc<Loaded>,
}

impl PluginOp {
    fn fail(&self, why: impl std::fmt::Display) -> OpError {
        OpError::invalid(format!(
            "plugin {}: op `{}`: {why}",
            self.loaded.file.display(),
            self.spec.name
        ))
    }
}

/// Row-major 4 x 4 of a grid.
fn affine_of(grid: &Grid) -> [f64; 16] {
    std::array::from_fn(|i| grid.voxel_to_patient[i / 4][i % 4])
}

fn array<T>(ty: u32, dt: u32, shape: &[usize], data: &[T]) -> FgArray {
    let mut s = [0u64; 4];
    for (i, &d) in shape.iter().enumerate() {
        s[i] = d as u64;
    }
    FgArray {
        value_type: ty,
        dtype: dt,
        ndim: shape.len() as u32,
        shape: s,
        data: data.as_ptr() as *const u8,
        byte_len: std::mem::size_of_val(data),
        affine: [0.0; 16],
        labels: FgStr::new(""),
    }
}

/// A borrowed view of `value` (`labels` keeps table column names alive).
fn borrow(value: &Value, labels: &mut Vec<String>) -> Result<FgArray, String> {
    Ok(match value {
        Value::Image(im) => {
            let shape = [im.height, im.width, im.channels];
            match &im.pixels {
                Pixels::U8(p) => array(value_type::IMAGE, dtype::U8, &shape, p),
                Pixels::F32(p) => array(value_type::IMAGE, dtype::F32, &shape, p),
            }
        }
        Value::Disparity(d) => array(
            value_type::DISPARITY,
            dtype::F32,
            &[d.height, d.width],
            &d.data,
        ),
        Value::Scalar(v) => array(
            value_type::SCALAR,
            dtype::F64,
            &[],
            std::slice::from_ref(&**v),
        ),
        Value::Table(t) => {
            labels.push(t.columns.join("\n"));
            let mut a = array(
                value_type::TABLE,
                dtype::F64,
                &[t.row_count(), t.columns.len()],
                &t.data,
            );
            a.labels = FgStr::new(labels.last().expect("just pushed"));
            a
        }
        Value::Volume(v) => grid_array(value_type::VOLUME, dtype::F32, &v.grid, &v.data),
        Value::Mask(v) => grid_array(value_type::MASK, dtype::U8, &v.grid, &v.data),
        Value::Labels(v) => grid_array(value_type::LABELS, dtype::U32, &v.grid, &v.data),
        other => {
            return Err(format!(
                "a {} does not cross the plugin ABI",
                other.value_type()
            ));
        }
    })
}

fn grid_array<T>(ty: u32, dt: u32, grid: &Grid, data: &[T]) -> FgArray {
    let [nx, ny, nz] = grid.dims;
    let mut a = array(ty, dt, &[nz, ny, nx], data);
    a.affine = affine_of(grid);
    a
}

/// A copy of the plugin's elements, checked against dtype, shape and length.
fn elements<T: Copy + Default>(a: &FgArray, want: u32) -> Result<Vec<T>, String> {
    if a.dtype != want {
        return Err(format!("dtype code {} where {want} is required", a.dtype));
    }
    if a.ndim > 4 {
        return Err(format!("{} dimensions", a.ndim));
    }
    let count = a.shape[..a.ndim as usize]
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(usize::try_from(d).ok()?))
        .ok_or("shape overflows")?;
    let size = std::mem::size_of::<T>();
    if count.checked_mul(size) != Some(a.byte_len) {
        return Err(format!(
            "{} bytes of data for shape {:?} ({count} elements of {size} bytes)",
            a.byte_len,
            &a.shape[..a.ndim as usize]
        ));
    }
    let mut out = vec![T::default(); count];
    if count > 0 {
        if a.data.is_null() {
            return Err("null data".into());
        }
        // SAFETY: the plugin promises `byte_len` readable bytes at `data`
        // until `free`; `out` holds exactly that many bytes. Copied bytewise,
        // so the plugin's alignment does not matter.
        unsafe {
            std::ptr::copy_nonoverlapping(a.data, out.as_mut_ptr() as *mut u8, a.byte_len);
        }
    }
    Ok(out)
}

fn dims_of(a: &FgArray, ndim: u32) -> Result<Vec<usize>, String> {
    if a.ndim != ndim {
        return Err(format!("{} dimensions where {ndim} are required", a.ndim));
    }
    a.shape[..ndim as usize]
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| "shape too large".to_string()))
        .collect()
}

fn grid_of(a: &FgArray) -> Result<Grid, String> {
    let d = dims_of(a, 3)?;
    if a.affine.iter().any(|v| !v.is_finite()) {
        return Err("a non-finite voxel -> patient matrix".into());
    }
    Ok(Grid {
        dims: [d[2], d[1], d[0]],
        voxel_to_patient: std::array::from_fn(|r| std::array::from_fn(|c| a.affine[4 * r + c])),
    })
}

/// The engine value of a plugin's output of declared type `ty`.
fn take(a: &FgArray, ty: ValueType) -> Result<Value, String> {
    let code = value_type::code(ty.name()).ok_or("a type outside the ABI")?;
    if a.value_type != code {
        return Err(format!(
            "a {} where the declaration says {}",
            value_type::name(a.value_type).unwrap_or("value of an unknown type code"),
            ty
        ));
    }
    let value: Value = match ty {
        ValueType::Image => {
            let d = dims_of(a, 3)?;
            let pixels = match a.dtype {
                dtype::U8 => Pixels::U8(elements::<u8>(a, dtype::U8)?.into()),
                _ => Pixels::F32(elements::<f32>(a, dtype::F32)?.into()),
            };
            Image::new(d[1], d[0], d[2], pixels)
                .map_err(|e| e.0)?
                .into()
        }
        ValueType::Disparity => {
            let d = dims_of(a, 2)?;
            Disparity::new(d[1], d[0], elements::<f32>(a, dtype::F32)?)
                .map_err(|e| e.0)?
                .into()
        }
        ValueType::Scalar => {
            let v = elements::<f64>(a, dtype::F64)?;
            match v[..] {
                [x] => Value::Scalar(Arc::new(x)),
                _ => return Err(format!("a scalar of {} numbers", v.len())),
            }
        }
        ValueType::Table => {
            let d = dims_of(a, 2)?;
            // SAFETY: the plugin's labels, valid until `free`.
            let labels = unsafe { a.labels.as_str() }.ok_or("column names not UTF-8")?;
            let columns: Vec<String> = if labels.is_empty() {
                Vec::new()
            } else {
                labels.split('\n').map(String::from).collect()
            };
            if columns.len() != d[1] {
                return Err(format!(
                    "{} column names for {} columns",
                    columns.len(),
                    d[1]
                ));
            }
            Table::new(columns, elements::<f64>(a, dtype::F64)?)
                .map_err(|e| e.0)?
                .into()
        }
        ValueType::Volume => Volume::new(grid_of(a)?, elements::<f32>(a, dtype::F32)?)
            .map_err(|e| e.0)?
            .into(),
        ValueType::Mask => Mask::new(grid_of(a)?, elements::<u8>(a, dtype::U8)?)
            .map_err(|e| e.0)?
            .into(),
        ValueType::Labels => Labels::new(grid_of(a)?, elements::<u32>(a, dtype::U32)?)
            .map_err(|e| e.0)?
            .into(),
        other => return Err(format!("a {other} does not cross the plugin ABI")),
    };
    Ok(value)
}

/// The ABI form of one parameter; list values borrow from `value`.
fn param_of<'a>(name: &'a str, value: &'a ParamValue) -> Result<FgParam, String> {
    let mut p = FgParam {
        name: FgStr::new(name),
        kind: 0,
        int: 0,
        float: 0.0,
        text: FgStr::new(""),
        ints: std::ptr::null(),
        floats: std::ptr::null(),
        len: 0,
    };
    match value {
        ParamValue::Int(v) => (p.kind, p.int) = (param_kind::INT, *v),
        ParamValue::Float(v) => (p.kind, p.float) = (param_kind::FLOAT, *v),
        ParamValue::Bool(v) => (p.kind, p.int) = (param_kind::BOOL, *v as i64),
        ParamValue::String(s) => (p.kind, p.text) = (param_kind::STRING, FgStr::new(s)),
        ParamValue::IntList(v) => {
            (p.kind, p.ints, p.len) = (param_kind::INT_LIST, v.as_ptr(), v.len())
        }
        ParamValue::FloatList(v) => {
            (p.kind, p.floats, p.len) = (param_kind::FLOAT_LIST, v.as_ptr(), v.len())
        }
        other => {
            return Err(format!(
                "parameter `{name}`: a {} does not cross the plugin ABI",
                other.kind()
            ));
        }
    }
    Ok(p)
}

/// `n` elements at `ptr` (empty when `n` is 0).
///
/// # Safety
/// A non-zero `n` needs `n` valid elements at a non-null `ptr` for `'a`.
unsafe fn view<'a, T>(ptr: *const T, n: usize) -> &'a [T] {
    if n == 0 {
        &[]
    } else {
        // SAFETY: as the caller guarantees.
        unsafe { std::slice::from_raw_parts(ptr, n) }
    }
}

/// Frees a result when dropped, whatever happens while it is read.
struct ResultGuard<'a> {
    result: FgResult,
    table: &'a FgPlugin,
}

impl Drop for ResultGuard<'_> {
    fn drop(&mut self) {
        // SAFETY: `run` filled this result; it is freed exactly once.
        unsafe { (self.table.free)(&mut self.result) };
    }
}

impl Op for PluginOp {
    fn spec(&self) -> &OpSpec {
        &self.spec
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let mut labels = Vec::new();
        let mut raw_inputs = Vec::with_capacity(inputs.0.len());
        for (port, value) in &inputs.0 {
            let value = borrow(value, &mut labels)
                .map_err(|e| self.fail(format!("input `{port}`: {e}")))?;
            raw_inputs.push(FgInput {
                port: FgStr::new(port),
                value,
            });
        }
        let raw_params = params
            .0
            .iter()
            .map(|(name, value)| param_of(name, value))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| self.fail(e))?;
        let table = self.loaded.table();
        let mut guard = ResultGuard {
            result: FgResult::empty(),
            table,
        };
        // SAFETY: the inputs and parameters point into values that outlive
        // the call; the result is the plugin's to fill.
        unsafe {
            (table.run)(
                self.index,
                raw_inputs.as_ptr(),
                raw_inputs.len(),
                raw_params.as_ptr(),
                raw_params.len(),
                &mut guard.result,
            )
        };
        let r = &guard.result;
        // SAFETY: the plugin's text, valid until `free`.
        let message = unsafe { r.message.as_str() }.unwrap_or("(a message that is not UTF-8)");
        match r.status {
            abi::STATUS_OK => {}
            abi::STATUS_ERROR => return Err(self.fail(message)),
            abi::STATUS_PANIC => return Err(self.fail(format!("panicked: {message}"))),
            other => return Err(self.fail(format!("returned an unknown status {other}"))),
        }
        let slice = |ptr: *const u8, n: usize, size: usize| -> Result<(), OpError> {
            if n > 0 && ptr.is_null() {
                return Err(self.fail("returned a null list"));
            }
            if n.checked_mul(size).is_none_or(|b| b > isize::MAX as usize) {
                return Err(self.fail("returned an absurd list length"));
            }
            Ok(())
        };
        slice(
            r.outputs as *const u8,
            r.n_outputs,
            std::mem::size_of::<abi::FgOutput>(),
        )?;
        slice(
            r.metrics as *const u8,
            r.n_metrics,
            std::mem::size_of::<abi::FgMetric>(),
        )?;
        slice(
            r.notes as *const u8,
            r.n_notes,
            std::mem::size_of::<FgStr>(),
        )?;
        let mut outputs = Outputs::new();
        // SAFETY: checked non-null; the plugin's lists, valid until `free`.
        for o in unsafe { view(r.outputs, r.n_outputs) } {
            // SAFETY: the plugin's text, valid until `free`.
            let port = unsafe { o.port.as_str() }
                .ok_or_else(|| self.fail("an output name that is not UTF-8"))?;
            let declared = self
                .spec
                .output_port(port)
                .ok_or_else(|| self.fail(format!("produced an undeclared output `{port}`")))?;
            let value = take(&o.value, declared.types[0])
                .map_err(|e| self.fail(format!("output `{port}`: {e}")))?;
            outputs.0.insert(port.to_string(), value);
        }
        if let Some(missing) = self
            .spec
            .outputs
            .iter()
            .find(|p| !outputs.0.contains_key(&p.name))
        {
            return Err(self.fail(format!("did not produce output `{}`", missing.name)));
        }
        // SAFETY: as above.
        for m in unsafe { view(r.metrics, r.n_metrics) } {
            // SAFETY: as above.
            let name = unsafe { m.name.as_str() }
                .ok_or_else(|| self.fail("a metric name that is not UTF-8"))?;
            ctx.metric(name, m.value);
        }
        // SAFETY: as above.
        for n in unsafe { view(r.notes, r.n_notes) } {
            // SAFETY: as above.
            ctx.note(unsafe { n.as_str() }.unwrap_or("(a note that is not UTF-8)"));
        }
        Ok(outputs)
    }
}
