//! `io.write_json`: writes a small value (a number, table, transform, markers,
//! camera, rig) as JSON under the output folder.

use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, Value, ValueType, path_value,
};

/// The value as JSON: `{"type": "Scalar", "value": ...}`, numbers in their
/// documented units; non-finite numbers become `null`.
pub fn value_to_json(value: &Value) -> serde_json::Value {
    serde_json::to_value(value).unwrap_or(serde_json::Value::Null)
}

/// Types small enough to be worth writing as JSON.
const SMALL_TYPES: &[ValueType] = &[
    ValueType::Scalar,
    ValueType::Table,
    ValueType::Transform,
    ValueType::Markers,
    ValueType::Camera,
    ValueType::StereoRig,
    ValueType::Rectification,
    ValueType::Path,
];

pub(crate) struct WriteJsonOp(OpSpec);

impl WriteJsonOp {
    pub(crate) fn new() -> Self {
        WriteJsonOp(
            OpSpec::new(
                "io.write_json",
                1,
                "Write a small value as JSON under the output folder",
            )
            .input("value", SMALL_TYPES, "The value to write")
            .param(ParamSpec::string(
                "file",
                "value.json",
                "File name, relative to the output folder",
            ))
            .output("file", ValueType::Path, "The written file")
            .writes_output(),
        )
    }
}

impl Op for WriteJsonOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let value = inputs
            .value("value")
            .ok_or_else(|| OpError::Input("value".into(), "not connected".into()))?;
        let path = ctx.output_path(&params.string("file")?)?;
        let text = serde_json::to_string_pretty(&value_to_json(value)).expect("JSON value");
        std::fs::write(&path, text + "\n").map_err(|e| OpError::io(&path, e))?;
        Ok(Outputs::new().with("file", path_value(&path)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::value::Transform;

    #[test]
    fn json_carries_type_and_units() {
        let j = value_to_json(&Value::from(Transform::identity("mri_lps", "camera_left")));
        assert_eq!(j["type"], "Transform");
        assert_eq!(j["value"]["from"], "mri_lps");
        assert_eq!(j["value"]["matrix"][3][3], 1.0);
        assert_eq!(
            value_to_json(&Value::from(f64::NAN))["value"],
            serde_json::Value::Null
        );
    }
}
