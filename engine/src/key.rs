//! Cache keys: blake3 over what decides a node's outputs and only that: the op
//! name and version, the parameters that differ from their declared defaults in
//! canonical sorted form (path parameters by content, not by name), and the keys
//! of the inputs. Sinks also hash the output
//! folder they write to.

use crate::error::{ErrorKind, GraphError, GraphErrors};
use crate::hash::hash_path;
use crate::param::ParamValue;
use crate::validate::{ValidGraph, ValidNode};
use std::fmt;
use std::path::Path;

/// The key of a node's outputs.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeKey(pub [u8; 32]);

impl NodeKey {
    /// Lower-case hex.
    pub fn hex(&self) -> String {
        blake3::Hash::from_bytes(self.0).to_hex().to_string()
    }

    /// The key written as [`NodeKey::hex`] writes it.
    pub fn from_hex(hex: &str) -> Option<NodeKey> {
        blake3::Hash::from_hex(hex)
            .ok()
            .map(|h| NodeKey(*h.as_bytes()))
    }
}

impl fmt::Debug for NodeKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "NodeKey({})", &self.hex()[..16])
    }
}

impl fmt::Display for NodeKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.hex())
    }
}

/// The key of every node (indexed like `graph.nodes`). Reads every path
/// parameter's content; a file that cannot be read is an error naming its node
/// and key.
pub fn node_keys(graph: &ValidGraph, out_dir: &Path) -> Result<Vec<NodeKey>, GraphErrors> {
    let mut keys: Vec<Option<NodeKey>> = vec![None; graph.nodes.len()];
    let mut errors = Vec::new();
    for &i in &graph.order {
        // Upstream keys exist: `order` is topological.
        let upstream = |j: usize| keys[j].unwrap_or(NodeKey([0; 32]));
        match node_key(&graph.nodes[i], upstream, out_dir) {
            Ok(key) => keys[i] = Some(key),
            Err(problems) => {
                keys[i] = Some(NodeKey([0; 32]));
                errors.extend(problems.into_iter().map(|(name, e)| {
                    GraphError::file(
                        ErrorKind::MissingFile,
                        &graph.file,
                        format!("cannot read: {e}"),
                    )
                    .at_node(&graph.nodes[i].id)
                    .at_key(&name)
                }));
            }
        }
    }
    if !errors.is_empty() {
        return Err(GraphErrors(errors));
    }
    Ok(keys
        .into_iter()
        .map(|k| k.expect("every node keyed"))
        .collect())
}

/// The key of one node, given its upstream nodes' keys (by node index):
/// its op's name, version and origin, its parameters (a path parameter by
/// its content), its inputs' sources and, for sinks, the output folder.
/// Errors name each parameter whose file cannot be read. Computed again after
/// the node ran, it tells whether a file the node read changed meanwhile.
pub fn node_key(
    node: &ValidNode,
    upstream: impl Fn(usize) -> NodeKey,
    out_dir: &Path,
) -> Result<NodeKey, Vec<(String, std::io::Error)>> {
    let spec = node.op.spec();
    let mut h = blake3::Hasher::new();
    h.update(b"fusegraph node key v2\0");
    put_str(&mut h, &spec.name);
    h.update(&spec.version.to_le_bytes());
    if let Some(origin) = &spec.origin {
        // A rebuilt plugin invalidates its own ops' results only.
        put_str(&mut h, &origin.content_hash);
    }
    if let Some(code) = &spec.code {
        // An edited op invalidates its own results (and, through the
        // chained keys, what follows) only.
        put_str(&mut h, "code");
        put_str(&mut h, code);
    }
    let mut problems = Vec::new();
    for (name, value) in &node.params.0 {
        // A parameter at its declared default is left out: an op that gains
        // a parameter whose default reproduces its old outputs keeps its
        // cached results. (A changed default changes the outputs for the
        // same graph, which bumps the op's version.)
        if spec
            .param_spec(name)
            .is_some_and(|p| p.default.as_ref() == Some(value))
        {
            continue;
        }
        put_str(&mut h, name);
        if let Err(e) = put_param(&mut h, value) {
            problems.push((name.clone(), e));
        }
    }
    let mut inputs: Vec<_> = node.inputs.iter().collect();
    inputs.sort_by(|a, b| a.port.cmp(&b.port));
    for e in inputs {
        put_str(&mut h, &e.port);
        put_str(&mut h, &e.from_port);
        h.update(&upstream(e.from).0);
    }
    if spec.writes_output {
        put_str(
            &mut h,
            &std::path::absolute(out_dir)
                .unwrap_or(out_dir.into())
                .to_string_lossy(),
        );
    }
    if !problems.is_empty() {
        return Err(problems);
    }
    Ok(NodeKey(*h.finalize().as_bytes()))
}

fn put_str(h: &mut blake3::Hasher, s: &str) {
    h.update(&(s.len() as u64).to_le_bytes());
    h.update(s.as_bytes());
}

fn put_param(h: &mut blake3::Hasher, value: &ParamValue) -> std::io::Result<()> {
    match value {
        ParamValue::Float(v) => {
            h.update(b"f");
            h.update(&canonical(*v).to_le_bytes());
        }
        ParamValue::Int(v) => {
            h.update(b"i");
            h.update(&v.to_le_bytes());
        }
        ParamValue::Bool(v) => {
            h.update(if *v { b"T" } else { b"F" });
        }
        ParamValue::String(s) => {
            h.update(b"s");
            put_str(h, s);
        }
        ParamValue::Path(p) if p.as_os_str().is_empty() => {
            h.update(b"p-none");
        }
        ParamValue::Path(p) => {
            h.update(b"p");
            h.update(hash_path(p)?.as_bytes());
        }
        ParamValue::FloatList(v) => {
            h.update(b"F");
            h.update(&(v.len() as u64).to_le_bytes());
            v.iter().for_each(|x| {
                h.update(&canonical(*x).to_le_bytes());
            });
        }
        ParamValue::IntList(v) => {
            h.update(b"I");
            h.update(&(v.len() as u64).to_le_bytes());
            v.iter().for_each(|x| {
                h.update(&x.to_le_bytes());
            });
        }
        ParamValue::StringList(v) => {
            h.update(b"S");
            h.update(&(v.len() as u64).to_le_bytes());
            v.iter().for_each(|s| put_str(h, s));
        }
    }
    Ok(())
}

/// -0.0 and 0.0 are the same parameter.
fn canonical(x: f64) -> u64 {
    if x == 0.0 { 0 } else { x.to_bits() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::GraphDoc;
    use crate::op::{Inputs, Op, OpError, OpSpec, Outputs, RunCtx};
    use crate::param::{ParamSpec, Params};
    use crate::registry::Registry;
    use crate::validate::validate;
    use crate::value::ValueType;
    use std::sync::Arc;

    struct Source(OpSpec);

    impl Op for Source {
        fn spec(&self) -> &OpSpec {
            &self.0
        }
        fn run(&self, _: &Inputs, _: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
            unreachable!("keys only")
        }
    }

    /// The key of node `a` in `text`, with `test.source` declaring `params`.
    fn key_of(text: &str, params: &[ParamSpec]) -> NodeKey {
        let mut spec = OpSpec::new("test.source", 1, "A number").output(
            "value",
            ValueType::Scalar,
            "The number",
        );
        for p in params {
            spec = spec.param(p.clone());
        }
        let mut registry = Registry::new();
        registry.register(Arc::new(Source(spec))).unwrap();
        let doc = GraphDoc::parse(text, Path::new("g.toml")).unwrap();
        let graph = validate(&doc, &registry).unwrap();
        node_key(&graph.nodes[0], |_| NodeKey([0; 32]), Path::new("out")).unwrap()
    }

    #[test]
    fn a_parameter_added_at_its_default_keeps_the_key_and_set_otherwise_changes_it() {
        let value = ParamSpec::float("value", 1.0, "mm", "The number");
        let gain = ParamSpec::float("gain", 1.0, "", "Added later; 1 is the old behaviour");
        let graph = "[node.a]\nop = \"test.source\"\nvalue = 2.0\n";
        let before = key_of(graph, std::slice::from_ref(&value));
        let after = key_of(graph, &[value.clone(), gain.clone()]);
        assert_eq!(before, after, "a new parameter at its default");
        let explicit = key_of(
            "[node.a]\nop = \"test.source\"\nvalue = 2.0\ngain = 1\n",
            &[value.clone(), gain.clone()],
        );
        assert_eq!(before, explicit, "written out at its default");
        let set = key_of(
            "[node.a]\nop = \"test.source\"\nvalue = 2.0\ngain = 1.5\n",
            &[value.clone(), gain],
        );
        assert_ne!(before, set, "set to another value");
        let default_value = key_of("[node.a]\nop = \"test.source\"\n", &[value]);
        assert_ne!(before, default_value, "value 2 is not the default 1");
    }
}
