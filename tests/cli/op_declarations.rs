//! Every op's declaration as `fusegraph nodes --json` lists it is the one
//! recorded in `tests/data/op_declarations.json`: names, versions, ports,
//! types, parameters, defaults, units, ranges and docs. It was first written
//! before the typed declaration form, which had to reproduce it exactly; now
//! it keeps any change to what users and their graphs see deliberate. Object
//! keys may come in any order; lists (ports, parameters, choices) keep theirs.
//!
//! After a deliberate change (a new parameter, a version bump), rewrite the
//! record with `FUSEGRAPH_BLESS=1 cargo test --test cli op_declarations` and
//! review its diff.

use serde_json::Value;
use std::collections::BTreeMap;

fn by_name(specs: Vec<Value>) -> BTreeMap<String, Value> {
    specs
        .into_iter()
        .map(|s| (s["name"].as_str().expect("a name").to_string(), s))
        .collect()
}

#[test]
fn every_op_is_declared_as_recorded() {
    let record =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/op_declarations.json");
    let registry = fusegraph_nodes::builtin_registry();
    if std::env::var_os("FUSEGRAPH_BLESS").is_some() {
        let specs: Vec<Value> = registry
            .specs()
            .map(|s| serde_json::to_value(s).expect("a spec serialises"))
            .collect();
        let text = serde_json::to_string_pretty(&specs).expect("JSON") + "\n";
        std::fs::write(&record, text).expect("writing the record");
    }
    let recorded: Vec<Value> =
        serde_json::from_str(&std::fs::read_to_string(&record).expect("the record"))
            .expect("the recorded list parses");
    let recorded = by_name(recorded);
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
