//! Errors in a graph file, found before anything runs. Each names the file, and
//! where it applies the node id and the key, so the user can go straight to it.

use std::fmt;
use std::path::PathBuf;

/// What kind of problem a [`GraphError`] is (for tools and tests; the message
/// says it for people).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// The file cannot be read.
    Unreadable,
    /// The TOML does not parse.
    Syntax,
    /// The TOML parses but is not a graph (misplaced or unknown keys).
    Structure,
    /// Two nodes share an id.
    DuplicateId,
    /// No op of that name is registered.
    UnknownOp,
    /// The op has no parameter of that name.
    UnknownParam,
    /// A required parameter is not given.
    MissingParam,
    /// A parameter has the wrong type or is out of range.
    BadParam,
    /// A path parameter names nothing readable.
    MissingFile,
    /// The op has no input port of that name.
    UnknownInput,
    /// A required input is not connected.
    MissingInput,
    /// An input names a node or port that does not exist.
    UnknownSource,
    /// An input's type does not fit the output it is connected to.
    TypeMismatch,
    /// The nodes form a cycle.
    Cycle,
    /// A `--set` override is malformed or names an unknown node.
    BadOverride,
    /// Two sinks write the same output file.
    OutputClash,
    /// A plugin the graph names cannot be loaded.
    Plugin,
}

/// One problem in a graph file.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphError {
    /// What kind of problem.
    pub kind: ErrorKind,
    /// The graph file.
    pub file: PathBuf,
    /// The node id, where the problem is in one node.
    pub node: Option<String>,
    /// The key (parameter, `op`, `in.PORT`), where the problem is in one key.
    pub key: Option<String>,
    /// What is wrong, and what would be right.
    pub message: String,
}

impl GraphError {
    /// A problem with the file as a whole.
    pub fn file(kind: ErrorKind, file: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        GraphError {
            kind,
            file: file.into(),
            node: None,
            key: None,
            message: message.into(),
        }
    }

    /// Narrows the error to node `node`.
    pub fn at_node(mut self, node: &str) -> Self {
        self.node = Some(node.into());
        self
    }

    /// Narrows the error to key `key` of its node.
    pub fn at_key(mut self, key: &str) -> Self {
        self.key = Some(key.into());
        self
    }
}

impl fmt::Display for GraphError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(node) = &self.node {
            write!(f, ": node `{node}`")?;
        }
        if let Some(key) = &self.key {
            write!(f, ", key `{key}`")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for GraphError {}

/// Every problem found in a graph file (validation reports them all at once).
#[derive(Debug, Clone, PartialEq)]
pub struct GraphErrors(pub Vec<GraphError>);

impl fmt::Display for GraphErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lines: Vec<String> = self.0.iter().map(|e| format!("error: {e}")).collect();
        f.write_str(&lines.join("\n"))
    }
}

impl std::error::Error for GraphErrors {}

impl From<GraphError> for GraphErrors {
    fn from(e: GraphError) -> Self {
        GraphErrors(vec![e])
    }
}

/// The closest of `candidates` to `name` by edit distance, if it is close enough
/// to be a likely typo.
pub fn closest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    candidates
        .into_iter()
        .map(|c| (strsim::damerau_levenshtein(name, c), c))
        .filter(|&(d, c)| d <= (c.len().max(name.len()) / 3).max(2))
        .min()
        .map(|(_, c)| c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_names_file_node_and_key() {
        let e = GraphError::file(ErrorKind::BadParam, "g.toml", "too big")
            .at_node("enhance")
            .at_key("low_percentile");
        assert_eq!(
            e.to_string(),
            "g.toml: node `enhance`, key `low_percentile`: too big"
        );
    }

    #[test]
    fn closest_finds_typos_only() {
        let ops = ["mri.otsu", "mri.isosurface", "dicom.load_series"];
        assert_eq!(closest("mri.ostu", ops), Some("mri.otsu"));
        assert_eq!(closest("dicom.load_serie", ops), Some("dicom.load_series"));
        assert_eq!(closest("stereo.sgm", ops), None);
    }
}
