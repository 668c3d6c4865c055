//! Node parameters: their declared kinds ([`ParamSpec`]), their values
//! ([`ParamValue`]), conversion from TOML with checks, and the resolved set an op
//! receives ([`Params`]).

use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

/// The kind of value a parameter holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ParamKind {
    /// A number (f64); TOML integers are accepted.
    Float,
    /// An integer (i64).
    Int,
    /// `true` or `false`.
    Bool,
    /// A string, optionally one of a fixed set of choices.
    String,
    /// A file or folder path, relative to the graph file; hashed by content.
    Path,
    /// A list of numbers.
    FloatList,
    /// A list of integers.
    IntList,
    /// A list of strings.
    StringList,
}

impl fmt::Display for ParamKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ParamKind::Float => "number",
            ParamKind::Int => "integer",
            ParamKind::Bool => "boolean",
            ParamKind::String => "string",
            ParamKind::Path => "path",
            ParamKind::FloatList => "list of numbers",
            ParamKind::IntList => "list of integers",
            ParamKind::StringList => "list of strings",
        })
    }
}

/// A parameter's value.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum ParamValue {
    /// A number.
    Float(f64),
    /// An integer.
    Int(i64),
    /// A boolean.
    Bool(bool),
    /// A string.
    String(String),
    /// A path (absolute once resolved against the graph file's folder).
    Path(PathBuf),
    /// A list of numbers.
    FloatList(Vec<f64>),
    /// A list of integers.
    IntList(Vec<i64>),
    /// A list of strings.
    StringList(Vec<String>),
}

impl ParamValue {
    /// The kind of this value.
    pub fn kind(&self) -> ParamKind {
        match self {
            ParamValue::Float(_) => ParamKind::Float,
            ParamValue::Int(_) => ParamKind::Int,
            ParamValue::Bool(_) => ParamKind::Bool,
            ParamValue::String(_) => ParamKind::String,
            ParamValue::Path(_) => ParamKind::Path,
            ParamValue::FloatList(_) => ParamKind::FloatList,
            ParamValue::IntList(_) => ParamKind::IntList,
            ParamValue::StringList(_) => ParamKind::StringList,
        }
    }

    /// The number of items, if this is a list.
    fn list_len(&self) -> Option<usize> {
        match self {
            ParamValue::FloatList(v) => Some(v.len()),
            ParamValue::IntList(v) => Some(v.len()),
            ParamValue::StringList(v) => Some(v.len()),
            _ => None,
        }
    }

    /// The numbers a range check applies to.
    fn numbers(&self) -> Vec<f64> {
        match self {
            ParamValue::Float(v) => vec![*v],
            ParamValue::Int(v) => vec![*v as f64],
            ParamValue::FloatList(v) => v.clone(),
            ParamValue::IntList(v) => v.iter().map(|&x| x as f64).collect(),
            _ => Vec::new(),
        }
    }
}

impl fmt::Display for ParamValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParamValue::Float(v) => write!(f, "{v}"),
            ParamValue::Int(v) => write!(f, "{v}"),
            ParamValue::Bool(v) => write!(f, "{v}"),
            ParamValue::String(v) => write!(f, "{v:?}"),
            ParamValue::Path(v) => write!(f, "{:?}", v.display().to_string()),
            ParamValue::FloatList(v) => write!(f, "{v:?}"),
            ParamValue::IntList(v) => write!(f, "{v:?}"),
            ParamValue::StringList(v) => write!(f, "{v:?}"),
        }
    }
}

/// The declaration of one parameter: name, kind, default, unit, range and doc.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamSpec {
    /// Key in the graph file, with its unit as a suffix where it has one (`_mm`).
    pub name: String,
    /// Kind of value.
    pub kind: ParamKind,
    /// Default value; `None` makes the parameter required.
    pub default: Option<ParamValue>,
    /// Unit (`"mm"`, `"px"`, `"deg"`, `"%"`), empty when dimensionless.
    pub unit: String,
    /// Smallest allowed number (for numbers and lists of numbers).
    pub min: Option<f64>,
    /// Largest allowed number.
    pub max: Option<f64>,
    /// Allowed strings, when the parameter is a choice.
    pub choices: Vec<String>,
    /// Allowed lengths, when the parameter is a list (`None`: any length).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub length: Option<ListLength>,
    /// One-line description.
    pub doc: String,
}

/// The lengths a list parameter may have.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ListLength {
    /// One of these lengths (`[2]`: a pair; `[0, 2]`: empty or a pair).
    OneOf(Vec<usize>),
    /// A multiple of this (flattened triples: 3).
    MultipleOf(usize),
}

impl ListLength {
    /// Whether a list of `n` items fits.
    pub fn allows(&self, n: usize) -> bool {
        match self {
            ListLength::OneOf(lengths) => lengths.contains(&n),
            ListLength::MultipleOf(k) => n.is_multiple_of(*k),
        }
    }
}

impl std::fmt::Display for ListLength {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ListLength::OneOf(lengths) => {
                let words: Vec<String> = lengths.iter().map(|n| n.to_string()).collect();
                write!(f, "{}", words.join(" or "))
            }
            ListLength::MultipleOf(k) => write!(f, "a multiple of {k}"),
        }
    }
}

impl ParamSpec {
    fn new(
        name: &str,
        kind: ParamKind,
        default: Option<ParamValue>,
        unit: &str,
        doc: &str,
    ) -> Self {
        ParamSpec {
            name: name.into(),
            kind,
            default,
            unit: unit.into(),
            min: None,
            max: None,
            choices: Vec::new(),
            length: None,
            doc: doc.into(),
        }
    }

    /// A number with a default.
    pub fn float(name: &str, default: f64, unit: &str, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::Float,
            Some(ParamValue::Float(default)),
            unit,
            doc,
        )
    }

    /// An integer with a default.
    pub fn int(name: &str, default: i64, unit: &str, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::Int,
            Some(ParamValue::Int(default)),
            unit,
            doc,
        )
    }

    /// A boolean with a default.
    pub fn bool(name: &str, default: bool, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::Bool,
            Some(ParamValue::Bool(default)),
            "",
            doc,
        )
    }

    /// A free string with a default.
    pub fn string(name: &str, default: &str, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::String,
            Some(ParamValue::String(default.into())),
            "",
            doc,
        )
    }

    /// One of `choices`, defaulting to the first.
    pub fn choice(name: &str, choices: &[&str], doc: &str) -> Self {
        let mut p = Self::string(name, choices[0], doc);
        p.choices = choices.iter().map(|c| c.to_string()).collect();
        p
    }

    /// A required path (no default).
    pub fn path(name: &str, doc: &str) -> Self {
        Self::new(name, ParamKind::Path, None, "", doc)
    }

    /// A path that may be left out (its default is the empty path, "not given";
    /// see [`Params::optional_path`]).
    pub fn optional_path(name: &str, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::Path,
            Some(ParamValue::Path(PathBuf::new())),
            "",
            doc,
        )
    }

    /// A list of numbers with a default.
    pub fn float_list(name: &str, default: &[f64], unit: &str, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::FloatList,
            Some(ParamValue::FloatList(default.to_vec())),
            unit,
            doc,
        )
    }

    /// A list of integers with a default.
    pub fn int_list(name: &str, default: &[i64], unit: &str, doc: &str) -> Self {
        Self::new(
            name,
            ParamKind::IntList,
            Some(ParamValue::IntList(default.to_vec())),
            unit,
            doc,
        )
    }

    /// A list of strings with a default.
    pub fn string_list(name: &str, default: &[&str], doc: &str) -> Self {
        let v = default.iter().map(|s| s.to_string()).collect();
        Self::new(
            name,
            ParamKind::StringList,
            Some(ParamValue::StringList(v)),
            "",
            doc,
        )
    }

    /// Makes the parameter required (removes its default).
    pub fn required(mut self) -> Self {
        self.default = None;
        self
    }

    /// Sets the allowed range of numbers (inclusive).
    pub fn range(mut self, min: f64, max: f64) -> Self {
        self.min = Some(min);
        self.max = Some(max);
        self
    }

    /// Requires a list of exactly `n` items (`pattern = [9, 6]`: 2).
    pub fn length(self, n: usize) -> Self {
        self.lengths(&[n])
    }

    /// Requires a list of one of these lengths (`&[0, 2]`: empty or a pair).
    pub fn lengths(mut self, allowed: &[usize]) -> Self {
        self.length = Some(ListLength::OneOf(allowed.to_vec()));
        self
    }

    /// Requires a list whose length is a multiple of `k` (flattened tuples).
    pub fn length_multiple_of(mut self, k: usize) -> Self {
        self.length = Some(ListLength::MultipleOf(k));
        self
    }

    /// Sets the smallest allowed number (inclusive).
    pub fn at_least(mut self, min: f64) -> Self {
        self.min = Some(min);
        self
    }

    /// Converts a TOML value to this parameter's kind and checks range and choices.
    /// Relative paths are resolved against `base_dir`. The error says what was
    /// expected and what was found.
    pub fn parse(&self, value: &toml::Value, base_dir: &Path) -> Result<ParamValue, String> {
        let parsed = self.convert(value, base_dir)?;
        if let (Some(length), Some(n)) = (&self.length, parsed.list_len())
            && !length.allows(n)
        {
            return Err(format!(
                "a list of {n} item{}, expected {length}",
                if n == 1 { "" } else { "s" }
            ));
        }
        for x in parsed.numbers() {
            if !x.is_finite() {
                return Err(format!("{x} is not a finite number"));
            }
            if let Some(min) = self.min.filter(|&m| x < m) {
                return Err(format!(
                    "{x} is below the minimum {min}{}",
                    self.unit_suffix()
                ));
            }
            if let Some(max) = self.max.filter(|&m| x > m) {
                return Err(format!(
                    "{x} is above the maximum {max}{}",
                    self.unit_suffix()
                ));
            }
        }
        if let ParamValue::String(s) = &parsed
            && !self.choices.is_empty()
            && !self.choices.contains(s)
        {
            return Err(format!("{s:?} is not one of: {}", self.choices.join(", ")));
        }
        Ok(parsed)
    }

    fn unit_suffix(&self) -> String {
        if self.unit.is_empty() {
            String::new()
        } else {
            format!(" {}", self.unit)
        }
    }

    fn convert(&self, value: &toml::Value, base_dir: &Path) -> Result<ParamValue, String> {
        use toml::Value as T;
        let kind = self.kind.to_string();
        let article = if kind.starts_with(['a', 'e', 'i', 'o', 'u']) {
            "an"
        } else {
            "a"
        };
        let wrong = || {
            format!(
                "expected {article} {kind}, found {} `{value}`",
                value.type_str()
            )
        };
        let float = |v: &T| match v {
            T::Float(f) => Some(*f),
            T::Integer(i) => Some(*i as f64),
            _ => None,
        };
        let list = |v: &T| v.as_array().cloned().ok_or_else(wrong);
        Ok(match self.kind {
            ParamKind::Float => ParamValue::Float(float(value).ok_or_else(wrong)?),
            ParamKind::Int => ParamValue::Int(value.as_integer().ok_or_else(wrong)?),
            ParamKind::Bool => ParamValue::Bool(value.as_bool().ok_or_else(wrong)?),
            ParamKind::String => ParamValue::String(value.as_str().ok_or_else(wrong)?.into()),
            ParamKind::Path => ParamValue::Path(base_dir.join(value.as_str().ok_or_else(wrong)?)),
            ParamKind::FloatList => ParamValue::FloatList(
                list(value)?
                    .iter()
                    .map(|v| float(v).ok_or_else(wrong))
                    .collect::<Result<_, _>>()?,
            ),
            ParamKind::IntList => ParamValue::IntList(
                list(value)?
                    .iter()
                    .map(|v| v.as_integer().ok_or_else(wrong))
                    .collect::<Result<_, _>>()?,
            ),
            ParamKind::StringList => ParamValue::StringList(
                list(value)?
                    .iter()
                    .map(|v| v.as_str().map(String::from).ok_or_else(wrong))
                    .collect::<Result<_, _>>()?,
            ),
        })
    }
}

/// The resolved parameters an op runs with: every declared parameter, given or
/// defaulted, already checked against its [`ParamSpec`].
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Params(pub BTreeMap<String, ParamValue>);

/// A parameter an op asked for is absent or of another kind (a bug in the op's
/// declaration, since validation checked the graph against it).
#[derive(Debug, Clone, thiserror::Error)]
#[error("parameter `{name}`: {problem}")]
pub struct ParamError {
    /// Parameter name.
    pub name: String,
    /// What is wrong.
    pub problem: String,
}

macro_rules! getter {
    ($(#[$doc:meta])* $fn:ident, $variant:ident, $ty:ty) => {
        $(#[$doc])*
        pub fn $fn(&self, name: &str) -> Result<$ty, ParamError> {
            match self.0.get(name) {
                Some(ParamValue::$variant(v)) => Ok(v.clone()),
                Some(other) => Err(ParamError {
                    name: name.into(),
                    problem: format!("is of kind {}, asked as {}", other.kind(), ParamKind::$variant),
                }),
                None => Err(ParamError { name: name.into(), problem: "is not declared".into() }),
            }
        }
    };
}

impl Params {
    getter!(
        /// A number parameter.
        float, Float, f64
    );
    getter!(
        /// An integer parameter.
        int, Int, i64
    );
    getter!(
        /// A boolean parameter.
        bool, Bool, bool
    );
    getter!(
        /// A string parameter.
        string, String, String
    );
    getter!(
        /// A path parameter (absolute).
        path, Path, PathBuf
    );
    getter!(
        /// A list-of-numbers parameter.
        float_list, FloatList, Vec<f64>
    );
    getter!(
        /// A list-of-integers parameter.
        int_list, IntList, Vec<i64>
    );
    getter!(
        /// A list-of-strings parameter.
        string_list, StringList, Vec<String>
    );

    /// A path parameter declared with [`ParamSpec::optional_path`]: `None` when
    /// not given.
    pub fn optional_path(&self, name: &str) -> Result<Option<PathBuf>, ParamError> {
        let p = self.path(name)?;
        Ok(if p.as_os_str().is_empty() {
            None
        } else {
            Some(p)
        })
    }

    /// A non-negative integer parameter as `usize`.
    pub fn count(&self, name: &str) -> Result<usize, ParamError> {
        let v = self.int(name)?;
        usize::try_from(v).map_err(|_| ParamError {
            name: name.into(),
            problem: format!("{v} is negative"),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(spec: &ParamSpec, toml_value: &str) -> Result<ParamValue, String> {
        let t: toml::Table = toml::from_str(&format!("v = {toml_value}")).unwrap();
        spec.parse(&t["v"], Path::new("/graphs"))
    }

    #[test]
    fn numbers_accept_integers_and_check_ranges() {
        let p = ParamSpec::float("low_percentile", 1.0, "%", "").range(0.0, 100.0);
        assert_eq!(parse(&p, "2"), Ok(ParamValue::Float(2.0)));
        let err = parse(&p, "120.0").unwrap_err();
        assert!(err.contains("above the maximum 100 %"), "{err}");
        let err = parse(&p, "\"a\"").unwrap_err();
        assert!(err.contains("expected a number, found string"), "{err}");
        let err = parse(&p, "nan").unwrap_err();
        assert!(err.contains("not a finite"), "{err}");
    }

    #[test]
    fn lists_choices_and_paths() {
        let l = ParamSpec::float_list("b_mm", &[1.0], "mm", "").at_least(0.0);
        assert_eq!(
            parse(&l, "[1, 2.5]"),
            Ok(ParamValue::FloatList(vec![1.0, 2.5]))
        );
        assert!(
            parse(&l, "[1, -2]")
                .unwrap_err()
                .contains("below the minimum 0 mm")
        );
        assert!(parse(&l, "[1, \"x\"]").is_err());
        let c = ParamSpec::choice("kernel", &["huber", "tukey"], "");
        assert!(
            parse(&c, "\"cauchy\"")
                .unwrap_err()
                .contains("huber, tukey")
        );
        let p = ParamSpec::path("path", "");
        assert_eq!(
            parse(&p, "\"data/x\""),
            Ok(ParamValue::Path("/graphs/data/x".into()))
        );
        assert_eq!(parse(&p, "\"/abs\""), Ok(ParamValue::Path("/abs".into())));
    }

    #[test]
    fn list_lengths_are_part_of_the_declaration() {
        let pair = ParamSpec::int_list("pattern", &[9, 6], "", "").length(2);
        assert_eq!(parse(&pair, "[9, 7]"), Ok(ParamValue::IntList(vec![9, 7])));
        assert_eq!(
            parse(&pair, "[9, 6, 10]"),
            Err("a list of 3 items, expected 2".into())
        );
        assert_eq!(
            parse(&pair, "[9]"),
            Err("a list of 1 item, expected 2".into())
        );
        let bounds = ParamSpec::float_list("bounds_px", &[], "px", "").lengths(&[0, 2]);
        assert!(parse(&bounds, "[]").is_ok() && parse(&bounds, "[1, 2]").is_ok());
        assert_eq!(
            parse(&bounds, "[1]"),
            Err("a list of 1 item, expected 0 or 2".into())
        );
        let triples = ParamSpec::float_list("xyz_mm", &[], "mm", "").length_multiple_of(3);
        assert!(parse(&triples, "[1, 2, 3, 4, 5, 6]").is_ok());
        assert_eq!(
            parse(&triples, "[1, 2, 3, 4]"),
            Err("a list of 4 items, expected a multiple of 3".into())
        );
        // A declaration whose default breaks its own length is refused.
        let spec = crate::OpSpec::new("t.op", 1, "")
            .param(ParamSpec::int_list("pattern", &[9, 6, 1], "", "").length(2));
        assert!(spec.check().is_err());
    }

    #[test]
    fn getters_check_kinds() {
        let mut p = Params::default();
        p.0.insert("n".into(), ParamValue::Int(-3));
        assert_eq!(p.int("n").unwrap(), -3);
        assert!(p.count("n").is_err());
        assert!(
            p.float("n")
                .unwrap_err()
                .to_string()
                .contains("is of kind integer, asked as number")
        );
        assert!(p.float("missing").is_err());
    }
}
