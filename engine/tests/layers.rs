//! The engine's modules stay in one-directional layers, so that a plugin
//! author reads the op API without the cache, and nothing imports in a
//! circle. Each module may use modules of its own layer or below, never
//! above; and the whole module graph has no cycle. Uses are read from the
//! sources (`crate::module` outside comments and test modules).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Bottom first.
const LAYERS: &[&[&str]] = &[
    // Plain data and helpers.
    &[
        "error", "figure", "atomic", "process", "panics", "hash", "value", "param", "memory",
    ],
    // What an op is, and ops in the typed form.
    &["op", "typed"],
    // Where ops come from.
    &["registry", "plugin", "script"],
    // Graph files, validation and keys.
    &["each", "graph", "validate", "key", "dot"],
    // Running: files, leases, the cache, the scheduler, reports.
    &[
        "workdir",
        "lease",
        "cache",
        "cache_admin",
        "report",
        "report_html",
        "provenance",
        "schedule",
        "session",
    ],
    // Many runs of one graph.
    &["sweep"],
];

/// Root re-exports (`crate::OpSpec`) and the module they come from.
fn reexport(name: &str) -> Option<&'static str> {
    Some(match name {
        "ErrorKind" | "GraphError" | "GraphErrors" => "error",
        "Inputs" | "Op" | "OpError" | "OpSpec" | "Outputs" | "PortSpec" | "RunCtx"
        | "path_value" => "op",
        "ParamKind" | "ParamSpec" | "ParamValue" | "Params" => "param",
        "Registry" => "registry",
        "NodeStatus" | "RunReport" => "report",
        "Value" | "ValueType" => "value",
        _ => return None,
    })
}

/// The modules that `source` uses, outside comments and `#[cfg(test)]`.
fn uses(source: &str) -> BTreeSet<String> {
    let code = source.split("#[cfg(test)]").next().unwrap_or("");
    let mut found = BTreeSet::new();
    for line in code.lines() {
        let line = line.split("//").next().unwrap_or("");
        let mut rest = line;
        while let Some(at) = rest.find("crate::") {
            rest = &rest[at + "crate::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if name.chars().next().is_some_and(|c| c.is_ascii_lowercase())
                && reexport(&name).is_none()
            {
                found.insert(name);
            } else if let Some(m) = reexport(&name) {
                found.insert(m.to_string());
            } else if let Some(braced) = rest.strip_prefix('{') {
                // `use crate::{a, b::C}`: the first segment of each item.
                let inner = braced.split('}').next().unwrap_or("");
                for item in inner.split(',') {
                    let first = item.trim().split("::").next().unwrap_or("").to_string();
                    if let Some(m) = reexport(&first) {
                        found.insert(m.to_string());
                    } else if !first.is_empty() {
                        found.insert(first);
                    }
                }
            }
        }
    }
    found
}

#[test]
fn engine_modules_use_only_their_own_layer_or_below_and_no_cycle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let layer_of: BTreeMap<&str, usize> = LAYERS
        .iter()
        .enumerate()
        .flat_map(|(i, mods)| mods.iter().map(move |m| (*m, i)))
        .collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        let (name, text) = if path.is_dir() {
            // A module folder: its files together.
            let mut text = String::new();
            for f in std::fs::read_dir(&path).unwrap() {
                text += &std::fs::read_to_string(f.unwrap().path()).unwrap();
            }
            (
                path.file_name().unwrap().to_string_lossy().into_owned(),
                text,
            )
        } else {
            let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
            (stem, std::fs::read_to_string(&path).unwrap())
        };
        if name == "lib" {
            continue;
        }
        let mut used = uses(&text);
        used.remove(&name);
        graph.insert(name, used);
    }
    let mut problems = Vec::new();
    for (module, used) in &graph {
        let Some(&own) = layer_of.get(module.as_str()) else {
            problems.push(format!(
                "module `{module}` is in no layer: add it to LAYERS"
            ));
            continue;
        };
        for u in used {
            match layer_of.get(u.as_str()) {
                Some(&l) if l > own => problems.push(format!(
                    "`{module}` (layer {own}) uses `{u}` (layer {l}, above it)"
                )),
                Some(_) => {}
                None => problems.push(format!("`{module}` uses `{u}`, which is in no layer")),
            }
        }
    }
    // No cycle, within a layer either (depth-first search).
    fn visit<'a>(
        m: &'a str,
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<&'a str, u8>,
        path: &mut Vec<&'a str>,
        problems: &mut Vec<String>,
    ) {
        match state.get(m) {
            Some(2) => return,
            Some(1) => {
                let start = path.iter().position(|p| *p == m).unwrap_or(0);
                problems.push(format!("cycle: {} -> {m}", path[start..].join(" -> ")));
                return;
            }
            _ => {}
        }
        state.insert(m, 1);
        path.push(m);
        for u in graph.get(m).into_iter().flatten() {
            visit(u, graph, state, path, problems);
        }
        path.pop();
        state.insert(m, 2);
    }
    let mut state = BTreeMap::new();
    for m in graph.keys() {
        visit(m, &graph, &mut state, &mut Vec::new(), &mut problems);
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert!(graph.len() >= 20, "{graph:?}");
}

/// A crate's modules by path (`["stereo", "cost"]`), each with its source
/// outside comments and test modules.
fn modules(src: &Path) -> BTreeMap<Vec<String>, String> {
    fn walk(dir: &Path, prefix: &[String], out: &mut BTreeMap<Vec<String>, String>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            let mut module = prefix.to_vec();
            if path.is_dir() {
                module.push(name);
                walk(&path, &module, out);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            if !matches!(name.as_str(), "mod" | "lib" | "main") {
                module.push(name);
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let code = text.split("#[cfg(test)]").next().unwrap_or("");
            let code: Vec<&str> = code
                .lines()
                .map(|l| l.split("//").next().unwrap_or(""))
                .collect();
            out.entry(module).or_default().push_str(&code.join("\n"));
        }
    }
    let mut out = BTreeMap::new();
    walk(src, &[], &mut out);
    out
}

/// The modules that `code` (of module `module`) names by path: `crate::a::b`,
/// `super::a`, `self::a`, resolved to the longest known module. Names of an
/// enclosing module (re-exports) are not followed.
fn references(
    module: &[String],
    code: &str,
    known: &BTreeSet<Vec<String>>,
) -> BTreeSet<Vec<String>> {
    let mut found = BTreeSet::new();
    let bytes = code.as_bytes();
    for (at, _) in code.match_indices("::") {
        // The start of the path this `::` belongs to.
        let mut start = at;
        while start > 0
            && (bytes[start - 1].is_ascii_alphanumeric()
                || bytes[start - 1] == b'_'
                || bytes[start - 1] == b':')
        {
            start -= 1;
        }
        if start != at && code[start..at].contains("::") {
            continue; // not the first `::` of its path
        }
        let path: Vec<&str> = code[start..]
            .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'))
            .next()
            .unwrap_or("")
            .split("::")
            .filter(|s| !s.is_empty())
            .collect();
        let mut resolved: Vec<String> = match path.first() {
            Some(&"crate") => Vec::new(),
            Some(&"super") | Some(&"self") => module.to_vec(),
            _ => continue,
        };
        for seg in &path {
            match *seg {
                "crate" | "self" => {}
                "super" => {
                    resolved.pop();
                }
                s => resolved.push(s.to_string()),
            }
        }
        while !resolved.is_empty() && !known.contains(&resolved) {
            resolved.pop();
        }
        if !resolved.is_empty() {
            found.insert(resolved);
        }
    }
    found
}

/// Import circles among the children of any one folder of the crate at
/// `src` (sibling files and sub-folders, each folder taken as a whole).
fn folder_cycles(src: &Path) -> Vec<String> {
    let modules = modules(src);
    let known: BTreeSet<Vec<String>> = modules.keys().cloned().collect();
    // Edges between modules, by full path.
    let mut edges = Vec::new();
    for (module, code) in &modules {
        for target in references(module, code, &known) {
            edges.push((module.clone(), target));
        }
    }
    let mut problems = Vec::new();
    for folder in known.iter().chain(std::iter::once(&Vec::new())) {
        // The child of `folder` that a module lies in, if any.
        let child = |m: &Vec<String>| -> Option<String> {
            (m.len() > folder.len() && m.starts_with(folder)).then(|| m[folder.len()].clone())
        };
        let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for (from, to) in &edges {
            if let (Some(a), Some(b)) = (child(from), child(to))
                && a != b
            {
                graph.entry(a).or_default().insert(b);
            }
        }
        // Depth-first search for a back edge.
        fn visit(
            m: &str,
            graph: &BTreeMap<String, BTreeSet<String>>,
            state: &mut BTreeMap<String, u8>,
            path: &mut Vec<String>,
            found: &mut Vec<String>,
        ) {
            match state.get(m) {
                Some(2) => return,
                Some(1) => {
                    let start = path.iter().position(|p| p == m).unwrap_or(0);
                    found.push(format!("{} -> {m}", path[start..].join(" -> ")));
                    return;
                }
                _ => {}
            }
            state.insert(m.to_string(), 1);
            path.push(m.to_string());
            for u in graph.get(m).into_iter().flatten() {
                visit(u, graph, state, path, found);
            }
            path.pop();
            state.insert(m.to_string(), 2);
        }
        let mut state = BTreeMap::new();
        let mut found = Vec::new();
        for m in graph.keys() {
            visit(m, &graph, &mut state, &mut Vec::new(), &mut found);
        }
        let shown = if folder.is_empty() {
            "crate".to_string()
        } else {
            folder.join("::")
        };
        problems.extend(found.into_iter().map(|c| format!("in {shown}: {c}")));
    }
    problems
}

#[test]
fn no_files_import_in_a_circle_in_the_engine_or_the_nodes() {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    for src in [here.join("src"), here.join("../nodes/src")] {
        let problems = folder_cycles(&src);
        assert!(
            problems.is_empty(),
            "{}: import circles:\n{}",
            src.display(),
            problems.join("\n")
        );
    }
}

#[test]
fn a_circle_between_sibling_files_is_found() {
    let t = tempfile::tempdir().unwrap();
    let stage = t.path().join("stereo");
    std::fs::create_dir_all(&stage).unwrap();
    std::fs::write(t.path().join("lib.rs"), "pub mod stereo;").unwrap();
    std::fs::write(stage.join("mod.rs"), "mod cost; mod sgm; mod select;").unwrap();
    std::fs::write(stage.join("cost.rs"), "use super::sgm::lanes;").unwrap();
    std::fs::write(stage.join("sgm.rs"), "use super::select::row;").unwrap();
    std::fs::write(
        stage.join("select.rs"),
        "fn f() { crate::stereo::cost::ks() }",
    )
    .unwrap();
    let problems = folder_cycles(t.path());
    assert_eq!(
        problems,
        vec!["in stereo: cost -> sgm -> select -> cost".to_string()]
    );
}
