//! [`PathValue`]: a file or folder, identified by the hash of its content.

use serde::Serialize;
use std::path::PathBuf;

/// A file or folder that a node read or wrote. Its identity is `content_hash`
/// (blake3 over the content, see [`crate::hash::hash_path`]), not its location: a
/// cached value whose path no longer holds that content is treated as missing.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PathValue {
    /// Absolute location.
    pub path: PathBuf,
    /// Hex blake3 hash of the content.
    pub content_hash: String,
}
