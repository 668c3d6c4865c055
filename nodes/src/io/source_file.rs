//! Which file a reader op reads: a `dir` input with a `file` name (or a glob
//! pattern matching exactly one file there, e.g. `left_00.*` for a camera
//! that writes PNG or JPEG), or a `path` (shared by `io.read_image`,
//! `io.read_markers`, `io.read_disparity`).

use fusegraph_engine::op::exactly_one_source;
use fusegraph_engine::value::PathValue;
use fusegraph_engine::{OpError, Wired};
use fusegraph_plugin_api::derive::{Inputs, Params};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The parameters naming a reader's file, flattened first into the op:
/// `file` (inside the `dir` input) or `path`; [`SourceFile::resolve`] picks.
#[derive(Debug, Clone, PartialEq, Params)]
pub struct SourceFile {
    /// File name inside `dir`, or a glob pattern (`*`, `?`, `[..]`) that
    /// matches exactly one file there
    #[param(default = "")]
    pub file: String,
    /// File, relative to the graph (instead of dir + file)
    pub path: Option<PathBuf>,
}

/// A reader op's inputs: the folder its file is in, if any.
#[derive(Inputs)]
pub struct SourceDir {
    /// Folder the file is in (else relative to the graph)
    pub dir: Option<Arc<PathValue>>,
}

impl SourceFile {
    /// The file to read: the `path` parameter, or the `dir` input joined with
    /// the `file` parameter (exactly one of the two).
    pub fn resolve(&self, dir: Option<&PathValue>) -> Result<PathBuf, OpError> {
        match (&self.path, dir) {
            (Some(p), None) => Ok(p.clone()),
            (None, Some(d)) if is_pattern(&self.file) => only_match(&d.path, &self.file),
            (None, Some(d)) => Ok(d.path.join(&self.file)),
            _ => Err(OpError::invalid(
                "give the `path` parameter, or the `dir` input and the `file` parameter",
            )),
        }
    }
}

impl SourceFile {
    /// What [`SourceFile::resolve`] would refuse, found at validation from the
    /// parameters and whether the `dir` input is connected.
    pub fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        let dir = wired.has("dir");
        if !dir && self.path.is_none() && !self.file.is_empty() {
            let problem = "`file` names a file inside the `dir` input, which is not connected: \
                           connect `in.dir`, or give `path` (relative to the graph)";
            return vec![("file", problem.into())];
        }
        let mut problems: Vec<_> =
            exactly_one_source(&[("path", self.path.is_some()), ("in.dir", dir)])
                .into_iter()
                .collect();
        if dir && self.file.is_empty() {
            problems.push((
                "file",
                "the file's name inside the `dir` input is missing".into(),
            ));
        }
        if is_pattern(&self.file)
            && let Err(e) = glob::Pattern::new(&self.file)
        {
            problems.push(("file", format!("not a glob pattern: {e}")));
        }
        if self.path.is_some() && !self.file.is_empty() {
            problems.push((
                "file",
                "`file` names a file inside the `dir` input; with `path`, leave it out".into(),
            ));
        }
        problems
    }
}

/// Whether a `file` is a glob pattern rather than a name.
fn is_pattern(file: &str) -> bool {
    file.contains(['*', '?', '['])
}

/// The one file of `dir` whose name matches `pattern`; none or several is an
/// error naming the folder (and the matches).
fn only_match(dir: &Path, pattern: &str) -> Result<PathBuf, OpError> {
    let glob = glob::Pattern::new(pattern)
        .map_err(|e| OpError::invalid(format!("file: `{pattern}` is not a glob pattern: {e}")))?;
    let entries =
        std::fs::read_dir(dir).map_err(|e| OpError::invalid(format!("{}: {e}", dir.display())))?;
    let mut matches: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| glob.matches(&n.to_string_lossy()))
        })
        .collect();
    matches.sort();
    match matches.len() {
        1 => Ok(matches.remove(0)),
        0 => Err(OpError::invalid(format!(
            "file: no file in {} matches `{pattern}`",
            dir.display()
        ))),
        n => Err(OpError::invalid(format!(
            "file: `{pattern}` matches {n} files in {} ({}); name one",
            dir.display(),
            matches
                .iter()
                .filter_map(|p| p.file_name())
                .map(|n| n.to_string_lossy())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pattern_must_match_exactly_one_file() {
        let d = tempfile::tempdir().unwrap();
        for name in ["left_00.jpg", "left_01.png", "left_01.jpg"] {
            std::fs::write(d.path().join(name), b"x").unwrap();
        }
        let dir = PathValue {
            path: d.path().to_path_buf(),
            content_hash: String::new(),
        };
        let source = |file: &str| SourceFile {
            file: file.into(),
            path: None,
        };
        assert_eq!(
            source("left_00.*").resolve(Some(&dir)).unwrap(),
            d.path().join("left_00.jpg")
        );
        let several = source("left_01.*")
            .resolve(Some(&dir))
            .unwrap_err()
            .to_string();
        assert!(
            several.contains("matches 2 files") && several.contains("left_01.jpg, left_01.png")
        );
        let none = source("left_02.*")
            .resolve(Some(&dir))
            .unwrap_err()
            .to_string();
        assert!(
            none.contains("no file in") && none.contains("left_02.*"),
            "{none}"
        );
        let bad = source("left_[.png").check(Wired::new(&["dir"]));
        assert!(
            bad.iter().any(|(k, p)| *k == "file" && p.contains("glob")),
            "{bad:?}"
        );
    }

    #[test]
    fn the_path_or_the_folder_and_name_but_not_both() {
        let dir = PathValue {
            path: PathBuf::from("/data"),
            content_hash: String::new(),
        };
        let by_path = SourceFile {
            file: String::new(),
            path: Some(PathBuf::from("/x/a.png")),
        };
        let by_name = SourceFile {
            file: "b.png".into(),
            path: None,
        };
        assert_eq!(by_path.resolve(None).unwrap(), PathBuf::from("/x/a.png"));
        assert_eq!(
            by_name.resolve(Some(&dir)).unwrap(),
            PathBuf::from("/data/b.png")
        );
        for e in [by_path.resolve(Some(&dir)), by_name.resolve(None)] {
            assert!(e.unwrap_err().to_string().contains("give the `path`"));
        }
    }
}
