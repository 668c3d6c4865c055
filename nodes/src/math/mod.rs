//! Scalar arithmetic nodes: constants and binary operations, for deriving
//! quantities (e.g. a lens focal length from sensor size and field of view) in a
//! graph without code.

mod binary;
mod constant;

pub use binary::{BinaryOp, apply_binary};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `math.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(constant::ConstantOp::new()))?;
    registry.register(Arc::new(binary::BinaryNode::new()))?;
    Ok(())
}
