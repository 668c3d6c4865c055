//! `io.write_volume`: a volume or mask with its voxel -> patient affine as
//! NRRD or NIfTI-1, by the file's extension.

use crate::io::deshear::{MAX_IGNORED_SHEAR_DEG, bilinear, deshear, grid_shear, nearest};
use crate::io::volumes::{VolumeFormat, volume_format};
use crate::io::{Voxels, write_nifti, write_nrrd};
use fusegraph_engine::Value;
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Grid;
use fusegraph_engine::value::PathValue;

/// Write a volume or mask with its voxel -> patient affine as NRRD (LPS) or NIfTI-1 (RAS), by extension, under the output folder
#[derive(Op)]
#[op(name = "io.write_volume", version = 2, writes_output)]
pub struct WriteVolume {
    /// File name (.nrrd, .nii or .nii.gz), relative to the output folder
    #[param(default = "volume.nrrd")]
    pub file: String,
    /// NRRD data encoding (NIfTI: the extension decides, .nii.gz is gzipped)
    #[param(default = NrrdEncoding::Gzip)]
    pub encoding: NrrdEncoding,
    /// NIfTI of a sheared grid (gantry tilt): resample onto an orthogonal grid, as dcm2niix does (ITK reads no sheared NIfTI); refuse; or write the exact sheared sform (NRRD always keeps the exact grid)
    #[param(default = ShearedNifti::Resample)]
    pub sheared_nifti: ShearedNifti,
}

/// What a NIfTI file gets of a sheared (gantry-tilted) voxel grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum ShearedNifti {
    /// Slices shifted in-plane onto an orthogonal grid, with a note.
    Resample,
    /// An error naming the shear; write NRRD instead.
    Refuse,
    /// The sheared affine as an sform, qform_code 0 (exact, but ITK refuses it).
    Exact,
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
            VolumeFormat::Nifti { gzip } => match self.nifti_grid(grid, voxels, file, ctx)? {
                Some((grid, Resampled::F32(v))) => write_nifti(&path, &grid, Voxels::F32(&v), gzip),
                Some((grid, Resampled::U8(v))) => write_nifti(&path, &grid, Voxels::U8(&v), gzip),
                None => write_nifti(&path, grid, voxels, gzip),
            },
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

/// Voxels resampled off a sheared grid.
enum Resampled {
    F32(Vec<f32>),
    U8(Vec<u8>),
}

impl WriteVolume {
    /// The grid and voxels a NIfTI file gets: `None` to write them as they
    /// are, or resampled ones for a sheared grid (see [`ShearedNifti`]).
    fn nifti_grid(
        &self,
        grid: &Grid,
        voxels: Voxels,
        file: &str,
        ctx: &mut RunCtx,
    ) -> Result<Option<(Grid, Resampled)>, OpError> {
        if self.sheared_nifti == ShearedNifti::Exact {
            return Ok(None);
        }
        let shear = grid_shear(grid).map_err(|e| OpError::invalid(format!("{file}: {e}")))?;
        if shear.angle_deg <= MAX_IGNORED_SHEAR_DEG {
            return Ok(None);
        }
        let depth = grid.dims[2].saturating_sub(1) as f64;
        if self.sheared_nifti == ShearedNifti::Refuse {
            return Err(OpError::invalid(format!(
                "{file}: the voxel grid is sheared by {:.3} deg (gantry tilt, or slices offset in-plane), \
                 which ITK-based readers refuse in NIfTI; write .nrrd for the exact grid, or set \
                 sheared_nifti = \"resample\"",
                shear.angle_deg
            )));
        }
        ctx.note(format!(
            "{file}: the voxel grid is sheared by {:.3} deg: resampled onto an orthogonal grid \
             (slices shifted in-plane by up to {:.2} mm, voxels from outside the field of view set to 0) \
             so ITK can read it; write .nrrd for the exact grid",
            shear.angle_deg,
            shear.shift_per_slice_mm * depth
        ));
        let (grid, values) = match voxels {
            Voxels::F32(v) => {
                let (g, out) = deshear(grid, v, &shear, 0.0, bilinear);
                (g, Resampled::F32(out))
            }
            Voxels::U8(v) => {
                let (g, out) = deshear(grid, v, &shear, 0, nearest);
                (g, Resampled::U8(out))
            }
        };
        Ok(Some((grid, values)))
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
                sheared_nifti: ShearedNifti::Resample,
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
            sheared_nifti: ShearedNifti::Resample,
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

    #[test]
    fn a_sheared_grid_is_resampled_refused_or_kept_for_nifti() {
        let t = tempfile::tempdir().unwrap();
        let mut grid = Grid::axis_aligned([4, 3, 5], [0.5, 0.5, 2.0], [10.0, 20.0, 30.0]);
        grid.voxel_to_patient[0][2] = 1.0; // 1 mm sideways per 2 mm slice
        let volume = Value::from(
            fusegraph_engine::value::Volume::new(grid.clone(), vec![1.0; grid.len()]).unwrap(),
        );
        let run = |file: &str, sheared_nifti: ShearedNifti| {
            let op = WriteVolume {
                file: file.into(),
                encoding: NrrdEncoding::Raw,
                sheared_nifti,
            };
            let mut ctx = RunCtx::new("write", t.path());
            let out = op.run(
                WriteVolumeInputs {
                    volume: volume.clone(),
                },
                &mut ctx,
            );
            (out.map(|o| o.file.path.clone()), ctx)
        };
        let (path, ctx) = run("r.nii", ShearedNifti::Resample);
        let back = read_nifti(&path.unwrap()).unwrap();
        assert!(
            back.qform_voxel_to_patient.is_some(),
            "an orthogonal grid gets a qform"
        );
        assert_eq!(back.grid.voxel_to_patient[0][2], 0.0);
        let notes = ctx.notes().join("\n");
        assert!(
            notes.contains("sheared by 26.565 deg") && notes.contains("4.00 mm"),
            "{notes}"
        );
        let (err, _) = run("x.nii", ShearedNifti::Refuse);
        let err = err.unwrap_err().to_string();
        assert!(
            err.contains("sheared by 26.565 deg") && err.contains(".nrrd"),
            "{err}"
        );
        let (path, _) = run("e.nii", ShearedNifti::Exact);
        let back = read_nifti(&path.unwrap()).unwrap();
        assert!(back.qform_voxel_to_patient.is_none());
        assert!((back.grid.voxel_to_patient[0][2] - 1.0).abs() < 1e-6);
        // NRRD keeps the exact grid whatever the NIfTI choice.
        let (path, ctx) = run("n.nrrd", ShearedNifti::Refuse);
        let (back, _) = read_nrrd(&path.unwrap()).unwrap();
        assert_eq!(back, grid);
        assert!(ctx.notes().is_empty());
    }
}
