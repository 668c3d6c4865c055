//! Values as JSON (what `io.write_json` writes for a number, table,
//! transform, markers, camera or rig).

use fusegraph_engine::Value;

/// The value as JSON: `{"type": "Scalar", "value": ...}`, numbers in their
/// documented units; non-finite numbers become `null`.
pub fn value_to_json(value: &Value) -> serde_json::Value {
    serde_json::to_value(value).unwrap_or(serde_json::Value::Null)
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
