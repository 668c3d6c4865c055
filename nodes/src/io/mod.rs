//! File nodes: sources that read files into the graph and sinks (`io.write_*`)
//! that write values under the run's output folder.

mod path;
mod write_json;

pub use write_json::value_to_json;

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `io.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(path::PathOp::new()))?;
    registry.register(Arc::new(write_json::WriteJsonOp::new()))?;
    Ok(())
}
