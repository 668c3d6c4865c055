//! Scalar arithmetic nodes: constants and binary operations, for deriving
//! quantities (e.g. a lens focal length from sensor size and field of view) in a
//! graph without code.

mod binary;
pub mod ops;

pub use binary::{BinaryOp, apply_binary};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `math.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::Constant>()?;
    registry.add::<ops::Binary>()?;
    Ok(())
}
