//! A library that exports fusegraph's symbol names as data, not functions:
//! calling one would crash the host, which must refuse it first.

// The names are the ABI's symbol names.
#![allow(non_upper_case_globals)]

/// A variable under the name of the ABI version function.
#[unsafe(no_mangle)]
pub static fusegraph_plugin_abi_version: [u8; 16] = [0xFF; 16];

/// A variable under the name of the plugin table function.
#[unsafe(no_mangle)]
pub static fusegraph_plugin: [u8; 16] = [0xFF; 16];
