//! `io.write_rig`: a stereo rig as JSON and as an OpenCV FileStorage YAML file.

use crate::io::rig_yaml;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, StereoRig};

/// Write a stereo rig as JSON and OpenCV FileStorage YAML
#[derive(Op)]
#[op(name = "io.write_rig", version = 1, writes_output)]
pub struct WriteRig {
    /// Base name: writes NAME.json and NAME.yml
    #[param(default = "rig")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteRigInputs {
    /// The rig
    pub rig: Arc<StereoRig>,
}

#[derive(Outputs)]
pub struct WriteRigOutputs {
    /// The JSON file
    pub json: PathValue,
    /// The YAML file
    pub yaml: PathValue,
}

impl RunOp for WriteRig {
    type Inputs = WriteRigInputs;
    type Outputs = WriteRigOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (rig, name) = (inputs.rig, &self.file);
        let json = ctx.output_path(&format!("{name}.json"))?;
        let text = serde_json::to_string_pretty(&*rig).expect("plain data");
        std::fs::write(&json, text + "\n").map_err(|e| OpError::io(&json, e))?;
        let yaml = ctx.output_path(&format!("{name}.yml"))?;
        std::fs::write(&yaml, rig_yaml(&rig)).map_err(|e| OpError::io(&yaml, e))?;
        Ok(WriteRigOutputs {
            json: path_value(&json)?,
            yaml: path_value(&yaml)?,
        })
    }
}
