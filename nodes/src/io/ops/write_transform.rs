//! `io.write_transform`: a transform as 4x4 JSON and as an ITK transform file
//! (for 3D Slicer).

use crate::io::itk_transform_text;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, Transform};

/// Write a transform as 4x4 JSON and as an ITK .tfm (for 3D Slicer)
#[derive(Op)]
#[op(name = "io.write_transform", version = 1, writes_output)]
pub struct WriteTransform {
    /// Base name: writes NAME.json and NAME.tfm
    #[param(default = "transform")]
    pub file: String,
    /// Write the inverse (to -> from), e.g. MRI -> camera from an ICP that ran camera -> MRI
    #[param(default = false)]
    pub invert: bool,
}

#[derive(Inputs)]
pub struct WriteTransformInputs {
    /// The transform (from -> to)
    pub transform: Arc<Transform>,
}

#[derive(Outputs)]
pub struct WriteTransformOutputs {
    /// The JSON file
    pub json: PathValue,
    /// The ITK file (inverse matrix: fixed -> moving)
    pub itk: PathValue,
}

impl RunOp for WriteTransform {
    type Inputs = WriteTransformInputs;
    type Outputs = WriteTransformOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let given = inputs.transform;
        let t = if self.invert {
            let m = nalgebra::Matrix4::from_fn(|r, c| given.matrix[r][c])
                .try_inverse()
                .ok_or_else(|| OpError::invalid("the transform is singular"))?;
            Arc::new(Transform {
                matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])),
                from: given.to.clone(),
                to: given.from.clone(),
            })
        } else {
            given
        };
        let name = &self.file;
        let json = ctx.output_path(&format!("{name}.json"))?;
        std::fs::write(
            &json,
            serde_json::to_string_pretty(&*t).expect("plain data") + "\n",
        )
        .map_err(|e| OpError::io(&json, e))?;
        let itk = ctx.output_path(&format!("{name}.tfm"))?;
        let text = itk_transform_text(&t.matrix)
            .ok_or_else(|| OpError::invalid("the transform is singular"))?;
        std::fs::write(&itk, text).map_err(|e| OpError::io(&itk, e))?;
        Ok(WriteTransformOutputs {
            json: path_value(&json)?,
            itk: path_value(&itk)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::read_itk_transform;

    #[test]
    fn invert_swaps_the_frames_and_the_itk_file_holds_the_given_matrix() {
        let t = tempfile::tempdir().unwrap();
        let mut moved = Transform::identity("camera_left", "mri_lps");
        moved.matrix[0][3] = 12.5;
        moved.matrix[2][3] = -40.0;
        let op = WriteTransform {
            file: "mri_to_camera".into(),
            invert: true,
        };
        let mut ctx = RunCtx::new("write", t.path());
        let inputs = WriteTransformInputs {
            transform: Arc::new(moved.clone()),
        };
        let out = op.run(inputs, &mut ctx).unwrap();
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out.json.path).unwrap()).unwrap();
        assert_eq!(
            (json["from"].as_str(), json["to"].as_str()),
            (Some("mri_lps"), Some("camera_left"))
        );
        assert_eq!(json["matrix"][0][3], -12.5);
        // ITK stores the inverse of what it is given: here the given transform.
        let itk = read_itk_transform(&std::fs::read_to_string(&out.itk.path).unwrap()).unwrap();
        assert_eq!(itk, moved.matrix);
    }
}
