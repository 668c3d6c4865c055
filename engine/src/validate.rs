//! Checking a [`GraphDoc`] against the registry: ops, parameters, inputs, types and
//! cycles. Every problem is collected (not just the first) and names the file, the
//! node and the key.

use crate::error::{ErrorKind, GraphError, GraphErrors, closest};
use crate::graph::GraphDoc;
use crate::op::{Op, Wired};
use crate::param::{ParamKind, ParamValue, Params};
use crate::registry::Registry;
use petgraph::graph::{DiGraph, NodeIndex};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

/// An input connection after validation: input `port` takes output `from_port`
/// of node number `from`.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Input port of this node.
    pub port: String,
    /// Index of the upstream node in [`ValidGraph::nodes`].
    pub from: usize,
    /// Output port of the upstream node.
    pub from_port: String,
}

/// A node whose op exists and whose parameters and inputs fit it.
#[derive(Clone)]
pub struct ValidNode {
    /// Node id.
    pub id: String,
    /// The node type.
    pub op: Arc<dyn Op>,
    /// Every declared parameter, given or defaulted.
    pub params: Params,
    /// Connected inputs.
    pub inputs: Vec<Edge>,
}

/// A graph that passed every check and is ready to be keyed and run.
#[derive(Clone)]
pub struct ValidGraph {
    /// Graph name.
    pub name: String,
    /// The graph file.
    pub file: PathBuf,
    /// Nodes in file order.
    pub nodes: Vec<ValidNode>,
    /// Node indices in a topological order (every node after its inputs).
    pub order: Vec<usize>,
    /// Figures from elsewhere the report shows beside ours (`[graph.references]`).
    pub references: Vec<crate::graph::Reference>,
}

impl ValidGraph {
    /// The index of node `id`.
    pub fn index_of(&self, id: &str) -> Option<usize> {
        self.nodes.iter().position(|n| n.id == id)
    }
}

/// Sinks whose `file` would land outside the output folder (absolute, or
/// with `..`), or that would write the same file (their `file` parameters are
/// equal): one output would be lost.
fn output_clashes(file: &std::path::Path, nodes: &[ValidNode]) -> Vec<GraphError> {
    let mut writers: HashMap<&str, &str> = HashMap::new();
    let mut errors = Vec::new();
    for n in nodes.iter().filter(|n| n.op.spec().writes_output) {
        let Some(ParamValue::String(name)) = n.params.0.get("file") else {
            continue;
        };
        if let Some(problem) = crate::op::output_path_problem(name) {
            errors.push(
                GraphError::file(ErrorKind::BadParam, file, problem)
                    .at_node(&n.id)
                    .at_key("file"),
            );
            continue;
        }
        if let Some(first) = writers.insert(name.as_str(), n.id.as_str()) {
            errors.push(
                GraphError::file(
                    ErrorKind::OutputClash,
                    file,
                    format!("writes {name:?}, as node `{first}` does: one output would be lost"),
                )
                .at_node(&n.id)
                .at_key("file"),
            );
        }
    }
    errors
}

/// Checks `doc` against `registry`.
pub fn validate(doc: &GraphDoc, registry: &Registry) -> Result<ValidGraph, GraphErrors> {
    let mut errors = Vec::new();
    let index: HashMap<&str, usize> = doc
        .nodes
        .iter()
        .enumerate()
        .map(|(i, n)| (n.id.as_str(), i))
        .collect();
    let ops: Vec<Option<&Arc<dyn Op>>> = doc.nodes.iter().map(|n| registry.get(&n.op)).collect();
    let mut nodes = Vec::new();
    for (decl, op) in doc.nodes.iter().zip(&ops) {
        let err = |kind, msg: String| GraphError::file(kind, &doc.file, msg).at_node(&decl.id);
        let Some(op) = op else {
            let hint = match closest(&decl.op, registry.names()) {
                Some(c) => format!(" (did you mean `{c}`?)"),
                None => " (`fusegraph nodes` lists them)".into(),
            };
            errors.push(
                err(
                    ErrorKind::UnknownOp,
                    format!("unknown op `{}`{hint}", decl.op),
                )
                .at_key("op"),
            );
            continue;
        };
        let spec = op.spec();

        let mut params = Params::default();
        for (key, value) in &decl.params {
            match spec.param_spec(key) {
                None => {
                    let valid = spec.params.iter().map(|p| p.name.as_str());
                    let hint = closest(key, valid.clone())
                        .map(|c| format!("did you mean `{c}`? "))
                        .unwrap_or_default();
                    let list = list_or_none(valid);
                    errors.push(
                        err(
                            ErrorKind::UnknownParam,
                            format!("`{}` has no such parameter; {hint}valid: {list}", spec.name),
                        )
                        .at_key(key),
                    );
                }
                Some(p) => match p.parse(value, &doc.base_dir) {
                    Ok(v) => {
                        params.0.insert(key.clone(), v);
                    }
                    Err(m) => errors.push(err(ErrorKind::BadParam, m).at_key(key)),
                },
            }
        }
        for p in &spec.params {
            if params.0.contains_key(&p.name) {
                continue;
            }
            match &p.default {
                Some(d) => {
                    params.0.insert(p.name.clone(), d.clone());
                }
                None => errors.push(
                    err(
                        ErrorKind::MissingParam,
                        format!("required parameter missing: {} ({})", p.doc, p.kind),
                    )
                    .at_key(&p.name),
                ),
            }
        }
        // The op's own checks, once every parameter parsed: all problems a
        // single pass can find are reported before anything runs.
        if params.0.len() == spec.params.len() {
            let wired: Vec<&str> = decl.inputs.iter().map(|i| i.port.as_str()).collect();
            for problem in op.check(&params, Wired::new(&wired)) {
                errors.push(err(ErrorKind::BadParam, problem.problem).at_key(&problem.name));
            }
        }
        for p in spec.params.iter().filter(|p| p.kind == ParamKind::Path) {
            if let Some(ParamValue::Path(path)) = params.0.get(&p.name)
                && !path.as_os_str().is_empty()
                && !path.exists()
            {
                errors.push(
                    err(
                        ErrorKind::MissingFile,
                        format!("no such file or folder: {}", path.display()),
                    )
                    .at_key(&p.name),
                );
            }
        }

        let mut inputs = Vec::new();
        for input in &decl.inputs {
            let key = format!("in.{}", input.port);
            let Some(port) = spec.input_port(&input.port) else {
                let list = list_or_none(spec.inputs.iter().map(|p| p.name.as_str()));
                errors.push(
                    err(
                        ErrorKind::UnknownInput,
                        format!(
                            "`{}` has no input port `{}`; inputs: {list}",
                            spec.name, input.port
                        ),
                    )
                    .at_key(&key),
                );
                continue;
            };
            let Some(&from) = index.get(input.source_node.as_str()) else {
                let hint = closest(&input.source_node, index.keys().copied())
                    .map(|c| format!(" (did you mean `{c}`?)"))
                    .unwrap_or_default();
                errors.push(
                    err(
                        ErrorKind::UnknownSource,
                        format!("no node `{}`{hint}", input.source_node),
                    )
                    .at_key(&key),
                );
                continue;
            };
            let Some(source_op) = ops[from] else { continue };
            let source_spec = source_op.spec();
            let Some(out) = source_spec.output_port(&input.source_port) else {
                let outs = list_or_none(source_spec.outputs.iter().map(|p| p.name.as_str()));
                errors.push(
                    err(
                        ErrorKind::UnknownSource,
                        format!(
                            "node `{}` ({}) has no output `{}`; outputs: {}",
                            input.source_node, source_spec.name, input.source_port, outs
                        ),
                    )
                    .at_key(&key),
                );
                continue;
            };
            if !port.accepts(out.types[0]) {
                errors.push(
                    err(
                        ErrorKind::TypeMismatch,
                        format!(
                            "type mismatch: input `{}` takes {}, but `{}.{}` is {}",
                            port.name,
                            port.type_names(),
                            input.source_node,
                            input.source_port,
                            out.types[0]
                        ),
                    )
                    .at_key(&key),
                );
                continue;
            }
            inputs.push(Edge {
                port: input.port.clone(),
                from,
                from_port: input.source_port.clone(),
            });
        }
        for port in spec.inputs.iter().filter(|p| !p.optional) {
            if !decl.inputs.iter().any(|i| i.port == port.name) {
                errors.push(
                    err(
                        ErrorKind::MissingInput,
                        format!(
                            "required input not connected: {} ({})",
                            port.doc,
                            port.type_names()
                        ),
                    )
                    .at_key(&format!("in.{}", port.name)),
                );
            }
        }
        nodes.push(ValidNode {
            id: decl.id.clone(),
            op: (*op).clone(),
            params,
            inputs,
        });
    }
    errors.extend(output_clashes(&doc.file, &nodes));
    if !errors.is_empty() {
        return Err(GraphErrors(errors));
    }
    let order = topological_order(&nodes).map_err(|cycles| {
        GraphErrors(
            cycles
                .into_iter()
                .map(|cycle| {
                    let names: Vec<&str> = cycle.iter().map(|&i| nodes[i].id.as_str()).collect();
                    GraphError::file(
                        ErrorKind::Cycle,
                        &doc.file,
                        format!("cycle: {} -> {}", names.join(" -> "), names[0]),
                    )
                    .at_node(names[0])
                })
                .collect(),
        )
    })?;
    Ok(ValidGraph {
        name: doc.name.clone(),
        file: doc.file.clone(),
        nodes,
        order,
        references: doc.references.clone(),
    })
}

/// Names joined by commas, or `none`.
fn list_or_none<'a>(names: impl Iterator<Item = &'a str>) -> String {
    let names: Vec<&str> = names.collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

/// A topological order, or every cycle (each as its nodes in order along it).
fn topological_order(nodes: &[ValidNode]) -> Result<Vec<usize>, Vec<Vec<usize>>> {
    let mut g = DiGraph::<usize, ()>::new();
    let idx: Vec<NodeIndex> = (0..nodes.len()).map(|i| g.add_node(i)).collect();
    for (i, n) in nodes.iter().enumerate() {
        for e in &n.inputs {
            // add_edge, not update_edge: that one scans the source's edges,
            // quadratic when one node feeds all the others. Parallel edges do
            // not change the order or the cycles.
            g.add_edge(idx[e.from], idx[i], ());
        }
    }
    match petgraph::algo::toposort(&g, None) {
        Ok(order) => Ok(order.into_iter().map(|n| g[n]).collect()),
        Err(_) => {
            // toposort names one node of one cycle; tarjan_scc finds them all.
            let mut cycles: Vec<Vec<usize>> = petgraph::algo::tarjan_scc(&g)
                .into_iter()
                .filter(|scc| scc.len() > 1 || g.contains_edge(scc[0], scc[0]))
                .map(|scc| cycle_through(&g, &scc))
                .collect();
            cycles.sort();
            Err(cycles)
        }
    }
}

/// Walks a strongly connected component from its first node (in file order)
/// back to it, giving the nodes of one cycle in order.
fn cycle_through(g: &DiGraph<usize, ()>, scc: &[NodeIndex]) -> Vec<usize> {
    let start = *scc
        .iter()
        .min_by_key(|n| g[**n])
        .expect("non-empty component");
    // Breadth-first search inside the component for the shortest way back to start.
    let mut parent: HashMap<NodeIndex, NodeIndex> = HashMap::new();
    let mut queue = std::collections::VecDeque::from([start]);
    while let Some(n) = queue.pop_front() {
        let mut next: Vec<NodeIndex> = g.neighbors(n).filter(|m| scc.contains(m)).collect();
        next.sort_by_key(|m| g[*m]);
        for m in next {
            if m == start {
                let mut path = vec![g[n]];
                let mut cur = n;
                while cur != start {
                    cur = parent[&cur];
                    path.push(g[cur]);
                }
                path.reverse();
                return path;
            }
            if let std::collections::hash_map::Entry::Vacant(e) = parent.entry(m) {
                e.insert(n);
                queue.push_back(m);
            }
        }
    }
    scc.iter().map(|n| g[*n]).collect()
}
