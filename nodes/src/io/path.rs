//! `io.path`: a file or folder on disk as a `Path` value, keyed by its content.

use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType, path_value,
};

pub(crate) struct PathOp(OpSpec);

impl PathOp {
    pub(crate) fn new() -> Self {
        PathOp(
            OpSpec::new(
                "io.path",
                1,
                "A file or folder on disk (relative to the graph file)",
            )
            .param(ParamSpec::path(
                "path",
                "File or folder, relative to the graph file",
            ))
            .output(
                "path",
                ValueType::Path,
                "The file or folder, identified by its content",
            ),
        )
    }
}

impl Op for PathOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, _: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let path = params.path("path")?;
        let value = path_value(&path)?;
        let bytes = dir_size(&path).map_err(|e| OpError::io(&path, e))?;
        ctx.metric("bytes", bytes as f64);
        Ok(Outputs::new().with("path", value))
    }
}

fn dir_size(path: &std::path::Path) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_dir() {
        return Ok(meta.len());
    }
    std::fs::read_dir(path)?.try_fold(0, |sum, entry| Ok(sum + dir_size(&entry?.path())?))
}
