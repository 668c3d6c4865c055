//! fusegraph's plugin API: what a dynamic library needs to add node types
//! (ops) to fusegraph without forking it. The boundary is a versioned C ABI
//! ([`abi`]); this crate wraps both of its sides in safe Rust.
//!
//! A plugin op is written in the same typed form as a built-in one (feature
//! `derive`; see [`typed`] and the example on [`TypedPluginOp`]): a struct
//! whose fields are its parameters, two structs for its ports, and
//! [`TypedPluginOp::run`]. [`Typed`] turns it into a [`PluginOp`] whose
//! TOML declaration (what the host reads) is generated from the derives.
//! [`OpDecl`] and [`Param`] are the lower-level builders of that TOML;
//! plugins written with them, and plugins built against ABI v1 before the
//! typed form, keep working.
//!
//! Build it as a `cdylib` and run a graph with `fusegraph run --plugin
//! target/release/libmy_plugin.so`. See plugins/README.md.

pub mod abi;
pub mod declare;
mod output;
pub mod typed;
mod typed_op;
mod view;

pub use declare::{OpDecl, Param};

/// The derives of the typed declaration form (feature `derive`):
/// `#[derive(Op)]`, `#[derive(Params)]`, `#[derive(Inputs)]`,
/// `#[derive(Outputs)]` and `#[derive(Choice)]` (see [`typed`]).
#[cfg(feature = "derive")]
pub mod derive {
    pub use fusegraph_derive::{Choice, Inputs, Op, Outputs, Params};
}

/// The plugin author's guide: its Rust examples compile and run as doctests.
#[cfg(all(doctest, feature = "derive"))]
#[doc = include_str!("../../README.md")]
pub struct PluginGuide;
pub use output::Outputs;
pub use typed_op::{DisparityMap, DisparityView, ImageU8, Typed, TypedPluginOp};
pub use view::{ImageView, Inputs, Params, PixelsView, TableView};

use abi::{FgInput, FgParam, FgPlugin, FgResult, FgStr};
use std::cell::Cell;

/// One op of a plugin: its declaration and how it runs.
///
/// `run` must be a function of its inputs and parameters only (the host
/// caches its results by them) and should report bad input as `Err` with a
/// message for the user; a panic is caught and reported too.
pub trait PluginOp: Send + Sync {
    /// The declaration (called once, when the plugin is loaded).
    fn declare(&self) -> OpDecl;
    /// Computes the outputs.
    fn run(&self, inputs: &Inputs, params: &Params, out: &mut Outputs) -> Result<(), String>;
}

thread_local! {
    static IN_OP: Cell<bool> = const { Cell::new(false) };
}

/// A plugin's ops and its table, built once by [`export_plugin!`].
pub struct Plugin {
    ops: Vec<Box<dyn PluginOp>>,
    declaration: String,
    table: Option<FgPlugin>,
}

impl Plugin {
    /// The plugin of `ops`, with its run and free functions (from the macro).
    #[doc(hidden)]
    pub fn new(ops: Vec<Box<dyn PluginOp>>, run: abi::FgRunFn, free: abi::FgFreeFn) -> Plugin {
        // The plugin's own copy of std prints panics by default; a panic inside
        // an op is returned to the host as an error instead.
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !IN_OP.with(|f| f.get()) {
                previous(info);
            }
        }));
        let declaration: String = ops.iter().map(|op| op.declare().to_toml()).collect();
        let mut plugin = Plugin {
            ops,
            declaration,
            table: None,
        };
        plugin.table = Some(FgPlugin {
            abi_version: abi::ABI_VERSION,
            declaration: FgStr::new(&plugin.declaration),
            run,
            free,
        });
        plugin
    }

    /// The table for the host (its declaration points into `self`).
    #[doc(hidden)]
    pub fn table(&self) -> *const FgPlugin {
        self.table
            .as_ref()
            .map_or(std::ptr::null(), |t| t as *const FgPlugin)
    }

    /// Runs op `op` on the host's arguments into `result`, catching panics.
    ///
    /// # Safety
    /// The pointers must be the host's, as the ABI describes.
    #[doc(hidden)]
    pub unsafe fn run(
        &self,
        op: usize,
        inputs: *const FgInput,
        n_inputs: usize,
        params: *const FgParam,
        n_params: usize,
        result: *mut FgResult,
    ) {
        if result.is_null() {
            return;
        }
        // SAFETY: the host passes a valid result to fill.
        let result = unsafe { &mut *result };
        // SAFETY: the host passes `n_inputs` inputs and `n_params` parameters.
        let (inputs, params) =
            unsafe { (host_slice(inputs, n_inputs), host_slice(params, n_params)) };
        IN_OP.with(|f| f.set(true));
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let op = self
                .ops
                .get(op)
                .ok_or_else(|| format!("no op number {op} in this plugin"))?;
            let mut out = Outputs::default();
            // SAFETY: the host's arguments, valid for this call.
            let (inputs, params) = unsafe { (Inputs::new(inputs), Params::new(params)) };
            op.run(&inputs, &params, &mut out).map(|()| out)
        }));
        IN_OP.with(|f| f.set(false));
        let filled = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match outcome {
            Ok(Ok(out)) => output::into_result(abi::STATUS_OK, String::new(), out, result),
            Ok(Err(why)) => output::into_result(abi::STATUS_ERROR, why, Outputs::default(), result),
            Err(panic) => {
                let why = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "a panic without a message".into());
                output::into_result(abi::STATUS_PANIC, why, Outputs::default(), result)
            }
        }));
        if filled.is_err() {
            *result = FgResult::empty();
            result.status = abi::STATUS_PANIC;
        }
    }

    /// Frees a result filled by [`Plugin::run`].
    ///
    /// # Safety
    /// `result` must have been filled by [`Plugin::run`] and not freed since.
    #[doc(hidden)]
    pub unsafe fn free(result: *mut FgResult) {
        if !result.is_null() {
            // SAFETY: as the caller guarantees.
            let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| unsafe {
                output::free_result(&mut *result)
            }));
        }
    }
}

/// `n` elements at `p`, empty when `n` is 0 or `p` null.
///
/// # Safety
/// A non-zero `n` with a non-null `p` needs `n` valid elements there for `'a`.
unsafe fn host_slice<'a, T>(p: *const T, n: usize) -> &'a [T] {
    if n == 0 || p.is_null() {
        &[]
    } else {
        // SAFETY: as the caller guarantees.
        unsafe { std::slice::from_raw_parts(p, n) }
    }
}

/// Exports the plugin's ops: the two symbols the host looks up. Give each op
/// as an expression of a type implementing [`PluginOp`].
#[macro_export]
macro_rules! export_plugin {
    ($($op:expr),+ $(,)?) => {
        fn __fusegraph_plugin() -> Option<&'static $crate::Plugin> {
            static PLUGIN: ::std::sync::OnceLock<Option<$crate::Plugin>> = ::std::sync::OnceLock::new();
            PLUGIN
                .get_or_init(|| {
                    ::std::panic::catch_unwind(|| {
                        $crate::Plugin::new(
                            vec![$(Box::new($op) as Box<dyn $crate::PluginOp>),+],
                            __fusegraph_run,
                            __fusegraph_free,
                        )
                    })
                    .ok()
                })
                .as_ref()
        }

        unsafe extern "C" fn __fusegraph_run(
            op: usize,
            inputs: *const $crate::abi::FgInput,
            n_inputs: usize,
            params: *const $crate::abi::FgParam,
            n_params: usize,
            result: *mut $crate::abi::FgResult,
        ) {
            if let Some(plugin) = __fusegraph_plugin() {
                // SAFETY: the host's arguments, as the ABI describes.
                unsafe { plugin.run(op, inputs, n_inputs, params, n_params, result) }
            }
        }

        unsafe extern "C" fn __fusegraph_free(result: *mut $crate::abi::FgResult) {
            // SAFETY: the host passes back a result `run` filled.
            unsafe { $crate::Plugin::free(result) }
        }

        /// The ABI version this plugin was built for.
        #[unsafe(no_mangle)]
        pub extern "C" fn fusegraph_plugin_abi_version() -> u32 {
            $crate::abi::ABI_VERSION
        }

        /// The plugin's table (null if its ops could not be declared).
        #[unsafe(no_mangle)]
        pub extern "C" fn fusegraph_plugin() -> *const $crate::abi::FgPlugin {
            __fusegraph_plugin().map_or(::std::ptr::null(), |p| p.table())
        }
    };
}
