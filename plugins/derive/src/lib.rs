//! Derives for fusegraph's typed op declarations (`fusegraph_plugin_api::typed`):
//! an op is a struct whose fields are its parameters, and its ports are two
//! more structs, so each parameter and port is named once, in Rust, and a
//! misspelt one is a compile error.
//!
//! - `#[derive(Op)]` with `#[op(name = "stage.action", version = N)]` (and
//!   `writes_output` for sinks): the op's name, version and doc (the struct's
//!   `///`), and its parameters (the fields).
//! - `#[derive(Params)]`: a group of parameters that an op flattens in with
//!   `#[param(flatten)]`.
//! - `#[derive(Inputs)]`, `#[derive(Outputs)]`: one field per port.
//! - `#[derive(Choice)]`: a fieldless enum as a string parameter with a fixed
//!   set of choices (variant names in snake_case, or `#[choice(name = "..")]`).
//!
//! Parameter fields take `#[param(default = EXPR, unit = "mm", min = X,
//! max = Y, length = N, lengths = [A, B], length_multiple_of = K,
//! name = "key", flatten)]`; a field without a default is required, except
//! `Option<PathBuf>`, which defaults to "not given". The generated code names
//! `::fusegraph_plugin_api::typed`, so the crate using a derive depends on
//! `fusegraph-plugin-api`.

use proc_macro::TokenStream;
use proc_macro2::{Span, TokenStream as Tokens};
use quote::quote;
use syn::spanned::Spanned;
use syn::{
    Attribute, Data, DeriveInput, Expr, Fields, GenericParam, Ident, Lifetime, LitInt, LitStr,
    Type, parse_macro_input,
};

fn typed() -> Tokens {
    quote!(::fusegraph_plugin_api::typed)
}

/// The `///` lines of an item, as string literals.
fn doc_lines(attrs: &[Attribute]) -> Vec<LitStr> {
    attrs
        .iter()
        .filter(|a| a.path().is_ident("doc"))
        .filter_map(|a| match &a.meta {
            syn::Meta::NameValue(nv) => match &nv.value {
                Expr::Lit(syn::ExprLit {
                    lit: syn::Lit::Str(s),
                    ..
                }) => Some(s.clone()),
                _ => None,
            },
            _ => None,
        })
        .collect()
}

fn joined_doc(attrs: &[Attribute]) -> String {
    doc_lines(attrs)
        .iter()
        .map(|l| l.value().trim().to_string())
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

fn named_fields(input: &DeriveInput) -> syn::Result<Vec<&syn::Field>> {
    match &input.data {
        Data::Struct(s) => match &s.fields {
            Fields::Named(f) => Ok(f.named.iter().collect()),
            Fields::Unit => Ok(Vec::new()),
            Fields::Unnamed(_) => Err(syn::Error::new(
                input.span(),
                "fields must be named: each name is a key or port",
            )),
        },
        _ => Err(syn::Error::new(input.span(), "expected a struct")),
    }
}

/// A field's key: its name without `r#`, or `name = ".."`.
fn field_key(field: &syn::Field, rename: Option<LitStr>) -> LitStr {
    rename.unwrap_or_else(|| {
        let ident = field.ident.as_ref().expect("named field").to_string();
        LitStr::new(ident.trim_start_matches("r#"), field.span())
    })
}

fn struct_init(input: &DeriveInput, inits: Vec<Tokens>) -> Tokens {
    match &input.data {
        Data::Struct(s) if matches!(s.fields, Fields::Unit) => quote!(Self),
        _ => quote!(Self { #(#inits),* }),
    }
}

/// The last path segment's name and its type arguments (`Vec<String>` ->
/// `("Vec", [String])`).
fn type_head(ty: &Type) -> Option<(String, Vec<&Type>)> {
    let Type::Path(p) = ty else { return None };
    let seg = p.path.segments.last()?;
    let args = match &seg.arguments {
        syn::PathArguments::AngleBracketed(a) => a
            .args
            .iter()
            .filter_map(|a| match a {
                syn::GenericArgument::Type(t) => Some(t),
                _ => None,
            })
            .collect(),
        _ => Vec::new(),
    };
    Some((seg.ident.to_string(), args))
}

/// `expr` as a value of `ty`, with the conversions a literal needs.
fn default_value(ty: &Type, expr: &Expr) -> Tokens {
    match type_head(ty) {
        Some((head, _)) if head == "String" => quote!(::std::string::String::from(#expr)),
        Some((head, _)) if head == "PathBuf" => quote!(::std::path::PathBuf::from(#expr)),
        Some((head, args)) if head == "Vec" && args.len() == 1 => {
            let elem = args[0];
            if matches!(type_head(elem), Some((h, _)) if h == "String") {
                quote!({
                    let items: &[&str] = &#expr;
                    items.iter().map(|s| s.to_string()).collect::<::std::vec::Vec<::std::string::String>>()
                })
            } else {
                quote!({ let items: &[#elem] = &#expr; items.to_vec() })
            }
        }
        _ => quote!({ let value: #ty = #expr; value }),
    }
}

#[derive(Default)]
struct ParamAttrs {
    default: Option<Expr>,
    unit: Option<LitStr>,
    min: Option<Expr>,
    max: Option<Expr>,
    length: Option<Tokens>,
    name: Option<LitStr>,
    flatten: bool,
}

fn param_attrs(field: &syn::Field) -> syn::Result<ParamAttrs> {
    let mut a = ParamAttrs::default();
    let typed = typed();
    for attr in field.attrs.iter().filter(|a| a.path().is_ident("param")) {
        attr.parse_nested_meta(|meta| {
            let key = meta
                .path
                .get_ident()
                .map(|i| i.to_string())
                .unwrap_or_default();
            match key.as_str() {
                "default" => a.default = Some(meta.value()?.parse()?),
                "unit" => a.unit = Some(meta.value()?.parse()?),
                "min" => a.min = Some(meta.value()?.parse()?),
                "max" => a.max = Some(meta.value()?.parse()?),
                "name" => a.name = Some(meta.value()?.parse()?),
                "flatten" => a.flatten = true,
                "length" => {
                    let n: LitInt = meta.value()?.parse()?;
                    a.length = Some(quote!(#typed::ListLength::OneOf(vec![#n])));
                }
                "lengths" => {
                    let list: syn::ExprArray = meta.value()?.parse()?;
                    let items = list.elems.iter();
                    a.length = Some(quote!(#typed::ListLength::OneOf(vec![#(#items),*])));
                }
                "length_multiple_of" => {
                    let n: LitInt = meta.value()?.parse()?;
                    a.length = Some(quote!(#typed::ListLength::MultipleOf(#n)));
                }
                _ => {
                    return Err(meta.error(
                        "unknown #[param] key: expected default, unit, min, max, length, \
                         lengths, length_multiple_of, name or flatten",
                    ));
                }
            }
            Ok(())
        })?;
    }
    Ok(a)
}

/// `impl ParamSet` for a struct whose fields are parameters.
fn param_set(input: &DeriveInput) -> syn::Result<Tokens> {
    let typed = typed();
    let name = &input.ident;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    let mut decls = Vec::new();
    let mut inits = Vec::new();
    for field in named_fields(input)? {
        let ident = field.ident.as_ref().expect("named");
        let ty = &field.ty;
        let a = param_attrs(field)?;
        if a.flatten {
            decls.push(quote!(decls.extend(<#ty as #typed::ParamSet>::param_decls());));
            inits.push(quote!(#ident: <#ty as #typed::ParamSet>::from_params(source)?));
            continue;
        }
        let key = field_key(field, a.name);
        let docs = doc_lines(&field.attrs);
        let default = match &a.default {
            Some(expr) => {
                let value = default_value(ty, expr);
                quote!(::std::option::Option::Some::<#ty>(#value))
            }
            None => quote!(<#ty as #typed::ParamType>::implicit_default()),
        };
        let unit = a.unit.unwrap_or_else(|| LitStr::new("", Span::call_site()));
        let number = |e: &Option<Expr>| match e {
            Some(e) => quote!(::std::option::Option::Some((#e) as f64)),
            None => quote!(::std::option::Option::None),
        };
        let (min, max) = (number(&a.min), number(&a.max));
        let length = match a.length {
            Some(l) => quote!(::std::option::Option::Some(#l)),
            None => quote!(<#ty as #typed::ParamType>::fixed_length()
                .map(|n| #typed::ListLength::OneOf(vec![n]))),
        };
        decls.push(quote!(decls.push(#typed::ParamDecl {
            name: #key.into(),
            kind: <#ty as #typed::ParamType>::KIND,
            default: #default.as_ref().map(#typed::ParamType::to_default),
            unit: #unit.into(),
            min: #min,
            max: #max,
            choices: <#ty as #typed::ParamType>::choices(),
            length: #length,
            doc: #typed::doc_line(&[#(#docs),*]),
        });));
        inits.push(quote!(#ident: #typed::read_param::<#ty>(source, #key)?));
    }
    let init = struct_init(input, inits);
    Ok(quote! {
        impl #impl_generics #typed::ParamSet for #name #ty_generics #where_clause {
            fn param_decls() -> ::std::vec::Vec<#typed::ParamDecl> {
                #[allow(unused_mut)]
                let mut decls = ::std::vec::Vec::new();
                #(#decls)*
                decls
            }
            #[allow(unused_variables)]
            fn from_params(
                source: &dyn #typed::ParamSource,
            ) -> ::std::result::Result<Self, #typed::ParamProblem> {
                ::std::result::Result::Ok(#init)
            }
        }
    })
}

/// An op: its parameters, plus `#[op(name = "stage.action", version = N)]`.
#[proc_macro_derive(Op, attributes(op, param))]
pub fn derive_op(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    op_impl(&input)
        .unwrap_or_else(|e| e.to_compile_error())
        .into()
}

fn op_impl(input: &DeriveInput) -> syn::Result<Tokens> {
    let typed = typed();
    let (mut op_name, mut version, mut writes_output, mut doc) =
        (None::<LitStr>, None::<LitInt>, false, None::<LitStr>);
    for attr in input.attrs.iter().filter(|a| a.path().is_ident("op")) {
        attr.parse_nested_meta(|meta| {
            if meta.path.is_ident("name") {
                op_name = Some(meta.value()?.parse()?);
            } else if meta.path.is_ident("version") {
                version = Some(meta.value()?.parse()?);
            } else if meta.path.is_ident("doc") {
                doc = Some(meta.value()?.parse()?);
            } else if meta.path.is_ident("writes_output") {
                writes_output = true;
            } else {
                return Err(
                    meta.error("unknown #[op] key: expected name, version, doc or writes_output")
                );
            }
            Ok(())
        })?;
    }
    let op_name = op_name.ok_or_else(|| {
        syn::Error::new(
            input.span(),
            "#[op(name = \"stage.action\", version = N)] is missing",
        )
    })?;
    let version =
        version.ok_or_else(|| syn::Error::new(input.span(), "#[op(version = N)] is missing"))?;
    let doc = doc.unwrap_or_else(|| LitStr::new(&joined_doc(&input.attrs), input.span()));
    let name = &input.ident;
    let (impl_generics, ty_generics, where_clause) = input.generics.split_for_impl();
    let params = param_set(input)?;
    Ok(quote! {
        impl #impl_generics #typed::OpInfo for #name #ty_generics #where_clause {
            const NAME: &'static str = #op_name;
            const VERSION: u32 = #version;
            const DOC: &'static str = #doc;
            const WRITES_OUTPUT: bool = #writes_output;
        }
        #params
    })
}

/// A group of parameters (flattened into an op with `#[param(flatten)]`).
#[proc_macro_derive(Params, attributes(param))]
pub fn derive_params(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    param_set(&input)
        .unwrap_or_else(|e| e.to_compile_error())
        .into()
}

#[derive(Default)]
struct PortAttrs {
    name: Option<LitStr>,
    types: Option<Vec<Ident>>,
}

fn port_attrs(field: &syn::Field, attr_name: &str) -> syn::Result<PortAttrs> {
    let mut a = PortAttrs::default();
    for attr in field.attrs.iter().filter(|a| a.path().is_ident(attr_name)) {
        attr.parse_nested_meta(|meta| {
            if meta.path.is_ident("name") {
                a.name = Some(meta.value()?.parse()?);
            } else if meta.path.is_ident("types") && attr_name == "input" {
                let mut types = Vec::new();
                meta.parse_nested_meta(|t| {
                    types.push(t.path.require_ident()?.clone());
                    Ok(())
                })?;
                a.types = Some(types);
            } else {
                return Err(meta.error("unknown key: expected name (or types(..) on inputs)"));
            }
            Ok(())
        })?;
    }
    Ok(a)
}

/// The struct's one lifetime parameter, or a fresh one for the impl.
fn source_lifetime(input: &DeriveInput) -> (Lifetime, bool) {
    match input.generics.params.iter().find_map(|p| match p {
        GenericParam::Lifetime(l) => Some(l.lifetime.clone()),
        _ => None,
    }) {
        Some(l) => (l, true),
        None => (Lifetime::new("'__source", Span::call_site()), false),
    }
}

/// An op's inputs, one field per port: `Arc<T>` (engine) or a view type
/// (plugins) for a required port, `Option<..>` for an optional one.
#[proc_macro_derive(Inputs, attributes(input))]
pub fn derive_inputs(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    inputs_impl(&input)
        .unwrap_or_else(|e| e.to_compile_error())
        .into()
}

fn inputs_impl(input: &DeriveInput) -> syn::Result<Tokens> {
    let typed = typed();
    let name = &input.ident;
    let (lifetime, own) = source_lifetime(input);
    let (_, ty_generics, _) = input.generics.split_for_impl();
    let impl_lifetime = if own { quote!() } else { quote!(#lifetime,) };
    let other_params = input.generics.params.iter();
    let mut decls = Vec::new();
    let mut inits = Vec::new();
    let mut bounds = Vec::new();
    for field in named_fields(input)? {
        let ident = field.ident.as_ref().expect("named");
        let ty = &field.ty;
        let a = port_attrs(field, "input")?;
        let key = field_key(field, a.name);
        let docs = doc_lines(&field.attrs);
        let port = quote!(<#ty as #typed::InputPort<#lifetime, __Source>>);
        let types = match a.types {
            Some(t) => {
                let names = t.iter().map(|i| LitStr::new(&i.to_string(), i.span()));
                quote!(vec![#(#names),*])
            }
            None => quote!(#port::type_names()),
        };
        decls.push(
            quote!(#typed::port(#key, #types, #port::OPTIONAL, &#typed::doc_line(&[#(#docs),*]))),
        );
        inits.push(quote!(#ident: #typed::read_input::<__Source, #ty>(source, #key)?));
        bounds.push(quote!(#ty: #typed::InputPort<#lifetime, __Source>));
    }
    let init = struct_init(input, inits);
    Ok(quote! {
        impl<#impl_lifetime #(#other_params,)* __Source: ?Sized> #typed::InputSet<#lifetime, __Source>
            for #name #ty_generics where #(#bounds),*
        {
            fn port_decls() -> ::std::vec::Vec<#typed::PortDecl> {
                vec![#(#decls),*]
            }
            #[allow(unused_variables)]
            fn from_inputs(source: &#lifetime __Source) -> ::std::result::Result<Self, #typed::PortProblem> {
                ::std::result::Result::Ok(#init)
            }
        }
    })
}

/// An op's outputs, one field per port.
#[proc_macro_derive(Outputs, attributes(output))]
pub fn derive_outputs(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    outputs_impl(&input)
        .unwrap_or_else(|e| e.to_compile_error())
        .into()
}

fn outputs_impl(input: &DeriveInput) -> syn::Result<Tokens> {
    let typed = typed();
    let name = &input.ident;
    let (_, ty_generics, _) = input.generics.split_for_impl();
    let params = input.generics.params.iter();
    let mut decls = Vec::new();
    let mut puts = Vec::new();
    let mut bounds = Vec::new();
    for field in named_fields(input)? {
        let ident = field.ident.as_ref().expect("named");
        let ty = &field.ty;
        let a = port_attrs(field, "output")?;
        let key = field_key(field, a.name);
        let docs = doc_lines(&field.attrs);
        decls.push(quote!(#typed::port(#key, vec![<#ty as #typed::OutputPort<__Sink>>::type_name()], false, &#typed::doc_line(&[#(#docs),*]))));
        puts.push(quote!(#typed::OutputPort::<__Sink>::put(self.#ident, sink, #key);));
        bounds.push(quote!(#ty: #typed::OutputPort<__Sink>));
    }
    Ok(quote! {
        impl<#(#params,)* __Sink: ?Sized> #typed::OutputSet<__Sink> for #name #ty_generics
            where #(#bounds),*
        {
            fn port_decls() -> ::std::vec::Vec<#typed::PortDecl> {
                vec![#(#decls),*]
            }
            #[allow(unused_variables)]
            fn put_all(self, sink: &mut __Sink) {
                #(#puts)*
            }
        }
    })
}

/// A fieldless enum as a choice parameter: `#[choice(name = "..")]` renames a
/// variant (default: its name in snake_case). Also gives `NAMES` and `name()`.
#[proc_macro_derive(Choice, attributes(choice))]
pub fn derive_choice(input: TokenStream) -> TokenStream {
    let input = parse_macro_input!(input as DeriveInput);
    choice_impl(&input)
        .unwrap_or_else(|e| e.to_compile_error())
        .into()
}

fn snake_case(s: &str) -> String {
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if c.is_uppercase() {
            if i > 0 {
                out.push('_');
            }
            out.extend(c.to_lowercase());
        } else {
            out.push(c);
        }
    }
    out
}

fn choice_impl(input: &DeriveInput) -> syn::Result<Tokens> {
    let typed = typed();
    let Data::Enum(e) = &input.data else {
        return Err(syn::Error::new(input.span(), "Choice is derived for enums"));
    };
    let name = &input.ident;
    let mut variants = Vec::new();
    let mut names = Vec::new();
    for v in &e.variants {
        if !matches!(v.fields, Fields::Unit) {
            return Err(syn::Error::new(
                v.span(),
                "a choice's variants have no fields",
            ));
        }
        let mut rename = None::<LitStr>;
        for attr in v.attrs.iter().filter(|a| a.path().is_ident("choice")) {
            attr.parse_nested_meta(|meta| {
                if meta.path.is_ident("name") {
                    rename = Some(meta.value()?.parse()?);
                    Ok(())
                } else {
                    Err(meta.error("unknown #[choice] key: expected name"))
                }
            })?;
        }
        names.push(
            rename
                .unwrap_or_else(|| LitStr::new(&snake_case(&v.ident.to_string()), v.ident.span())),
        );
        variants.push(v.ident.clone());
    }
    let count = variants.len();
    let doc = "Every choice, by its name in graph files.";
    Ok(quote! {
        impl #name {
            #[doc = #doc]
            pub const NAMES: [&'static str; #count] = [#(#names),*];
            /// This choice's name in graph files.
            pub fn name(&self) -> &'static str {
                match self { #(#name::#variants => #names),* }
            }
        }
        impl #typed::ParamType for #name {
            const KIND: #typed::ParamKind = #typed::ParamKind::String;
            fn from_param(value: #typed::ParamRef<'_>) -> ::std::result::Result<Self, ::std::string::String> {
                match value {
                    #(#typed::ParamRef::Str(#names) => ::std::result::Result::Ok(#name::#variants),)*
                    #typed::ParamRef::Str(other) => ::std::result::Result::Err(
                        format!("{other:?} is not one of: {}", #name::NAMES.join(", "))),
                    _ => ::std::result::Result::Err("is not a string".into()),
                }
            }
            fn to_default(&self) -> #typed::ParamDefault {
                #typed::ParamDefault::String(self.name().into())
            }
            fn choices() -> ::std::vec::Vec<::std::string::String> {
                #name::NAMES.iter().map(|s| s.to_string()).collect()
            }
        }
    })
}
