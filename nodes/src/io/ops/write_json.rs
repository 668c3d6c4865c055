//! `io.write_json`: a small value (a number, table, transform, markers,
//! camera, rig) as JSON under the output folder.

use crate::io::value_to_json;
use fusegraph_engine::Value;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PathValue;

/// Write a small value as JSON under the output folder
#[derive(Op)]
#[op(name = "io.write_json", version = 1, writes_output)]
pub struct WriteJson {
    /// File name, relative to the output folder
    #[param(default = "value.json")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteJsonInputs {
    /// The value to write
    #[input(types(
        Scalar,
        Table,
        Transform,
        Markers,
        Camera,
        StereoRig,
        Rectification,
        Path
    ))]
    pub value: Value,
}

#[derive(Outputs)]
pub struct WriteJsonOutputs {
    /// The written file
    pub file: PathValue,
}

impl RunOp for WriteJson {
    type Inputs = WriteJsonInputs;
    type Outputs = WriteJsonOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let path = ctx.output_path(&self.file)?;
        let text = serde_json::to_string_pretty(&value_to_json(&inputs.value)).expect("JSON value");
        std::fs::write(&path, text + "\n").map_err(|e| OpError::io(&path, e))?;
        Ok(WriteJsonOutputs {
            file: path_value(&path)?,
        })
    }
}
