//! `[each.NAME]` groups: nodes written once and copied for every value of a
//! list, so a graph that runs one branch per camera view (or per anything)
//! says it once.
//!
//! ```toml
//! [each.view]
//! values = [0, 1, 2]
//!
//! [each.view.node.left]
//! op = "io.read_image"
//! file = "left_{view:02}.png"     # left_00.png, left_01.png, ...
//!
//! [each.view.node.grey]
//! op = "image.grey"
//! in.image = "left.image"         # this copy's `left`: left_0, left_1, ...
//! ```
//!
//! Copy ids are the written id, `_` and the value (`left_0`). In every string
//! of a copy, `{NAME}` becomes the value and `{NAME:0W}` the value padded with
//! zeros to W digits (a string that is only `"{NAME}"` becomes the value
//! itself, a number if it is one: `view = "{view}"`); an input naming a node of the same group means that
//! node's copy, any other input is left as written. Nodes outside the group
//! name the copies by their ids (`grey_2.image`), and `--set grey.KEY=...`
//! sets KEY on every copy of `grey`.

use crate::error::{ErrorKind, GraphError};
use std::path::Path;

/// One `[each.NAME]` group after expansion.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    /// The group's name (the placeholder in its strings).
    pub name: String,
    /// The values, as they appear in ids and strings.
    pub values: Vec<String>,
    /// Ids of the nodes as written in the group (before the suffix).
    pub members: Vec<String>,
}

impl Group {
    /// The ids of the copies of member `id`, or `None` if it is no member.
    pub fn copies_of(&self, id: &str) -> Option<Vec<String>> {
        self.members
            .iter()
            .any(|m| m == id)
            .then(|| self.values.iter().map(|v| copy_id(id, v)).collect())
    }
}

/// The most nodes `[each.NAME]` groups may bring a graph to: twice the
/// 100,000-node graph `fusegraph bench scheduler --nodes 100000` validates.
pub const MAX_NODES: usize = 200_000;

/// Node tables as written: (id, body).
type NodeTables = Vec<(String, toml::Value)>;

fn copy_id(id: &str, value: &str) -> String {
    format!("{id}_{value}")
}

/// Expands group `name` (the body of `[each.NAME]`) into node tables: (id,
/// body) pairs for the usual node parser, in value order then file order.
///
/// `budget` is how many nodes the copies may add: a group that would make
/// more is refused before any copy is made, so a small file cannot cost a
/// gigabyte.
pub(crate) fn expand(
    name: &str,
    body: &toml::Value,
    file: &Path,
    budget: usize,
) -> Result<(Group, NodeTables), Vec<GraphError>> {
    let err =
        |msg: String| GraphError::file(ErrorKind::Structure, file, format!("[each.{name}]: {msg}"));
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(vec![err(
            "a group name may hold only letters, digits and '_'".into(),
        )]);
    }
    let Some(body) = body.as_table() else {
        return Err(vec![err(
            "must be a table with `values` and [each.NAME.node.ID] tables".into(),
        )]);
    };
    let mut errors = Vec::new();
    for key in body.keys().filter(|k| *k != "values" && *k != "node") {
        errors.push(err("unknown key; a group has `values` and `node` tables".into()).at_key(key));
    }
    let values = match body.get("values").and_then(|v| v.as_array()) {
        Some(list) if !list.is_empty() => list
            .iter()
            .map(|v| match v {
                toml::Value::Integer(i) if *i >= 0 => Ok(i.to_string()),
                toml::Value::String(s)
                    if !s.is_empty()
                        && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') =>
                {
                    Ok(s.clone())
                }
                other => Err(err(format!(
                    "value {other} must be a whole number >= 0 or a name of letters, digits, '_' and '-'"
                ))
                .at_key("values")),
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| vec![e])?,
        _ => {
            errors.push(err("`values` must be a non-empty list".into()).at_key("values"));
            Vec::new()
        }
    };
    let mut seen = std::collections::HashSet::with_capacity(values.len());
    for v in &values {
        if !seen.insert(v) {
            errors.push(err(format!("value {v} appears twice")).at_key("values"));
        }
    }
    let nodes = match body.get("node").map(|n| n.as_table()) {
        Some(Some(nodes)) if !nodes.is_empty() => nodes.clone(),
        _ => {
            errors.push(err("has no nodes (add [each.NAME.node.ID] tables)".into()));
            toml::Table::new()
        }
    };
    let copies = values.len().saturating_mul(nodes.len());
    if copies > budget {
        errors.push(
            err(format!(
                "{} values x {} nodes make {copies} nodes, more than the {budget} a graph may still add \
                 (at most {} nodes in all)",
                values.len(),
                nodes.len(),
                MAX_NODES
            ))
            .at_key("values"),
        );
    }
    if !errors.is_empty() {
        return Err(errors);
    }
    let members: Vec<String> = nodes.keys().cloned().collect();
    let mut out = Vec::with_capacity(values.len() * members.len());
    for value in &values {
        for (id, node) in &nodes {
            let mut copy = substitute(node, name, value);
            if let Some(ins) = copy.get_mut("in").and_then(|i| i.as_table_mut()) {
                for (_, source) in ins.iter_mut() {
                    let rewired = match &*source {
                        toml::Value::String(s) => s
                            .split_once('.')
                            .filter(|(node, _)| members.iter().any(|m| m == node))
                            .map(|(node, port)| format!("{}.{port}", copy_id(node, value))),
                        _ => None,
                    };
                    if let Some(r) = rewired {
                        *source = toml::Value::String(r);
                    }
                }
            }
            out.push((copy_id(id, value), copy));
        }
    }
    Ok((
        Group {
            name: name.to_string(),
            values,
            members,
        },
        out,
    ))
}

/// `v` with `{name}` and `{name:0W}` in every string replaced by `value`; a
/// string that is just `{name}` becomes the value itself, a number when it
/// is one (`view = "{view}"` is the integer view).
fn substitute(v: &toml::Value, name: &str, value: &str) -> toml::Value {
    match v {
        toml::Value::String(s) if *s == format!("{{{name}}}") => value
            .parse::<i64>()
            .map(toml::Value::Integer)
            .unwrap_or_else(|_| toml::Value::String(value.to_string())),
        toml::Value::String(s) => toml::Value::String(fill(s, name, value)),
        toml::Value::Array(a) => {
            toml::Value::Array(a.iter().map(|x| substitute(x, name, value)).collect())
        }
        toml::Value::Table(t) => toml::Value::Table(
            t.iter()
                .map(|(k, x)| (k.clone(), substitute(x, name, value)))
                .collect(),
        ),
        other => other.clone(),
    }
}

/// `text` with `{name}` replaced by `value` and `{name:0W}` by `value` padded
/// with zeros to W characters; other braces are left alone.
fn fill(text: &str, name: &str, value: &str) -> String {
    let open = format!("{{{name}");
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(&open) {
        out.push_str(&rest[..at]);
        let after = &rest[at + open.len()..];
        let width = if let Some(tail) = after.strip_prefix('}') {
            Some((0, tail))
        } else {
            after
                .strip_prefix(":0")
                .and_then(|t| t.split_once('}'))
                .and_then(|(w, tail)| w.parse::<usize>().ok().map(|w| (w, tail)))
        };
        match width {
            Some((w, tail)) => {
                out.push_str(&format!("{value:0>w$}"));
                rest = tail;
            }
            None => {
                out.push_str(&open);
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placeholders_with_and_without_padding() {
        assert_eq!(fill("left_{view:02}.png", "view", "3"), "left_03.png");
        assert_eq!(fill("v{view}/{view}", "view", "12"), "v12/12");
        assert_eq!(fill("{other} {view:x}", "view", "1"), "{other} {view:x}");
        assert_eq!(fill("{view:03}", "view", "1234"), "1234");
    }

    #[test]
    fn copies_rewire_their_own_group_only() {
        let body: toml::Value = toml::from_str(
            r#"
values = [0, 5]
[node.read]
op = "io.read_image"
file = "left_{view:02}.png"
sizes = ["{view}", 2]
[node.grey]
op = "image.grey"
in.image = "read.image"
in.rig = "calib.rig"
"#,
        )
        .unwrap();
        let (group, nodes) = expand("view", &body, Path::new("g.toml"), 1000).unwrap();
        let ids: Vec<&str> = nodes.iter().map(|(id, _)| id.as_str()).collect();
        assert_eq!(ids, ["read_0", "grey_0", "read_5", "grey_5"]);
        let read5 = &nodes[2].1;
        assert_eq!(read5["file"].as_str(), Some("left_05.png"));
        assert_eq!(read5["sizes"][0].as_integer(), Some(5));
        let grey5 = &nodes[3].1;
        assert_eq!(grey5["in"]["image"].as_str(), Some("read_5.image"));
        assert_eq!(grey5["in"]["rig"].as_str(), Some("calib.rig"));
        assert_eq!(
            group.copies_of("grey"),
            Some(vec!["grey_0".into(), "grey_5".into()])
        );
        assert_eq!(group.copies_of("calib"), None);
    }

    #[test]
    fn bad_groups_say_what_is_wrong() {
        let bad = |text: &str| {
            let body: toml::Value = toml::from_str(text).unwrap();
            let e = expand("view", &body, Path::new("g.toml"), 1000).unwrap_err();
            e.iter()
                .map(|e| e.to_string())
                .collect::<Vec<_>>()
                .join("; ")
        };
        assert!(bad("values = []\n[node.a]\nop = \"x\"").contains("non-empty list"));
        assert!(bad("values = [1, 1]\n[node.a]\nop = \"x\"").contains("appears twice"));
        assert!(bad("values = [1.5]\n[node.a]\nop = \"x\"").contains("whole number"));
        assert!(bad("values = [1]").contains("has no nodes"));
        assert!(bad("values = [1]\ncolour = 2\n[node.a]\nop = \"x\"").contains("unknown key"));
    }

    #[test]
    fn a_group_that_would_make_too_many_nodes_is_refused_before_copying() {
        let values: Vec<String> = (0..10_000).map(|i| i.to_string()).collect();
        let nodes: String = (0..100)
            .map(|i| format!("[node.n{i}]\nop = \"t.x\"\n"))
            .collect();
        let text = format!("values = [{}]\n{nodes}", values.join(", "));
        let body: toml::Value = toml::from_str(&text).unwrap();
        let e = expand("v", &body, Path::new("g.toml"), MAX_NODES).unwrap_err();
        assert_eq!(e.len(), 1, "{e:?}");
        assert!(
            e[0].message
                .contains("[each.v]: 10000 values x 100 nodes make 1000000 nodes"),
            "{}",
            e[0].message
        );
        assert_eq!(e[0].key.as_deref(), Some("values"));
    }
}
