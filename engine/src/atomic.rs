//! Whole-or-nothing file writes: a temporary file in the same folder, then a
//! rename, so that a reader, a concurrent writer or a full disk never leaves a
//! partial file under the name.

use std::io;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` through a temporary file unique to this process
/// and call, then renames it into place; creates the folder. The error names
/// the path.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let named = |e: io::Error| io::Error::new(e.kind(), format!("{}: {e}", path.display()));
    let folder = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(folder).map_err(named)?;
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    let temp = folder.join(format!(
        ".{name}.{}.{}.tmp",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = std::fs::write(&temp, bytes).and_then(|()| std::fs::rename(&temp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result.map_err(named)
}

/// As [`write_atomically`], but a file that already holds exactly `bytes`
/// is left as it is (no new file, its times unchanged): most of a re-run's
/// figures are those of the run before. Whether it wrote.
pub fn write_if_changed(path: &Path, bytes: &[u8]) -> io::Result<bool> {
    let same = std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() == bytes.len() as u64)
        && std::fs::read(path).is_ok_and(|held| held == bytes);
    if same {
        return Ok(false);
    }
    write_atomically(path, bytes).map(|()| true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unchanged_file_is_left_and_a_changed_one_replaced() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("figures/a.svg");
        assert!(write_if_changed(&path, b"<svg/>").unwrap(), "a new file");
        assert!(
            !write_if_changed(&path, b"<svg/>").unwrap(),
            "the same bytes"
        );
        assert!(
            write_if_changed(&path, b"<svg />").unwrap(),
            "one byte more"
        );
        assert!(
            write_if_changed(&path, b"<svg!>").unwrap(),
            "same length, other bytes"
        );
        assert_eq!(std::fs::read(&path).unwrap(), b"<svg!>");
        // A folder in the file's place is an error naming it, as before.
        let folder = t.path().join("figures/b.png");
        std::fs::create_dir_all(&folder).unwrap();
        let e = write_if_changed(&folder, b"png").unwrap_err();
        assert!(e.to_string().contains("b.png"), "{e}");
        let leftovers: Vec<_> = std::fs::read_dir(t.path().join("figures"))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .filter(|n| n.ends_with(".tmp"))
            .collect();
        assert!(leftovers.is_empty(), "{leftovers:?}");
    }
}
