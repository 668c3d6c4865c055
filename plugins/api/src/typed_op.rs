//! Plugin ops in the typed form (`fusegraph_plugin_api::typed`), as the
//! built-in ones are written: `#[derive(Op)]` on a struct of parameters,
//! `#[derive(Inputs)]` and `#[derive(Outputs)]` on its ports, and
//! [`TypedPluginOp::run`] on them. [`Typed`] turns such an op into a
//! [`PluginOp`], whose TOML declaration (what the host reads, ABI v1) is
//! generated from the derives.

use crate::typed::{
    InputPort, InputSet, InputSource, ListLength, OpInfo, OutputPort, OutputSet, ParamDecl,
    ParamDefault, ParamRef, ParamSet, ParamSource,
};
use crate::view::{ImageView, Inputs, Params, TableView};
use crate::{OpDecl, Outputs, Param, PluginOp};
use std::marker::PhantomData;

/// A plugin op in the typed form: `Self` holds its parameters (filled from
/// the graph), `run` gets its inputs and returns its outputs; metrics and
/// notes go to `out`. (The example needs the `derive` feature.)
///
#[cfg_attr(feature = "derive", doc = "```")]
#[cfg_attr(not(feature = "derive"), doc = "```ignore")]
/// use fusegraph_plugin_api::derive::{Inputs, Op, Outputs};
/// use fusegraph_plugin_api::{ImageU8, ImageView, PixelsView, Typed, TypedPluginOp, export_plugin};
///
/// /// Each 8-bit sample's distance from a level
/// #[derive(Op)]
/// #[op(name = "demo.invert", version = 1)]
/// pub struct Invert {
///     /// The level samples are inverted around
///     #[param(default = 255, min = 0, max = 255)]
///     pub level: i64,
/// }
///
/// #[derive(Inputs)]
/// pub struct InvertInputs<'a> {
///     /// An 8-bit image
///     pub image: ImageView<'a>,
/// }
///
/// #[derive(Outputs)]
/// pub struct InvertOutputs {
///     /// The inverted image
///     pub image: ImageU8,
/// }
///
/// impl TypedPluginOp for Invert {
///     type Inputs<'a> = InvertInputs<'a>;
///     type Outputs = InvertOutputs;
///     fn run(&self, inputs: InvertInputs<'_>, out: &mut fusegraph_plugin_api::Outputs)
///         -> Result<InvertOutputs, String> {
///         let im = inputs.image;
///         let PixelsView::U8(px) = im.pixels else {
///             return Err("8-bit images only".into());
///         };
///         let level = self.level as i32;
///         let pixels = px.iter().map(|&v| (level - v as i32).unsigned_abs().min(255) as u8).collect();
///         out.metric("level", level as f64);
///         Ok(InvertOutputs {
///             image: ImageU8 { width: im.width, height: im.height, channels: im.channels, pixels },
///         })
///     }
/// }
///
/// export_plugin!(Typed::<Invert>::new());
///
/// use fusegraph_plugin_api::PluginOp;
/// let toml = Typed::<Invert>::new().declare().to_toml();
/// assert!(toml.contains("kind = \"int\", unit = \"\", doc = \"The level samples are inverted around\", default = 255, min = 0.0, max = 255.0"), "{toml}");
/// ```
pub trait TypedPluginOp: OpInfo + ParamSet + Send + Sync + 'static {
    /// The input ports (view types borrow the host's buffers).
    type Inputs<'a>: InputSet<'a, Inputs<'a>>;
    /// The output ports.
    type Outputs: OutputSet<Outputs>;
    /// Computes the outputs, or says why not.
    fn run(&self, inputs: Self::Inputs<'_>, out: &mut Outputs) -> Result<Self::Outputs, String>;
}

/// A typed op as a [`PluginOp`], for [`crate::export_plugin!`]:
/// `export_plugin!(Typed::<MyOp>::new())`.
pub struct Typed<T>(PhantomData<fn() -> T>);

impl<T: TypedPluginOp> Typed<T> {
    /// The adapter.
    pub fn new() -> Self {
        Typed(PhantomData)
    }
}

impl<T: TypedPluginOp> Default for Typed<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: TypedPluginOp> PluginOp for Typed<T> {
    fn declare(&self) -> OpDecl {
        let mut decl = OpDecl::new(T::NAME, T::VERSION, T::DOC);
        for p in <T::Inputs<'_> as InputSet<'_, Inputs<'_>>>::port_decls() {
            decl = if p.optional {
                decl.optional_input(&p.name, &p.types, &p.doc)
            } else {
                decl.input(&p.name, &p.types, &p.doc)
            };
        }
        for p in <T::Outputs as OutputSet<Outputs>>::port_decls() {
            decl = decl.output(&p.name, p.types.first().copied().unwrap_or(""), &p.doc);
        }
        for p in T::param_decls() {
            decl = decl.param(param(p));
        }
        decl
    }

    fn run(&self, inputs: &Inputs, params: &Params, out: &mut Outputs) -> Result<(), String> {
        let op = T::from_params(params).map_err(|p| p.to_string())?;
        let inputs = <T::Inputs<'_> as InputSet<'_, Inputs<'_>>>::from_inputs(inputs)
            .map_err(|p| p.problem)?;
        op.run(inputs, out)?.put_all(out);
        Ok(())
    }
}

/// The TOML declaration of a typed parameter. Kinds the ABI does not carry
/// (`path`, `string_list`) and lengths given as a multiple are declared as
/// they are, and the host refuses them naming the op and parameter.
fn param(p: ParamDecl) -> Param {
    let mut out = Param::declared(&p.name, p.kind.toml_name(), &p.unit, &p.doc);
    out = match p.default {
        None => out,
        Some(ParamDefault::Float(v)) => out.with_default(crate::declare::toml_float(v)),
        Some(ParamDefault::Int(v)) => out.with_default(v.to_string()),
        Some(ParamDefault::Bool(v)) => out.with_default(v.to_string()),
        Some(ParamDefault::String(v)) => out.with_default(crate::declare::toml_string(&v)),
        Some(ParamDefault::Path(v)) => {
            out.with_default(crate::declare::toml_string(&v.to_string_lossy()))
        }
        Some(ParamDefault::FloatList(v)) => {
            let items: Vec<String> = v.iter().map(|&x| crate::declare::toml_float(x)).collect();
            out.with_default(format!("[{}]", items.join(", ")))
        }
        Some(ParamDefault::IntList(v)) => {
            let items: Vec<String> = v.iter().map(|x| x.to_string()).collect();
            out.with_default(format!("[{}]", items.join(", ")))
        }
        Some(ParamDefault::StringList(v)) => {
            let items: Vec<String> = v.iter().map(|x| crate::declare::toml_string(x)).collect();
            out.with_default(format!("[{}]", items.join(", ")))
        }
    };
    if let (Some(min), Some(max)) = (p.min, p.max) {
        out = out.range(min, max);
    } else {
        out = out.bounds(p.min, p.max);
    }
    match p.length {
        Some(ListLength::OneOf(n)) => out = out.lengths(&n),
        Some(ListLength::MultipleOf(k)) => out = out.length_multiple_of(k),
        None => {}
    }
    out.with_choices(p.choices)
}

impl ParamSource for Params<'_> {
    fn param(&self, name: &str) -> Option<ParamRef<'_>> {
        use crate::abi::param_kind;
        Some(match self.kind(name)? {
            param_kind::INT => ParamRef::Int(self.int(name).ok()?),
            param_kind::FLOAT => ParamRef::Float(self.float(name).ok()?),
            param_kind::BOOL => ParamRef::Bool(self.bool(name).ok()?),
            param_kind::STRING => ParamRef::Str(self.string(name).ok()?),
            param_kind::INT_LIST => ParamRef::IntList(self.int_list(name).ok()?),
            param_kind::FLOAT_LIST => ParamRef::FloatList(self.float_list(name).ok()?),
            _ => return None,
        })
    }
}

impl InputSource for Inputs<'_> {
    fn is_connected(&self, port: &str) -> bool {
        self.is_connected(port)
    }
}

impl<'a> InputPort<'a, Inputs<'a>> for ImageView<'a> {
    fn type_names() -> Vec<&'static str> {
        vec!["Image"]
    }
    fn take(source: &'a Inputs<'a>, port: &str) -> Result<Self, String> {
        source.image(port)
    }
}

impl<'a> InputPort<'a, Inputs<'a>> for f64 {
    fn type_names() -> Vec<&'static str> {
        vec!["Scalar"]
    }
    fn take(source: &'a Inputs<'a>, port: &str) -> Result<Self, String> {
        source.scalar(port)
    }
}

impl<'a> InputPort<'a, Inputs<'a>> for TableView<'a> {
    fn type_names() -> Vec<&'static str> {
        vec!["Table"]
    }
    fn take(source: &'a Inputs<'a>, port: &str) -> Result<Self, String> {
        source.table(port)
    }
}

/// A disparity map on an input port, borrowed from the host.
#[derive(Debug, Clone, Copy)]
pub struct DisparityView<'a> {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Disparities, px, row-major (NaN: no match).
    pub data: &'a [f32],
}

impl<'a> InputPort<'a, Inputs<'a>> for DisparityView<'a> {
    fn type_names() -> Vec<&'static str> {
        vec!["Disparity"]
    }
    fn take(source: &'a Inputs<'a>, port: &str) -> Result<Self, String> {
        let (width, height, data) = source.disparity(port)?;
        Ok(DisparityView {
            width,
            height,
            data,
        })
    }
}

/// A disparity map for an output port.
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Disparities, px, row-major (NaN: no match).
    pub data: Vec<f32>,
}

impl OutputPort<Outputs> for DisparityMap {
    fn type_name() -> &'static str {
        "Disparity"
    }
    fn put(self, sink: &mut Outputs, port: &str) {
        sink.disparity(port, self.width, self.height, self.data);
    }
}

/// An 8-bit image for an output port.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageU8 {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// Samples, row-major, channels interleaved.
    pub pixels: Vec<u8>,
}

impl OutputPort<Outputs> for ImageU8 {
    fn type_name() -> &'static str {
        "Image"
    }
    fn put(self, sink: &mut Outputs, port: &str) {
        sink.image_u8(port, self.width, self.height, self.channels, self.pixels);
    }
}

impl OutputPort<Outputs> for f64 {
    fn type_name() -> &'static str {
        "Scalar"
    }
    fn put(self, sink: &mut Outputs, port: &str) {
        sink.scalar(port, self);
    }
}
