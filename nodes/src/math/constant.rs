//! `math.constant`: a number given as a parameter.

use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};

pub(crate) struct ConstantOp(OpSpec);

impl ConstantOp {
    pub(crate) fn new() -> Self {
        ConstantOp(
            OpSpec::new("math.constant", 1, "A number given as a parameter")
                .param(ParamSpec::float(
                    "value",
                    0.0,
                    "",
                    "The number (put its unit in the node id)",
                ))
                .output("value", ValueType::Scalar, "The number"),
        )
    }
}

impl Op for ConstantOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, _: &Inputs, params: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
        Ok(Outputs::new().with("value", params.float("value")?))
    }
}
