//! A plugin built for another ABI version: the host must refuse it before
//! touching anything else.

/// Says version 999.
#[unsafe(no_mangle)]
pub extern "C" fn fusegraph_plugin_abi_version() -> u32 {
    999
}

/// Never called by a host that checks the version first.
#[unsafe(no_mangle)]
pub extern "C" fn fusegraph_plugin() -> *const fusegraph_plugin_api::abi::FgPlugin {
    std::ptr::null()
}
