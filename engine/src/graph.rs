//! The graph file as written: parsing TOML into a [`GraphDoc`] and applying
//! `--set` overrides. Nothing here knows about registered ops; [`crate::validate`]
//! checks the document against them.
//!
//! ```toml
//! [graph]
//! name = "mri-markers"
//!
//! [node.mask]
//! op = "mri.otsu"
//! in.volume = "enhance.volume"   # input port <- "node.output_port"
//! bins = 256                     # every other key is a parameter
//! ```

pub use crate::each::MAX_NODES;
use crate::each::{Group, expand};
use crate::error::{ErrorKind, GraphError, GraphErrors, closest};
use std::path::{Path, PathBuf};

/// A connection as written: input `port` takes output `source_port` of node
/// `source_node`.
#[derive(Debug, Clone, PartialEq)]
pub struct InputDecl {
    /// Input port of this node.
    pub port: String,
    /// Id of the upstream node.
    pub source_node: String,
    /// Output port of the upstream node.
    pub source_port: String,
}

/// One `[node.ID]` table as written.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeDecl {
    /// Node id (the table name).
    pub id: String,
    /// Op name.
    pub op: String,
    /// Input connections, in file order.
    pub inputs: Vec<InputDecl>,
    /// Parameters as TOML values, in file order.
    pub params: Vec<(String, toml::Value)>,
}

/// A figure from elsewhere to show beside one of ours (e.g. the paper's).
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Our metric, `node.metric`.
    pub metric: String,
    /// Their value.
    pub value: f64,
    /// Where it comes from and what it measures.
    pub note: String,
}

/// A graph file as written, before validation.
#[derive(Debug, Clone, PartialEq)]
pub struct GraphDoc {
    /// The graph file.
    pub file: PathBuf,
    /// `[graph] name`, or the file stem.
    pub name: String,
    /// The folder relative paths are resolved against (the graph file's).
    pub base_dir: PathBuf,
    /// Nodes in file order (the copies of `[each.NAME]` groups included).
    pub nodes: Vec<NodeDecl>,
    /// The `[each.NAME]` groups the copies came from.
    pub groups: Vec<Group>,
    /// `[graph.references]`: figures from elsewhere to show beside ours.
    pub references: Vec<Reference>,
    /// `[graph] plugins`: plugin libraries the graph needs, resolved against
    /// the graph file's folder.
    pub plugins: Vec<PathBuf>,
    /// `[graph] python`: Python files declaring ops the graph needs,
    /// resolved against the graph file's folder (see [`crate::script`]).
    pub python: Vec<PathBuf>,
}

const GRAPH_KEYS: &[&str] = &["name", "description", "references", "plugins", "python"];

/// The largest graph file read (64 MiB: about a million nodes).
const MAX_GRAPH_BYTES: u64 = 64 << 20;

impl GraphDoc {
    /// Reads and parses a graph file.
    pub fn load(file: &Path) -> Result<GraphDoc, GraphErrors> {
        let unreadable = |why: String| GraphError::file(ErrorKind::Unreadable, file, why);
        let meta = std::fs::metadata(file)
            .map_err(|e| unreadable(format!("cannot read the graph file: {e}")))?;
        if !meta.is_file() {
            return Err(unreadable(
                "not a regular file (a folder, device or FIFO): give a graph's .toml file".into(),
            )
            .into());
        }
        if meta.len() > MAX_GRAPH_BYTES {
            return Err(unreadable(format!(
                "{} bytes, more than a graph file may hold ({MAX_GRAPH_BYTES})",
                meta.len()
            ))
            .into());
        }
        let text = std::fs::read_to_string(file)
            .map_err(|e| unreadable(format!("cannot read the graph file: {e}")))?;
        Self::parse(&text, file)
    }

    /// Parses graph text; `file` names it in errors and anchors relative paths.
    pub fn parse(text: &str, file: &Path) -> Result<GraphDoc, GraphErrors> {
        check_duplicate_ids(text, file)?;
        let table: toml::Table = toml::from_str(text).map_err(|e| syntax_error(text, file, &e))?;
        let err = |msg: String| GraphError::file(ErrorKind::Structure, file, msg);
        let mut errors = Vec::new();
        let mut name = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "graph".into());
        let mut nodes = Vec::new();
        let mut groups = Vec::new();
        let mut references = Vec::new();
        let mut plugins: Vec<PathBuf> = Vec::new();
        let mut python: Vec<PathBuf> = Vec::new();
        for (key, value) in &table {
            match (key.as_str(), value) {
                ("graph", toml::Value::Table(g)) => {
                    for (k, v) in g {
                        if k == "references" {
                            match parse_references(v) {
                                Ok(r) => references = r,
                                Err(m) => errors.push(err(m).at_key("references")),
                            }
                            continue;
                        }
                        if k == "plugins" || k == "python" {
                            let what = if k == "plugins" { "library" } else { "Python file" };
                            match v.as_array().map(|a| a.iter().map(|p| p.as_str()).collect::<Option<Vec<_>>>()) {
                                Some(Some(list)) => {
                                    let list = list.iter().map(PathBuf::from).collect();
                                    if k == "plugins" { plugins = list } else { python = list }
                                }
                                _ => errors.push(
                                    err(format!("[graph] {k} must be a list of {what} paths (relative to the graph file)"))
                                        .at_key(k),
                                ),
                            }
                            continue;
                        }
                        match (k.as_str(), v.as_str()) {
                            ("name", Some(n)) if !n.trim().is_empty() => name = n.to_string(),
                            ("description", Some(_)) => {}
                            (k, _) if GRAPH_KEYS.contains(&k) => errors.push(
                                err(format!("[graph] {k} must be a non-empty string")).at_key(k),
                            ),
                            (k, _) => errors.push(
                                err(format!(
                                    "unknown key in [graph]; valid keys: {}",
                                    GRAPH_KEYS.join(", ")
                                ))
                                .at_key(k),
                            ),
                        }
                    }
                }
                ("node", toml::Value::Table(n)) => {
                    for (id, body) in n {
                        match parse_node(id, body, file) {
                            Ok(node) => nodes.push(node),
                            Err(mut e) => errors.append(&mut e),
                        }
                    }
                }
                // A sweep over this graph (see `crate::sweep`), read there.
                ("sweep" | "variant", toml::Value::Table(_)) => {}
                ("each", toml::Value::Table(g)) => {
                    for (name, body) in g {
                        let budget = MAX_NODES.saturating_sub(nodes.len());
                        match expand(name, body, file, budget) {
                            Ok((group, copies)) => {
                                for (id, body) in copies {
                                    match parse_node(&id, &body, file) {
                                        Ok(node) => nodes.push(node),
                                        Err(mut e) => errors.append(&mut e),
                                    }
                                }
                                groups.push(group);
                            }
                            Err(mut e) => errors.append(&mut e),
                        }
                    }
                }
                ("graph" | "node" | "each", _) => errors.push(
                    err(format!("`{key}` must be a table ([{key}] or [{key}.ID])")).at_key(key),
                ),
                _ => errors.push(
                    err(
                        "unknown top-level key; a graph has [graph], [node.ID] and [each.NAME] tables"
                            .into(),
                    )
                    .at_key(key),
                ),
            }
        }
        if nodes.is_empty() && errors.is_empty() {
            errors.push(err("the graph has no nodes (add [node.ID] tables)".into()));
        }
        // A group's copies must not take the id of another node.
        let mut ids = std::collections::HashSet::with_capacity(nodes.len());
        for n in &nodes {
            if !ids.insert(n.id.as_str()) {
                errors.push(
                    GraphError::file(
                        ErrorKind::DuplicateId,
                        file,
                        "duplicate node id: a copy of an [each] group's node has the id of another node"
                            .to_string(),
                    )
                    .at_node(&n.id),
                );
            }
        }
        if !errors.is_empty() {
            return Err(GraphErrors(errors));
        }
        let base_dir = file
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_path_buf();
        let base_dir = std::path::absolute(&base_dir).unwrap_or(base_dir);
        let plugins = plugins.iter().map(|p| base_dir.join(p)).collect();
        let python = python.iter().map(|p| base_dir.join(p)).collect();
        Ok(GraphDoc {
            file: file.to_path_buf(),
            name,
            base_dir,
            nodes,
            groups,
            references,
            plugins,
            python,
        })
    }

    /// Applies one `--set ID.KEY=VALUE` override: `ID.op=NAME` swaps the op,
    /// `ID.in.PORT=node.port` rewires an input (`ID.in.PORT=` disconnects it),
    /// any other key sets a parameter.
    /// VALUE is read as TOML (`2`, `true`, `[1, 2]`, `"s"`); anything that is not
    /// valid TOML is taken as a plain string.
    pub fn apply_set(&mut self, assignment: &str) -> Result<(), GraphError> {
        let bad = |msg: String| GraphError::file(ErrorKind::BadOverride, &self.file, msg);
        // A line break would end the value early in TOML, or start a table.
        if assignment.contains(['\n', '\r']) {
            return Err(bad(format!(
                "--set {assignment:?}: a value may not hold a line break"
            )));
        }
        let (lhs, raw) = assignment
            .split_once('=')
            .ok_or_else(|| bad(format!("--set {assignment:?}: expected ID.KEY=VALUE")))?;
        let (id, key) = lhs
            .trim()
            .split_once('.')
            .ok_or_else(|| bad(format!("--set {assignment:?}: expected ID.KEY=VALUE")))?;
        let value = parse_cli_value(raw.trim());
        self.set(id, key, &value, "--set")
    }

    /// Sets `key` (a parameter, `op` or `in.PORT`) of node `id`, or of every
    /// copy of an `[each]` group's node `id`, to `value`; `by` names who asks
    /// in errors (`--set`, `variant v03`).
    pub fn set(
        &mut self,
        id: &str,
        key: &str,
        value: &toml::Value,
        by: &str,
    ) -> Result<(), GraphError> {
        let targets: Vec<String> = if self.nodes.iter().any(|n| n.id == id) {
            vec![id.to_string()]
        } else if let Some(copies) = self.groups.iter().find_map(|g| g.copies_of(id)) {
            copies
        } else {
            let ids = self.nodes.iter().map(|n| n.id.as_str()).chain(
                self.groups
                    .iter()
                    .flat_map(|g| g.members.iter().map(String::as_str)),
            );
            let hint = closest(id, ids).map(|c| format!(" (did you mean `{c}`?)"));
            return Err(GraphError::file(
                ErrorKind::BadOverride,
                &self.file,
                format!("{by}: no node with this id{}", hint.unwrap_or_default()),
            )
            .at_node(id)
            .at_key(key));
        };
        let file = self.file.clone();
        for target in targets {
            let node = self
                .nodes
                .iter_mut()
                .find(|n| n.id == target)
                .expect("targets are node ids");
            set_on_node(node, key, value).map_err(|msg| {
                GraphError::file(ErrorKind::BadOverride, &file, format!("{by}: {msg}"))
                    .at_node(id)
                    .at_key(key)
            })?;
        }
        Ok(())
    }
}

/// Sets `key` of `node` to `value` (see [`GraphDoc::apply_set`]).
fn set_on_node(node: &mut NodeDecl, key: &str, value: &toml::Value) -> Result<(), String> {
    if key == "op" {
        node.op = value.as_str().ok_or("op must be a name")?.to_string();
    } else if let Some(port) = key.strip_prefix("in.") {
        let src = value.as_str().ok_or("an input must be \"node.port\"")?;
        node.inputs.retain(|i| i.port != port);
        // An empty source disconnects the input (validation then says if
        // it was required).
        if !src.is_empty() {
            node.inputs.push(parse_input(port, src)?);
        }
    } else {
        match node.params.iter_mut().find(|(k, _)| k == key) {
            Some((_, v)) => *v = value.clone(),
            None => node.params.push((key.to_string(), value.clone())),
        }
    }
    Ok(())
}

/// `[graph.references]`: `"node.metric" = { value = 3.39, note = "..." }`.
fn parse_references(v: &toml::Value) -> Result<Vec<Reference>, String> {
    let table = v.as_table().ok_or(
        "[graph.references] must be a table of \"node.metric\" = { value = ..., note = \"...\" }",
    )?;
    table
        .iter()
        .map(|(metric, r)| {
            let value = r
                .get("value")
                .and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)));
            match (value, r.get("note").and_then(|n| n.as_str())) {
                (Some(value), Some(note)) if metric.contains('.') => Ok(Reference {
                    metric: metric.clone(),
                    value,
                    note: note.to_string(),
                }),
                _ => Err(format!(
                    "reference {metric:?}: write \"node.metric\" = {{ value = 1.0, note = \"where it comes from\" }}"
                )),
            }
        })
        .collect()
}

fn parse_cli_value(raw: &str) -> toml::Value {
    toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()))
}

fn parse_node(id: &str, body: &toml::Value, file: &Path) -> Result<NodeDecl, Vec<GraphError>> {
    let err = |msg: String| GraphError::file(ErrorKind::Structure, file, msg).at_node(id);
    let Some(body) = body.as_table() else {
        return Err(vec![err(
            "must be a table: [node.ID] with op = \"...\"".into()
        )]);
    };
    let mut errors = Vec::new();
    if id.is_empty()
        || !id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        errors.push(err(
            "node ids may hold only letters, digits, '_' and '-'".into()
        ));
    }
    let op = match body.get("op") {
        Some(toml::Value::String(op)) => op.clone(),
        Some(_) => {
            errors.push(err("`op` must be a string naming the node type".into()).at_key("op"));
            String::new()
        }
        None => {
            errors.push(
                err("missing `op` (the node type, e.g. op = \"mri.otsu\")".into()).at_key("op"),
            );
            String::new()
        }
    };
    let mut inputs = Vec::new();
    let mut params = Vec::new();
    for (key, value) in body {
        match key.as_str() {
            "op" => {}
            "in" => match value.as_table() {
                Some(ins) => {
                    for (port, src) in ins {
                        let key = format!("in.{port}");
                        match src
                            .as_str()
                            .ok_or("must be a string \"node.port\"".to_string())
                        {
                            Ok(s) => match parse_input(port, s) {
                                Ok(i) => inputs.push(i),
                                Err(m) => errors.push(err(m).at_key(&key)),
                            },
                            Err(m) => errors.push(err(m).at_key(&key)),
                        }
                    }
                }
                None => errors
                    .push(err("`in` must be a table of port = \"node.port\"".into()).at_key("in")),
            },
            _ => params.push((key.clone(), value.clone())),
        }
    }
    if errors.is_empty() {
        Ok(NodeDecl {
            id: id.to_string(),
            op,
            inputs,
            params,
        })
    } else {
        Err(errors)
    }
}

fn parse_input(port: &str, source: &str) -> Result<InputDecl, String> {
    match source.split_once('.') {
        Some((n, p)) if !n.is_empty() && !p.is_empty() => Ok(InputDecl {
            port: port.to_string(),
            source_node: n.to_string(),
            source_port: p.to_string(),
        }),
        _ => Err(format!("{source:?} must name an output as \"node.port\"")),
    }
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

fn syntax_error(text: &str, file: &Path, e: &toml::de::Error) -> GraphErrors {
    let at = e
        .span()
        .map(|s| {
            let (l, c) = line_col(text, s.start);
            format!("line {l}, column {c}: ")
        })
        .unwrap_or_default();
    GraphError::file(
        ErrorKind::Syntax,
        file,
        format!("TOML syntax error at {at}{}", e.message().trim()),
    )
    .into()
}

/// TOML itself rejects a repeated `[node.ID]` table, with a generic message; find
/// repeats first so the error names the id and both lines.
fn check_duplicate_ids(text: &str, file: &Path) -> Result<(), GraphErrors> {
    // Id -> the line it was first defined on.
    let mut seen: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
    let mut errors = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let t = line.trim();
        let Some(inner) = t.strip_prefix('[').and_then(|r| r.split(']').next()) else {
            continue;
        };
        if t.starts_with("[[") {
            continue;
        }
        let parts: Vec<String> = inner
            .split('.')
            .map(|p| p.trim().trim_matches('"').to_string())
            .collect();
        if parts.len() != 2 || parts[0] != "node" {
            continue;
        }
        match seen.get_key_value(&parts[1]) {
            Some((id, first)) => errors.push(
                GraphError::file(
                    ErrorKind::DuplicateId,
                    file,
                    format!(
                        "duplicate node id (first defined on line {first}, again on line {})",
                        n + 1
                    ),
                )
                .at_node(id),
            ),
            None => {
                seen.insert(parts[1].clone(), n + 1);
            }
        }
    }
    if errors.is_empty() {
        Ok(())
    } else {
        Err(GraphErrors(errors))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<GraphDoc, GraphErrors> {
        GraphDoc::parse(text, Path::new("dir/g.toml"))
    }

    const TWO: &str = r#"
[graph]
name = "demo"

[node.a]
op = "math.constant"
value = 2.0

[node.b]
op = "math.binary"
in.a = "a.value"
in.b = "a.value"
operation = "mul"
"#;

    #[test]
    fn parses_nodes_inputs_and_params_in_file_order() {
        let g = parse(TWO).unwrap();
        assert_eq!(g.name, "demo");
        assert_eq!(
            g.nodes.iter().map(|n| n.id.as_str()).collect::<Vec<_>>(),
            ["a", "b"]
        );
        let b = &g.nodes[1];
        assert_eq!(b.inputs[0].port, "a");
        assert_eq!(
            (
                b.inputs[1].source_node.as_str(),
                b.inputs[1].source_port.as_str()
            ),
            ("a", "value")
        );
        assert_eq!(
            b.params,
            vec![("operation".to_string(), toml::Value::String("mul".into()))]
        );
        assert!(g.base_dir.ends_with("dir") && g.base_dir.is_absolute());
    }

    #[test]
    fn syntax_errors_give_line_and_column() {
        let e = parse("[node.a]\nop = \"x\"\nvalue = = 3\n").unwrap_err();
        assert_eq!(e.0[0].kind, ErrorKind::Syntax);
        assert!(e.0[0].to_string().contains("line 3, column"), "{e}");
        assert!(e.0[0].to_string().starts_with("dir/g.toml"), "{e}");
    }

    #[test]
    fn duplicate_ids_name_the_id_and_lines() {
        let e = parse("[node.a]\nop = \"x\"\n\n[node.a]\nop = \"y\"\n").unwrap_err();
        assert_eq!(e.0[0].kind, ErrorKind::DuplicateId);
        assert_eq!(e.0[0].node.as_deref(), Some("a"));
        assert!(e.0[0].message.contains("line 1") && e.0[0].message.contains("line 4"));
    }

    #[test]
    fn structural_errors_name_node_and_key() {
        let e = parse("[node.a]\nvalue = 1\n[node.b]\nop = \"x\"\nin.v = \"nodot\"\n").unwrap_err();
        let keys: Vec<_> =
            e.0.iter()
                .map(|e| (e.node.clone().unwrap(), e.key.clone().unwrap()))
                .collect();
        assert_eq!(
            keys,
            [("a".into(), "op".into()), ("b".into(), "in.v".into())]
        );
        let e = parse("[graph]\nname = \"x\"\ncolour = 1\n[node.a]\nop = \"x\"\n").unwrap_err();
        assert_eq!(e.0[0].key.as_deref(), Some("colour"));
        assert!(parse("[graph]\nname = \"x\"\n").is_err());
        assert!(
            parse("title = 1\n[node.a]\nop = \"x\"\n").unwrap_err().0[0]
                .message
                .contains("top-level")
        );
    }

    #[test]
    fn set_overrides_params_ops_and_inputs() {
        let mut g = parse(TWO).unwrap();
        g.apply_set("a.value=3").unwrap();
        g.apply_set("b.op=math.other").unwrap();
        g.apply_set("b.in.b=a.other").unwrap();
        g.apply_set("b.label=some text").unwrap();
        assert_eq!(g.nodes[0].params[0].1, toml::Value::Integer(3));
        assert_eq!(g.nodes[1].op, "math.other");
        assert_eq!(
            g.nodes[1]
                .inputs
                .iter()
                .find(|i| i.port == "b")
                .unwrap()
                .source_port,
            "other"
        );
        assert_eq!(
            g.nodes[1].params[1].1,
            toml::Value::String("some text".into())
        );
        g.apply_set("b.in.b=").unwrap();
        assert!(
            g.nodes[1].inputs.iter().all(|i| i.port != "b"),
            "disconnected"
        );
        let e = g.apply_set("aa.value=1").unwrap_err();
        assert_eq!(e.kind, ErrorKind::BadOverride);
        assert!(e.message.contains("did you mean `a`"), "{e}");
        assert!(g.apply_set("a.value").is_err());
        assert!(g.apply_set("novalue=1").is_err());
    }

    #[test]
    fn each_groups_copy_nodes_and_take_group_wide_sets() {
        let text = r#"
[node.calib]
op = "math.constant"
value = 1.0

[each.view]
values = [0, 1]

[each.view.node.read]
op = "math.constant"
value = "{view}"

[each.view.node.scale]
op = "math.binary"
in.a = "read.value"
in.b = "calib.value"
operation = "mul"

[node.sum]
op = "math.binary"
in.a = "scale_0.value"
in.b = "scale_1.value"
"#;
        let mut g = parse(text).unwrap();
        let ids: Vec<&str> = g.nodes.iter().map(|n| n.id.as_str()).collect();
        // [node] tables first, then the groups' copies, value by value.
        assert_eq!(
            ids,
            ["calib", "sum", "read_0", "scale_0", "read_1", "scale_1"]
        );
        let scale1 = &g.nodes[5];
        assert_eq!(scale1.inputs[0].source_node, "read_1");
        assert_eq!(scale1.inputs[1].source_node, "calib");
        // A set on the written id reaches every copy; one on a copy, that copy.
        g.apply_set("scale.operation=add").unwrap();
        g.apply_set("scale_1.op=math.other").unwrap();
        for (i, op) in [(3, "math.binary"), (5, "math.other")] {
            assert_eq!(g.nodes[i].op, op);
            assert_eq!(g.nodes[i].params[0].1.as_str(), Some("add"));
        }
        let e = g.apply_set("scal.operation=add").unwrap_err();
        assert!(e.message.contains("did you mean `scale`"), "{e}");
        // A copy may not take another node's id.
        let clash = format!("{text}\n[node.read_0]\nop = \"x\"\n");
        let e = parse(&clash).unwrap_err();
        assert_eq!(e.0[0].kind, ErrorKind::DuplicateId);
    }

    #[test]
    fn references_are_read_and_checked() {
        let g = parse(
            "[graph]\nname = \"r\"\n[graph.references]\n\"icp.rmse_mm\" = { value = 3.39, note = \"paper\" }\n[node.a]\nop = \"x\"\n",
        )
        .unwrap();
        assert_eq!(g.references.len(), 1);
        assert_eq!(
            (g.references[0].metric.as_str(), g.references[0].value),
            ("icp.rmse_mm", 3.39)
        );
        let e = parse("[graph]\n[graph.references]\nrmse = { value = 1 }\n[node.a]\nop = \"x\"\n")
            .unwrap_err();
        assert_eq!(e.0[0].key.as_deref(), Some("references"));
        assert!(e.0[0].message.contains("node.metric"), "{e}");
    }
}
