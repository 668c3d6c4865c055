//! fusegraph's dataflow engine: graph files ([`graph`]), their validation
//! ([`validate`]), the value types ([`value`]), node types and their registry
//! ([`op`], [`registry`]), cache keys and the two cache levels ([`key`],
//! [`cache`]), and the scheduler ([`schedule`]) that writes a [`report`].
//!
//! The engine knows nothing about MRI or cameras: node types come from the
//! `fusegraph-nodes` crate or from plugins.

pub mod atomic;
pub mod cache;
pub mod cache_admin;
pub mod dot;
pub mod each;
pub mod error;
pub mod figure;
pub mod graph;
pub mod hash;
pub mod key;
pub mod lease;
pub mod memory;
pub mod op;
pub mod panics;
pub mod param;
pub mod plugin;
pub mod process;
pub mod provenance;
pub mod registry;
pub mod report;
pub mod report_html;
pub mod schedule;
pub mod script;
pub mod session;
pub mod sweep;
pub mod typed;
pub mod validate;
pub mod value;
pub mod workdir;

pub use error::{ErrorKind, GraphError, GraphErrors};
pub use op::{Inputs, Op, OpError, OpSpec, Outputs, PortSpec, RunCtx, Wired, path_value};
pub use param::{ParamKind, ParamSpec, ParamValue, Params};
pub use registry::Registry;
pub use report::{NodeStatus, RunReport};
pub use value::{Value, ValueType};
