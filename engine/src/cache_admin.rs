//! A cache a lab shares for months, managed: what is in it ([`stats`]),
//! removing the least recently used entries ([`gc`]) and checking it
//! ([`verify`]). An entry is its file `vN/ab/<key>.entry` plus, for a node
//! that made files, its folder `vN/files/<key>/`; reading an entry marks it
//! used (its modification time, see [`crate::cache::DiskCache::load`]).
//!
//! gc is safe while other runs use the cache: it takes each key's lease
//! before removing it (a key another process is computing is skipped, and
//! none starts computing it meanwhile), and it never removes an entry used
//! within `keep_recent` (a run that just read an entry still needs its
//! files). A run that finds an entry gone computes it again.

use crate::cache::FORMAT_VERSION;
use crate::lease::{Acquired, try_acquire};
use std::collections::BTreeMap;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// One entry as found on disk.
#[derive(Debug, Clone)]
pub struct EntryInfo {
    /// Its key (hex).
    pub key: String,
    /// The op that computed it ("?" when the entry cannot be read).
    pub op: String,
    /// Bytes of its entry file and its files folder.
    pub bytes: u64,
    /// When it was last written or read.
    pub last_used: SystemTime,
}

/// What [`stats`] found.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    /// Apparent bytes of everything under the cache folder, folders
    /// included (as `du -sb` counts them).
    pub total_bytes: u64,
    /// Entries, least recently used first.
    pub entries: Vec<EntryInfo>,
    /// Entries and bytes by op.
    pub by_op: BTreeMap<String, (usize, u64)>,
    /// Folders of older formats (see [`older_formats`]), in `total_bytes`.
    pub older_formats: Vec<(PathBuf, u64)>,
}

/// The versioned folder of the cache at `dir` (`dir/vN`); an error naming
/// `dir` when there is no cache there.
fn versioned(dir: &Path) -> io::Result<PathBuf> {
    let v = dir.join(format!("v{FORMAT_VERSION}"));
    if !v.is_dir() {
        let older = older_formats(dir);
        let why = if older.is_empty() {
            "the default cache is .fusegraph/cache beside a graph \
             (graphs/.fusegraph/cache for the shipped ones)"
                .to_string()
        } else {
            format!(
                "only {}, which this build does not read",
                describe_older(&older)
            )
        };
        return Err(io::Error::new(
            io::ErrorKind::NotFound,
            format!(
                "{}: no fusegraph cache (format v{FORMAT_VERSION}) here; {why}",
                dir.display()
            ),
        ));
    }
    Ok(v)
}

/// The folders of older entry formats in the cache at `dir` (`vN`, N below
/// [`FORMAT_VERSION`]) and their apparent bytes, oldest first: this build
/// never reads them, and `gc` leaves them (an older build may still use
/// them); removing one once no older build does frees its space.
pub fn older_formats(dir: &Path) -> Vec<(PathBuf, u64)> {
    let Ok(children) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut older: Vec<(u32, PathBuf)> = children
        .flatten()
        .filter(|e| e.path().is_dir())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let version: u32 = name.strip_prefix('v')?.parse().ok()?;
            (version < FORMAT_VERSION).then(|| (version, e.path()))
        })
        .collect();
    older.sort();
    older
        .into_iter()
        .map(|(_, path)| {
            let bytes = apparent_bytes(&path);
            (path, bytes)
        })
        .collect()
}

/// Removes the folders of older entry formats in the cache at `dir` (see
/// [`older_formats`]) and returns them with the bytes each held; with
/// `dry_run`, only returns them. Only for a cache no older fusegraph uses
/// any more: a run of an older build on one of them loses its cache (it
/// recomputes, its results stay right). A symbolic link is removed, not
/// followed.
pub fn remove_older_formats(dir: &Path, dry_run: bool) -> io::Result<Vec<(PathBuf, u64)>> {
    let older = older_formats(dir);
    if !dry_run {
        for (path, _) in &older {
            let removed = if path.is_symlink() {
                std::fs::remove_file(path)
            } else {
                std::fs::remove_dir_all(path)
            };
            removed.map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
        }
    }
    Ok(older)
}

/// `n` bytes for people: `1.3 GiB`.
pub fn human_bytes(n: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut x = n as f64;
    let mut u = 0;
    while x >= 1024.0 && u + 1 < units.len() {
        x /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{x:.1} {}", units[u])
    }
}

/// "older formats v4 (21.5 GiB)" for [`older_formats`]' folders.
fn describe_older(older: &[(PathBuf, u64)]) -> String {
    let named: Vec<String> = older
        .iter()
        .map(|(path, bytes)| {
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            format!("{} ({})", name.unwrap_or_default(), human_bytes(*bytes))
        })
        .collect();
    format!("older formats {}", named.join(", "))
}

/// Apparent bytes of `path` and everything under it (folders included).
fn apparent_bytes(path: &Path) -> u64 {
    let Ok(meta) = std::fs::symlink_metadata(path) else {
        return 0;
    };
    let mut total = meta.len();
    if meta.is_dir()
        && let Ok(entries) = std::fs::read_dir(path)
    {
        total += entries
            .flatten()
            .map(|e| apparent_bytes(&e.path()))
            .sum::<u64>();
    }
    total
}

/// Every entry of the cache at `dir`.
fn entries(v: &Path) -> Vec<(PathBuf, EntryInfo)> {
    let mut out = Vec::new();
    let Ok(shards) = std::fs::read_dir(v) else {
        return out;
    };
    for shard in shards.flatten() {
        let name = shard.file_name().to_string_lossy().into_owned();
        if name.len() != 2 || !shard.path().is_dir() {
            continue;
        }
        for e in std::fs::read_dir(shard.path())
            .into_iter()
            .flatten()
            .flatten()
        {
            let path = e.path();
            let Some(key) = path
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(|n| n.strip_suffix(".entry"))
                .map(str::to_string)
            else {
                continue;
            };
            let Ok(meta) = e.metadata() else { continue };
            let files = v.join("files").join(&key);
            let info = EntryInfo {
                op: crate::cache::entry_op(&path).unwrap_or_else(|| "?".into()),
                bytes: meta.len() + apparent_bytes(&files),
                last_used: meta.modified().unwrap_or(SystemTime::UNIX_EPOCH),
                key,
            };
            out.push((path, info));
        }
    }
    out.sort_by(|a, b| {
        a.1.last_used
            .cmp(&b.1.last_used)
            .then(a.1.key.cmp(&b.1.key))
    });
    out
}

/// What is in the cache at `dir`.
pub fn stats(dir: &Path) -> io::Result<Stats> {
    let v = versioned(dir)?;
    let entries: Vec<EntryInfo> = entries(&v).into_iter().map(|(_, e)| e).collect();
    let mut by_op: BTreeMap<String, (usize, u64)> = BTreeMap::new();
    for e in &entries {
        let slot = by_op.entry(e.op.clone()).or_default();
        slot.0 += 1;
        slot.1 += e.bytes;
    }
    Ok(Stats {
        total_bytes: apparent_bytes(dir),
        entries,
        by_op,
        older_formats: older_formats(dir),
    })
}

/// What [`gc`] keeps.
#[derive(Debug, Clone, Copy, Default)]
pub struct GcLimits {
    /// Remove entries not used for this long.
    pub older_than: Option<Duration>,
    /// Remove the least recently used entries until the cache holds at most
    /// this many bytes (of entries and their files).
    pub max_bytes: Option<u64>,
    /// Never remove an entry used this recently.
    pub keep_recent: Duration,
    /// Only say what would be removed.
    pub dry_run: bool,
}

/// What [`gc`] did.
#[derive(Debug, Clone, Default)]
pub struct GcReport {
    /// Entries removed (or, in a dry run, that would be).
    pub removed: Vec<EntryInfo>,
    /// Bytes they held.
    pub removed_bytes: u64,
    /// Entries a live lease was computing, left alone.
    pub busy: usize,
    /// Entries over a limit but used within `keep_recent`, left alone.
    pub recent: usize,
}

/// Removes the least recently used entries of the cache at `dir` (and
/// their files) beyond `limits`; see the module doc for why it is safe
/// while other runs use the cache.
pub fn gc(dir: &Path, limits: GcLimits, now: SystemTime) -> io::Result<GcReport> {
    let v = versioned(dir)?;
    let all = entries(&v);
    let mut held: u64 = all.iter().map(|(_, e)| e.bytes).sum();
    let mut report = GcReport::default();
    for (path, info) in all {
        let age = now.duration_since(info.last_used).unwrap_or_default();
        let too_old = limits.older_than.is_some_and(|d| age > d);
        let too_big = limits.max_bytes.is_some_and(|m| held > m);
        if !too_old && !too_big {
            continue;
        }
        if age < limits.keep_recent {
            report.recent += 1;
            continue;
        }
        if limits.dry_run {
            held -= info.bytes;
            report.removed_bytes += info.bytes;
            report.removed.push(info);
            continue;
        }
        let lease_path = v.join("leases").join(format!("{}.lease", info.key));
        let lease = match try_acquire(&lease_path)? {
            Acquired::Held(lease) => lease,
            Acquired::Busy => {
                report.busy += 1;
                continue;
            }
        };
        // Read again under the lease: a run may have used it meanwhile.
        let used_since = std::fs::metadata(&path)
            .and_then(|m| m.modified())
            .is_ok_and(|t| t > info.last_used);
        if used_since {
            report.recent += 1;
            drop(lease);
            continue;
        }
        // The entry first: a run looking it up then misses and recomputes,
        // never finds an entry whose files are gone.
        match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(io::Error::new(e.kind(), format!("{}: {e}", path.display()))),
        }
        let files = v.join("files").join(&info.key);
        if files.exists() {
            std::fs::remove_dir_all(&files)
                .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", files.display())))?;
        }
        drop(lease);
        held -= info.bytes;
        report.removed_bytes += info.bytes;
        report.removed.push(info);
    }
    Ok(report)
}

/// What [`verify`] found wrong.
#[derive(Debug, Clone, Default)]
pub struct VerifyReport {
    /// Entries checked.
    pub checked: usize,
    /// Entries that fail their checksum, length or key test, and why.
    pub corrupt: Vec<(PathBuf, String)>,
    /// Files folders without an entry.
    pub orphans: Vec<PathBuf>,
    /// Leases whose owner is gone.
    pub stale_leases: Vec<PathBuf>,
    /// Temporary files and folders that dead runs left.
    pub stale_temporaries: Vec<PathBuf>,
    /// Whether they were removed (`repair`).
    pub repaired: bool,
}

impl VerifyReport {
    /// Whether nothing is wrong.
    pub fn clean(&self) -> bool {
        self.corrupt.is_empty()
            && self.orphans.is_empty()
            && self.stale_leases.is_empty()
            && self.stale_temporaries.is_empty()
    }
}

/// The age after which an atomic write's temporary file (`.<name>.<pid>.<n>.tmp`,
/// which names no host, so a pid cannot be checked on a shared cache) is
/// taken as left by a dead run: no write takes this long.
const ABANDONED_WRITE: Duration = Duration::from_secs(3600);

/// Whether the file or folder at `path` (named `name`) is a temporary a
/// dead run left: a node's files folder `.tmp-<key>-<host>-<pid>-<n>` of
/// this host whose process is gone, or an atomic write's temporary file
/// older than [`ABANDONED_WRITE`].
fn dead_temporary(path: &Path, name: &str) -> bool {
    if name.starts_with(".tmp-") {
        return crate::workdir::left_by_dead_run(name, ".tmp-");
    }
    name.starts_with('.')
        && name.ends_with(".tmp")
        && std::fs::metadata(path)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age > ABANDONED_WRITE)
}

/// Checks every entry of the cache at `dir` (length, checksum, key), and
/// finds files folders without an entry, leases of dead owners and
/// temporaries of dead runs; `repair` removes what it found.
pub fn verify(dir: &Path, repair: bool) -> io::Result<VerifyReport> {
    let v = versioned(dir)?;
    let mut report = VerifyReport {
        repaired: repair,
        ..Default::default()
    };
    let cache = crate::cache::DiskCache::open(dir)?;
    let found = entries(&v);
    let keys: std::collections::BTreeSet<String> =
        found.iter().map(|(_, e)| e.key.clone()).collect();
    for (path, info) in &found {
        report.checked += 1;
        let Some(key) = crate::key::NodeKey::from_hex(&info.key) else {
            report
                .corrupt
                .push((path.clone(), "its name is not a key".into()));
            continue;
        };
        if let Some(why) = cache.check(&key) {
            report.corrupt.push((path.clone(), why));
        }
    }
    for e in std::fs::read_dir(v.join("files"))
        .into_iter()
        .flatten()
        .flatten()
    {
        let name = e.file_name().to_string_lossy().into_owned();
        if dead_temporary(&e.path(), &name) {
            report.stale_temporaries.push(e.path());
        } else if !name.starts_with('.') && !keys.contains(&name) {
            report.orphans.push(e.path());
        }
    }
    for e in std::fs::read_dir(v.join("leases"))
        .into_iter()
        .flatten()
        .flatten()
    {
        if crate::lease::is_stale(&e.path()) {
            report.stale_leases.push(e.path());
        }
    }
    for shard in std::fs::read_dir(&v).into_iter().flatten().flatten() {
        if shard.file_name().len() != 2 {
            continue;
        }
        for e in std::fs::read_dir(shard.path())
            .into_iter()
            .flatten()
            .flatten()
        {
            if dead_temporary(&e.path(), &e.file_name().to_string_lossy()) {
                report.stale_temporaries.push(e.path());
            }
        }
    }
    if repair {
        for (p, _) in &report.corrupt {
            let _ = std::fs::remove_file(p);
        }
        for p in report.orphans.iter().chain(&report.stale_temporaries) {
            let _ = if p.is_dir() {
                std::fs::remove_dir_all(p)
            } else {
                std::fs::remove_file(p)
            };
        }
        for p in &report.stale_leases {
            let _ = std::fs::remove_file(p);
        }
    }
    Ok(report)
}

/// `30d`, `12h`, `90m`, `45s` (or plain seconds) as a duration.
pub fn parse_age(text: &str) -> Result<Duration, String> {
    let t = text.trim();
    let (number, unit) = t.split_at(t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len()));
    let n: f64 = number
        .trim()
        .parse()
        .map_err(|_| format!("{text:?}: expected a number and a unit, e.g. 30d, 12h, 90m"))?;
    let secs = match unit {
        "" | "s" => 1.0,
        "m" => 60.0,
        "h" => 3600.0,
        "d" => 86_400.0,
        "w" => 7.0 * 86_400.0,
        _ => return Err(format!("{text:?}: unit {unit:?}; one of s, m, h, d, w")),
    };
    if !(n.is_finite() && n >= 0.0) {
        return Err(format!("{text:?}: must be a non-negative duration"));
    }
    Ok(Duration::from_secs_f64(n * secs))
}

/// `10G`, `500M`, `64K`, `1T` (binary: GiB ...) or plain bytes.
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text
        .trim()
        .trim_end_matches(['B', 'b'])
        .trim_end_matches('i');
    let (number, unit) = t.split_at(t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len()));
    let n: f64 = number
        .trim()
        .parse()
        .map_err(|_| format!("{text:?}: expected a size, e.g. 10G, 500M"))?;
    let scale = match unit.to_ascii_uppercase().as_str() {
        "" => 1u64,
        "K" => 1 << 10,
        "M" => 1 << 20,
        "G" => 1 << 30,
        "T" => 1 << 40,
        _ => return Err(format!("{text:?}: unit {unit:?}; one of K, M, G, T")),
    };
    if !(n.is_finite() && n >= 0.0) {
        return Err(format!("{text:?}: must be a non-negative size"));
    }
    Ok((n * scale as f64) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn older_formats_are_named_with_their_size_and_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        let old = dir.path().join("v1");
        std::fs::create_dir_all(old.join("ab")).unwrap();
        std::fs::write(old.join("ab").join("x.entry"), [0u8; 1000]).unwrap();
        std::fs::create_dir_all(dir.path().join("notes")).unwrap();
        let why = stats(dir.path()).unwrap_err().to_string();
        assert!(why.contains("no fusegraph cache (format v"), "{why}");
        assert!(why.contains("only older formats v1 ("), "{why}");
        std::fs::create_dir_all(dir.path().join(format!("v{FORMAT_VERSION}"))).unwrap();
        let s = stats(dir.path()).unwrap();
        assert_eq!(s.older_formats.len(), 1);
        assert_eq!(s.older_formats[0].0, old);
        assert!(s.older_formats[0].1 >= 1000);
        let report = gc(
            dir.path(),
            GcLimits {
                max_bytes: Some(0),
                ..Default::default()
            },
            SystemTime::now(),
        )
        .unwrap();
        assert!(report.removed.is_empty());
        assert!(old.join("ab").join("x.entry").exists());
        // Removed only when asked, and never the current format's folder.
        let listed = remove_older_formats(dir.path(), true).unwrap();
        assert_eq!(listed, s.older_formats);
        assert!(old.exists());
        let removed = remove_older_formats(dir.path(), false).unwrap();
        assert_eq!(removed, s.older_formats);
        assert!(!old.exists());
        assert!(dir.path().join(format!("v{FORMAT_VERSION}")).exists());
        assert!(dir.path().join("notes").exists());
        assert!(remove_older_formats(dir.path(), false).unwrap().is_empty());
    }

    #[test]
    fn ages_and_sizes_parse_with_their_units() {
        assert_eq!(parse_age("30d").unwrap(), Duration::from_secs(30 * 86_400));
        assert_eq!(parse_age("90m").unwrap(), Duration::from_secs(5400));
        assert_eq!(parse_age("12").unwrap(), Duration::from_secs(12));
        assert!(parse_age("3 fortnights").is_err());
        assert!(parse_age("-1d").is_err());
        assert_eq!(parse_size("10G").unwrap(), 10 << 30);
        assert_eq!(parse_size("500MiB").unwrap(), 500 << 20);
        assert_eq!(parse_size("1024").unwrap(), 1024);
        assert!(parse_size("10X").is_err());
    }

    #[test]
    fn temporaries_of_dead_processes_are_recognised() {
        let dir = tempfile::tempdir().unwrap();
        let host = crate::process::host_name();
        // pid 4194304 is above Linux's largest (2^22): never alive.
        let dead = format!(".tmp-ab12-{host}-4194304-0");
        assert!(dead_temporary(&dir.path().join(&dead), &dead));
        let mine = format!(".tmp-ab12-{host}-{}-0", std::process::id());
        assert!(!dead_temporary(&dir.path().join(&mine), &mine));
        // An atomic write's temporary: judged by its age, not its pid.
        let write = dir.path().join(".abc.entry.4194304.7.tmp");
        let f = std::fs::File::create(&write).unwrap();
        assert!(!dead_temporary(&write, ".abc.entry.4194304.7.tmp"));
        f.set_modified(SystemTime::now() - 2 * ABANDONED_WRITE)
            .unwrap();
        assert!(dead_temporary(&write, ".abc.entry.4194304.7.tmp"));
        assert!(!dead_temporary(
            &dir.path().join("ab12cd.entry"),
            "ab12cd.entry"
        ));
    }
}
