//! The C ABI, version [`ABI_VERSION`]: `#[repr(C)]` structs and `extern "C"`
//! functions only, so a plugin may be built by another compiler version (or
//! in C). What crosses the boundary:
//!
//! - The plugin exports two symbols: [`ABI_VERSION_SYMBOL`], a function
//!   returning the ABI version it was built for, and [`PLUGIN_SYMBOL`], a
//!   function returning a pointer to its [`FgPlugin`] table. The host calls the
//!   first before anything else and refuses another version.
//! - The table holds the declaration of the plugin's ops as UTF-8 TOML text
//!   (see [`crate::declare`] for its keys), a `run` function and a `free`
//!   function for what `run` allocated.
//! - `run` gets the op's index in the declaration, its inputs as borrowed
//!   arrays ([`FgArray`]: the host's buffers, not copies) and its parameters
//!   ([`FgParam`], defaults filled in by the host), and fills an [`FgResult`]
//!   that the plugin owns until the host passes it to `free`.
//!
//! Versioning: any change to these structs, the symbols or the meaning of a
//! field bumps [`ABI_VERSION`]. New optional keys in the TOML declaration and
//! new value-type or dtype codes do not: a host ignores keys it does not know,
//! and refuses (naming the op) a code it does not know.

use std::ffi::c_void;

/// The ABI version this crate speaks.
pub const ABI_VERSION: u32 = 1;

/// `extern "C" fn() -> u32`: the ABI version the plugin was built for.
pub const ABI_VERSION_SYMBOL: &str = "fusegraph_plugin_abi_version";

/// `extern "C" fn() -> *const FgPlugin`: the plugin's table (static, never
/// freed).
pub const PLUGIN_SYMBOL: &str = "fusegraph_plugin";

/// Borrowed UTF-8 text: `len` bytes at `ptr` (`ptr` may dangle when `len` is 0).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct FgStr {
    /// First byte.
    pub ptr: *const u8,
    /// Length in bytes.
    pub len: usize,
}

impl FgStr {
    /// A view of `s` (it must outlive every use of the view).
    pub fn new(s: &str) -> FgStr {
        FgStr {
            ptr: s.as_ptr(),
            len: s.len(),
        }
    }

    /// The text, or `None` when it is not UTF-8.
    ///
    /// # Safety
    /// `ptr` must point to `len` readable bytes that outlive `'a`.
    pub unsafe fn as_str<'a>(self) -> Option<&'a str> {
        if self.len == 0 {
            return Some("");
        }
        if self.ptr.is_null() {
            return None;
        }
        // SAFETY: the caller guarantees `len` readable bytes at `ptr`.
        std::str::from_utf8(unsafe { std::slice::from_raw_parts(self.ptr, self.len) }).ok()
    }
}

/// Value types that cross the boundary, as `FgArray::value_type`. The names
/// are the engine's (`fusegraph nodes` shows them on every port).
pub mod value_type {
    /// An image: `shape = [height, width, channels]`, u8 or f32, channels 1 or 3.
    pub const IMAGE: u32 = 1;
    /// A disparity map, px (NaN = no match): `shape = [height, width]`, f32.
    pub const DISPARITY: u32 = 2;
    /// One number: `shape = []`, f64, one element.
    pub const SCALAR: u32 = 3;
    /// Rows of named numbers: `shape = [rows, columns]`, f64; `labels` holds
    /// the column names, one per line.
    pub const TABLE: u32 = 4;
    /// Voxels: `shape = [nz, ny, nx]` (x fastest), f32; `affine` is the
    /// voxel -> patient (LPS, mm) matrix.
    pub const VOLUME: u32 = 5;
    /// A mask (0/1): as a volume, u8.
    pub const MASK: u32 = 6;
    /// Component labels: as a volume, u32.
    pub const LABELS: u32 = 7;

    /// The engine's name of a code, `None` for a code this ABI does not have.
    pub fn name(code: u32) -> Option<&'static str> {
        Some(match code {
            IMAGE => "Image",
            DISPARITY => "Disparity",
            SCALAR => "Scalar",
            TABLE => "Table",
            VOLUME => "Volume",
            MASK => "Mask",
            LABELS => "Labels",
            _ => return None,
        })
    }

    /// The code of an engine type name.
    pub fn code(name: &str) -> Option<u32> {
        (1..=7).find(|&c| self::name(c) == Some(name))
    }
}

/// Element types of an [`FgArray`], as `FgArray::dtype`.
pub mod dtype {
    /// 8-bit unsigned.
    pub const U8: u32 = 1;
    /// 32-bit unsigned.
    pub const U32: u32 = 2;
    /// 32-bit float.
    pub const F32: u32 = 3;
    /// 64-bit float.
    pub const F64: u32 = 4;

    /// Bytes per element, `None` for an unknown code.
    pub fn size(code: u32) -> Option<usize> {
        match code {
            U8 => Some(1),
            U32 | F32 => Some(4),
            F64 => Some(8),
            _ => None,
        }
    }
}

/// A value as a typed n-dimensional array.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct FgArray {
    /// A [`value_type`] code.
    pub value_type: u32,
    /// A [`dtype`] code.
    pub dtype: u32,
    /// Number of dimensions used in `shape` (0 to 4).
    pub ndim: u32,
    /// Extent of each dimension, outermost first.
    pub shape: [u64; 4],
    /// First element, row-major, aligned for `dtype`.
    pub data: *const u8,
    /// Length of the data in bytes: the product of the shape times the
    /// element size.
    pub byte_len: usize,
    /// Row-major 4 x 4 voxel -> patient matrix of grids (zeros otherwise).
    pub affine: [f64; 16],
    /// Table column names, one per line (empty otherwise).
    pub labels: FgStr,
}

/// An input value on a named port.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct FgInput {
    /// The input port's name.
    pub port: FgStr,
    /// Its value, borrowed from the host for the duration of `run`.
    pub value: FgArray,
}

/// Parameter kinds, as `FgParam::kind` (the declaration's `kind` names).
pub mod param_kind {
    /// `int`: in `FgParam::int`.
    pub const INT: u32 = 1;
    /// `float`: in `FgParam::float`.
    pub const FLOAT: u32 = 2;
    /// `bool`: in `FgParam::int` (0 or 1).
    pub const BOOL: u32 = 3;
    /// `string` (and a choice): in `FgParam::text`.
    pub const STRING: u32 = 4;
    /// `int_list`: `len` values at `FgParam::ints`.
    pub const INT_LIST: u32 = 5;
    /// `float_list`: `len` values at `FgParam::floats`.
    pub const FLOAT_LIST: u32 = 6;
}

/// A parameter's value (the graph's, or the declared default).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct FgParam {
    /// The parameter's name.
    pub name: FgStr,
    /// A [`param_kind`] code.
    pub kind: u32,
    /// `INT` and `BOOL` values.
    pub int: i64,
    /// `FLOAT` values.
    pub float: f64,
    /// `STRING` values.
    pub text: FgStr,
    /// `INT_LIST` values.
    pub ints: *const i64,
    /// `FLOAT_LIST` values.
    pub floats: *const f64,
    /// Length of a list.
    pub len: usize,
}

/// An output value on a named port, owned by the plugin until `free`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct FgOutput {
    /// The output port's name.
    pub port: FgStr,
    /// Its value.
    pub value: FgArray,
}

/// A named metric (unit in the name: `coverage_pct`).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct FgMetric {
    /// The metric's name.
    pub name: FgStr,
    /// Its value.
    pub value: f64,
}

/// `FgResult::status`: the op succeeded.
pub const STATUS_OK: u32 = 0;
/// `FgResult::status`: the op refused its input; `message` says why.
pub const STATUS_ERROR: u32 = 1;
/// `FgResult::status`: the op panicked (caught in the plugin); `message` is
/// the panic's.
pub const STATUS_PANIC: u32 = 2;

/// What one run of an op produced, owned by the plugin until the host passes
/// it to `FgPlugin::free`.
#[repr(C)]
#[derive(Debug)]
pub struct FgResult {
    /// [`STATUS_OK`], [`STATUS_ERROR`] or [`STATUS_PANIC`].
    pub status: u32,
    /// Why it failed (empty on success).
    pub message: FgStr,
    /// The outputs (on success).
    pub outputs: *const FgOutput,
    /// Number of outputs.
    pub n_outputs: usize,
    /// Metrics.
    pub metrics: *const FgMetric,
    /// Number of metrics.
    pub n_metrics: usize,
    /// Notes for the user (inputs refused or repaired, and why).
    pub notes: *const FgStr,
    /// Number of notes.
    pub n_notes: usize,
    /// The plugin's own handle on the memory behind the pointers.
    pub owner: *mut c_void,
}

impl FgResult {
    /// A result with nothing in it yet.
    pub fn empty() -> FgResult {
        FgResult {
            status: STATUS_ERROR,
            message: FgStr::new(""),
            outputs: std::ptr::null(),
            n_outputs: 0,
            metrics: std::ptr::null(),
            n_metrics: 0,
            notes: std::ptr::null(),
            n_notes: 0,
            owner: std::ptr::null_mut(),
        }
    }
}

/// Runs op number `op` of the declaration. Must not unwind.
pub type FgRunFn = unsafe extern "C" fn(
    op: usize,
    inputs: *const FgInput,
    n_inputs: usize,
    params: *const FgParam,
    n_params: usize,
    result: *mut FgResult,
);

/// Frees what `run` put in `result`. Must not unwind.
pub type FgFreeFn = unsafe extern "C" fn(result: *mut FgResult);

/// The plugin's table.
#[repr(C)]
#[derive(Debug)]
pub struct FgPlugin {
    /// [`ABI_VERSION`] of the build.
    pub abi_version: u32,
    /// The ops, as TOML (see [`crate::declare`]).
    pub declaration: FgStr,
    /// Runs an op.
    pub run: FgRunFn,
    /// Frees a result.
    pub free: FgFreeFn,
}

// SAFETY: the table is immutable static data (a string and two functions).
unsafe impl Sync for FgPlugin {}
// SAFETY: as above.
unsafe impl Send for FgPlugin {}
