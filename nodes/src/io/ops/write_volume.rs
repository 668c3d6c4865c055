//! `io.write_volume`: a volume or mask with its voxel -> patient affine as
//! NRRD or NIfTI-1, by the file's extension.

use crate::io::volumes::{VolumeFormat, volume_format};
use crate::io::{Voxels, write_nifti, write_nrrd};
use fusegraph_engine::Value;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PathValue;

/// Write a volume or mask with its voxel -> patient affine as NRRD (LPS) or NIfTI-1 (RAS), by extension, under the output folder
#[derive(Op)]
#[op(name = "io.write_volume", version = 1, writes_output)]
pub struct WriteVolume {
    /// File name (.nrrd, .nii or .nii.gz), relative to the output folder
    #[param(default = "volume.nrrd")]
    pub file: String,
    /// NRRD data encoding (NIfTI: the extension decides, .nii.gz is gzipped)
    #[param(default = NrrdEncoding::Gzip)]
    pub encoding: NrrdEncoding,
}

/// How a NRRD file stores its voxel data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum NrrdEncoding {
    /// gzip-compressed (level 1).
    Gzip,
    /// As they are.
    Raw,
}

#[derive(Inputs)]
pub struct WriteVolumeInputs {
    /// Volume (written as float32) or mask (uint8)
    #[input(types(Volume, Mask))]
    pub volume: Value,
}

#[derive(Outputs)]
pub struct WriteVolumeOutputs {
    /// The written file
    pub file: PathValue,
}

impl RunOp for WriteVolume {
    type Inputs = WriteVolumeInputs;
    type Outputs = WriteVolumeOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let file = &self.file;
        let format = volume_format(file).ok_or_else(|| {
            OpError::invalid(format!(
                "file {file:?}: use a .nrrd, .nii or .nii.gz extension"
            ))
        })?;
        let (grid, voxels) = match &inputs.volume {
            Value::Volume(v) => (&v.grid, Voxels::F32(&v.data)),
            Value::Mask(m) => (&m.grid, Voxels::U8(&m.data)),
            _ => {
                return Err(OpError::Input(
                    "volume".into(),
                    "expected a Volume or a Mask".into(),
                ));
            }
        };
        let path = ctx.output_path(file)?;
        match format {
            VolumeFormat::Nrrd => {
                write_nrrd(&path, grid, voxels, self.encoding == NrrdEncoding::Gzip)
            }
            VolumeFormat::Nifti { gzip } => write_nifti(&path, grid, voxels, gzip),
        }
        .map_err(|e| OpError::io(&path, e))?;
        let bytes = std::fs::metadata(&path)
            .map_err(|e| OpError::io(&path, e))?
            .len();
        ctx.metric("bytes", bytes as f64);
        Ok(WriteVolumeOutputs {
            file: path_value(&path)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::{VoxelBuf, read_nifti, read_nrrd};
    use fusegraph_engine::value::{Grid, Mask};
    use std::io::Read;

    #[test]
    fn masks_are_uint8_and_the_op_picks_the_format_by_extension() {
        let t = tempfile::tempdir().unwrap();
        let grid = Grid::axis_aligned([5, 4, 3], [0.7, 1.3, 2.9], [-83.9063, 112.25, -40.125]);
        let bits: Vec<u8> = (0..grid.len()).map(|i| (i % 3 == 0) as u8).collect();
        let mask = Value::from(Mask::new(grid.clone(), bits.clone()).unwrap());
        let run = |file: &str, encoding: NrrdEncoding| {
            let op = WriteVolume {
                file: file.into(),
                encoding,
            };
            let inputs = WriteVolumeInputs {
                volume: mask.clone(),
            };
            let mut ctx = RunCtx::new("write", t.path());
            op.run(inputs, &mut ctx).map(|out| out.file.path.clone())
        };
        let path = run("m/mask.nrrd", NrrdEncoding::Raw).unwrap();
        assert_eq!(path, t.path().join("m/mask.nrrd"));
        let (back, data) = read_nrrd(&path).unwrap();
        assert_eq!((back, data), (grid.clone(), VoxelBuf::U8(bits.clone())));
        let back = read_nifti(&run("mask.nii.gz", NrrdEncoding::Gzip).unwrap()).unwrap();
        assert_eq!(back.voxels, VoxelBuf::U8(bits));
        let gz = std::fs::read(t.path().join("mask.nii.gz")).unwrap();
        let mut raw = Vec::new();
        flate2::read::GzDecoder::new(&gz[..])
            .read_to_end(&mut raw)
            .unwrap();
        assert_eq!(i16::from_le_bytes([raw[70], raw[71]]), 2, "DT_UINT8");
        let err = run("mask.mha", NrrdEncoding::Gzip).unwrap_err().to_string();
        assert!(err.contains(".nrrd, .nii or .nii.gz"), "{err}");
        let err = WriteVolume {
            file: "v.nrrd".into(),
            encoding: NrrdEncoding::Raw,
        }
        .run(
            WriteVolumeInputs {
                volume: Value::from(1.0),
            },
            &mut RunCtx::new("write", t.path()),
        )
        .map(|_| ())
        .unwrap_err()
        .to_string();
        assert!(err.contains("expected a Volume or a Mask"), "{err}");
    }
}
