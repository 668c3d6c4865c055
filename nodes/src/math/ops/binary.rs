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

#[derive(Debug, Outputs)]
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

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::param::ParamValue;
    use fusegraph_engine::typed::Typed;
    use fusegraph_engine::value::FromValue;
    use fusegraph_engine::{Inputs, Op, Params};

    #[test]
    fn the_operation_is_read_by_its_name() {
        let op = Typed::<Binary>::new().unwrap();
        let params = Params(
            [("operation".into(), ParamValue::String("atan2_deg".into()))]
                .into_iter()
                .collect(),
        );
        let inputs = Inputs(
            [("a".into(), 55.0.into()), ("b".into(), 400.0.into())]
                .into_iter()
                .collect(),
        );
        let mut ctx = RunCtx::new("binary", std::path::Path::new("."));
        let out = op.run(&inputs, &params, &mut ctx).unwrap();
        let value = **f64::from_value(&out.0["value"]).unwrap();
        assert!((value - 7.82908).abs() < 1e-5, "{value}");
        assert_eq!(ctx.metrics()["value"], value);
    }

    #[test]
    fn an_undefined_result_is_an_error() {
        let op = Binary {
            operation: BinaryOp::Div,
        };
        let mut ctx = RunCtx::new("binary", std::path::Path::new("."));
        let e = op
            .run(BinaryInputs { a: 1.0, b: 0.0 }, &mut ctx)
            .unwrap_err();
        assert!(e.to_string().contains("division by zero"), "{e}");
    }
}
