//! Leases on cache keys across processes (and, on a shared filesystem, across
//! machines): the first run to need a key takes its lease, a file
//! `CACHE/vN/leases/<key>.lease` holding its host and pid, created with
//! `create_new` so exactly one process gets it. The others wait, then reuse
//! the entry it stores. A lease is stale when its owner is gone: on this host
//! when its pid no longer runs; from another host (a pid there cannot be
//! checked) when its owner has not renewed it for [`FOREIGN_STALE`]. Owners
//! renew their leases every [`HEARTBEAT`] by setting the file's modification
//! time, so a computation may run for hours on one machine while a machine
//! that died blocks the others for two minutes at most. This assumes the
//! hosts' clocks agree to well within that (NTP, as on any cluster).

use std::collections::BTreeSet;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, SystemTime};

/// How often a process renews the leases it holds.
pub const HEARTBEAT: Duration = Duration::from_secs(20);

/// The time without renewal after which another host's lease is stale: six
/// missed heartbeats.
pub const FOREIGN_STALE: Duration = Duration::from_secs(120);

/// How long a run waits for a live owner's entry before computing the key
/// itself (the result is the same; only the time is spent twice).
pub const WAIT_LIMIT: Duration = Duration::from_secs(1800);

/// The leases this process holds, renewed by one heartbeat thread.
fn held() -> &'static Mutex<BTreeSet<PathBuf>> {
    static HELD: OnceLock<Mutex<BTreeSet<PathBuf>>> = OnceLock::new();
    HELD.get_or_init(|| {
        let spawned = std::thread::Builder::new()
            .name("fusegraph-lease-heartbeat".into())
            .spawn(|| {
                loop {
                    std::thread::sleep(HEARTBEAT);
                    renew_held();
                }
            });
        if let Err(e) = spawned {
            // Leases still work; another host may take one after FOREIGN_STALE.
            tracing::warn!("no lease heartbeat thread: {e}");
        }
        Mutex::new(BTreeSet::new())
    })
}

fn held_set() -> std::sync::MutexGuard<'static, BTreeSet<PathBuf>> {
    held()
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Sets the modification time of every lease this process holds to now.
pub fn renew_held() {
    let paths: Vec<PathBuf> = held_set().iter().cloned().collect();
    for path in paths {
        // Opened without `create`: a lease released meanwhile stays gone.
        let renewed = std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .and_then(|f| f.set_modified(SystemTime::now()));
        if let Err(e) = renewed {
            tracing::debug!("lease {}: not renewed: {e}", path.display());
        }
    }
}

/// A held lease; dropping it releases it.
#[derive(Debug)]
pub struct Lease {
    path: PathBuf,
}

impl Drop for Lease {
    fn drop(&mut self) {
        held_set().remove(&self.path);
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
                writeln!(f, "{} {}", crate::process::host_name(), std::process::id())?;
                held_set().insert(path.to_path_buf());
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
pub fn is_stale(path: &Path) -> bool {
    let Ok(text) = std::fs::read_to_string(path) else {
        return false; // being written, or just released
    };
    let mut words = text.split_whitespace();
    match (
        words.next(),
        words.next().and_then(|p| p.parse::<u32>().ok()),
    ) {
        (Some(host), Some(pid)) if host == crate::process::host_name() => {
            !crate::process::process_alive(pid)
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
            std::fs::write(&path, format!("{} {dead}\n", crate::process::host_name())).unwrap();
            assert!(matches!(try_acquire(&path).unwrap(), Acquired::Held(_)));
        }
    }

    fn set_age(path: &Path, age: Duration) {
        let f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
        f.set_modified(SystemTime::now() - age).unwrap();
    }

    #[test]
    fn another_hosts_lease_is_stale_only_when_not_renewed() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("cd.lease");
        std::fs::write(&path, "another-host 1\n").unwrap();
        assert!(matches!(try_acquire(&path).unwrap(), Acquired::Busy));
        set_age(&path, FOREIGN_STALE - HEARTBEAT);
        assert!(matches!(try_acquire(&path).unwrap(), Acquired::Busy));
        set_age(&path, FOREIGN_STALE + HEARTBEAT);
        let Acquired::Held(lease) = try_acquire(&path).unwrap() else {
            panic!("a stale foreign lease is taken over")
        };
        // What we hold is renewed, so other hosts keep seeing it alive.
        set_age(&path, FOREIGN_STALE + HEARTBEAT);
        renew_held();
        let age = std::fs::metadata(&path)
            .unwrap()
            .modified()
            .unwrap()
            .elapsed();
        assert!(age.as_ref().is_ok_and(|a| *a < HEARTBEAT), "{age:?}");
        drop(lease);
        renew_held();
        assert!(!path.exists(), "a released lease is not recreated");
    }
}
