//! Fingerprints of the built-in ops' code, for their cache keys: editing an
//! op re-runs that op's nodes (and what follows, whose keys chain), while a
//! rebuild that changes nothing keeps the whole cache.
//!
//! An op `stage.action` lives in `src/<stage>/ops/<action>.rs`; the code it
//! runs is that file, the files of its own stage outside `ops/` (the stage's
//! algorithms), and those of every other module its code names through
//! `crate::<module>`, followed transitively. Its fingerprint is the blake3
//! hash of those files' paths and contents, in path order. A stage-level
//! closure is conservative: editing an algorithm file re-runs every op of
//! the stages that can reach it, never fewer. Used by `build.rs` and unit
//! tested from the crate (`src/lib.rs`).

use std::collections::{BTreeMap, BTreeSet};

/// Sources by path relative to `src/` (`stereo/ops/sgm.rs`), `/`-separated.
pub type Sources = BTreeMap<String, String>;

/// The top-level module a source file belongs to (`stereo` for
/// `stereo/sgm.rs`, `math` for `math.rs`); `None` for `lib.rs`.
fn module_of(path: &str) -> Option<&str> {
    match path.split_once('/') {
        Some((m, _)) => Some(m),
        None => path.strip_suffix(".rs").filter(|m| *m != "lib"),
    }
}

/// Whether `path` is an op's own file (`<stage>/ops/<action>.rs`).
fn is_op_file(path: &str) -> bool {
    let parts: Vec<&str> = path.split('/').collect();
    parts.len() == 3 && parts[1] == "ops" && parts[2].ends_with(".rs") && parts[2] != "mod.rs"
}

/// The top-level modules `code` names as `crate::<module>`, outside line
/// comments.
fn named_modules(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for line in code.lines() {
        let line = line.split("//").next().unwrap_or("");
        let mut rest = line;
        while let Some(at) = rest.find("crate::") {
            rest = &rest[at + "crate::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                out.insert(name);
            }
        }
    }
    out
}

/// Every op's fingerprint (hex), by op name (`stage.action`).
pub fn fingerprints(sources: &Sources) -> BTreeMap<String, String> {
    // A module's algorithm files: everything of it but its ops' own files.
    let mut algorithm: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for path in sources.keys() {
        if let Some(m) = module_of(path)
            && !is_op_file(path)
        {
            algorithm.entry(m).or_default().push(path);
        }
    }
    let modules: BTreeSet<&str> = sources.keys().filter_map(|p| module_of(p)).collect();
    // What each module's algorithm files name.
    let uses = |m: &str| -> BTreeSet<String> {
        algorithm
            .get(m)
            .into_iter()
            .flatten()
            .flat_map(|p| named_modules(&sources[*p]))
            .filter(|n| modules.contains(n.as_str()))
            .collect()
    };
    let mut out = BTreeMap::new();
    for (path, code) in sources.iter().filter(|(p, _)| is_op_file(p)) {
        let stage = module_of(path).expect("an op file is in a stage");
        let action = path.rsplit('/').next().unwrap().trim_end_matches(".rs");
        let mut reach: BTreeSet<String> = named_modules(code)
            .into_iter()
            .filter(|n| modules.contains(n.as_str()))
            .collect();
        reach.insert(stage.to_string());
        let mut todo: Vec<String> = reach.iter().cloned().collect();
        while let Some(m) = todo.pop() {
            for n in uses(&m) {
                if reach.insert(n.clone()) {
                    todo.push(n);
                }
            }
        }
        let mut files: BTreeSet<&str> = reach
            .iter()
            .flat_map(|m| algorithm.get(m.as_str()).into_iter().flatten().copied())
            .collect();
        files.insert(path);
        let mut hasher = blake3::Hasher::new();
        for f in files {
            for part in [f, sources[f].as_str()] {
                hasher.update(&(part.len() as u64).to_le_bytes());
                hasher.update(part.as_bytes());
            }
        }
        out.insert(
            format!("{stage}.{action}"),
            hasher.finalize().to_hex().to_string(),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn workspace() -> Sources {
        [
            ("lib.rs", "pub mod stereo; pub mod cloud; pub mod mri;"),
            ("stereo/mod.rs", "pub mod ops; mod sgm;"),
            ("stereo/sgm.rs", "use crate::cloud::Nearest; fn sgm() {}"),
            (
                "stereo/ops/sgm.rs",
                "use super::sgm; // crate::mri in a comment",
            ),
            ("stereo/ops/features.rs", "fn features() {}"),
            ("cloud/mod.rs", "pub struct Nearest;"),
            ("mri/mod.rs", "fn otsu() {}"),
            ("mri/ops/otsu.rs", "use crate::mri::otsu;"),
        ]
        .into_iter()
        .map(|(p, c)| (p.to_string(), c.to_string()))
        .collect()
    }

    fn edited(path: &str) -> BTreeMap<String, String> {
        let mut s = workspace();
        s.get_mut(path).unwrap().push_str("\n// edited");
        fingerprints(&s)
    }

    fn changed(path: &str) -> Vec<String> {
        let before = fingerprints(&workspace());
        let after = edited(path);
        before
            .keys()
            .filter(|op| before[*op] != after[*op])
            .cloned()
            .collect()
    }

    #[test]
    fn every_op_has_a_fingerprint_and_the_same_code_the_same_one() {
        let f = fingerprints(&workspace());
        assert_eq!(
            f.keys().collect::<Vec<_>>(),
            ["mri.otsu", "stereo.features", "stereo.sgm"]
        );
        assert_eq!(f, fingerprints(&workspace()));
    }

    #[test]
    fn editing_an_op_changes_that_op_only() {
        assert_eq!(changed("stereo/ops/sgm.rs"), ["stereo.sgm"]);
        assert_eq!(changed("mri/ops/otsu.rs"), ["mri.otsu"]);
    }

    #[test]
    fn editing_an_algorithm_changes_every_op_that_can_reach_it() {
        assert_eq!(changed("stereo/sgm.rs"), ["stereo.features", "stereo.sgm"]);
        // Reached from stereo's algorithms, not from mri.
        assert_eq!(changed("cloud/mod.rs"), ["stereo.features", "stereo.sgm"]);
        assert_eq!(changed("mri/mod.rs"), ["mri.otsu"]);
        // lib.rs holds only the module list and the registry.
        assert!(changed("lib.rs").is_empty());
    }
}
