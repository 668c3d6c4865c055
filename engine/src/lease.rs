//! Leases on cache keys across processes (and, on a shared filesystem, across
//! machines): the first run to need a key takes its lease, a file
//! `CACHE/vN/leases/<key>.lease` holding its host and pid, created with
//! `create_new` so exactly one process gets it. The others wait, then reuse
//! the entry it stores. A lease is stale when its owner is gone: on this host
//! when its pid no longer runs; from another host when it is older than
//! [`FOREIGN_STALE`] (a pid there cannot be checked), so a machine that died
//! does not block the others for long.

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The age after which another host's lease is taken as stale.
pub const FOREIGN_STALE: Duration = Duration::from_secs(600);

/// A held lease; dropping it releases it.
#[derive(Debug)]
pub struct Lease {
    path: PathBuf,
}

impl Drop for Lease {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Whether the lease was taken or another live owner holds it.
#[derive(Debug)]
pub enum Acquired {
    /// This process holds it.
    Held(Lease),
    /// Another live process holds it.
    Busy,
}

/// Tries to take the lease at `path` (a stale one is removed and retaken).
pub fn try_acquire(path: &Path) -> io::Result<Acquired> {
    for _ in 0..3 {
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
        {
            Ok(mut f) => {
                writeln!(f, "{} {}", crate::workdir::host_name(), std::process::id())?;
                return Ok(Acquired::Held(Lease {
                    path: path.to_path_buf(),
                }));
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                if !is_stale(path) {
                    return Ok(Acquired::Busy);
                }
                let _ = std::fs::remove_file(path);
            }
            // The leases folder is made on first use, not stat-ed every time.
            Err(e) if e.kind() == io::ErrorKind::NotFound => match path.parent() {
                Some(parent) => std::fs::create_dir_all(parent)?,
                None => return Err(e),
            },
            Err(e) => return Err(e),
        }
    }
    Ok(Acquired::Busy)
}

/// Whether the lease at `path` has no live owner.
fn is_stale(path: &Path) -> bool {
    let Ok(text) = std::fs::read_to_string(path) else {
        return false; // being written, or just released
    };
    let mut words = text.split_whitespace();
    match (
        words.next(),
        words.next().and_then(|p| p.parse::<u32>().ok()),
    ) {
        (Some(host), Some(pid)) if host == crate::workdir::host_name() => {
            !crate::workdir::process_alive(pid)
        }
        _ => std::fs::metadata(path)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age > FOREIGN_STALE),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_holder_at_a_time_and_a_dead_owner_is_replaced() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("leases/ab.lease");
        let first = try_acquire(&path).unwrap();
        assert!(matches!(first, Acquired::Held(_)));
        assert!(matches!(try_acquire(&path).unwrap(), Acquired::Busy));
        drop(first);
        assert!(!path.exists(), "released on drop");
        #[cfg(target_os = "linux")]
        {
            let mut child = std::process::Command::new("true").spawn().unwrap();
            let dead = child.id();
            child.wait().unwrap();
            std::fs::write(&path, format!("{} {dead}\n", crate::workdir::host_name())).unwrap();
            assert!(matches!(try_acquire(&path).unwrap(), Acquired::Held(_)));
        }
    }
}
