//! `dicom.load_series`: a DICOM series as a volume.

use crate::dicom::load_series;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, Volume};
use std::path::PathBuf;

/// Read a DICOM series (a folder of slices, or one multi-frame file) as a
/// volume in patient LPS mm
#[derive(Op)]
#[op(name = "dicom.load_series", version = 3)]
pub struct LoadSeries {
    /// Folder of slices or a multi-frame file, relative to the graph
    pub path: Option<PathBuf>,
    /// SeriesInstanceUID to read when the folder holds several
    #[param(default = "")]
    pub series_uid: String,
}

#[derive(Inputs)]
pub struct LoadSeriesInputs {
    /// Folder or file from another node (instead of `path`)
    pub dir: Option<Arc<PathValue>>,
}

#[derive(Outputs)]
pub struct LoadSeriesOutputs {
    /// Rescaled voxels; voxel (column, row, slice) -> patient LPS mm
    pub volume: Volume,
}

impl RunOp for LoadSeries {
    type Inputs = LoadSeriesInputs;
    type Outputs = LoadSeriesOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let path = match (&self.path, inputs.dir) {
            (Some(p), None) => p.clone(),
            (None, Some(dir)) => dir.path.clone(),
            (Some(_), Some(_)) => {
                return Err(OpError::invalid(
                    "give either the `path` parameter or the `dir` input, not both",
                ));
            }
            (None, None) => {
                return Err(OpError::invalid(
                    "give the `path` parameter or connect the `dir` input",
                ));
            }
        };
        let uid = &self.series_uid;
        let series = load_series(&path, (!uid.is_empty()).then_some(uid.as_str()))
            .map_err(|e| OpError::invalid(e.to_string()))?;
        for w in &series.warnings {
            ctx.note(w.clone());
        }
        let spacing = series.grid.spacing_mm();
        ctx.metric("files", series.files as f64);
        ctx.metric("slices", series.grid.dims[2] as f64);
        ctx.metric("spacing_x_mm", spacing[0]);
        ctx.metric("spacing_y_mm", spacing[1]);
        ctx.metric("spacing_z_mm", spacing[2]);
        let volume = Volume::new(series.grid, series.voxels).map_err(|e| OpError::invalid(e.0))?;
        Ok(LoadSeriesOutputs { volume })
    }
}
