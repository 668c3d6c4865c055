//! The registry of node types, open to registration at run time (plugins add
//! theirs after the built-in ones).

use crate::op::{Op, OpSpec};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

/// A node type that cannot be registered.
#[derive(Debug, thiserror::Error)]
pub enum RegisterError {
    /// Another node type already has this op name.
    #[error("op `{0}` is already registered")]
    Duplicate(String),
    /// The declaration is inconsistent.
    #[error("op `{0}`: {1}")]
    InvalidSpec(String, String),
}

/// Runs script files (Python) and registers the ops they declare; the
/// program that embeds an interpreter puts one in its registry (see
/// [`crate::script`]).
pub trait ScriptHost: Send + Sync {
    /// Runs `file` (absolute) and adds the ops it declares to `registry`;
    /// returns their names. Loading a file again whose ops are already in
    /// `registry` unchanged is not an error.
    fn load(&self, file: &Path, registry: &mut Registry) -> Result<Vec<String>, String>;
}

/// Node types by op name.
#[derive(Clone, Default)]
pub struct Registry {
    ops: BTreeMap<String, Arc<dyn Op>>,
    /// Plugin libraries loaded into this registry (canonical paths), with
    /// the ops each declared.
    plugins: BTreeMap<std::path::PathBuf, Vec<String>>,
    /// Runs the scripts (Python files) graphs name, where the program embeds
    /// an interpreter.
    script_host: Option<Arc<dyn ScriptHost>>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a node type; its op name must be new and its declaration consistent.
    pub fn register(&mut self, op: Arc<dyn Op>) -> Result<(), RegisterError> {
        let name = op.spec().name.clone();
        op.spec()
            .check()
            .map_err(|why| RegisterError::InvalidSpec(name.clone(), why))?;
        if self.ops.contains_key(&name) {
            return Err(RegisterError::Duplicate(name));
        }
        self.ops.insert(name, op);
        Ok(())
    }

    /// Adds a node type written in the typed form (see [`crate::typed`]).
    pub fn add<T: crate::typed::RunOp>(&mut self) -> Result<(), RegisterError> {
        let op = crate::typed::Typed::<T>::new()
            .map_err(|why| RegisterError::InvalidSpec(T::NAME.into(), why))?;
        self.register(Arc::new(op))
    }

    /// Records that the plugin at `file` (canonical) declared `ops`.
    pub fn add_plugin(&mut self, file: std::path::PathBuf, ops: Vec<String>) {
        self.plugins.insert(file, ops);
    }

    /// The ops of the plugin at `file` (canonical), if it is loaded.
    pub fn plugin_ops(&self, file: &std::path::Path) -> Option<&[String]> {
        self.plugins.get(file).map(Vec::as_slice)
    }

    /// Sets the fingerprint of op `name`'s implementation (see
    /// [`OpSpec::code`]); whether the op is registered.
    pub fn set_code(&mut self, name: &str, code: &str) -> bool {
        let Some(op) = self.ops.get(name).cloned() else {
            return false;
        };
        let mut spec = op.spec().clone();
        spec.code = Some(code.to_string());
        self.ops
            .insert(name.to_string(), Arc::new(WithCode { spec, op }));
        true
    }

    /// Lets graphs name scripts, which `host` loads (see [`crate::script`]).
    pub fn set_script_host(&mut self, host: Arc<dyn ScriptHost>) {
        self.script_host = Some(host);
    }

    /// The host that loads scripts, if the program has one.
    pub fn script_host(&self) -> Option<Arc<dyn ScriptHost>> {
        self.script_host.clone()
    }

    /// Removes the node type called `name` (a script's op declared again
    /// with other code replaces the old one); whether it was there.
    pub fn unregister(&mut self, name: &str) -> bool {
        self.ops.remove(name).is_some()
    }

    /// The node type called `name`.
    pub fn get(&self, name: &str) -> Option<&Arc<dyn Op>> {
        self.ops.get(name)
    }

    /// Every op name, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.ops.keys().map(String::as_str)
    }

    /// Every declaration, sorted by op name.
    pub fn specs(&self) -> impl Iterator<Item = &OpSpec> {
        self.ops.values().map(|op| op.spec())
    }
}

/// An op with its code fingerprint set.
struct WithCode {
    spec: OpSpec,
    op: Arc<dyn Op>,
}

impl Op for WithCode {
    fn spec(&self) -> &OpSpec {
        &self.spec
    }

    fn run(
        &self,
        inputs: &crate::op::Inputs,
        params: &crate::param::Params,
        ctx: &mut crate::op::RunCtx,
    ) -> Result<crate::op::Outputs, crate::op::OpError> {
        self.op.run(inputs, params, ctx)
    }

    fn check(
        &self,
        params: &crate::param::Params,
        wired: crate::op::Wired,
    ) -> Vec<crate::param::ParamError> {
        self.op.check(params, wired)
    }
}
