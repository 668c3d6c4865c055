//! Files on disk as `Path` values: keyed by their content, with their size.

use fusegraph_engine::value::PathValue;
use fusegraph_engine::{OpError, path_value};
use std::path::Path;
use std::sync::Arc;

/// The file or folder at `path` as a `Path` value (absolute, keyed by its
/// content), for an op's `Path` output.
pub(crate) fn path_of(path: &Path) -> Result<Arc<PathValue>, OpError> {
    path_value(path).map(Arc::new)
}

/// Bytes in the file at `path`, or in every file under the folder at `path`.
pub(crate) fn dir_size(path: &Path) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_dir() {
        return Ok(meta.len());
    }
    std::fs::read_dir(path)?.try_fold(0, |sum, entry| Ok(sum + dir_size(&entry?.path())?))
}
