//! Content hashing of files and folders (blake3), for cache keys and for
//! [`crate::value::PathValue`]s: the same bytes give the same hash wherever they
//! live, so moving a project does not invalidate its cache.
//!
//! A folder's files are read a batch at a time in parallel and hashed in
//! their fixed order with blake3's multithreaded update: a phantom's folders
//! (46 MB) are hashed once made, and again in every run in which a node that
//! runs reads them. blake3 gives the same hash however a stream is split
//! into updates, so the hash is the one a plain sequential read gives (a
//! test keeps that definition).

use rayon::prelude::*;
use std::io::{self, Read};
use std::path::{Path, PathBuf};

/// Files read side by side before they are hashed: at most this many bytes
/// (a larger file is streamed alone) ...
const BATCH_BYTES: u64 = 8 << 20;
/// ... and at most this many files.
const BATCH_FILES: usize = 64;

/// Below this many bytes, blake3's multithreaded update is slower than its
/// plain one (its documentation's rule of thumb on x86-64).
const PARALLEL_HASH_BYTES: usize = 128 << 10;

/// Hashes a file's bytes, or a folder's files (recursively, in sorted order,
/// each with its relative path so renames change the hash). Symbolic links are
/// followed. Only regular files and folders are read: a device (`/dev/zero`),
/// a FIFO or a socket would block or never end, and is refused naming it.
pub fn hash_path(path: &Path) -> io::Result<blake3::Hash> {
    let mut hasher = blake3::Hasher::new();
    let meta = std::fs::metadata(path).map_err(|e| with_path(path, e))?;
    if meta.is_dir() {
        hasher.update(b"dir\0");
        let mut items = Vec::new();
        list_dir(path, Path::new(""), &mut items)?;
        hash_items(&items, &mut hasher)?;
    } else {
        hasher.update(b"file\0");
        check_readable_kind(path, &meta)?;
        hash_file_streamed(path, &mut hasher)?;
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

/// A folder's entry, in the order it is hashed.
enum Item {
    /// A subfolder, by its path relative to the hashed folder (its own
    /// items follow).
    Dir(String),
    /// A file: relative path, where it is, and its size when listed.
    File(String, PathBuf, u64),
}

/// The items of `dir` (reached as `relative` from the hashed folder), sorted
/// by name, subfolders followed by their own items.
fn list_dir(dir: &Path, relative: &Path, items: &mut Vec<Item>) -> io::Result<()> {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| with_path(dir, e))?
        .collect::<Result<_, _>>()
        .map_err(|e| with_path(dir, e))?;
    entries.sort_by_key(|e| e.file_name());
    for entry in entries {
        let path = entry.path();
        let rel = relative.join(entry.file_name());
        let rel_text = rel.to_string_lossy().into_owned();
        let meta = std::fs::metadata(&path).map_err(|e| with_path(&path, e))?;
        if meta.is_dir() {
            items.push(Item::Dir(rel_text));
            list_dir(&path, &rel, items)?;
        } else {
            check_readable_kind(&path, &meta)?;
            items.push(Item::File(rel_text, path, meta.len()));
        }
    }
    Ok(())
}

/// Feeds `items` to `hasher` in order, a batch at a time: the next batch's
/// files are read (in parallel) while this one's are hashed; a file larger
/// than a batch is streamed alone.
fn hash_items(items: &[Item], hasher: &mut blake3::Hasher) -> io::Result<()> {
    let batches = batches(items);
    let read = |batch: &[Item]| -> Vec<Option<io::Result<Vec<u8>>>> {
        batch
            .par_iter()
            .map(|item| match item {
                Item::File(_, path, size) if *size <= BATCH_BYTES => Some(read_whole(path)),
                _ => None,
            })
            .collect()
    };
    let mut contents = batches.first().map(|b| read(&items[b.clone()]));
    for (k, batch) in batches.iter().enumerate() {
        let this = contents.take().unwrap_or_default();
        let (fed, next) = rayon::join(
            || feed(&items[batch.clone()], this, hasher),
            || batches.get(k + 1).map(|b| read(&items[b.clone()])),
        );
        fed?;
        contents = next;
    }
    Ok(())
}

/// `items` cut into runs of at most [`BATCH_FILES`] files and
/// [`BATCH_BYTES`] bytes (a larger file alone).
fn batches(items: &[Item]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut next = 0;
    while next < items.len() {
        let (mut end, mut bytes) = (next, 0u64);
        while end < items.len() && end - next < BATCH_FILES {
            let size = match &items[end] {
                Item::File(_, _, size) => *size,
                Item::Dir(_) => 0,
            };
            if end > next && bytes + size > BATCH_BYTES {
                break;
            }
            bytes += size;
            end += 1;
        }
        out.push(next..end);
        next = end;
    }
    out
}

/// Feeds one batch's items, with the contents read for them (`None` for a
/// folder or a file to stream), to `hasher`: the batch's stream is laid
/// out in one buffer and hashed by blake3's threads at once (hashed a file
/// at a time, a phantom's DICOM slices of 70 kB each would be too small to
/// share).
fn feed(
    batch: &[Item],
    contents: Vec<Option<io::Result<Vec<u8>>>>,
    hasher: &mut blake3::Hasher,
) -> io::Result<()> {
    let mut stream = Vec::new();
    for (item, content) in batch.iter().zip(contents) {
        match item {
            Item::Dir(rel) => {
                stream.push(b'd');
                put_name(&mut stream, rel);
            }
            Item::File(rel, path, _) => {
                stream.push(b'f');
                put_name(&mut stream, rel);
                match content {
                    Some(bytes) => {
                        let bytes = bytes?;
                        stream.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
                        stream.extend_from_slice(&bytes);
                    }
                    None => {
                        update(hasher, &std::mem::take(&mut stream));
                        hash_file_streamed(path, hasher)?;
                    }
                }
            }
        }
    }
    update(hasher, &stream);
    Ok(())
}

fn put_name(stream: &mut Vec<u8>, rel: &str) {
    stream.extend_from_slice(&(rel.len() as u64).to_le_bytes());
    stream.extend_from_slice(rel.as_bytes());
}

fn update(hasher: &mut blake3::Hasher, bytes: &[u8]) {
    if bytes.len() >= PARALLEL_HASH_BYTES {
        hasher.update_rayon(bytes);
    } else {
        hasher.update(bytes);
    }
}

fn read_whole(path: &Path) -> io::Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| with_path(path, e))
}

/// A file's length (as it is when opened), then its bytes, read and hashed
/// a block at a time (a file of any size).
fn hash_file_streamed(path: &Path, hasher: &mut blake3::Hasher) -> io::Result<()> {
    let mut file = std::fs::File::open(path).map_err(|e| with_path(path, e))?;
    let len = file.metadata().map_err(|e| with_path(path, e))?.len();
    hasher.update(&len.to_le_bytes());
    let mut block = vec![0; (BATCH_BYTES as usize).min(len as usize).max(1 << 16)];
    loop {
        let mut filled = 0;
        while filled < block.len() {
            match file.read(&mut block[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(with_path(path, e)),
            }
        }
        update(hasher, &block[..filled]);
        if filled < block.len() {
            return Ok(());
        }
    }
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

    /// The hash's definition, read and hashed sequentially (what the
    /// batched, parallel reading must give bit for bit).
    fn sequential_hash(path: &Path) -> blake3::Hash {
        fn file(path: &Path, h: &mut blake3::Hasher) {
            let bytes = std::fs::read(path).unwrap();
            h.update(&(bytes.len() as u64).to_le_bytes());
            h.update(&bytes);
        }
        fn dir(dir_path: &Path, relative: &Path, h: &mut blake3::Hasher) {
            let mut entries: Vec<_> = std::fs::read_dir(dir_path)
                .unwrap()
                .map(|e| e.unwrap())
                .collect();
            entries.sort_by_key(|e| e.file_name());
            for entry in entries {
                let rel = relative.join(entry.file_name());
                let name = rel.to_string_lossy();
                let is_dir = entry.path().is_dir();
                h.update(if is_dir { b"d" } else { b"f" });
                h.update(&(name.len() as u64).to_le_bytes());
                h.update(name.as_bytes());
                if is_dir {
                    dir(&entry.path(), &rel, h);
                } else {
                    file(&entry.path(), h);
                }
            }
        }
        let mut h = blake3::Hasher::new();
        if path.is_dir() {
            h.update(b"dir\0");
            dir(path, Path::new(""), &mut h);
        } else {
            h.update(b"file\0");
            file(path, &mut h);
        }
        h.finalize()
    }

    #[test]
    fn batched_parallel_reading_gives_the_sequential_hash() {
        // More files than a batch holds, files on both sides of the
        // multithreaded update's threshold, one larger than a batch (streamed
        // alone), an empty one and nested folders.
        let t = tempfile::tempdir().unwrap();
        let root = t.path();
        let bytes = |n: usize, seed: u8| -> Vec<u8> {
            (0..n)
                .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
                .collect()
        };
        for i in 0..(BATCH_FILES + 9) {
            std::fs::write(
                root.join(format!("small_{i:03}")),
                bytes(100 + 37 * i, i as u8),
            )
            .unwrap();
        }
        std::fs::create_dir_all(root.join("sub/deeper")).unwrap();
        std::fs::create_dir_all(root.join("empty_folder")).unwrap();
        std::fs::write(
            root.join("sub/large"),
            bytes(PARALLEL_HASH_BYTES * 3 + 5, 7),
        )
        .unwrap();
        std::fs::write(root.join("sub/deeper/empty"), b"").unwrap();
        let huge = root.join("sub/huge");
        std::fs::write(&huge, bytes(BATCH_BYTES as usize + 12345, 9)).unwrap();
        assert_eq!(hash_path(root).unwrap(), sequential_hash(root));
        assert_eq!(hash_path(&huge).unwrap(), sequential_hash(&huge));
        let large = root.join("sub/large");
        assert_eq!(hash_path(&large).unwrap(), sequential_hash(&large));
        // And the definition is the content's: one byte changed changes it.
        let before = hash_path(root).unwrap();
        let mut changed = bytes(PARALLEL_HASH_BYTES * 3 + 5, 7);
        changed[PARALLEL_HASH_BYTES * 2] ^= 1;
        std::fs::write(&large, changed).unwrap();
        assert_ne!(hash_path(root).unwrap(), before);
        assert_eq!(hash_path(root).unwrap(), sequential_hash(root));
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
