//! Typed op declarations: the one form in which every op, built-in or plugin,
//! declares its parameters and ports.
//!
//! An op is a struct whose fields are its parameters; `#[derive(Op)]` (from
//! the `derive` feature, crate `fusegraph-derive`) reads the fields' types,
//! `#[param(..)]` attributes and `///` docs and implements [`OpInfo`] and
//! [`ParamSet`] for it. Its ports are two more structs, `#[derive(Inputs)]`
//! and `#[derive(Outputs)]`, one field per port. A host (the engine, or this
//! crate's plugin side) turns the declarations into its own spec or TOML, and
//! fills the structs from its own values: the traits here are generic over
//! where values come from ([`ParamSource`], [`InputSource`]) and where they go,
//! so the same declaration serves both.
//!
//! ```ignore
//! /// Otsu's threshold over the whole volume -> foreground mask
//! #[derive(Op)]
//! #[op(name = "mri.otsu", version = 2)]
//! pub struct Otsu {
//!     /// Histogram bins
//!     #[param(default = 256, min = 2, max = 65536)]
//!     pub bins: usize,
//! }
//! ```
//!
//! Kept free of dependencies, like the rest of this crate.

use std::path::{Path, PathBuf};

/// The kind of value a parameter holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKind {
    /// A number (f64).
    Float,
    /// An integer (i64).
    Int,
    /// `true` or `false`.
    Bool,
    /// A string, optionally one of a fixed set of choices.
    String,
    /// A file or folder path, relative to the graph file.
    Path,
    /// A list of numbers.
    FloatList,
    /// A list of integers.
    IntList,
    /// A list of strings.
    StringList,
}

impl ParamKind {
    /// The kind's name in a plugin's TOML declaration (`float`, `int_list`).
    pub fn toml_name(self) -> &'static str {
        match self {
            ParamKind::Float => "float",
            ParamKind::Int => "int",
            ParamKind::Bool => "bool",
            ParamKind::String => "string",
            ParamKind::Path => "path",
            ParamKind::FloatList => "float_list",
            ParamKind::IntList => "int_list",
            ParamKind::StringList => "string_list",
        }
    }
}

/// A parameter's declared default value.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamDefault {
    /// A number.
    Float(f64),
    /// An integer.
    Int(i64),
    /// A boolean.
    Bool(bool),
    /// A string.
    String(String),
    /// A path (the empty path: "not given").
    Path(PathBuf),
    /// A list of numbers.
    FloatList(Vec<f64>),
    /// A list of integers.
    IntList(Vec<i64>),
    /// A list of strings.
    StringList(Vec<String>),
}

/// The lengths a list parameter may have.
#[derive(Debug, Clone, PartialEq)]
pub enum ListLength {
    /// One of these lengths.
    OneOf(Vec<usize>),
    /// A multiple of this (flattened tuples).
    MultipleOf(usize),
}

/// One parameter's declaration.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamDecl {
    /// Key in the graph file, with its unit as a suffix where it has one.
    pub name: String,
    /// Kind of value.
    pub kind: ParamKind,
    /// Default; `None` makes the parameter required.
    pub default: Option<ParamDefault>,
    /// Unit (`"mm"`, `"px"`, `"%"`), empty when dimensionless.
    pub unit: String,
    /// Smallest allowed number (inclusive).
    pub min: Option<f64>,
    /// Largest allowed number (inclusive).
    pub max: Option<f64>,
    /// Allowed strings, when the parameter is a choice.
    pub choices: Vec<String>,
    /// Allowed lengths of a list.
    pub length: Option<ListLength>,
    /// One-line description.
    pub doc: String,
}

/// One input or output port's declaration.
#[derive(Debug, Clone, PartialEq)]
pub struct PortDecl {
    /// Port name.
    pub name: String,
    /// Accepted types (inputs) or the one type produced (outputs), by the
    /// engine's names (`Volume`, `Image`, ...).
    pub types: Vec<&'static str>,
    /// Whether an input may be left unconnected.
    pub optional: bool,
    /// One-line description, with units and frame.
    pub doc: String,
}

/// The name, version and doc of an op (from `#[derive(Op)]`).
pub trait OpInfo {
    /// `stage.action`.
    const NAME: &'static str;
    /// Bumped whenever the op's outputs change for the same inputs (part of
    /// the cache key).
    const VERSION: u32;
    /// One-line description.
    const DOC: &'static str;
    /// Whether the op writes files under the run's output folder (a sink).
    const WRITES_OUTPUT: bool = false;
}

/// A parameter that an op could not read: absent or of another kind (a bug
/// in the host or the declaration, since the host checked values against it).
#[derive(Debug, Clone, PartialEq)]
pub struct ParamProblem {
    /// Parameter name.
    pub name: String,
    /// What is wrong.
    pub problem: String,
}

impl std::fmt::Display for ParamProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "parameter `{}`: {}", self.name, self.problem)
    }
}

/// A parameter's value as a host lends it.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamRef<'a> {
    /// A number.
    Float(f64),
    /// An integer.
    Int(i64),
    /// A boolean.
    Bool(bool),
    /// A string.
    Str(&'a str),
    /// A path (absolute once the host resolved it).
    Path(&'a Path),
    /// A list of numbers.
    FloatList(&'a [f64]),
    /// A list of integers.
    IntList(&'a [i64]),
    /// A list of strings.
    StringList(Vec<&'a str>),
}

impl ParamRef<'_> {
    fn kind(&self) -> &'static str {
        match self {
            ParamRef::Float(_) => "number",
            ParamRef::Int(_) => "integer",
            ParamRef::Bool(_) => "boolean",
            ParamRef::Str(_) => "string",
            ParamRef::Path(_) => "path",
            ParamRef::FloatList(_) => "list of numbers",
            ParamRef::IntList(_) => "list of integers",
            ParamRef::StringList(_) => "list of strings",
        }
    }
}

/// Where a host keeps the parameter values of one run.
pub trait ParamSource {
    /// The value of parameter `name`, `None` when absent.
    fn param(&self, name: &str) -> Option<ParamRef<'_>>;
}

/// A Rust type a parameter field may have: its kind, how it is read from a
/// host's value and how its default is declared.
pub trait ParamType: Sized {
    /// The declared kind.
    const KIND: ParamKind;
    /// Reads the host's value.
    fn from_param(value: ParamRef<'_>) -> Result<Self, String>;
    /// The declaration of `self` as a default.
    fn to_default(&self) -> ParamDefault;
    /// The default when the field declares none (`None`: required).
    fn implicit_default() -> Option<Self> {
        None
    }
    /// The allowed strings of a choice.
    fn choices() -> Vec<String> {
        Vec::new()
    }
    /// The length a fixed-size list must have.
    fn fixed_length() -> Option<usize> {
        None
    }
}

/// A set of parameters: an op struct, or a group of fields flattened into one
/// (`#[param(flatten)]`).
pub trait ParamSet: Sized {
    /// The declarations, in field order.
    fn param_decls() -> Vec<ParamDecl>;
    /// Fills the struct from a host's values.
    fn from_params(source: &dyn ParamSource) -> Result<Self, ParamProblem>;
}

/// Reads parameter `name` as `T` (used by the derive).
pub fn read_param<T: ParamType>(source: &dyn ParamSource, name: &str) -> Result<T, ParamProblem> {
    let problem = |problem: String| ParamProblem {
        name: name.into(),
        problem,
    };
    let value = source
        .param(name)
        .ok_or_else(|| problem("is not declared".into()))?;
    T::from_param(value).map_err(problem)
}

fn wrong(expected: &str, found: &ParamRef) -> String {
    format!("is of kind {}, asked as {expected}", found.kind())
}

macro_rules! float_param {
    ($($t:ty),+) => {$(
        impl ParamType for $t {
            const KIND: ParamKind = ParamKind::Float;
            fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
                match value {
                    ParamRef::Float(v) => Ok(v as $t),
                    other => Err(wrong("number", &other)),
                }
            }
            fn to_default(&self) -> ParamDefault {
                ParamDefault::Float(*self as f64)
            }
        }
    )+};
}
float_param!(f64, f32);

macro_rules! int_param {
    ($($t:ty),+) => {$(
        impl ParamType for $t {
            const KIND: ParamKind = ParamKind::Int;
            fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
                match value {
                    ParamRef::Int(v) => <$t>::try_from(v)
                        .map_err(|_| format!("{v} does not fit a {}", stringify!($t))),
                    other => Err(wrong("integer", &other)),
                }
            }
            fn to_default(&self) -> ParamDefault {
                ParamDefault::Int(*self as i64)
            }
        }
    )+};
}
int_param!(i64, i32, u32, u64, usize, u8, u16);

impl ParamType for bool {
    const KIND: ParamKind = ParamKind::Bool;
    fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
        match value {
            ParamRef::Bool(v) => Ok(v),
            other => Err(wrong("boolean", &other)),
        }
    }
    fn to_default(&self) -> ParamDefault {
        ParamDefault::Bool(*self)
    }
}

impl ParamType for String {
    const KIND: ParamKind = ParamKind::String;
    fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
        match value {
            ParamRef::Str(v) => Ok(v.to_string()),
            other => Err(wrong("string", &other)),
        }
    }
    fn to_default(&self) -> ParamDefault {
        ParamDefault::String(self.clone())
    }
}

/// A required path.
impl ParamType for PathBuf {
    const KIND: ParamKind = ParamKind::Path;
    fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
        match value {
            ParamRef::Path(v) => Ok(v.to_path_buf()),
            other => Err(wrong("path", &other)),
        }
    }
    fn to_default(&self) -> ParamDefault {
        ParamDefault::Path(self.clone())
    }
}

/// A path that may be left out: its default is the empty path, read as `None`.
impl ParamType for Option<PathBuf> {
    const KIND: ParamKind = ParamKind::Path;
    fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
        let path = PathBuf::from_param(value)?;
        Ok((!path.as_os_str().is_empty()).then_some(path))
    }
    fn to_default(&self) -> ParamDefault {
        ParamDefault::Path(self.clone().unwrap_or_default())
    }
    fn implicit_default() -> Option<Self> {
        Some(None)
    }
}

macro_rules! list_param {
    ($kind:ident, $variant:ident, $default:ident, $elem:ident, $word:literal, $($t:ty),+) => {$(
        impl ParamType for Vec<$t> {
            const KIND: ParamKind = ParamKind::$kind;
            fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
                match value {
                    ParamRef::$variant(v) => v
                        .iter()
                        .map(|&x| <$t as ParamType>::from_param(ParamRef::$elem(x)))
                        .collect(),
                    other => Err(wrong($word, &other)),
                }
            }
            fn to_default(&self) -> ParamDefault {
                ParamDefault::$default(self.iter().map(|&x| x as _).collect())
            }
        }
        impl<const N: usize> ParamType for [$t; N] {
            const KIND: ParamKind = ParamKind::$kind;
            fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
                let items = Vec::<$t>::from_param(value)?;
                let n = items.len();
                items.try_into().map_err(|_| format!("a list of {n} items, expected {N}"))
            }
            fn to_default(&self) -> ParamDefault {
                ParamDefault::$default(self.iter().map(|&x| x as _).collect())
            }
            fn fixed_length() -> Option<usize> {
                Some(N)
            }
        }
    )+};
}
list_param!(
    FloatList,
    FloatList,
    FloatList,
    Float,
    "list of numbers",
    f64,
    f32
);
list_param!(
    IntList,
    IntList,
    IntList,
    Int,
    "list of integers",
    i64,
    i32,
    u32,
    usize
);

impl ParamType for Vec<String> {
    const KIND: ParamKind = ParamKind::StringList;
    fn from_param(value: ParamRef<'_>) -> Result<Self, String> {
        match value {
            ParamRef::StringList(v) => Ok(v.iter().map(|s| s.to_string()).collect()),
            other => Err(wrong("list of strings", &other)),
        }
    }
    fn to_default(&self) -> ParamDefault {
        ParamDefault::StringList(self.clone())
    }
}

/// An input port that a host could not fill (a bug in the host or the
/// declaration: the host checked the graph against it).
#[derive(Debug, Clone, PartialEq)]
pub struct PortProblem {
    /// Port name.
    pub port: String,
    /// What is wrong.
    pub problem: String,
}

impl std::fmt::Display for PortProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "input `{}`: {}", self.port, self.problem)
    }
}

/// Where a host keeps the input values of one run.
pub trait InputSource {
    /// Whether a value is on `port`.
    fn is_connected(&self, port: &str) -> bool;
}

/// A Rust type an input field may have, read from host `S`.
pub trait InputPort<'a, S: ?Sized>: Sized {
    /// Whether the port may be left unconnected.
    const OPTIONAL: bool = false;
    /// The accepted types, by the engine's names.
    fn type_names() -> Vec<&'static str>;
    /// Reads the value on `port`.
    fn take(source: &'a S, port: &str) -> Result<Self, String>;
}

/// An optional port: `None` when unconnected.
impl<'a, S: InputSource + ?Sized, T: InputPort<'a, S>> InputPort<'a, S> for Option<T> {
    const OPTIONAL: bool = true;
    fn type_names() -> Vec<&'static str> {
        T::type_names()
    }
    fn take(source: &'a S, port: &str) -> Result<Self, String> {
        if source.is_connected(port) {
            T::take(source, port).map(Some)
        } else {
            Ok(None)
        }
    }
}

/// An op's inputs: one field per port (from `#[derive(Inputs)]`).
pub trait InputSet<'a, S: ?Sized>: Sized {
    /// The declarations, in field order.
    fn port_decls() -> Vec<PortDecl>;
    /// Fills the struct from a host's values.
    fn from_inputs(source: &'a S) -> Result<Self, PortProblem>;
}

/// Reads input `port` as `T` (used by the derive).
pub fn read_input<'a, S: ?Sized, T: InputPort<'a, S>>(
    source: &'a S,
    port: &str,
) -> Result<T, PortProblem> {
    T::take(source, port).map_err(|problem| PortProblem {
        port: port.into(),
        problem,
    })
}

/// A Rust type an output field may have, handed to host sink `K`.
pub trait OutputPort<K: ?Sized> {
    /// The produced type, by the engine's name.
    fn type_name() -> &'static str;
    /// Puts the value on `port`.
    fn put(self, sink: &mut K, port: &str);
}

/// An op's outputs: one field per port (from `#[derive(Outputs)]`).
pub trait OutputSet<K: ?Sized> {
    /// The declarations, in field order.
    fn port_decls() -> Vec<PortDecl>;
    /// Hands every value to the host.
    fn put_all(self, sink: &mut K);
}

/// A port declaration (used by the derive).
pub fn port(name: &str, types: Vec<&'static str>, optional: bool, doc: &str) -> PortDecl {
    PortDecl {
        name: name.into(),
        types,
        optional,
        doc: doc.into(),
    }
}

/// Joins a field's `///` lines into its one-line doc (used by the derive).
pub fn doc_line(lines: &[&str]) -> String {
    lines
        .iter()
        .map(|l| l.trim())
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Values(Vec<(&'static str, ParamRef<'static>)>);
    impl ParamSource for Values {
        fn param(&self, name: &str) -> Option<ParamRef<'_>> {
            self.0
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, v)| v.clone())
        }
    }

    #[test]
    fn values_convert_to_field_types_or_say_why_not() {
        let v = Values(vec![
            ("n", ParamRef::Int(-3)),
            ("pair", ParamRef::IntList(&[9, 6])),
            ("path", ParamRef::Path(Path::new(""))),
        ]);
        assert_eq!(read_param::<i64>(&v, "n"), Ok(-3));
        let e = read_param::<usize>(&v, "n").unwrap_err();
        assert_eq!(e.to_string(), "parameter `n`: -3 does not fit a usize");
        let e = read_param::<f64>(&v, "n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "parameter `n`: is of kind integer, asked as number"
        );
        assert_eq!(read_param::<[usize; 2]>(&v, "pair"), Ok([9, 6]));
        assert!(read_param::<[usize; 3]>(&v, "pair").is_err());
        assert_eq!(read_param::<Option<PathBuf>>(&v, "path"), Ok(None));
        assert!(read_param::<bool>(&v, "missing").is_err());
        assert_eq!(<[usize; 2]>::fixed_length(), Some(2));
        assert_eq!([9usize, 6].to_default(), ParamDefault::IntList(vec![9, 6]));
    }

    #[test]
    fn doc_lines_join_into_one() {
        assert_eq!(
            doc_line(&[" Lowest", " disparity, px ", ""]),
            "Lowest disparity, px"
        );
    }
}
