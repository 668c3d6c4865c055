//! Every validation error names the file, the node and the key, and comes before
//! anything runs.

mod common;

use common::{registry, write_graph};
use fusegraph_engine::session::load_graph;
use fusegraph_engine::{ErrorKind, GraphError};

/// Validates `text` (with overrides) and returns its errors.
fn errors(text: &str, sets: &[&str]) -> Vec<GraphError> {
    let t = tempfile::tempdir().unwrap();
    let (reg, counters) = registry();
    let g = write_graph(t.path(), "exp.toml", text);
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let errs = match load_graph(&g, &sets, &reg) {
        Ok(_) => panic!("graph should be invalid:\n{text}"),
        Err(e) => e.0,
    };
    assert_eq!(counters.total(), 0, "nothing runs during validation");
    for e in &errs {
        assert!(
            e.to_string().starts_with(&g.display().to_string()),
            "names the file: {e}"
        );
    }
    errs
}

/// The one error of `kind`, checked to name `node` and `key` and to say `says`.
fn expect(errs: &[GraphError], kind: ErrorKind, node: &str, key: Option<&str>, says: &[&str]) {
    let e = errs
        .iter()
        .find(|e| e.kind == kind)
        .unwrap_or_else(|| panic!("no {kind:?} error in {errs:?}"));
    assert_eq!(e.node.as_deref(), Some(node), "{e}");
    assert_eq!(e.key.as_deref(), key, "{e}");
    let text = e.to_string();
    assert!(text.contains(&format!("node `{node}`")), "{text}");
    if let Some(k) = key {
        assert!(text.contains(&format!("key `{k}`")), "{text}");
    }
    for s in says {
        assert!(text.contains(s), "{text:?} should contain {s:?}");
    }
}

const OK: &str = "[node.a]\nop = \"test.source\"\nvalue = 1.5\n\n[node.b]\nop = \"test.add\"\nin.a = \"a.value\"\n";

#[test]
fn a_valid_graph_passes() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let g = load_graph(&write_graph(t.path(), "ok.toml", OK), &[], &reg).unwrap();
    assert_eq!(g.name, "ok", "name defaults to the file stem");
    assert_eq!(g.order, [0, 1]);
}

#[test]
fn toml_syntax_error_gives_line_and_column() {
    let errs = errors("[node.a]\nop = \"test.source\"\nvalue = [1.0,\n", &[]);
    assert_eq!(errs[0].kind, ErrorKind::Syntax);
    assert!(errs[0].message.contains("line 3, column"), "{}", errs[0]);
}

#[test]
fn unknown_op_suggests_the_closest() {
    let errs = errors(&OK.replace("test.add", "test.ad"), &[]);
    expect(
        &errs,
        ErrorKind::UnknownOp,
        "b",
        Some("op"),
        &["unknown op `test.ad`", "did you mean `test.add`?"],
    );
}

#[test]
fn unknown_parameter_lists_the_valid_ones() {
    let errs = errors(&OK.replace("value = 1.5", "valeu = 1.5"), &[]);
    expect(
        &errs,
        ErrorKind::UnknownParam,
        "a",
        Some("valeu"),
        &["did you mean `value`?", "valid: value, repeat, mode"],
    );
}

#[test]
fn wrong_type_and_out_of_range_parameters() {
    let errs = errors(&OK.replace("value = 1.5", "value = \"big\""), &[]);
    expect(
        &errs,
        ErrorKind::BadParam,
        "a",
        Some("value"),
        &["expected a number, found string"],
    );
    let errs = errors(&OK.replace("value = 1.5", "value = 2e7"), &[]);
    expect(
        &errs,
        ErrorKind::BadParam,
        "a",
        Some("value"),
        &["above the maximum 1000000 mm"],
    );
    let errs = errors(&OK.replace("value = 1.5", "repeat = 1.5"), &[]);
    expect(
        &errs,
        ErrorKind::BadParam,
        "a",
        Some("repeat"),
        &["expected an integer, found float `1.5`"],
    );
    let errs = errors(&OK.replace("value = 1.5", "mode = \"medium\""), &[]);
    expect(
        &errs,
        ErrorKind::BadParam,
        "a",
        Some("mode"),
        &["not one of: fast, slow"],
    );
}

#[test]
fn missing_required_input_and_parameter() {
    let errs = errors("[node.b]\nop = \"test.add\"\n", &[]);
    expect(
        &errs,
        ErrorKind::MissingInput,
        "b",
        Some("in.a"),
        &["required input not connected", "Scalar"],
    );
    let errs = errors("[node.f]\nop = \"test.file\"\n", &[]);
    expect(
        &errs,
        ErrorKind::MissingParam,
        "f",
        Some("path"),
        &["required parameter missing"],
    );
}

#[test]
fn missing_file_is_named() {
    let errs = errors(
        "[node.f]\nop = \"test.file\"\npath = \"nowhere.dcm\"\n",
        &[],
    );
    expect(
        &errs,
        ErrorKind::MissingFile,
        "f",
        Some("path"),
        &["no such file or folder", "nowhere.dcm"],
    );
}

#[test]
fn input_naming_an_unknown_node_or_port() {
    let errs = errors(
        &OK.replace("in.a = \"a.value\"", "in.a = \"aa.value\""),
        &[],
    );
    expect(
        &errs,
        ErrorKind::UnknownSource,
        "b",
        Some("in.a"),
        &["no node `aa`", "did you mean `a`?"],
    );
    let errs = errors(
        &OK.replace("in.a = \"a.value\"", "in.a = \"a.volume\""),
        &[],
    );
    expect(
        &errs,
        ErrorKind::UnknownSource,
        "b",
        Some("in.a"),
        &["has no output `volume`", "outputs: value"],
    );
    let errs = errors(
        &OK.replace(
            "in.a = \"a.value\"",
            "in.a = \"a.value\"\nin.c = \"a.value\"",
        ),
        &[],
    );
    expect(
        &errs,
        ErrorKind::UnknownInput,
        "b",
        Some("in.c"),
        &["no input port `c`", "inputs: a, b"],
    );
}

#[test]
fn port_type_mismatch_names_both_types() {
    let text =
        "[node.v]\nop = \"test.volume\"\n\n[node.b]\nop = \"test.add\"\nin.a = \"v.volume\"\n";
    let errs = errors(text, &[]);
    expect(
        &errs,
        ErrorKind::TypeMismatch,
        "b",
        Some("in.a"),
        &["takes Scalar", "`v.volume` is Volume"],
    );
    let text = "[node.a]\nop = \"test.source\"\n\n[node.n]\nop = \"test.voxels\"\nin.volume = \"a.value\"\n";
    let errs = errors(text, &[]);
    expect(
        &errs,
        ErrorKind::TypeMismatch,
        "n",
        Some("in.volume"),
        &["takes Volume | Mask", "is Scalar"],
    );
}

#[test]
fn duplicate_ids_are_named() {
    let errs = errors(&format!("{OK}\n[node.a]\nop = \"test.source\"\n"), &[]);
    expect(
        &errs,
        ErrorKind::DuplicateId,
        "a",
        None,
        &["duplicate node id", "line 1", "line 9"],
    );
}

#[test]
fn cycles_name_every_node_in_order() {
    let text = r#"
[node.src]
op = "test.source"

[node.p]
op = "test.add"
in.a = "src.value"
in.b = "r.value"

[node.q]
op = "test.add"
in.a = "p.value"

[node.r]
op = "test.add"
in.a = "q.value"

[node.self_loop]
op = "test.add"
in.a = "self_loop.value"
"#;
    let errs = errors(text, &[]);
    assert_eq!(errs.len(), 2, "{errs:?}");
    expect(
        &errs[..1],
        ErrorKind::Cycle,
        "p",
        None,
        &["cycle: p -> q -> r -> p"],
    );
    expect(
        &errs[1..],
        ErrorKind::Cycle,
        "self_loop",
        None,
        &["cycle: self_loop -> self_loop"],
    );
}

#[test]
fn all_errors_are_reported_at_once() {
    let text = "[node.a]\nop = \"test.sorce\"\n\n[node.b]\nop = \"test.add\"\nin.a = \"zz.value\"\nfoo = 1\n";
    let kinds: Vec<ErrorKind> = errors(text, &[]).iter().map(|e| e.kind).collect();
    assert_eq!(
        kinds,
        [
            ErrorKind::UnknownOp,
            ErrorKind::UnknownParam,
            ErrorKind::UnknownSource
        ]
    );
}

#[test]
fn overrides_are_validated_the_same_way() {
    let errs = errors(OK, &["a.value=\"x\""]);
    expect(
        &errs,
        ErrorKind::BadParam,
        "a",
        Some("value"),
        &["expected a number"],
    );
    let errs = errors(OK, &["a.valu=2"]);
    expect(
        &errs,
        ErrorKind::UnknownParam,
        "a",
        Some("valu"),
        &["did you mean `value`?"],
    );
    let errs = errors(OK, &["b.op=test.volume"]);
    expect(
        &errs,
        ErrorKind::UnknownInput,
        "b",
        Some("in.a"),
        &["`test.volume` has no input port `a`"],
    );
    let errs = errors(OK, &["b.op=test.voxels", "b.in.volume=a.value"]);
    expect(
        &errs,
        ErrorKind::TypeMismatch,
        "b",
        Some("in.volume"),
        &["is Scalar"],
    );
    let errs = errors(OK, &["c.value=1"]);
    expect(
        &errs,
        ErrorKind::BadOverride,
        "c",
        Some("value"),
        &["no node with this id"],
    );
    let errs = errors(OK, &["b.in.a="]);
    expect(
        &errs,
        ErrorKind::MissingInput,
        "b",
        Some("in.a"),
        &["required input not connected"],
    );
    let errs = errors(OK, &["b.op=test.nope"]);
    expect(
        &errs,
        ErrorKind::UnknownOp,
        "b",
        Some("op"),
        &["unknown op `test.nope`"],
    );
}

#[test]
fn a_swapped_op_with_fitting_ports_is_valid() {
    let t = tempfile::tempdir().unwrap();
    let (reg, _) = registry();
    let g = write_graph(
        t.path(),
        "g.toml",
        "[node.a]\nop = \"test.source\"\n\n[node.b]\nop = \"test.fail\"\nin.a = \"a.value\"\n",
    );
    let valid = load_graph(&g, &["b.op=test.add".into()], &reg).unwrap();
    assert_eq!(valid.nodes[1].op.spec().name, "test.add");
}

#[test]
fn two_sinks_writing_one_file_are_refused() {
    let sinks = format!(
        "{OK}\n[node.w1]\nop = \"test.write\"\nin.value = \"a.value\"\nfile = \"out.txt\"\n\n\
         [node.w2]\nop = \"test.write\"\nin.value = \"b.value\"\nfile = \"out.txt\"\n"
    );
    let errs = errors(&sinks, &[]);
    expect(
        &errs,
        ErrorKind::OutputClash,
        "w2",
        Some("file"),
        &["writes \"out.txt\", as node `w1` does"],
    );
}

#[test]
fn a_sink_file_outside_the_output_folder_is_refused_before_running() {
    for file in ["../../x.txt", "/tmp/x.txt", "a/../../x.txt", ""] {
        let sink = format!(
            "{OK}\n[node.w1]\nop = \"test.write\"\nin.value = \"a.value\"\nfile = {file:?}\n"
        );
        let errs = errors(&sink, &[]);
        expect(
            &errs,
            ErrorKind::BadParam,
            "w1",
            Some("file"),
            &["must be a relative path inside the output folder"],
        );
    }
}

#[test]
fn a_set_value_with_a_line_break_is_refused() {
    let errs = errors(OK, &["a.value=2\n[node.x]"]);
    assert_eq!(errs[0].kind, ErrorKind::BadOverride, "{errs:?}");
    assert!(
        errs[0].message.contains("may not hold a line break"),
        "{}",
        errs[0]
    );
}
