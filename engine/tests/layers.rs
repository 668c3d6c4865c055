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
        "error", "figure", "atomic", "process", "panics", "hash", "value", "param",
    ],
    // What an op is.
    &["op"],
    // Where ops come from.
    &["registry", "plugin"],
    // Graph files, validation and keys.
    &["each", "graph", "validate", "key", "dot"],
    // Running: files, leases, the cache, the scheduler, reports.
    &[
        "workdir",
        "lease",
        "cache",
        "report",
        "report_html",
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
