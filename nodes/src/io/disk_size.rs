//! Sizes of files and folders on disk (for `io.path`'s metric).

use std::path::Path;

/// Bytes in the file at `path`, or in every file under the folder at `path`.
pub(crate) fn dir_size(path: &Path) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_dir() {
        return Ok(meta.len());
    }
    std::fs::read_dir(path)?.try_fold(0, |sum, entry| Ok(sum + dir_size(&entry?.path())?))
}
