//! `io.path`: a file or folder on disk as a `Path` value, keyed by its content.

use crate::io::disk_size::dir_size;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PathValue;
use std::path::PathBuf;

/// A file or folder on disk (relative to the graph file)
#[derive(Op)]
#[op(name = "io.path", version = 1)]
pub struct DiskPath {
    /// File or folder, relative to the graph file
    pub path: PathBuf,
}

#[derive(Inputs)]
pub struct DiskPathInputs;

#[derive(Outputs)]
pub struct DiskPathOutputs {
    /// The file or folder, identified by its content
    pub path: PathValue,
}

impl RunOp for DiskPath {
    type Inputs = DiskPathInputs;
    type Outputs = DiskPathOutputs;

    fn run(&self, _: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let value = path_value(&self.path)?;
        let bytes = dir_size(&self.path).map_err(|e| OpError::io(&self.path, e))?;
        ctx.metric("bytes", bytes as f64);
        Ok(DiskPathOutputs { path: value })
    }
}
