//! Content-addressed folders for files that ops produce (a generated DICOM
//! series, rendered images). An op writes into a private temporary folder; when it
//! succeeds the folder is renamed to `files_root/<node key>`, and its `Path`
//! outputs are rewritten to point there. Concurrent runs producing the same key
//! keep whichever folder landed first when its content matches.

use crate::op::{OpError, Outputs};
use crate::process::{host_name, process_alive};
use crate::value::{PathValue, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// Removes the temporary folders under `files_root` that this machine's
/// processes left when they died mid-run (kill -9, power loss): a folder
/// `.tmp-<key>-<host>-<pid>-<n>` of this host whose pid is gone. Returns how
/// many it removed.
pub fn clean_stale_temps(files_root: &Path) -> usize {
    clean_stale(files_root, ".tmp-")
}

/// A folder name private to this process: `<prefix><key>-<host>-<pid>-<n>`,
/// as [`clean_stale`] parses it.
fn private_name(prefix: &str, key_hex: &str) -> String {
    format!(
        "{prefix}{key_hex}-{}-{}-{}",
        host_name(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// Removes `<prefix><key>-<host>-<pid>-<n>` folders under `dir` that dead
/// processes of this host left.
fn clean_stale(dir: &Path, prefix: &str) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if left_by_dead_run(&name, prefix) && std::fs::remove_dir_all(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Whether `name` is a private folder `<prefix><key>-<host>-<pid>-<n>` of
/// this host whose process is gone (another host's are never judged here).
pub fn left_by_dead_run(name: &str, prefix: &str) -> bool {
    let Some(rest) = name.strip_prefix(prefix) else {
        return false;
    };
    // <key>-<host>-<pid>-<n>; the host may hold '-' only as '_'.
    let parts: Vec<&str> = rest.split('-').collect();
    let [_key, h, pid, _n] = parts[..] else {
        return false;
    };
    let Ok(pid) = pid.parse::<u32>() else {
        return false;
    };
    h == host_name() && pid != std::process::id() && !process_alive(pid)
}

/// A node's files folder: a temporary location while it runs, a final one after.
#[derive(Debug)]
pub struct WorkDir {
    temp: PathBuf,
    final_dir: PathBuf,
    created: bool,
    key_hex: String,
    /// Where to go when `files_root` cannot be written (a read-only cache).
    fallback_root: Option<PathBuf>,
    /// Why the fallback was taken, once it was.
    fell_back: Option<String>,
}

impl WorkDir {
    /// The folder for key `key_hex` under `files_root` (not created yet).
    pub fn new(files_root: &Path, key_hex: &str) -> Self {
        // Absolute, because `Path` values are absolute and are matched against it.
        let files_root =
            std::path::absolute(files_root).unwrap_or_else(|_| files_root.to_path_buf());
        WorkDir {
            temp: Self::temp_under(&files_root, key_hex),
            final_dir: files_root.join(key_hex),
            created: false,
            key_hex: key_hex.to_string(),
            fallback_root: None,
            fell_back: None,
        }
    }

    /// Writes under `root` instead when the files root cannot be written.
    pub fn with_fallback(mut self, root: &Path) -> Self {
        self.fallback_root = Some(std::path::absolute(root).unwrap_or_else(|_| root.to_path_buf()));
        self
    }

    /// Why the files went to the fallback folder, if they did.
    pub fn fell_back(&self) -> Option<&str> {
        self.fell_back.as_deref()
    }

    fn temp_under(root: &Path, key_hex: &str) -> PathBuf {
        root.join(private_name(".tmp-", key_hex))
    }

    /// Creates the temporary folder (once) and returns it. Where the files
    /// root cannot be written and a fallback is set, the folder goes there.
    pub fn create(&mut self) -> Result<PathBuf, OpError> {
        if !self.created
            && let Err(e) = std::fs::create_dir_all(&self.temp)
            && let Some(root) = self.fallback_root.take()
        {
            self.fell_back = Some(format!(
                "{}: {e}; its files are kept in {} instead",
                self.temp.parent().unwrap_or(&self.temp).display(),
                root.display()
            ));
            self.temp = Self::temp_under(&root, &self.key_hex);
            self.final_dir = root.join(&self.key_hex);
        }
        if !self.created {
            if self.temp.exists() {
                std::fs::remove_dir_all(&self.temp).map_err(|e| OpError::io(&self.temp, e))?;
            }
            std::fs::create_dir_all(&self.temp).map_err(|e| OpError::io(&self.temp, e))?;
            self.created = true;
        }
        Ok(self.temp.clone())
    }

    /// Removes the temporary folder (after a failure).
    pub fn discard(self) {
        if self.created {
            let _ = std::fs::remove_dir_all(&self.temp);
        }
    }

    /// Moves the folder to its final place and points `outputs` there.
    pub fn finalize(self, outputs: &mut Outputs) -> Result<(), OpError> {
        if !self.created {
            return Ok(());
        }
        let rewritten = rewrite(outputs, &self.temp, &self.final_dir);
        if let Some(parent) = self.final_dir.parent() {
            std::fs::create_dir_all(parent).map_err(|e| OpError::io(parent, e))?;
        }
        match std::fs::rename(&self.temp, &self.final_dir) {
            Ok(()) => {
                *outputs = rewritten;
                return Ok(());
            }
            Err(e) if !self.final_dir.exists() => return Err(OpError::io(&self.final_dir, e)),
            Err(_) => {}
        }
        // Another run (or an earlier one) left this key's folder. Keep it if it
        // holds what we produced; otherwise swap ours in.
        let matches = outputs_hold(&rewritten);
        if !matches {
            let trash = self
                .final_dir
                .with_extension(format!("old-{}", COUNTER.fetch_add(1, Ordering::Relaxed)));
            std::fs::rename(&self.final_dir, &trash)
                .map_err(|e| OpError::io(&self.final_dir, e))?;
            std::fs::rename(&self.temp, &self.final_dir)
                .map_err(|e| OpError::io(&self.final_dir, e))?;
            let _ = std::fs::remove_dir_all(&trash);
        } else {
            let _ = std::fs::remove_dir_all(&self.temp);
        }
        *outputs = rewritten;
        Ok(())
    }
}

/// A private folder an op writes into while it runs: moved into place with
/// its `Path` outputs when the op succeeds, removed when it fails.
pub trait Settle: Sized {
    /// Moves the files into place and points `outputs` there.
    fn finalize(self, outputs: &mut Outputs) -> Result<(), OpError>;
    /// Removes what was written.
    fn discard(self);
}

impl Settle for WorkDir {
    fn finalize(self, outputs: &mut Outputs) -> Result<(), OpError> {
        WorkDir::finalize(self, outputs)
    }
    fn discard(self) {
        WorkDir::discard(self)
    }
}

impl Settle for Staging {
    fn finalize(self, outputs: &mut Outputs) -> Result<(), OpError> {
        self.publish(outputs)
    }
    fn discard(self) {
        Staging::discard(self)
    }
}

/// An op's result after settling its private folder, if it had one: moved
/// into place on success (a failure to move fails the op), removed on failure.
pub fn settle<P: Settle>(
    result: Result<Outputs, String>,
    place: Option<P>,
) -> Result<Outputs, String> {
    match (result, place) {
        (Ok(mut outputs), Some(place)) => place
            .finalize(&mut outputs)
            .map(|()| outputs)
            .map_err(|e| e.to_string()),
        (Err(e), Some(place)) => {
            place.discard();
            Err(e)
        }
        (result, None) => result,
    }
}

/// A sink's private output folder, `OUT/.staging-<key>-<host>-<pid>-<n>`:
/// the sink writes there, and only when it succeeds are its files renamed
/// into the output folder, each whole (a full disk or a failure leaves no
/// partial file under a sink's name).
#[derive(Debug)]
pub struct Staging {
    dir: PathBuf,
    out_dir: PathBuf,
}

impl Staging {
    /// A staging folder for the sink of key `key_hex` (created when written).
    pub fn new(out_dir: &Path, key_hex: &str) -> Self {
        let out_dir = std::path::absolute(out_dir).unwrap_or_else(|_| out_dir.to_path_buf());
        let dir = out_dir.join(private_name(".staging-", key_hex));
        Staging { dir, out_dir }
    }

    /// Where the sink writes.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Renames every file written into its place under the output folder and
    /// points `outputs` there.
    pub fn publish(self, outputs: &mut Outputs) -> Result<(), OpError> {
        let result = move_files(&self.dir, &self.dir, &self.out_dir);
        if result.is_ok() {
            *outputs = rewrite(outputs, &self.dir, &self.out_dir);
        }
        let _ = std::fs::remove_dir_all(&self.dir);
        result
    }

    /// Removes what the sink wrote (after a failure).
    pub fn discard(self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }

    /// Removes staging folders that dead processes of this host left in
    /// `out_dir`.
    pub fn clean_stale(out_dir: &Path) -> usize {
        clean_stale(out_dir, ".staging-")
    }
}

/// Renames the files under `dir` (recursively) from `root` to `to`.
fn move_files(dir: &Path, root: &Path, to: &Path) -> Result<(), OpError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(()); // the sink wrote nothing
    };
    for entry in entries {
        let path = entry.map_err(|e| OpError::io(dir, e))?.path();
        if path.is_dir() {
            move_files(&path, root, to)?;
            continue;
        }
        let target = to.join(path.strip_prefix(root).expect("under the staging folder"));
        if let Some(parent) = target.parent() {
            std::fs::create_dir_all(parent).map_err(|e| OpError::io(parent, e))?;
        }
        std::fs::rename(&path, &target).map_err(|e| OpError::io(&target, e))?;
    }
    Ok(())
}

/// `outputs` with every `Path` under `from` moved under `to`.
fn rewrite(outputs: &Outputs, from: &Path, to: &Path) -> Outputs {
    let mut out = outputs.clone();
    for value in out.0.values_mut() {
        if let Value::Path(p) = value
            && let Ok(rel) = p.path.strip_prefix(from)
        {
            *value = PathValue {
                path: to.join(rel),
                content_hash: p.content_hash.clone(),
            }
            .into();
        }
    }
    out
}

/// Whether every `Path` output holds its recorded content.
fn outputs_hold(outputs: &Outputs) -> bool {
    outputs.paths_intact().is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn staged_files_appear_whole_on_success_and_not_at_all_on_failure() {
        let out = tempfile::tempdir().unwrap();
        let write = |s: &Staging| {
            let f = s.dir().join("mesh/skin.ply");
            std::fs::create_dir_all(f.parent().unwrap()).unwrap();
            std::fs::write(&f, "ply").unwrap();
            f
        };
        let failed = Staging::new(out.path(), "ab");
        write(&failed);
        failed.discard();
        assert!(!out.path().join("mesh/skin.ply").exists());
        let good = Staging::new(out.path(), "ab");
        let staged = write(&good);
        let mut outputs = Outputs::new().with(
            "file",
            PathValue {
                path: staged,
                content_hash: "h".into(),
            },
        );
        good.publish(&mut outputs).unwrap();
        let final_path = std::path::absolute(out.path().join("mesh/skin.ply")).unwrap();
        assert_eq!(std::fs::read_to_string(&final_path).unwrap(), "ply");
        match &outputs.0["file"] {
            Value::Path(p) => assert_eq!(p.path, final_path),
            other => panic!("{other:?}"),
        }
        let left: Vec<_> = std::fs::read_dir(out.path()).unwrap().flatten().collect();
        assert_eq!(left.len(), 1, "only mesh/ remains: {left:?}");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn only_this_hosts_dead_processes_temps_are_cleaned() {
        let root = tempfile::tempdir().unwrap();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let host = host_name();
        let names = [
            format!(".tmp-ab12-{host}-{dead}-0"),
            format!(".tmp-ab12-{host}-{}-0", std::process::id()),
            format!(".tmp-ab12-otherhost-{dead}-0"),
            "ab12".to_string(),
        ];
        for n in &names {
            std::fs::create_dir_all(root.path().join(n).join("mri")).unwrap();
        }
        assert_eq!(clean_stale_temps(root.path()), 1);
        assert!(!root.path().join(&names[0]).exists());
        for n in &names[1..] {
            assert!(root.path().join(n).exists(), "{n}");
        }
    }
}
