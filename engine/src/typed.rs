//! Ops in the typed declaration form: a struct whose fields are the op's
//! parameters (`#[derive(Op)]`), an inputs struct and an outputs struct
//! (`#[derive(Inputs)]`, `#[derive(Outputs)]`), and [`RunOp::run`] on them.
//! [`Typed`] adapts such an op to the engine's [`Op`]: its [`OpSpec`] is
//! derived from the declarations, and its `run` fills the structs from the
//! graph's values. The declaration model and derives are shared with plugins
//! (`fusegraph_plugin_api::typed`), so built-in and plugin ops are written in
//! one form.
//!
//! ```
//! use fusegraph_engine::typed::prelude::*;
//! use fusegraph_engine::value::Volume;
//!
//! /// Multiplies every voxel by a factor
//! #[derive(Op)]
//! #[op(name = "demo.scale", version = 1)]
//! pub struct Scale {
//!     /// Factor applied to every voxel
//!     #[param(default = 2.0, min = 0.0)]
//!     pub factor: f64,
//! }
//!
//! #[derive(Inputs)]
//! pub struct ScaleInputs {
//!     /// Any volume
//!     pub volume: Arc<Volume>,
//! }
//!
//! #[derive(Outputs)]
//! pub struct ScaleOutputs {
//!     /// The scaled volume, same grid
//!     pub volume: Volume,
//! }
//!
//! impl RunOp for Scale {
//!     type Inputs = ScaleInputs;
//!     type Outputs = ScaleOutputs;
//!     fn run(&self, inputs: ScaleInputs, _: &mut RunCtx) -> Result<ScaleOutputs, OpError> {
//!         let data: Vec<f32> = inputs.volume.data.iter().map(|v| v * self.factor as f32).collect();
//!         let volume = Volume::new(inputs.volume.grid.clone(), data)
//!             .map_err(|e| OpError::invalid(e.0))?;
//!         Ok(ScaleOutputs { volume })
//!     }
//! }
//!
//! let mut registry = fusegraph_engine::Registry::new();
//! registry.add::<Scale>().unwrap();
//! let spec = registry.get("demo.scale").unwrap().spec();
//! assert_eq!(spec.params[0].name, "factor");
//! assert_eq!(spec.params[0].min, Some(0.0));
//! ```

use crate::op::{Inputs, Op, OpError, OpSpec, Outputs, PortSpec, RunCtx, Wired};
use crate::param::{ListLength, ParamError, ParamKind, ParamSpec, ParamValue, Params};
use crate::value::{self, FromValue, Value, ValueType};
use fusegraph_plugin_api::typed::{
    self as decl, InputPort, InputSet, InputSource, OpInfo, OutputPort, OutputSet, ParamRef,
    ParamSet, ParamSource,
};
use std::marker::PhantomData;
use std::sync::Arc;

pub use fusegraph_plugin_api::typed as declaration;

/// What an op file imports: the derives, the traits they implement and the
/// types `run` uses.
pub mod prelude {
    pub use super::RunOp;
    pub use crate::op::{OpError, RunCtx, Wired, exactly_one_source};
    pub use fusegraph_plugin_api::derive::{Choice, Inputs, Op, Outputs, Params};
    pub use std::sync::Arc;
}

/// An op in the typed form: `Self` holds its parameters (filled from the
/// graph), `run` gets its inputs and returns its outputs.
pub trait RunOp: OpInfo + ParamSet + Send + Sync + 'static {
    /// The input ports.
    type Inputs: for<'a> InputSet<'a, Inputs>;
    /// The output ports.
    type Outputs: OutputSet<Outputs>;
    /// Computes the outputs (see [`Op`] for what `run` may and must not do).
    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError>;
    /// Problems with the parameters and the wiring the declaration cannot
    /// express, found at validation (see [`Op::check`]): `(key, problem)`
    /// pairs, the key a parameter or `in.<port>`.
    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        let _ = wired;
        Vec::new()
    }
}

/// A typed op as the engine's [`Op`].
pub struct Typed<T> {
    spec: OpSpec,
    op: PhantomData<fn() -> T>,
}

impl<T: RunOp> Typed<T> {
    /// The adapter, with the spec derived from `T`'s declarations; an
    /// unknown port type name is an error.
    pub fn new() -> Result<Self, String> {
        Ok(Typed {
            spec: spec_of::<T>()?,
            op: PhantomData,
        })
    }
}

impl<T: RunOp> Op for Typed<T> {
    fn spec(&self) -> &OpSpec {
        &self.spec
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let op = T::from_params(params).map_err(|p| {
            OpError::Param(ParamError {
                name: p.name,
                problem: p.problem,
            })
        })?;
        let inputs = <T::Inputs as InputSet<'_, Inputs>>::from_inputs(inputs)
            .map_err(|p| OpError::Input(p.port, p.problem))?;
        let mut outputs = Outputs::new();
        op.run(inputs, ctx)?.put_all(&mut outputs);
        Ok(outputs)
    }

    fn check(&self, params: &Params, wired: Wired) -> Vec<ParamError> {
        match T::from_params(params) {
            Ok(op) => op
                .check(wired)
                .into_iter()
                .map(|(name, problem)| ParamError {
                    name: name.to_string(),
                    problem,
                })
                .collect(),
            Err(p) => vec![ParamError {
                name: p.name,
                problem: p.problem,
            }],
        }
    }
}

/// The engine's spec of a typed op.
pub fn spec_of<T: RunOp>() -> Result<OpSpec, String> {
    let ports = |decls: Vec<decl::PortDecl>| -> Result<Vec<PortSpec>, String> {
        decls
            .into_iter()
            .map(|p| {
                let types = p
                    .types
                    .iter()
                    .map(|t| {
                        ValueType::from_name(t)
                            .ok_or_else(|| format!("port `{}`: unknown type `{t}`", p.name))
                    })
                    .collect::<Result<_, _>>()?;
                Ok(PortSpec {
                    name: p.name,
                    types,
                    optional: p.optional,
                    doc: p.doc,
                })
            })
            .collect()
    };
    Ok(OpSpec {
        name: T::NAME.into(),
        version: T::VERSION,
        doc: T::DOC.into(),
        inputs: ports(<T::Inputs as InputSet<'_, Inputs>>::port_decls())?,
        outputs: ports(<T::Outputs as OutputSet<Outputs>>::port_decls())?,
        params: T::param_decls().into_iter().map(param_spec).collect(),
        writes_output: T::WRITES_OUTPUT,
        origin: None,
        code: None,
    })
}

/// The declared defaults of `T` (an op or a parameter group) as the engine's
/// parameter values; a parameter without a default is left out.
pub fn default_params<T: ParamSet>() -> Params {
    Params(
        T::param_decls()
            .into_iter()
            .filter_map(|d| {
                let p = param_spec(d);
                Some((p.name, p.default?))
            })
            .collect(),
    )
}

/// `T` (an op or a parameter group) with every parameter at its declared
/// default; `None` when one has no default.
pub fn declared_defaults<T: ParamSet>() -> Option<T> {
    T::from_params(&default_params::<T>()).ok()
}

/// The engine's spec of one declared parameter.
pub fn param_spec(p: decl::ParamDecl) -> ParamSpec {
    ParamSpec {
        name: p.name,
        kind: param_kind(p.kind),
        default: p.default.map(param_value),
        unit: p.unit,
        min: p.min,
        max: p.max,
        choices: p.choices,
        length: p.length.map(|l| match l {
            decl::ListLength::OneOf(n) => ListLength::OneOf(n),
            decl::ListLength::MultipleOf(k) => ListLength::MultipleOf(k),
        }),
        doc: p.doc,
    }
}

fn param_kind(kind: decl::ParamKind) -> ParamKind {
    match kind {
        decl::ParamKind::Float => ParamKind::Float,
        decl::ParamKind::Int => ParamKind::Int,
        decl::ParamKind::Bool => ParamKind::Bool,
        decl::ParamKind::String => ParamKind::String,
        decl::ParamKind::Path => ParamKind::Path,
        decl::ParamKind::FloatList => ParamKind::FloatList,
        decl::ParamKind::IntList => ParamKind::IntList,
        decl::ParamKind::StringList => ParamKind::StringList,
    }
}

fn param_value(d: decl::ParamDefault) -> ParamValue {
    match d {
        decl::ParamDefault::Float(v) => ParamValue::Float(v),
        decl::ParamDefault::Int(v) => ParamValue::Int(v),
        decl::ParamDefault::Bool(v) => ParamValue::Bool(v),
        decl::ParamDefault::String(v) => ParamValue::String(v),
        decl::ParamDefault::Path(v) => ParamValue::Path(v),
        decl::ParamDefault::FloatList(v) => ParamValue::FloatList(v),
        decl::ParamDefault::IntList(v) => ParamValue::IntList(v),
        decl::ParamDefault::StringList(v) => ParamValue::StringList(v),
    }
}

impl ParamSource for Params {
    fn param(&self, name: &str) -> Option<ParamRef<'_>> {
        Some(match self.0.get(name)? {
            ParamValue::Float(v) => ParamRef::Float(*v),
            ParamValue::Int(v) => ParamRef::Int(*v),
            ParamValue::Bool(v) => ParamRef::Bool(*v),
            ParamValue::String(v) => ParamRef::Str(v),
            ParamValue::Path(v) => ParamRef::Path(v),
            ParamValue::FloatList(v) => ParamRef::FloatList(v),
            ParamValue::IntList(v) => ParamRef::IntList(v),
            ParamValue::StringList(v) => {
                ParamRef::StringList(v.iter().map(String::as_str).collect())
            }
        })
    }
}

impl InputSource for Inputs {
    fn is_connected(&self, port: &str) -> bool {
        self.0.contains_key(port)
    }
}

/// The value on `port` as `T` (for the value types' [`InputPort`]s).
fn take_input<T: FromValue>(inputs: &Inputs, port: &str) -> Result<Arc<T>, String> {
    match inputs.get::<T>(port) {
        Ok(v) => Ok(v),
        Err(OpError::Input(_, why)) => Err(why),
        Err(e) => Err(e.to_string()),
    }
}

/// Ports of every value type: `Arc<T>` in, `T` or `Arc<T>` out.
macro_rules! value_ports {
    ($($name:ident => $ty:ty),+ $(,)?) => {
        /// The value types given ports here (checked against
        /// [`ValueType::ALL`] by a test).
        #[cfg(test)]
        const PORT_TYPES: &[ValueType] = &[$(ValueType::$name),+];
        $(
            impl<'a> InputPort<'a, Inputs> for Arc<$ty> {
                fn type_names() -> Vec<&'static str> {
                    vec![ValueType::$name.name()]
                }
                fn take(source: &'a Inputs, port: &str) -> Result<Self, String> {
                    take_input::<$ty>(source, port)
                }
            }
            impl OutputPort<Outputs> for $ty {
                fn type_name() -> &'static str {
                    ValueType::$name.name()
                }
                fn put(self, sink: &mut Outputs, port: &str) {
                    sink.0.insert(port.into(), Value::$name(Arc::new(self)));
                }
            }
            impl OutputPort<Outputs> for Arc<$ty> {
                fn type_name() -> &'static str {
                    ValueType::$name.name()
                }
                fn put(self, sink: &mut Outputs, port: &str) {
                    sink.0.insert(port.into(), Value::$name(self));
                }
            }
        )+
    };
}

value_ports! {
    Volume => value::Volume,
    Mask => value::Mask,
    Labels => value::Labels,
    Image => value::Image,
    Disparity => value::Disparity,
    Mesh => value::Mesh,
    PointCloud => value::PointCloud,
    Markers => value::Markers,
    Matches => value::Matches,
    Camera => value::Camera,
    StereoRig => value::StereoRig,
    Rectification => value::Rectification,
    Transform => value::Transform,
    Table => value::Table,
    Scalar => f64,
    Path => value::PathValue,
}

/// A number on a `Scalar` port.
impl<'a> InputPort<'a, Inputs> for f64 {
    fn type_names() -> Vec<&'static str> {
        vec![ValueType::Scalar.name()]
    }
    fn take(source: &'a Inputs, port: &str) -> Result<Self, String> {
        take_input::<f64>(source, port).map(|v| *v)
    }
}

/// A port of several types (give them with `#[input(types(A, B))]`) as the
/// raw value, matched on by the op.
impl<'a> InputPort<'a, Inputs> for Value {
    fn type_names() -> Vec<&'static str> {
        ValueType::ALL.iter().map(|t| t.name()).collect()
    }
    fn take(source: &'a Inputs, port: &str) -> Result<Self, String> {
        source
            .value(port)
            .cloned()
            .ok_or_else(|| "not connected".into())
    }
}

/// A parameter is a field, so a misspelt one does not compile:
///
/// ```compile_fail
/// use fusegraph_engine::typed::prelude::*;
/// /// Doc
/// #[derive(Op)]
/// #[op(name = "demo.typo", version = 1)]
/// pub struct Typo {
///     /// Bins
///     #[param(default = 256)]
///     pub bins: usize,
/// }
/// impl Typo {
///     fn histogram_size(&self) -> usize {
///         self.binz
///     }
/// }
/// ```
///
/// and neither does an attribute the derive does not know:
///
/// ```compile_fail
/// use fusegraph_engine::typed::prelude::*;
/// /// Doc
/// #[derive(Op)]
/// #[op(name = "demo.typo", version = 1)]
/// pub struct Typo {
///     /// Bins
///     #[param(defualt = 256)]
///     pub bins: usize,
/// }
/// ```
#[doc(hidden)]
pub fn _misspelt_parameters_do_not_compile() {}

#[cfg(test)]
mod tests {
    use super::prelude::*;
    use super::*;
    use crate::op::Op;
    use crate::value::{Mask, Table};
    use std::path::{Path, PathBuf};

    #[test]
    fn every_value_type_has_ports() {
        assert_eq!(PORT_TYPES, ValueType::ALL);
    }

    /// How far to go
    #[derive(Params, Debug)]
    struct Reach {
        /// Distance
        #[param(default = 4.0, unit = "mm", min = 0.0)]
        distance_mm: f64,
    }

    /// A kernel
    #[derive(Choice, Debug, Clone, Copy, PartialEq)]
    enum Kernel {
        Huber,
        #[choice(name = "l2")]
        Squared,
    }

    /// Every kind of field
    #[derive(Op, Debug)]
    #[op(name = "test.kinds", version = 3, writes_output)]
    struct Kinds {
        /// The kernel,
        /// on two lines
        #[param(default = Kernel::Squared)]
        kernel: Kernel,
        #[param(flatten)]
        reach: Reach,
        /// A pair
        #[param(default = [9, 6])]
        pattern: [usize; 2],
        /// Flattened triples
        #[param(default = [], unit = "mm", length_multiple_of = 3)]
        points_mm: Vec<f64>,
        /// Empty or a pair
        #[param(default = [], lengths = [0, 2])]
        bounds_px: Vec<f64>,
        /// Left out: not given
        truth: Option<PathBuf>,
        /// Required
        #[param(name = "type")]
        r#type: String,
    }

    #[derive(Inputs)]
    struct KindsInputs {
        /// A volume or mask
        #[input(types(Volume, Mask))]
        grid: Value,
        /// A number
        level: Option<f64>,
        /// A table
        table: Option<Arc<Table>>,
    }

    #[derive(Outputs)]
    struct KindsOutputs {
        /// The level given, or the distance
        level: f64,
        /// The grid, passed through
        grid: Arc<Mask>,
    }

    impl RunOp for Kinds {
        type Inputs = KindsInputs;
        type Outputs = KindsOutputs;
        fn run(&self, inputs: KindsInputs, ctx: &mut RunCtx) -> Result<KindsOutputs, OpError> {
            let Value::Mask(grid) = inputs.grid else {
                return Err(OpError::invalid("a mask, please"));
            };
            ctx.metric(
                "kernel_is_l2",
                (self.kernel == Kernel::Squared) as u8 as f64,
            );
            assert!(inputs.table.is_none() && self.truth.is_none());
            assert_eq!(self.pattern, [9, 6]);
            assert!(self.points_mm.is_empty() && self.bounds_px.is_empty());
            assert_eq!(self.r#type, "x");
            Ok(KindsOutputs {
                level: inputs.level.unwrap_or(self.reach.distance_mm),
                grid,
            })
        }
    }

    #[test]
    fn the_spec_is_derived_from_the_declarations() {
        let spec = spec_of::<Kinds>().unwrap();
        assert_eq!((spec.name.as_str(), spec.version), ("test.kinds", 3));
        assert_eq!(spec.doc, "Every kind of field");
        assert!(spec.writes_output);
        spec.check().unwrap();
        let names: Vec<&str> = spec.params.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "kernel",
                "distance_mm",
                "pattern",
                "points_mm",
                "bounds_px",
                "truth",
                "type"
            ]
        );
        let kernel = &spec.params[0];
        assert_eq!(kernel.doc, "The kernel, on two lines");
        assert_eq!(kernel.choices, ["huber", "l2"]);
        assert_eq!(kernel.default, Some(ParamValue::String("l2".into())));
        let reach = &spec.params[1];
        assert_eq!(
            (reach.unit.as_str(), reach.min, reach.max),
            ("mm", Some(0.0), None)
        );
        assert_eq!(spec.params[2].length, Some(ListLength::OneOf(vec![2])));
        assert_eq!(
            spec.params[2].default,
            Some(ParamValue::IntList(vec![9, 6]))
        );
        assert_eq!(spec.params[3].length, Some(ListLength::MultipleOf(3)));
        assert_eq!(spec.params[4].length, Some(ListLength::OneOf(vec![0, 2])));
        assert_eq!(
            spec.params[5].default,
            Some(ParamValue::Path(PathBuf::new()))
        );
        assert_eq!(spec.params[6].default, None, "no default: required");
        let grid = &spec.inputs[0];
        assert_eq!(grid.types, [ValueType::Volume, ValueType::Mask]);
        assert!(!grid.optional && spec.inputs[1].optional && spec.inputs[2].optional);
        assert_eq!(spec.inputs[1].types, [ValueType::Scalar]);
        assert_eq!(spec.outputs[0].types, [ValueType::Scalar]);
        assert_eq!(spec.outputs[1].types, [ValueType::Mask]);
    }

    fn params_of(spec: &OpSpec, set: &[(&str, ParamValue)]) -> Params {
        let mut p = Params::default();
        for s in &spec.params {
            if let Some(d) = &s.default {
                p.0.insert(s.name.clone(), d.clone());
            }
        }
        for (k, v) in set {
            p.0.insert(k.to_string(), v.clone());
        }
        p
    }

    #[test]
    fn run_fills_the_structs_and_names_what_is_missing() {
        let op = Typed::<Kinds>::new().unwrap();
        let params = params_of(op.spec(), &[("type", ParamValue::String("x".into()))]);
        let grid = crate::value::Grid::axis_aligned([2, 1, 1], [1.0; 3], [0.0; 3]);
        let mask = Mask::new(grid, vec![0u8, 1]).unwrap();
        let mut inputs = Inputs::default();
        inputs.0.insert("grid".into(), mask.into());
        let mut ctx = RunCtx::new("n", Path::new("."));
        let out = op.run(&inputs, &params, &mut ctx).unwrap();
        assert_eq!(out.0["level"], Value::from(4.0));
        assert_eq!(ctx.metrics()["kernel_is_l2"], 1.0);
        inputs.0.insert("level".into(), Value::from(2.5));
        let out = op.run(&inputs, &params, &mut ctx).unwrap();
        assert_eq!(out.0["level"], Value::from(2.5));

        let e = op
            .run(&Inputs::default(), &params, &mut ctx)
            .unwrap_err()
            .to_string();
        assert_eq!(e, "input `grid`: not connected");
        inputs.0.insert("table".into(), Value::from(2.5));
        let e = op.run(&inputs, &params, &mut ctx).unwrap_err().to_string();
        assert_eq!(e, "input `table`: is a Scalar, expected Table");
        let bad = params_of(op.spec(), &[("type", ParamValue::Int(1))]);
        let e = op.run(&inputs, &bad, &mut ctx).unwrap_err().to_string();
        assert_eq!(e, "parameter `type`: is of kind integer, asked as string");
        let missing = params_of(op.spec(), &[]);
        let e = op.run(&inputs, &missing, &mut ctx).unwrap_err().to_string();
        assert_eq!(e, "parameter `type`: is not declared");
    }
}
