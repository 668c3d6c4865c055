//! `io.write_markers`: marker centres as a 3D Slicer markups file (`.mrk.json`,
//! LPS) and as CSV.

use crate::io::{MarkerNotes, slicer_markups, write_markers_csv};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, PathValue, Table};
use std::io::{BufWriter, Write};
use std::path::Path;

/// Write markers as a 3D Slicer .mrk.json (LPS) and a CSV
#[derive(Op)]
// 2: optional notes per marker (e.g. each target's predicted error).
#[op(name = "io.write_markers", version = 2, writes_output)]
pub struct WriteMarkers {
    /// Base name: writes NAME.mrk.json and NAME.csv
    #[param(default = "markers")]
    pub file: String,
}

#[derive(Inputs)]
pub struct WriteMarkersInputs {
    /// Marker centres (patient LPS mm for Slicer)
    pub markers: Arc<Markers>,
    /// Figures per marker, by an `id` column (e.g. register.map_targets'
    /// `errors`): extra CSV columns and each markup point's description
    pub notes: Option<Arc<Table>>,
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
        let notes = inputs
            .notes
            .as_deref()
            .map(MarkerNotes::from_table)
            .transpose()
            .map_err(|e| OpError::invalid(format!("notes: {e}")))?;
        if markers.frame != "mri_lps" {
            tracing::warn!(node = %ctx.node_id(), "markers are in frame `{}`; Slicer will read them as LPS", markers.frame);
        }
        let json_path = ctx.output_path(&format!("{name}.mrk.json"))?;
        write_streamed(&json_path, |out| {
            serde_json::to_writer_pretty(
                &mut *out,
                &slicer_markups(&markers, "M", notes.as_ref()),
            )?;
            writeln!(out)
        })?;
        let csv_path = ctx.output_path(&format!("{name}.csv"))?;
        write_streamed(&csv_path, |out| {
            write_markers_csv(&markers, notes.as_ref(), out)
        })?;
        Ok(WriteMarkersOutputs {
            markups: path_value(&json_path)?,
            csv: path_value(&csv_path)?,
        })
    }
}

/// Writes `path` through a buffer, so memory stays flat however many markers.
fn write_streamed(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<(), OpError> {
    let file = std::fs::File::create(path).map_err(|e| OpError::io(path, e))?;
    let mut out = BufWriter::new(file);
    write(&mut out)
        .and_then(|()| out.flush())
        .map_err(|e| OpError::io(path, e))
}
