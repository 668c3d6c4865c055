//! `io.write_markers`: marker centres as a 3D Slicer markups file (`.mrk.json`,
//! LPS) and as CSV.

use fusegraph_engine::value::Markers;
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType, path_value,
};

/// A Slicer markups fiducial list: every control point `defined`, positions in
/// LPS mm (Slicer converts to its RAS display itself).
pub fn slicer_markups(markers: &Markers, name: &str) -> serde_json::Value {
    let points: Vec<serde_json::Value> = markers
        .positions_mm
        .chunks(3)
        .zip(markers.ids.iter())
        .map(|(p, id)| {
            serde_json::json!({
                "id": id.to_string(),
                "label": format!("{name}-{id}"),
                "position": [p[0], p[1], p[2]],
                "positionStatus": "defined",
                "selected": true,
                "locked": false,
                "visibility": true,
            })
        })
        .collect();
    serde_json::json!({
        "@schema": "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#",
        "markups": [{
            "type": "Fiducial",
            "coordinateSystem": "LPS",
            "coordinateUnits": "mm",
            "locked": false,
            "labelFormat": "%N-%d",
            "controlPoints": points,
        }]
    })
}

/// The markers as CSV: `id,x_mm,y_mm,z_mm,frame`.
pub fn markers_csv(markers: &Markers) -> String {
    let mut s = String::from("id,x_mm,y_mm,z_mm,frame\n");
    for (p, id) in markers.positions_mm.chunks(3).zip(markers.ids.iter()) {
        s += &format!("{id},{},{},{},{}\n", p[0], p[1], p[2], markers.frame);
    }
    s
}

pub(crate) struct WriteMarkersOp(OpSpec);

impl WriteMarkersOp {
    pub(crate) fn new() -> Self {
        WriteMarkersOp(
            OpSpec::new(
                "io.write_markers",
                1,
                "Write markers as a 3D Slicer .mrk.json (LPS) and a CSV",
            )
            .input(
                "markers",
                &[ValueType::Markers],
                "Marker centres (patient LPS mm for Slicer)",
            )
            .param(ParamSpec::string(
                "file",
                "markers",
                "Base name: writes NAME.mrk.json and NAME.csv",
            ))
            .output("markups", ValueType::Path, "The .mrk.json file")
            .output("csv", ValueType::Path, "The .csv file")
            .writes_output(),
        )
    }
}

impl Op for WriteMarkersOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let markers = inputs.get::<Markers>("markers")?;
        let name = params.string("file")?;
        if markers.frame != "mri_lps" {
            tracing::warn!(node = %ctx.node_id(), "markers are in frame `{}`; Slicer will read them as LPS", markers.frame);
        }
        let json_path = ctx.output_path(&format!("{name}.mrk.json"))?;
        let text =
            serde_json::to_string_pretty(&slicer_markups(&markers, "M")).expect("JSON value");
        std::fs::write(&json_path, text + "\n").map_err(|e| OpError::io(&json_path, e))?;
        let csv_path = ctx.output_path(&format!("{name}.csv"))?;
        std::fs::write(&csv_path, markers_csv(&markers)).map_err(|e| OpError::io(&csv_path, e))?;
        Ok(Outputs::new()
            .with("markups", path_value(&json_path)?)
            .with("csv", path_value(&csv_path)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markups_are_lps_and_defined() {
        let m = Markers::new(vec![1.0, -2.0, 3.5, 4.0, 5.0, 6.0], vec![1, 2], "mri_lps").unwrap();
        let j = slicer_markups(&m, "M");
        let mk = &j["markups"][0];
        assert_eq!(mk["coordinateSystem"], "LPS");
        assert_eq!(mk["controlPoints"].as_array().unwrap().len(), 2);
        assert_eq!(mk["controlPoints"][0]["position"][1], -2.0);
        assert_eq!(mk["controlPoints"][1]["positionStatus"], "defined");
        assert_eq!(markers_csv(&m).lines().nth(1), Some("1,1,-2,3.5,mri_lps"));
    }
}
