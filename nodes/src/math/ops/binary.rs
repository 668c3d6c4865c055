//! `math.binary`: one arithmetic operation on two numbers.

use crate::math::{BinaryOp, apply_binary};
use fusegraph_engine::typed::prelude::*;

/// One arithmetic operation on two numbers a and b
#[derive(Op)]
#[op(name = "math.binary", version = 1)]
pub struct Binary {
    /// add, sub, mul, div, pow, min, max, or atan2_deg (atan2(a, b) in degrees)
    #[param(default = BinaryOp::Add)]
    pub operation: BinaryOp,
}

#[derive(Inputs)]
pub struct BinaryInputs {
    /// First operand
    pub a: f64,
    /// Second operand
    pub b: f64,
}

#[derive(Outputs)]
pub struct BinaryOutputs {
    /// The result
    pub value: f64,
}

impl RunOp for Binary {
    type Inputs = BinaryInputs;
    type Outputs = BinaryOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let value = apply_binary(self.operation, inputs.a, inputs.b).map_err(OpError::invalid)?;
        ctx.metric("value", value);
        Ok(BinaryOutputs { value })
    }
}
