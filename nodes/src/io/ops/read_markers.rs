//! `io.read_markers`: points a user marked (targets in MRI, say) from a 3D
//! Slicer markups file or a CSV.

use crate::io::{ReadPoints, SourceDir, SourceFile, parse_points_csv, read_markups};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::Markers;

/// Read marked points (e.g. targets in MRI) from a 3D Slicer .mrk.json or a CSV with x, y, z columns (mm)
#[derive(Op)]
// 3: the markups file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "io.read_markers", version = 3)]
pub struct ReadMarkers {
    /// Which file: `file` in the `dir` input, or `path`.
    #[param(flatten)]
    pub source: SourceFile,
    /// Frame the points are in (a Slicer file's RAS points are turned into LPS)
    #[param(default = "mri_lps")]
    pub frame: String,
}

#[derive(Outputs)]
pub struct ReadMarkersOutputs {
    /// The points, mm, in `frame`
    pub markers: Markers,
}

impl RunOp for ReadMarkers {
    type Inputs = SourceDir;
    type Outputs = ReadMarkersOutputs;

    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        self.source.check(wired)
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let path = self.source.resolve(inputs.dir.as_deref())?;
        let parsed = if path.to_string_lossy().ends_with(".json") {
            let file = std::fs::File::open(&path).map_err(|e| OpError::io(&path, e))?;
            read_markups(file)
        } else {
            let text = std::fs::read_to_string(&path).map_err(|e| OpError::io(&path, e))?;
            parse_points_csv(&text)
        };
        let ReadPoints { points, ids, notes } =
            parsed.map_err(|e| OpError::invalid(format!("{}: {e}", path.display())))?;
        for note in notes {
            ctx.note(format!("{}: {note}", path.display()));
        }
        ctx.metric("points", points.len() as f64);
        let markers = Markers::new(
            points.iter().flatten().copied().collect::<Vec<f64>>(),
            ids,
            &self.frame,
        )
        .map_err(|e| OpError::invalid(e.0))?;
        Ok(ReadMarkersOutputs { markers })
    }
}
