//! Marker files: 3D Slicer markups (`.mrk.json`; written in LPS, read in LPS
//! or RAS) and CSV with `x`, `y`, `z` columns (mm; `x_mm` etc. too, as
//! [`markers_csv`] writes them).

use fusegraph_engine::value::Markers;

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

/// The markers as CSV: a header `id,x_mm,y_mm,z_mm,frame`, then one row per
/// marker, positions in mm of `markers.frame` in full precision.
/// [`parse_points_csv`] reads it back.
///
/// # Examples
///
/// ```
/// use fusegraph_engine::value::Markers;
/// use fusegraph_nodes::io::{markers_csv, parse_points_csv};
///
/// let m = Markers::new(vec![1.0, -2.5, 30.0, 4.0, 5.0, 6.0], vec![7, 9], "mri_lps").unwrap();
/// let csv = markers_csv(&m);
/// assert_eq!(csv.lines().nth(1), Some("7,1,-2.5,30,mri_lps"));
/// let (points, ids) = parse_points_csv(&csv).unwrap();
/// assert_eq!(points, vec![[1.0, -2.5, 30.0], [4.0, 5.0, 6.0]]);
/// assert_eq!(ids, vec![7, 9]);
/// ```
pub fn markers_csv(markers: &Markers) -> String {
    let mut s = String::from("id,x_mm,y_mm,z_mm,frame\n");
    for (p, id) in markers.positions_mm.chunks(3).zip(markers.ids.iter()) {
        s += &format!("{id},{},{},{},{}\n", p[0], p[1], p[2], markers.frame);
    }
    s
}

/// The control points of a Slicer markups file, in LPS mm, with their ids
/// (the order in the file when an id is not a number).
pub fn parse_markups(text: &str) -> Result<(Vec<[f64; 3]>, Vec<u32>), String> {
    let doc: serde_json::Value =
        serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
    let lists = doc["markups"]
        .as_array()
        .ok_or("no `markups` list: not a Slicer markups file")?;
    let (mut points, mut ids) = (Vec::new(), Vec::new());
    for list in lists {
        // Slicer writes LPS since 4.11; older files and some tools write RAS.
        let ras = match list["coordinateSystem"].as_str().unwrap_or("LPS") {
            "LPS" => false,
            "RAS" => true,
            other => return Err(format!("coordinate system {other:?}: expected LPS or RAS")),
        };
        for (i, p) in list["controlPoints"]
            .as_array()
            .into_iter()
            .flatten()
            .enumerate()
        {
            let pos = p["position"]
                .as_array()
                .filter(|a| a.len() == 3)
                .and_then(|a| a.iter().map(|v| v.as_f64()).collect::<Option<Vec<f64>>>())
                .ok_or_else(|| format!("control point {i}: `position` must be 3 numbers"))?;
            let [x, y, z] = [pos[0], pos[1], pos[2]];
            points.push(if ras { [-x, -y, z] } else { [x, y, z] });
            let id = p["id"].as_str().and_then(|s| s.parse::<u32>().ok());
            ids.push(id.unwrap_or(ids.len() as u32));
        }
    }
    if points.is_empty() {
        return Err("no control points".into());
    }
    Ok((points, ids))
}

/// The points of a CSV with a header naming `x`, `y`, `z` (or `x_mm` ...)
/// columns and optionally `id`; `#` lines are comments.
pub fn parse_points_csv(text: &str) -> Result<(Vec<[f64; 3]>, Vec<u32>), String> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (_, header) = lines.next().ok_or("empty file")?;
    let names: Vec<String> = header.split(',').map(|c| c.trim().to_lowercase()).collect();
    let column = |axis: &str| {
        names
            .iter()
            .position(|n| n == axis || *n == format!("{axis}_mm"))
            .ok_or_else(|| format!("no `{axis}` column in the header {header:?}"))
    };
    let (cx, cy, cz) = (column("x")?, column("y")?, column("z")?);
    let cid = names.iter().position(|n| n == "id");
    let (mut points, mut ids) = (Vec::new(), Vec::new());
    for (n, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let num = |c: usize| {
            cells
                .get(c)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("line {}: column {} is not a number", n + 1, c + 1))
        };
        points.push([num(cx)?, num(cy)?, num(cz)?]);
        let id = cid
            .and_then(|c| cells.get(c))
            .and_then(|v| v.parse::<u32>().ok());
        ids.push(id.unwrap_or(ids.len() as u32));
    }
    if points.is_empty() {
        return Err("no points under the header".into());
    }
    Ok((points, ids))
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

    #[test]
    fn what_write_markers_writes_reads_back() {
        let m = Markers::new(vec![1.0, -2.5, 30.0, 4.0, 5.0, 6.0], vec![7, 9], "mri_lps").unwrap();
        let (p, ids) = parse_markups(&slicer_markups(&m, "t").to_string()).unwrap();
        assert_eq!(
            (p, ids.clone()),
            (vec![[1.0, -2.5, 30.0], [4.0, 5.0, 6.0]], vec![7, 9])
        );
        let (p, ids2) = parse_points_csv(&markers_csv(&m)).unwrap();
        assert_eq!(p[0], [1.0, -2.5, 30.0]);
        assert_eq!(ids2, ids);
    }

    #[test]
    fn ras_files_turn_into_lps_and_bad_files_say_why() {
        let ras = r#"{"markups":[{"coordinateSystem":"RAS","controlPoints":[{"id":"a","position":[1,2,3]}]}]}"#;
        assert_eq!(
            parse_markups(ras).unwrap(),
            (vec![[-1.0, -2.0, 3.0]], vec![0])
        );
        assert!(parse_markups("{}").unwrap_err().contains("markups"));
        assert!(parse_markups("nope").unwrap_err().contains("not JSON"));
        let bad = r#"{"markups":[{"controlPoints":[{"position":[1,2]}]}]}"#;
        assert!(parse_markups(bad).unwrap_err().contains("3 numbers"));
        assert!(
            parse_points_csv("a,b\n1,2\n")
                .unwrap_err()
                .contains("no `x` column")
        );
        assert!(
            parse_points_csv("x,y,z\n1,oops,3\n")
                .unwrap_err()
                .contains("line 2")
        );
        assert_eq!(
            parse_points_csv("# targets\nX,Y,Z\n1,2,3\n").unwrap(),
            (vec![[1.0, 2.0, 3.0]], vec![0])
        );
    }
}
