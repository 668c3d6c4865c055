//! Every op's declaration as `fusegraph nodes --json` lists it is the one
//! recorded in `tests/data/nodes_before_typed_ops.json` (the 63 ops as they
//! were declared before the typed form): names, versions, ports, types,
//! parameters, defaults, units, ranges and docs. Object keys may come in any
//! order; lists (ports, parameters, choices) keep theirs.

use serde_json::Value;
use std::collections::BTreeMap;

fn by_name(specs: Vec<Value>) -> BTreeMap<String, Value> {
    specs
        .into_iter()
        .map(|s| (s["name"].as_str().expect("a name").to_string(), s))
        .collect()
}

#[test]
fn every_op_is_declared_as_before() {
    let recorded: Vec<Value> =
        serde_json::from_str(include_str!("data/nodes_before_typed_ops.json"))
            .expect("the recorded list parses");
    let recorded = by_name(recorded);
    let registry = fusegraph_nodes::builtin_registry();
    let now = by_name(
        registry
            .specs()
            .map(|s| serde_json::to_value(s).expect("a spec serialises"))
            .collect(),
    );
    let missing: Vec<&String> = recorded.keys().filter(|k| !now.contains_key(*k)).collect();
    let added: Vec<&String> = now.keys().filter(|k| !recorded.contains_key(*k)).collect();
    assert!(
        missing.is_empty() && added.is_empty(),
        "missing {missing:?}, added {added:?}"
    );
    let mut differ = Vec::new();
    for (name, before) in &recorded {
        let after = &now[name];
        if before != after {
            differ.push(format!(
                "{name}:\n  before {}\n  after  {}",
                serde_json::to_string(before).unwrap(),
                serde_json::to_string(after).unwrap()
            ));
        }
    }
    assert!(
        differ.is_empty(),
        "{} ops differ:\n{}",
        differ.len(),
        differ.join("\n")
    );
}
