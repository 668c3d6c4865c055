//! Declaring a plugin's ops: [`OpDecl`] and [`Param`] builders, written to the
//! TOML text the host reads. One `[[op]]` table per op:
//!
//! ```toml
//! [[op]]
//! name = "census.match"          # stage.action, unique among all ops
//! version = 1                    # bump when outputs change for the same inputs
//! doc = "one line"
//! inputs = [{ name = "left", types = ["Image"], optional = false, doc = "..." }]
//! outputs = [{ name = "disparity", type = "Disparity", doc = "..." }]
//! params = [{ name = "window_px", kind = "int", default = 9, unit = "px",
//!             doc = "...", min = 1.0, max = 51.0 }]
//! ```
//!
//! Parameter keys: `name`, `kind` (`int`, `float`, `bool`, `string`,
//! `int_list`, `float_list`), `default` (absent: the graph must set it),
//! `unit`, `doc`, `min`, `max`, `choices` (strings), `lengths` (allowed list
//! lengths), `length_multiple_of` (a list of flattened tuples). Hosts ignore keys they do not know, so new optional keys do not
//! change the ABI version.

use std::fmt::Write;

/// One parameter's declaration.
#[derive(Debug, Clone, PartialEq)]
pub struct Param {
    name: String,
    kind: &'static str,
    default: Option<String>,
    unit: String,
    doc: String,
    min: Option<f64>,
    max: Option<f64>,
    choices: Vec<String>,
    lengths: Vec<usize>,
    length_multiple_of: Option<usize>,
}

impl Param {
    fn new(
        name: &str,
        kind: &'static str,
        default: Option<String>,
        unit: &str,
        doc: &str,
    ) -> Param {
        Param {
            name: name.into(),
            kind,
            default,
            unit: unit.into(),
            doc: doc.into(),
            min: None,
            max: None,
            choices: Vec::new(),
            lengths: Vec::new(),
            length_multiple_of: None,
        }
    }

    /// A parameter of `kind` (a kind name of the TOML declaration) without a
    /// default yet (for the typed form, [`crate::typed_op`]).
    pub(crate) fn declared(name: &str, kind: &'static str, unit: &str, doc: &str) -> Param {
        Param::new(name, kind, None, unit, doc)
    }

    /// Sets the default, as TOML text.
    pub(crate) fn with_default(mut self, toml: String) -> Param {
        self.default = Some(toml);
        self
    }

    /// Sets either bound of a number.
    pub(crate) fn bounds(mut self, min: Option<f64>, max: Option<f64>) -> Param {
        self.min = min;
        self.max = max;
        self
    }

    /// Sets the allowed strings.
    pub(crate) fn with_choices(mut self, choices: Vec<String>) -> Param {
        self.choices = choices;
        self
    }

    /// A list whose length must be a multiple of `k` (flattened tuples).
    pub fn length_multiple_of(mut self, k: usize) -> Param {
        self.length_multiple_of = Some(k);
        self
    }

    /// An integer with a default.
    pub fn int(name: &str, default: i64, unit: &str, doc: &str) -> Param {
        Param::new(name, "int", Some(default.to_string()), unit, doc)
    }

    /// A number with a default.
    pub fn float(name: &str, default: f64, unit: &str, doc: &str) -> Param {
        Param::new(name, "float", Some(toml_float(default)), unit, doc)
    }

    /// A switch with a default.
    pub fn bool(name: &str, default: bool, doc: &str) -> Param {
        Param::new(name, "bool", Some(default.to_string()), "", doc)
    }

    /// Text with a default.
    pub fn string(name: &str, default: &str, doc: &str) -> Param {
        Param::new(name, "string", Some(toml_string(default)), "", doc)
    }

    /// One of `choices`; the first is the default.
    pub fn choice(name: &str, choices: &[&str], doc: &str) -> Param {
        let mut p = Param::new(
            name,
            "string",
            choices.first().map(|c| toml_string(c)),
            "",
            doc,
        );
        p.choices = choices.iter().map(|c| c.to_string()).collect();
        p
    }

    /// A list of integers with a default.
    pub fn int_list(name: &str, default: &[i64], unit: &str, doc: &str) -> Param {
        let items: Vec<String> = default.iter().map(|v| v.to_string()).collect();
        Param::new(
            name,
            "int_list",
            Some(format!("[{}]", items.join(", "))),
            unit,
            doc,
        )
    }

    /// A list of numbers with a default.
    pub fn float_list(name: &str, default: &[f64], unit: &str, doc: &str) -> Param {
        let items: Vec<String> = default.iter().map(|&v| toml_float(v)).collect();
        Param::new(
            name,
            "float_list",
            Some(format!("[{}]", items.join(", "))),
            unit,
            doc,
        )
    }

    /// Without a default: every graph must set it.
    pub fn required(mut self) -> Param {
        self.default = None;
        self
    }

    /// Allowed range of a number (or of each number of a list).
    pub fn range(mut self, min: f64, max: f64) -> Param {
        self.min = Some(min);
        self.max = Some(max);
        self
    }

    /// Allowed lengths of a list.
    pub fn lengths(mut self, allowed: &[usize]) -> Param {
        self.lengths = allowed.to_vec();
        self
    }

    fn write_toml(&self, out: &mut String) {
        let _ = write!(
            out,
            "{{ name = {}, kind = \"{}\", unit = {}, doc = {}",
            toml_string(&self.name),
            self.kind,
            toml_string(&self.unit),
            toml_string(&self.doc)
        );
        if let Some(d) = &self.default {
            let _ = write!(out, ", default = {d}");
        }
        if let Some(m) = self.min {
            let _ = write!(out, ", min = {}", toml_float(m));
        }
        if let Some(m) = self.max {
            let _ = write!(out, ", max = {}", toml_float(m));
        }
        if !self.choices.is_empty() {
            let c: Vec<String> = self.choices.iter().map(|c| toml_string(c)).collect();
            let _ = write!(out, ", choices = [{}]", c.join(", "));
        }
        if !self.lengths.is_empty() {
            let l: Vec<String> = self.lengths.iter().map(|l| l.to_string()).collect();
            let _ = write!(out, ", lengths = [{}]", l.join(", "));
        }
        if let Some(k) = self.length_multiple_of {
            let _ = write!(out, ", length_multiple_of = {k}");
        }
        out.push_str(" }");
    }
}

/// An input or output port.
#[derive(Debug, Clone, PartialEq)]
struct Port {
    name: String,
    types: Vec<String>,
    optional: bool,
    doc: String,
}

/// One op's declaration.
#[derive(Debug, Clone, PartialEq)]
pub struct OpDecl {
    name: String,
    version: u32,
    doc: String,
    inputs: Vec<Port>,
    outputs: Vec<Port>,
    params: Vec<Param>,
}

impl OpDecl {
    /// An op `stage.action` at `version` (bump it whenever its outputs change
    /// for the same inputs: it is part of the cache key).
    pub fn new(name: &str, version: u32, doc: &str) -> OpDecl {
        OpDecl {
            name: name.into(),
            version,
            doc: doc.into(),
            inputs: Vec::new(),
            outputs: Vec::new(),
            params: Vec::new(),
        }
    }

    /// The op's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// A required input accepting any of `types` (engine type names:
    /// `Image`, `Disparity`, `Scalar`, `Table`, `Volume`, `Mask`, `Labels`).
    pub fn input(mut self, name: &str, types: &[&str], doc: &str) -> OpDecl {
        self.inputs.push(Port {
            name: name.into(),
            types: types.iter().map(|t| t.to_string()).collect(),
            optional: false,
            doc: doc.into(),
        });
        self
    }

    /// An input that may be left unconnected.
    pub fn optional_input(mut self, name: &str, types: &[&str], doc: &str) -> OpDecl {
        self = self.input(name, types, doc);
        if let Some(p) = self.inputs.last_mut() {
            p.optional = true;
        }
        self
    }

    /// An output of type `ty`.
    pub fn output(mut self, name: &str, ty: &str, doc: &str) -> OpDecl {
        self.outputs.push(Port {
            name: name.into(),
            types: vec![ty.into()],
            optional: false,
            doc: doc.into(),
        });
        self
    }

    /// A parameter.
    pub fn param(mut self, p: Param) -> OpDecl {
        self.params.push(p);
        self
    }

    /// The `[[op]]` table of this op.
    pub fn to_toml(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(out, "[[op]]");
        let _ = writeln!(out, "name = {}", toml_string(&self.name));
        let _ = writeln!(out, "version = {}", self.version);
        let _ = writeln!(out, "doc = {}", toml_string(&self.doc));
        out.push_str("inputs = [");
        for (i, p) in self.inputs.iter().enumerate() {
            let types: Vec<String> = p.types.iter().map(|t| toml_string(t)).collect();
            let _ = write!(
                out,
                "{}{{ name = {}, types = [{}], optional = {}, doc = {} }}",
                if i > 0 { ", " } else { "" },
                toml_string(&p.name),
                types.join(", "),
                p.optional,
                toml_string(&p.doc)
            );
        }
        out.push_str("]\noutputs = [");
        for (i, p) in self.outputs.iter().enumerate() {
            let _ = write!(
                out,
                "{}{{ name = {}, type = {}, doc = {} }}",
                if i > 0 { ", " } else { "" },
                toml_string(&p.name),
                toml_string(&p.types[0]),
                toml_string(&p.doc)
            );
        }
        out.push_str("]\nparams = [");
        for (i, p) in self.params.iter().enumerate() {
            if i > 0 {
                out.push_str(", ");
            }
            p.write_toml(&mut out);
        }
        out.push_str("]\n");
        out
    }
}

/// A TOML basic string.
pub(crate) fn toml_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c if c.is_control() => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A TOML float (always with a point or exponent, `nan` and `inf` spelled as
/// TOML spells them).
pub(crate) fn toml_float(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf".into() } else { "-inf".into() }
    } else {
        format!("{v:?}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strings_are_escaped_and_floats_keep_a_point() {
        assert_eq!(
            toml_string("a \"b\"\\\n\u{1}"),
            "\"a \\\"b\\\"\\\\\\n\\u0001\""
        );
        assert_eq!(toml_float(1.0), "1.0");
        assert_eq!(toml_float(1e300), "1e300");
        assert_eq!(toml_float(f64::NEG_INFINITY), "-inf");
    }

    #[test]
    fn a_declaration_is_one_op_table() {
        let d = OpDecl::new("census.match", 2, "Census \"WTA\"")
            .input("left", &["Image"], "left")
            .optional_input("min_disparity", &["Scalar"], "lowest")
            .output("disparity", "Disparity", "px")
            .param(Param::int("window_px", 9, "px", "side").range(1.0, 51.0))
            .param(Param::choice("cost", &["census", "sad"], "cost"))
            .param(Param::int_list("census_px", &[9, 7], "px", "w, h").lengths(&[2]))
            .param(Param::float("scale", 0.5, "", "s").required());
        let text = d.to_toml();
        assert!(
            text.starts_with("[[op]]\nname = \"census.match\"\nversion = 2\n"),
            "{text}"
        );
        assert!(text.contains("doc = \"Census \\\"WTA\\\"\""), "{text}");
        assert!(
            text.contains("{ name = \"min_disparity\", types = [\"Scalar\"], optional = true"),
            "{text}"
        );
        assert!(text.contains("kind = \"int\", unit = \"px\", doc = \"side\", default = 9, min = 1.0, max = 51.0 }"), "{text}");
        assert!(
            text.contains("default = \"census\", choices = [\"census\", \"sad\"]"),
            "{text}"
        );
        assert!(text.contains("default = [9, 7], lengths = [2]"), "{text}");
        assert!(
            text.contains("{ name = \"scale\", kind = \"float\", unit = \"\", doc = \"s\" }"),
            "{text}"
        );
    }
}
