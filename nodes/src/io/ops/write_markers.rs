//! `io.write_markers`: marker centres as a 3D Slicer markups file (`.mrk.json`,
//! LPS) and as CSV.

use crate::io::{markers_csv, slicer_markups};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue};

/// Write markers as a 3D Slicer .mrk.json (LPS) and a CSV
#[derive(Op)]
#[op(name = "io.write_markers", version = 1, writes_output)]
pub struct WriteMarkers {
    /// Base name: writes NAME.mrk.json and NAME.csv
    #[param(default = "markers")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteMarkersInputs {
    /// Marker centres (patient LPS mm for Slicer)
    pub markers: Arc<Markers>,
}

#[derive(Outputs)]
pub struct WriteMarkersOutputs {
    /// The .mrk.json file
    pub markups: PathValue,
    /// The .csv file
    pub csv: PathValue,
}

impl RunOp for WriteMarkers {
    type Inputs = WriteMarkersInputs;
    type Outputs = WriteMarkersOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (markers, name) = (inputs.markers, &self.file);
        if markers.frame != "mri_lps" {
            tracing::warn!(node = %ctx.node_id(), "markers are in frame `{}`; Slicer will read them as LPS", markers.frame);
        }
        let json_path = ctx.output_path(&format!("{name}.mrk.json"))?;
        let text =
            serde_json::to_string_pretty(&slicer_markups(&markers, "M")).expect("JSON value");
        std::fs::write(&json_path, text + "\n").map_err(|e| OpError::io(&json_path, e))?;
        let csv_path = ctx.output_path(&format!("{name}.csv"))?;
        std::fs::write(&csv_path, markers_csv(&markers)).map_err(|e| OpError::io(&csv_path, e))?;
        Ok(WriteMarkersOutputs {
            markups: path_value(&json_path)?,
            csv: path_value(&csv_path)?,
        })
    }
}
