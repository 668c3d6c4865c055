//! fusegraph's built-in node types, one module per pipeline stage. Each module
//! holds its algorithms as plain functions on plain types, plus thin op adapters
//! that unpack values, call them and report metrics.

pub mod calib;
pub mod camera;
pub mod cloud;
pub mod design;
pub mod dicom;
pub mod eval;
pub mod io;
pub mod math;
pub mod mri;
mod numeric;
pub mod phantom;
pub mod plot;
pub mod register;
mod simd;
pub mod stereo;

/// Runs `f` on a pool of `threads` workers: tests compare one thread with
/// several to check that parallel loops give the same bits.
#[cfg(test)]
pub(crate) fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
        .install(f)
}

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers every built-in node type, each with its code fingerprint (the
/// build script's, see `build/fingerprint.rs`) for its cache keys.
pub fn register_all(registry: &mut Registry) -> Result<(), RegisterError> {
    calib::register(registry)?;
    cloud::register(registry)?;
    design::register(registry)?;
    dicom::register(registry)?;
    eval::register(registry)?;
    io::register(registry)?;
    math::register(registry)?;
    mri::register(registry)?;
    phantom::register(registry)?;
    plot::register(registry)?;
    register::register(registry)?;
    stereo::register(registry)?;
    for (op, code) in CODE_FINGERPRINTS {
        registry.set_code(op, code);
    }
    Ok(())
}

include!(concat!(env!("OUT_DIR"), "/code_fingerprints.rs"));

#[cfg(test)]
#[path = "../build/fingerprint.rs"]
mod code_fingerprint;

/// A registry holding every built-in node type.
pub fn builtin_registry() -> Registry {
    let mut registry = Registry::new();
    register_all(&mut registry).expect("built-in op names are unique");
    registry
}
