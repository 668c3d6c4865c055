//! Content-addressed folders for files that ops produce (a generated DICOM
//! series, rendered images). An op writes into a private temporary folder; when it
//! succeeds the folder is renamed to `files_root/<node key>`, and its `Path`
//! outputs are rewritten to point there. Concurrent runs producing the same key
//! keep whichever folder landed first when its content matches.

use crate::op::{OpError, Outputs};
use crate::value::{PathValue, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// A node's files folder: a temporary location while it runs, a final one after.
#[derive(Debug)]
pub struct WorkDir {
    temp: PathBuf,
    final_dir: PathBuf,
    created: bool,
}

impl WorkDir {
    /// The folder for key `key_hex` under `files_root` (not created yet).
    pub fn new(files_root: &Path, key_hex: &str) -> Self {
        // Absolute, because `Path` values are absolute and are matched against it.
        let files_root =
            std::path::absolute(files_root).unwrap_or_else(|_| files_root.to_path_buf());
        let temp = files_root.join(format!(
            ".tmp-{key_hex}-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        WorkDir {
            temp,
            final_dir: files_root.join(key_hex),
            created: false,
        }
    }

    /// Creates the temporary folder (once) and returns it.
    pub fn create(&mut self) -> Result<PathBuf, OpError> {
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
    crate::cache::CacheEntry {
        outputs: outputs.clone(),
        ..Default::default()
    }
    .paths_intact()
    .is_ok()
}
