//! A library that is not a fusegraph plugin: it exports something else.

/// Not what the host looks for.
#[unsafe(no_mangle)]
pub extern "C" fn some_other_library_function() -> u32 {
    7
}
