//! The `math.*` ops: one file per op, each its declaration and thin adapter.

mod binary;
mod constant;

pub use binary::{Binary, BinaryInputs, BinaryOutputs};
pub use constant::{Constant, ConstantInputs, ConstantOutputs};
