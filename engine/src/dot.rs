//! Graphviz rendering of a graph: one box per node (id and op), one edge per
//! connection labelled `output -> input`.

use crate::validate::ValidGraph;

/// The graph in Graphviz `dot` syntax.
pub fn to_dot(graph: &ValidGraph) -> String {
    let quote = |s: &str| format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""));
    let mut out = format!(
        "digraph {} {{\n  rankdir=LR;\n  node [shape=box, fontname=\"Helvetica\"];\n",
        quote(&graph.name)
    );
    for node in &graph.nodes {
        let label = format!("{}\\n{}", node.id, node.op.spec().name);
        out += &format!(
            "  {} [label={}];\n",
            quote(&node.id),
            format_args!("\"{label}\"")
        );
    }
    for node in &graph.nodes {
        for e in &node.inputs {
            out += &format!(
                "  {} -> {} [label={}];\n",
                quote(&graph.nodes[e.from].id),
                quote(&node.id),
                quote(&format!("{} -> {}", e.from_port, e.port))
            );
        }
    }
    out + "}\n"
}
