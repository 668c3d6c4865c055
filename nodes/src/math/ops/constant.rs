//! `math.constant`: a number given as a parameter.

use fusegraph_engine::typed::prelude::*;

/// A number given as a parameter
#[derive(Op)]
#[op(name = "math.constant", version = 1)]
pub struct Constant {
    /// The number (put its unit in the node id)
    #[param(default = 0.0)]
    pub value: f64,
}

#[derive(Inputs)]
pub struct ConstantInputs;

#[derive(Debug, Outputs)]
pub struct ConstantOutputs {
    /// The number
    pub value: f64,
}

impl RunOp for Constant {
    type Inputs = ConstantInputs;
    type Outputs = ConstantOutputs;

    fn run(&self, _: Self::Inputs, _: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        Ok(ConstantOutputs { value: self.value })
    }
}
