//! `dicom.load_series`: a DICOM series as a volume.

use crate::dicom::{LoadOptions, load_series_with};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{PathValue, Volume};
use std::path::PathBuf;

/// Read a DICOM series (a folder of slices, or one multi-frame file) as a
/// volume in patient LPS mm
#[derive(Op)]
#[op(name = "dicom.load_series", version = 4)]
pub struct LoadSeries {
    /// Folder of slices or a multi-frame file, relative to the graph
    pub path: Option<PathBuf>,
    /// SeriesInstanceUID to read when the folder holds several
    #[param(default = "")]
    pub series_uid: String,
    /// Fail on a DICOM file that cannot be read, instead of skipping it with a note (a skipped slice inside the stack is refused as a gap either way)
    #[param(default = false)]
    pub strict: bool,
}

#[derive(Inputs)]
pub struct LoadSeriesInputs {
    /// Folder or file from another node (instead of `path`)
    pub dir: Option<Arc<PathValue>>,
}

#[derive(Debug, Outputs)]
pub struct LoadSeriesOutputs {
    /// Rescaled voxels; voxel (column, row, slice) -> patient LPS mm
    pub volume: Volume,
}

impl RunOp for LoadSeries {
    type Inputs = LoadSeriesInputs;
    type Outputs = LoadSeriesOutputs;

    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        exactly_one_source(&[("path", self.path.is_some()), ("in.dir", wired.has("dir"))])
            .into_iter()
            .collect()
    }

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
        let options = LoadOptions {
            series_uid: (!uid.is_empty()).then(|| uid.clone()),
            strict: self.strict,
        };
        let series =
            load_series_with(&path, &options).map_err(|e| OpError::invalid(e.to_string()))?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_or_a_dir_but_not_both() {
        let mut ctx = RunCtx::new("load", std::path::Path::new("."));
        let dir = || {
            Some(Arc::new(PathValue {
                path: "/nonexistent".into(),
                content_hash: String::new(),
            }))
        };
        let given = |path: Option<&str>| LoadSeries {
            path: path.map(PathBuf::from),
            series_uid: String::new(),
            strict: false,
        };
        let e = given(None)
            .run(LoadSeriesInputs { dir: None }, &mut ctx)
            .unwrap_err();
        assert!(e.to_string().contains("give the `path` parameter"), "{e}");
        let e = given(Some("/nonexistent"))
            .run(LoadSeriesInputs { dir: dir() }, &mut ctx)
            .unwrap_err();
        assert!(e.to_string().contains("not both"), "{e}");
    }
}
