//! `math.binary`: one arithmetic operation on two numbers.

use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};

/// An operation on two numbers `a` and `b`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinaryOp {
    /// a + b
    Add,
    /// a - b
    Sub,
    /// a * b
    Mul,
    /// a / b (b must not be 0)
    Div,
    /// a ^ b
    Pow,
    /// The smaller of a and b.
    Min,
    /// The larger of a and b.
    Max,
    /// atan2(a, b) in degrees: the angle subtended by an opposite side a at an
    /// adjacent side b (e.g. a verging angle from a baseline and a distance).
    Atan2Deg,
}

impl BinaryOp {
    /// Every operation, by its name in graph files.
    pub const NAMES: &'static [(&'static str, BinaryOp)] = &[
        ("add", BinaryOp::Add),
        ("sub", BinaryOp::Sub),
        ("mul", BinaryOp::Mul),
        ("div", BinaryOp::Div),
        ("pow", BinaryOp::Pow),
        ("min", BinaryOp::Min),
        ("max", BinaryOp::Max),
        ("atan2_deg", BinaryOp::Atan2Deg),
    ];

    /// The operation called `name`.
    pub fn from_name(name: &str) -> Option<BinaryOp> {
        Self::NAMES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|&(_, op)| op)
    }
}

/// Applies `op` to `a` and `b`; an undefined or non-finite result is an error.
pub fn apply_binary(op: BinaryOp, a: f64, b: f64) -> Result<f64, String> {
    let result = match op {
        BinaryOp::Add => a + b,
        BinaryOp::Sub => a - b,
        BinaryOp::Mul => a * b,
        BinaryOp::Div if b == 0.0 => return Err(format!("division by zero ({a} / 0)")),
        BinaryOp::Div => a / b,
        BinaryOp::Pow => a.powf(b),
        BinaryOp::Min => a.min(b),
        BinaryOp::Max => a.max(b),
        BinaryOp::Atan2Deg => a.atan2(b).to_degrees(),
    };
    if result.is_finite() {
        Ok(result)
    } else {
        Err(format!("{op:?} of {a} and {b} is not a finite number"))
    }
}

pub(crate) struct BinaryNode(OpSpec);

impl BinaryNode {
    pub(crate) fn new() -> Self {
        let names: Vec<&str> = BinaryOp::NAMES.iter().map(|(n, _)| *n).collect();
        BinaryNode(
            OpSpec::new(
                "math.binary",
                1,
                "One arithmetic operation on two numbers a and b",
            )
            .input("a", &[ValueType::Scalar], "First operand")
            .input("b", &[ValueType::Scalar], "Second operand")
            .param(ParamSpec::choice(
                "operation",
                &names,
                "add, sub, mul, div, pow, min, max, or atan2_deg (atan2(a, b) in degrees)",
            ))
            .output("value", ValueType::Scalar, "The result"),
        )
    }
}

impl Op for BinaryNode {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let name = params.string("operation")?;
        let op = BinaryOp::from_name(&name)
            .ok_or_else(|| OpError::invalid(format!("unknown operation {name}")))?;
        let (a, b) = (*inputs.get::<f64>("a")?, *inputs.get::<f64>("b")?);
        let value = apply_binary(op, a, b).map_err(OpError::invalid)?;
        ctx.metric("value", value);
        Ok(Outputs::new().with("value", value))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_matches_hand_computed_values() {
        // The paper's lens: f = s * Dmin / FOV = 4.8 * 400 / 250 = 7.68 mm.
        let sd = apply_binary(BinaryOp::Mul, 4.8, 400.0).unwrap();
        assert!((apply_binary(BinaryOp::Div, sd, 250.0).unwrap() - 7.68).abs() < 1e-12);
        // The paper's verging angle: atan(55 / 400) = 7.82908 deg (the paper rounds to 7.9).
        let theta = apply_binary(BinaryOp::Atan2Deg, 55.0, 400.0).unwrap();
        assert!((theta - 7.82908).abs() < 1e-5, "{theta}");
        assert_eq!(apply_binary(BinaryOp::Pow, 2.0, 10.0), Ok(1024.0));
        assert_eq!(apply_binary(BinaryOp::Min, 2.0, -1.0), Ok(-1.0));
    }

    #[test]
    fn undefined_results_are_errors() {
        assert!(
            apply_binary(BinaryOp::Div, 1.0, 0.0)
                .unwrap_err()
                .contains("division by zero")
        );
        assert!(apply_binary(BinaryOp::Pow, -1.0, 0.5).is_err());
    }

    #[test]
    fn every_name_parses() {
        for (name, op) in BinaryOp::NAMES {
            assert_eq!(BinaryOp::from_name(name), Some(*op));
        }
        assert_eq!(BinaryOp::from_name("modulo"), None);
    }
}
