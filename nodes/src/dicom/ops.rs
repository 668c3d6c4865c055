//! Node adapter: `dicom.load_series`.

use super::series::load_series;
use fusegraph_engine::value::{PathValue, Volume};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};
use std::sync::Arc;

pub(crate) struct LoadSeriesOp(OpSpec);

impl LoadSeriesOp {
    pub(crate) fn new() -> Self {
        LoadSeriesOp(
            OpSpec::new(
                "dicom.load_series",
                3,
                "Read a DICOM series (a folder of slices, or one multi-frame file) as a volume in patient LPS mm",
            )
            .optional_input("dir", &[ValueType::Path], "Folder or file from another node (instead of `path`)")
            .param(ParamSpec::optional_path("path", "Folder of slices or a multi-frame file, relative to the graph"))
            .param(ParamSpec::string("series_uid", "", "SeriesInstanceUID to read when the folder holds several"))
            .output("volume", ValueType::Volume, "Rescaled voxels; voxel (column, row, slice) -> patient LPS mm"),
        )
    }
}

impl Op for LoadSeriesOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let from_input: Option<Arc<PathValue>> = inputs.optional("dir")?;
        let path = match (params.optional_path("path")?, from_input) {
            (Some(p), None) => p,
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
        let uid = params.string("series_uid")?;
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
        Ok(Outputs::new().with("volume", volume))
    }
}
