//! Which file a reader op reads: a `dir` input with a `file` name, or a
//! `path` (shared by `io.read_image`, `io.read_markers`, `io.read_disparity`).

use fusegraph_engine::op::exactly_one_source;
use fusegraph_engine::value::PathValue;
use fusegraph_engine::{OpError, Wired};
use fusegraph_plugin_api::derive::{Inputs, Params};
use std::path::PathBuf;
use std::sync::Arc;

/// The parameters naming a reader's file, flattened first into the op:
/// `file` (inside the `dir` input) or `path`; [`SourceFile::resolve`] picks.
#[derive(Debug, Clone, PartialEq, Params)]
pub struct SourceFile {
    /// File name (inside `dir` when connected)
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
        if self.path.is_some() && !self.file.is_empty() {
            problems.push((
                "file",
                "`file` names a file inside the `dir` input; with `path`, leave it out".into(),
            ));
        }
        problems
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
