//! Content hashing of files and folders (blake3), for cache keys and for
//! [`crate::value::PathValue`]s: the same bytes give the same hash wherever they
//! live, so moving a project does not invalidate its cache.

use std::io;
use std::path::Path;

/// Hashes a file's bytes, or a folder's files (recursively, in sorted order,
/// each with its relative path so renames change the hash). Symbolic links are
/// followed. Only regular files and folders are read: a device (`/dev/zero`),
/// a FIFO or a socket would block or never end, and is refused naming it.
pub fn hash_path(path: &Path) -> io::Result<blake3::Hash> {
    let mut hasher = blake3::Hasher::new();
    let meta = std::fs::metadata(path).map_err(|e| with_path(path, e))?;
    if meta.is_dir() {
        hasher.update(b"dir\0");
        hash_dir(path, Path::new(""), &mut hasher)?;
    } else {
        hasher.update(b"file\0");
        hash_file(path, &mut hasher)?;
    }
    Ok(hasher.finalize())
}

/// Refuses anything but a regular file or a folder (a device, FIFO or
/// socket), naming it: reading one blocks or never ends.
pub fn check_readable_kind(path: &Path, meta: &std::fs::Metadata) -> io::Result<()> {
    if meta.is_file() || meta.is_dir() {
        return Ok(());
    }
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!(
            "{}: not a regular file or folder (a device, FIFO or socket), refused",
            path.display()
        ),
    ))
}

fn hash_file(path: &Path, hasher: &mut blake3::Hasher) -> io::Result<()> {
    let meta = std::fs::metadata(path).map_err(|e| with_path(path, e))?;
    check_readable_kind(path, &meta)?;
    let file = std::fs::File::open(path).map_err(|e| with_path(path, e))?;
    let len = file.metadata().map_err(|e| with_path(path, e))?.len();
    hasher.update(&len.to_le_bytes());
    hasher.update_reader(file).map_err(|e| with_path(path, e))?;
    Ok(())
}

fn hash_dir(dir: &Path, relative: &Path, hasher: &mut blake3::Hasher) -> io::Result<()> {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| with_path(dir, e))?
        .collect::<Result<_, _>>()
        .map_err(|e| with_path(dir, e))?;
    entries.sort_by_key(|e| e.file_name());
    for entry in entries {
        let path = entry.path();
        let rel = relative.join(entry.file_name());
        let rel_bytes = rel.to_string_lossy();
        if std::fs::metadata(&path)
            .map_err(|e| with_path(&path, e))?
            .is_dir()
        {
            hasher.update(b"d");
            hasher.update(&(rel_bytes.len() as u64).to_le_bytes());
            hasher.update(rel_bytes.as_bytes());
            hash_dir(&path, &rel, hasher)?;
        } else {
            hasher.update(b"f");
            hasher.update(&(rel_bytes.len() as u64).to_le_bytes());
            hasher.update(rel_bytes.as_bytes());
            hash_file(&path, hasher)?;
        }
    }
    Ok(())
}

fn with_path(path: &Path, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn devices_and_fifos_are_refused_not_read() {
        let e = hash_path(Path::new("/dev/zero")).unwrap_err();
        assert!(
            e.to_string().contains("/dev/zero: not a regular file"),
            "{e}"
        );
        let t = tempfile::tempdir().unwrap();
        std::fs::write(t.path().join("a.dcm"), "x").unwrap();
        let fifo = t.path().join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = hash_path(t.path()).unwrap_err();
            assert!(e.to_string().contains("pipe: not a regular file"), "{e}");
        }
    }

    #[test]
    fn content_not_location_decides() {
        let t = tempfile::tempdir().unwrap();
        let (a, b) = (t.path().join("a"), t.path().join("b"));
        for d in [&a, &b] {
            std::fs::create_dir_all(d.join("sub")).unwrap();
            std::fs::write(d.join("x.txt"), "one").unwrap();
            std::fs::write(d.join("sub/y.txt"), "two").unwrap();
        }
        assert_eq!(hash_path(&a).unwrap(), hash_path(&b).unwrap());
        std::fs::write(b.join("sub/y.txt"), "twO").unwrap();
        assert_ne!(hash_path(&a).unwrap(), hash_path(&b).unwrap());
        std::fs::write(b.join("sub/y.txt"), "two").unwrap();
        std::fs::rename(b.join("x.txt"), b.join("z.txt")).unwrap();
        assert_ne!(hash_path(&a).unwrap(), hash_path(&b).unwrap());
        assert_ne!(hash_path(&a.join("x.txt")).unwrap(), hash_path(&a).unwrap());
        let err = hash_path(&t.path().join("missing")).unwrap_err();
        assert!(err.to_string().contains("missing"), "{err}");
    }
}
