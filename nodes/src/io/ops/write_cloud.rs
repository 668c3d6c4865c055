//! `io.write_cloud`: one or two point clouds as one coloured binary PLY.

use crate::io::write_ply;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, PointCloud};

/// Write one or two point clouds (same frame) as one coloured binary PLY
#[derive(Op)]
#[op(name = "io.write_cloud", version = 1, writes_output)]
pub struct WriteCloud {
    /// RGB of the first cloud (if it has no colours)
    #[param(default = [230, 120, 60], min = 0, max = 255)]
    pub color: [i64; 3],
    /// RGB of the second cloud
    #[param(default = [60, 140, 230], min = 0, max = 255)]
    pub other_color: [i64; 3],
    /// PLY file, relative to the output folder
    #[param(default = "cloud.ply")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteCloudInputs {
    /// First cloud
    pub cloud: Arc<PointCloud>,
    /// Second cloud, coloured apart
    pub other: Option<Arc<PointCloud>>,
}

#[derive(Outputs)]
pub struct WriteCloudOutputs {
    /// The PLY
    pub file: PathValue,
}

impl RunOp for WriteCloud {
    type Inputs = WriteCloudInputs;
    type Outputs = WriteCloudOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (a, b) = (inputs.cloud, inputs.other);
        if let Some(b) = &b
            && b.frame != a.frame
        {
            return Err(OpError::invalid(format!(
                "the clouds are in different frames: `{}` and `{}`",
                a.frame, b.frame
            )));
        }
        // Validation keeps each channel in 0..=255.
        let rgb = |c: [i64; 3]| c.map(|v| v as u8);
        let mut points: Vec<f32> = a.points.to_vec();
        let mut colors: Vec<u8> = match &a.colors {
            Some(c) => c.to_vec(),
            None => rgb(self.color).repeat(a.len()),
        };
        if let Some(b) = &b {
            points.extend_from_slice(&b.points);
            colors.extend(match &b.colors {
                Some(c) => c.to_vec(),
                None => rgb(self.other_color).repeat(b.len()),
            });
        }
        let path = ctx.output_path(&self.file)?;
        write_ply(
            &path,
            &points,
            None,
            Some(&colors),
            &[],
            &format!("fusegraph cloud, mm, frame {}", a.frame),
        )
        .map_err(|e| OpError::io(&path, e))?;
        Ok(WriteCloudOutputs {
            file: path_value(&path)?,
        })
    }
}
