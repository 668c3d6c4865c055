//! The two cache levels. [`MemoryCache`] holds results within a process (shared by
//! every run of a session, e.g. the variants of a sweep); [`DiskCache`] keeps them
//! across runs.
//!
//! A disk entry is one file `DIR/v{FORMAT_VERSION}/ab/<key>.entry`: magic
//! `FUSEGRPH`, format version (u32), the lengths of its two parts (u64 each),
//! blake3 of the first, then the parts. The first (the meta) holds the key it
//! was written for, the op, metrics, each output's place (a `Path` value
//! inline, any other as the offset, length and blake3 of its bytes in the
//! second part), figures and notes; the second holds the other outputs'
//! values one after another. So a run reads an entry's meta alone where no
//! node downstream computes ([`DiskCache::load_meta`]: a cached re-run reads
//! kilobytes, not every image and cloud it made), and a value is still
//! checked against its own hash before it is used. An entry copied over
//! another key's file fails the key test and is recomputed, never read as
//! that key's result. It is written to a unique temporary file in the same
//! folder and renamed into place, so readers see either nothing or a whole
//! entry and concurrent writers of one key both succeed. A truncated or
//! corrupt entry fails its length or a checksum and is recomputed.

use crate::figure::{Figure, FigureData};
use crate::key::NodeKey;
use crate::op::Outputs;
use crate::value::{Reader, Value, Writer, encode_value};
use std::collections::{BTreeMap, HashMap};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, Weak};

/// The cache a graph file uses by default: `.fusegraph/cache` beside it.
pub fn default_dir(graph_file: &Path) -> PathBuf {
    graph_file
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .join(".fusegraph")
        .join("cache")
}

/// Version of the entry layout and of the value encoding; bump on any change.
pub const FORMAT_VERSION: u32 = 5;
const MAGIC: &[u8; 8] = b"FUSEGRPH";
const HEADER_LEN: usize = 8 + 4 + 8 + 8 + 32;

/// What a node produced: its outputs, metrics and figures.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CacheEntry {
    /// The op that computed it (for `fusegraph cache stats`).
    pub op: String,
    /// Output values by port.
    pub outputs: Outputs,
    /// Metrics by name.
    pub metrics: BTreeMap<String, f64>,
    /// Figures for the report.
    pub figures: Arc<[Figure]>,
    /// The op's warnings (see [`crate::RunCtx::note`]).
    pub notes: Arc<[String]>,
    /// Outputs whose values were left on disk ([`DiskCache::load_meta`]):
    /// named here, absent from `outputs`; [`DiskCache::load`] reads them.
    /// Empty for a whole entry.
    pub on_disk: Vec<String>,
}

impl CacheEntry {
    /// Whether every `Path` output still holds the content it was recorded with
    /// (a cached path that was edited or deleted makes the entry stale).
    pub fn paths_intact(&self) -> Result<(), String> {
        self.outputs.paths_intact()
    }
}

/// Results by key, in memory: the entries something still holds (a run's
/// nodes whose consumers have not all run, a caller's [`RunOutcome`]). It
/// keeps none alive itself, so a long run or a sweep of many variants does
/// not hold every value it ever made; what was released is read back from
/// the disk cache.
///
/// [`RunOutcome`]: crate::schedule::RunOutcome
#[derive(Debug, Default)]
pub struct MemoryCache {
    entries: Mutex<HashMap<NodeKey, Weak<CacheEntry>>>,
}

impl MemoryCache {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// The entry for `key`, while something holds it.
    pub fn get(&self, key: &NodeKey) -> Option<Arc<CacheEntry>> {
        self.entries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(key)
            .and_then(Weak::upgrade)
    }

    /// Stores the entry for `key` (and forgets entries no longer held).
    pub fn insert(&self, key: NodeKey, entry: &Arc<CacheEntry>) {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        entries.retain(|_, held| held.strong_count() > 0);
        entries.insert(key, Arc::downgrade(entry));
    }
}

/// The outcome of looking a key up on disk.
#[derive(Debug)]
pub enum Lookup {
    /// A verified entry: whole from [`DiskCache::load`], its meta alone
    /// from [`DiskCache::load_meta`] (the values named in
    /// [`CacheEntry::on_disk`]).
    Hit(CacheEntry),
    /// No entry.
    Miss,
    /// An entry that failed verification, and why. It should be recomputed.
    Corrupt(String),
}

/// Results by key, on disk.
#[derive(Debug, Clone)]
pub struct DiskCache {
    dir: PathBuf,
}

/// How a stored `Path` inside the cache starts (never a real path: relative).
const CACHE_ROOT: &str = "$CACHE";

#[derive(Clone, Copy)]
enum PathsTo {
    Relative,
    Absolute,
}

impl DiskCache {
    /// A cache rooted at `dir` (created if missing).
    pub fn open(dir: &Path) -> io::Result<DiskCache> {
        let dir = std::path::absolute(dir)?.join(format!("v{FORMAT_VERSION}"));
        std::fs::create_dir_all(&dir).map_err(|e| {
            io::Error::new(e.kind(), format!("cache folder {}: {e}", dir.display()))
        })?;
        let cache = DiskCache { dir };
        let removed = crate::workdir::clean_stale_temps(&cache.files_root());
        if removed > 0 {
            tracing::info!("removed {removed} temporary folders left by dead runs");
        }
        Ok(cache)
    }

    /// Where the lease on computing `key` lives (see [`crate::lease`]).
    pub fn lease_path(&self, key: &NodeKey) -> PathBuf {
        self.dir.join("leases").join(format!("{}.lease", key.hex()))
    }

    /// The folder holding the files of nodes that produce files, by key.
    pub fn files_root(&self) -> PathBuf {
        self.dir.join("files")
    }

    /// Where the entry for `key` lives.
    pub fn entry_path(&self, key: &NodeKey) -> PathBuf {
        let hex = key.hex();
        self.dir.join(&hex[..2]).join(format!("{hex}.entry"))
    }

    /// Reads and verifies the entry for `key`.
    pub fn load(&self, key: &NodeKey) -> Lookup {
        let path = self.entry_path(key);
        match read_entry_bytes(&path) {
            Ok(Ok(bytes)) => match decode_entry(&bytes, key) {
                Ok(entry) => {
                    // Reading an entry marks it used: `fusegraph cache gc`
                    // removes the least recently used first.
                    mark_used(&path);
                    Lookup::Hit(self.with_paths(entry, PathsTo::Absolute))
                }
                Err(why) => Lookup::Corrupt(format!("{}: {why}", path.display())),
            },
            Ok(Err(why)) => Lookup::Corrupt(format!("{}: {why}", path.display())),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Lookup::Miss,
            Err(e) => Lookup::Corrupt(format!("{}: {e}", path.display())),
        }
    }

    /// Reads and verifies the meta of the entry for `key`: its metrics,
    /// figures, notes and `Path` outputs, the other outputs named in
    /// [`CacheEntry::on_disk`] and left unread.
    pub fn load_meta(&self, key: &NodeKey) -> Lookup {
        let path = self.entry_path(key);
        match read_entry_meta(&path) {
            Ok(Ok(bytes)) => match decode_meta(&bytes, key) {
                Ok((mut entry, stored)) => {
                    mark_used(&path);
                    entry.on_disk = stored.into_iter().map(|s| s.port).collect();
                    Lookup::Hit(self.with_paths(entry, PathsTo::Absolute))
                }
                Err(why) => Lookup::Corrupt(format!("{}: {why}", path.display())),
            },
            Ok(Err(why)) => Lookup::Corrupt(format!("{}: {why}", path.display())),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Lookup::Miss,
            Err(e) => Lookup::Corrupt(format!("{}: {e}", path.display())),
        }
    }

    /// Writes the entry for `key` atomically (temporary file, then rename).
    pub fn store(&self, key: &NodeKey, entry: &CacheEntry) -> io::Result<()> {
        let bytes = encode_entry(key, &self.with_paths(entry.clone(), PathsTo::Relative));
        crate::atomic::write_atomically(&self.entry_path(key), &bytes)
    }

    /// The entry with its `Path` outputs inside this cache written relative
    /// to it (`$CACHE/files/<key>/...`) or resolved back: so a cache copied or
    /// moved elsewhere (another machine's mount) reads its own files, not the
    /// original's, and does not regenerate them.
    fn with_paths(&self, mut entry: CacheEntry, to: PathsTo) -> CacheEntry {
        for value in entry.outputs.0.values_mut() {
            let Value::Path(p) = value else { continue };
            let moved = match to {
                PathsTo::Relative => p
                    .path
                    .strip_prefix(&self.dir)
                    .ok()
                    .map(|rel| Path::new(CACHE_ROOT).join(rel)),
                PathsTo::Absolute => p
                    .path
                    .strip_prefix(CACHE_ROOT)
                    .ok()
                    .map(|rel| self.dir.join(rel)),
            };
            if let Some(path) = moved {
                *value = Value::Path(Arc::new(crate::value::PathValue {
                    path,
                    content_hash: p.content_hash.clone(),
                }));
            }
        }
        entry
    }

    /// Why the entry for `key` is not a whole, valid entry of that key
    /// (`None`: it is, or there is none), without marking it used.
    pub fn check(&self, key: &NodeKey) -> Option<String> {
        let path = self.entry_path(key);
        match read_entry_bytes(&path) {
            Ok(Ok(bytes)) => decode_entry(&bytes, key).err(),
            Ok(Err(why)) => Some(why),
            Err(e) if e.kind() == io::ErrorKind::NotFound => None,
            Err(e) => Some(e.to_string()),
        }
    }

    /// Removes the entry for `key`, if any.
    pub fn remove(&self, key: &NodeKey) {
        let _ = std::fs::remove_file(self.entry_path(key));
    }
}

/// The bytes of the entry file at `path`, read only once its kind and size
/// make sense: a regular file (a FIFO would block, a link to a device never
/// end) whose length is the header's plus the part lengths the header
/// declares. So a damaged entry costs a header read, not its size in memory.
/// The inner error says why an existing file is not an entry.
fn read_entry_bytes(path: &Path) -> io::Result<Result<Vec<u8>, String>> {
    read_entry(path, Part::Whole)
}

/// The header and meta of the entry file at `path`, checked as
/// [`read_entry_bytes`] checks a whole one.
fn read_entry_meta(path: &Path) -> io::Result<Result<Vec<u8>, String>> {
    read_entry(path, Part::Meta)
}

#[derive(Clone, Copy, PartialEq)]
enum Part {
    Meta,
    Whole,
}

fn read_entry(path: &Path, part: Part) -> io::Result<Result<Vec<u8>, String>> {
    use std::io::Read;
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Ok(Err("not a regular file (a FIFO, device or folder)".into()));
    }
    let mut file = std::fs::File::open(path)?;
    let mut header = [0u8; HEADER_LEN];
    if let Err(e) = file.read_exact(&mut header) {
        return match e.kind() {
            io::ErrorKind::UnexpectedEof => Ok(Err(format!(
                "not a cache entry ({} bytes, shorter than a header)",
                meta.len()
            ))),
            _ => Err(e),
        };
    }
    if &header[..8] != MAGIC {
        return Ok(Err(format!(
            "not a cache entry ({} bytes, bad header)",
            meta.len()
        )));
    }
    let (meta_len, values_len) = part_lengths(&header);
    let expected = (HEADER_LEN as u64)
        .checked_add(meta_len)
        .and_then(|n| n.checked_add(values_len));
    if expected != Some(meta.len()) {
        return Ok(Err(format!(
            "{} bytes, but its header declares parts of {meta_len} and {values_len} bytes (truncated, grown or overwritten)",
            meta.len()
        )));
    }
    let wanted = match part {
        Part::Meta => meta_len,
        Part::Whole => meta_len + values_len,
    };
    let mut bytes = Vec::with_capacity(HEADER_LEN + wanted as usize);
    bytes.extend_from_slice(&header);
    // Read no more than declared, should the file grow meanwhile.
    file.take(wanted).read_to_end(&mut bytes)?;
    Ok(Ok(bytes))
}

/// The meta's and the values' lengths a header declares, bytes.
fn part_lengths(header: &[u8]) -> (u64, u64) {
    let at = |i: usize| u64::from_le_bytes(header[i..i + 8].try_into().expect("8 bytes"));
    (at(12), at(20))
}

/// Where an output's value lies in an entry's second part.
struct StoredValue {
    port: String,
    offset: usize,
    len: usize,
    hash: [u8; 32],
}

fn encode_entry(key: &NodeKey, entry: &CacheEntry) -> Vec<u8> {
    let mut meta = Vec::new();
    let mut values = Vec::new();
    meta.extend_from_slice(&key.0);
    let mut w = Writer(&mut meta);
    // First after the key, so `fusegraph cache stats` reads it without the rest.
    w.str(&entry.op);
    w.usize(entry.metrics.len());
    for (name, value) in &entry.metrics {
        w.str(name);
        w.f64(*value);
    }
    w.usize(entry.outputs.0.len());
    for (port, value) in &entry.outputs.0 {
        w.str(port);
        if matches!(value, Value::Path(_)) {
            // A path is checked against its files on every lookup: inline.
            w.u8(0);
            encode_value(value, w.0);
        } else {
            let offset = values.len();
            encode_value(value, &mut values);
            w.u8(1);
            w.usize(offset);
            w.usize(values.len() - offset);
            w.u8s(blake3::hash(&values[offset..]).as_bytes());
        }
    }
    w.usize(entry.figures.len());
    for f in entry.figures.iter() {
        w.str(&f.name);
        w.str(&f.caption);
        match &f.data {
            FigureData::Png(bytes) => {
                w.u8(0);
                w.u8s(bytes);
            }
            FigureData::Svg(text) => {
                w.u8(1);
                w.str(text);
            }
            FigureData::Points3d { xyz, rgb } => {
                w.u8(2);
                w.f32s(xyz);
                w.u8s(rgb);
            }
        }
    }
    w.usize(entry.notes.len());
    for n in entry.notes.iter() {
        w.str(n);
    }
    entry_bytes(&meta, &values)
}

/// An entry file's bytes: the header over `meta` and `values`, then both.
fn entry_bytes(meta: &[u8], values: &[u8]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(HEADER_LEN + meta.len() + values.len());
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&(meta.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&(values.len() as u64).to_le_bytes());
    bytes.extend_from_slice(blake3::hash(meta).as_bytes());
    bytes.extend_from_slice(meta);
    bytes.extend_from_slice(values);
    bytes
}

/// A whole entry from its bytes: the meta, then every stored value checked
/// against its hash.
fn decode_entry(bytes: &[u8], key: &NodeKey) -> Result<CacheEntry, String> {
    let (mut entry, stored) = decode_meta(bytes, key)?;
    let (meta_len, values_len) = part_lengths(bytes);
    let values = &bytes[HEADER_LEN + meta_len as usize..];
    if values.len() as u64 != values_len {
        return Err(format!(
            "truncated: values of {} bytes, header says {values_len}",
            values.len()
        ));
    }
    // The values follow one another and fill the part: no byte unchecked.
    let mut next = 0;
    for s in stored {
        let end = s
            .offset
            .checked_add(s.len)
            .filter(|&end| end <= values.len());
        let Some(end) = end.filter(|_| s.offset == next) else {
            return Err(format!(
                "output `{}`: its value lies outside the entry",
                s.port
            ));
        };
        next = end;
        let value = &values[s.offset..next];
        if blake3::hash(value).as_bytes() != &s.hash {
            return Err(format!("output `{}`: checksum mismatch", s.port));
        }
        let (decoded, used) =
            crate::value::decode_value(value).map_err(|e| format!("output `{}`: {e}", s.port))?;
        if used != value.len() {
            return Err(format!(
                "output `{}`: {} bytes past its value",
                s.port,
                value.len() - used
            ));
        }
        entry.outputs.0.insert(s.port, decoded);
    }
    if next != values.len() {
        return Err(format!("{} bytes past the last value", values.len() - next));
    }
    Ok(entry)
}

/// The meta of an entry (its header and first part, at least): the entry
/// with its inline outputs, and where the others lie.
fn decode_meta(bytes: &[u8], key: &NodeKey) -> Result<(CacheEntry, Vec<StoredValue>), String> {
    if bytes.len() < HEADER_LEN || &bytes[..8] != MAGIC {
        return Err(format!(
            "not a cache entry ({} bytes, bad header)",
            bytes.len()
        ));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
    if version != FORMAT_VERSION {
        return Err(format!(
            "format version {version}, expected {FORMAT_VERSION}"
        ));
    }
    let (meta_len, values_len) = part_lengths(bytes);
    // The bytes are the header and meta (a meta read) or the whole entry.
    let with_meta = (HEADER_LEN as u64).saturating_add(meta_len);
    let read = bytes.len() as u64;
    if read != with_meta && Some(read) != with_meta.checked_add(values_len) {
        return Err(format!(
            "{read} bytes, but its header declares parts of {meta_len} and {values_len} bytes (truncated, grown or overwritten)"
        ));
    }
    let meta = usize::try_from(meta_len)
        .ok()
        .and_then(|len| bytes.get(HEADER_LEN..HEADER_LEN.checked_add(len)?))
        .ok_or_else(|| {
            format!(
                "truncated: {} bytes of meta, header says {meta_len}",
                bytes.len() - HEADER_LEN
            )
        })?;
    if blake3::hash(meta).as_bytes() != &bytes[28..60] {
        return Err("checksum mismatch".into());
    }
    if meta.len() < 32 || meta[..32] != key.0 {
        let written_for = meta
            .get(..32)
            .map(|k| k.iter().map(|b| format!("{b:02x}")).collect::<String>())
            .unwrap_or_default();
        return Err(format!(
            "written for key {written_for}, not {} (an entry copied over another's)",
            key.hex()
        ));
    }
    let mut r = Reader::new(&meta[32..]);
    let err = |e: crate::value::CodecError| e.to_string();
    let mut entry = CacheEntry {
        op: r.str().map_err(err)?,
        ..CacheEntry::default()
    };
    for _ in 0..r.usize().map_err(err)? {
        let name = r.str().map_err(err)?;
        entry.metrics.insert(name, r.f64().map_err(err)?);
    }
    let mut stored = Vec::new();
    for _ in 0..r.usize().map_err(err)? {
        let port = r.str().map_err(err)?;
        match r.u8().map_err(err)? {
            0 => {
                entry.outputs.0.insert(port, r.value().map_err(err)?);
            }
            1 => {
                let (offset, len) = (r.usize().map_err(err)?, r.usize().map_err(err)?);
                let hash: [u8; 32] = r
                    .u8s()
                    .map_err(err)?
                    .try_into()
                    .map_err(|_| format!("output `{port}`: a hash is 32 bytes"))?;
                stored.push(StoredValue {
                    port,
                    offset,
                    len,
                    hash,
                });
            }
            k => return Err(format!("output `{port}`: unknown place {k}")),
        }
    }
    let mut figures = Vec::new();
    for _ in 0..r.usize().map_err(err)? {
        let (name, caption) = (r.str().map_err(err)?, r.str().map_err(err)?);
        let data = match r.u8().map_err(err)? {
            0 => FigureData::Png(r.u8s().map_err(err)?),
            1 => FigureData::Svg(r.str().map_err(err)?),
            2 => FigureData::Points3d {
                xyz: r.f32s().map_err(err)?,
                rgb: r.u8s().map_err(err)?,
            },
            k => return Err(format!("figure `{name}`: unknown kind {k}")),
        };
        figures.push(Figure {
            name,
            caption,
            data,
        });
    }
    entry.figures = figures.into();
    let notes: Vec<String> = (0..r.usize().map_err(err)?)
        .map(|_| r.str().map_err(err))
        .collect::<Result<_, _>>()?;
    entry.notes = notes.into();
    if !r.is_empty() {
        return Err("bytes past the meta's end".into());
    }
    Ok((entry, stored))
}

/// The op an entry file records, read from the start of its payload (the
/// header, the key, then the op's name) without the rest; `None` for a file
/// that is not an entry.
pub(crate) fn entry_op(path: &Path) -> Option<String> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).ok()?;
    let mut head = [0u8; HEADER_LEN + 32 + 8];
    f.read_exact(&mut head).ok()?;
    if &head[..8] != MAGIC {
        return None;
    }
    let len = u64::from_le_bytes(head[HEADER_LEN + 32..].try_into().ok()?) as usize;
    // An op name is `stage.action`: a longer one is a damaged entry.
    if len > 4096 {
        return None;
    }
    let mut name = vec![0u8; len];
    f.read_exact(&mut name).ok()?;
    String::from_utf8(name).ok()
}

/// Marks the entry file at `path` used now (its modification time), for
/// the least-recently-used order of `fusegraph cache gc`. A cache on a
/// read-only mount stays as it is.
fn mark_used(path: &Path) {
    let _ = std::fs::File::options()
        .write(true)
        .open(path)
        .and_then(|f| f.set_modified(std::time::SystemTime::now()));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::Table;

    fn sample() -> CacheEntry {
        let mut e = CacheEntry::default();
        e.metrics.insert("rmse_mm".into(), 0.25);
        e.outputs.0.insert("value".into(), Value::from(3.5));
        e.outputs.0.insert(
            "table".into(),
            Table::new(vec!["a".into()], vec![1.0, 2.0]).unwrap().into(),
        );
        e.figures = vec![
            Figure {
                name: "map".into(),
                caption: "a picture".into(),
                data: FigureData::Png(vec![137, 80, 78, 71]),
            },
            Figure {
                name: "plot".into(),
                caption: "a plot".into(),
                data: FigureData::Svg("<svg/>".into()),
            },
            Figure {
                name: "cloud".into(),
                caption: "points".into(),
                data: FigureData::Points3d {
                    xyz: vec![1.0, 2.0, 3.0],
                    rgb: vec![9, 8, 7],
                },
            },
        ]
        .into();
        e.notes = vec!["left_07.png: refused: blurred".to_string()].into();
        e
    }

    #[test]
    fn round_trip_and_miss() {
        let dir = tempfile::tempdir().unwrap();
        let cache = DiskCache::open(dir.path()).unwrap();
        let key = NodeKey([7; 32]);
        assert!(matches!(cache.load(&key), Lookup::Miss));
        cache.store(&key, &sample()).unwrap();
        match cache.load(&key) {
            Lookup::Hit(e) => assert_eq!(e, sample()),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn an_entry_copied_over_another_keys_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let cache = DiskCache::open(dir.path()).unwrap();
        let (a, b) = (NodeKey([1; 32]), NodeKey([2; 32]));
        cache.store(&a, &sample()).unwrap();
        std::fs::create_dir_all(cache.entry_path(&b).parent().unwrap()).unwrap();
        std::fs::copy(cache.entry_path(&a), cache.entry_path(&b)).unwrap();
        match cache.load(&b) {
            Lookup::Corrupt(why) => assert!(why.contains("written for key 0101"), "{why}"),
            other => panic!("{other:?}"),
        }
        assert!(matches!(cache.load(&a), Lookup::Hit(_)));
    }

    #[test]
    fn a_meta_holds_all_but_the_stored_values_and_is_checked_whole() {
        let dir = tempfile::tempdir().unwrap();
        let cache = DiskCache::open(dir.path()).unwrap();
        let key = NodeKey([5; 32]);
        cache.store(&key, &sample()).unwrap();
        let Lookup::Hit(meta) = cache.load_meta(&key) else {
            panic!("no meta")
        };
        let whole = sample();
        assert_eq!(meta.on_disk, ["table", "value"]);
        assert!(meta.outputs.0.is_empty());
        assert_eq!(
            (&meta.op, &meta.metrics, &meta.figures, &meta.notes),
            (&whole.op, &whole.metrics, &whole.figures, &whole.notes)
        );
        // Every byte of the header and meta is checked by a meta read.
        let bytes = encode_entry(&key, &whole);
        let (meta_len, _) = part_lengths(&bytes);
        for i in 0..HEADER_LEN + meta_len as usize {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(decode_meta(&b, &key).is_err(), "flip at {i}");
        }
    }

    #[test]
    fn a_value_placed_past_the_entry_is_refused_not_read() {
        // A meta whose checksum holds (written so) but whose value's place
        // overflows: an error, not a panic.
        let key = NodeKey([9; 32]);
        let mut values = Vec::new();
        encode_value(&Value::from(3.5), &mut values);
        let mut meta = key.0.to_vec();
        let mut w = Writer(&mut meta);
        w.str("test.op");
        w.usize(0);
        w.usize(2);
        w.str("first");
        w.u8(1);
        w.usize(0);
        w.usize(values.len());
        w.u8s(blake3::hash(&values).as_bytes());
        w.str("second");
        w.u8(1);
        w.usize(values.len());
        w.usize(usize::MAX);
        w.u8s(&[0; 32]);
        w.usize(0);
        w.usize(0);
        let bytes = entry_bytes(&meta, &values);
        let why = decode_entry(&bytes, &key).unwrap_err();
        assert!(why.contains("`second`: its value lies outside"), "{why}");
    }

    #[test]
    fn every_truncation_and_bit_flip_is_detected() {
        let key = NodeKey([3; 32]);
        let bytes = encode_entry(&key, &sample());
        assert_eq!(decode_entry(&bytes, &key), Ok(sample()));
        for cut in 0..bytes.len() {
            assert!(decode_entry(&bytes[..cut], &key).is_err(), "cut at {cut}");
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(decode_entry(&b, &key).is_err(), "flip at {i}");
        }
    }
}
