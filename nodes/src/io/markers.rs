//! Marker files: 3D Slicer markups (`.mrk.json`; written in LPS, read in LPS
//! or RAS) and CSV with `x`, `y`, `z` columns (mm; `x_mm` etc. too, as
//! [`markers_csv`] writes them).

use fusegraph_engine::value::{Markers, Table};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::io::{Read, Write};

/// Figures attached to markers by id (e.g. each target's predicted error):
/// extra CSV columns and, in a markups file, each control point's
/// description.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MarkerNotes {
    /// Column names (units in them), without `id`.
    pub columns: Vec<String>,
    /// The values of each marker that has them, by id.
    pub rows: HashMap<u32, Vec<f64>>,
}

impl MarkerNotes {
    /// From a table with an `id` column (whole numbers); the others become
    /// the notes' columns.
    pub fn from_table(table: &Table) -> Result<Self, String> {
        let id_column = table
            .columns
            .iter()
            .position(|c| c == "id")
            .ok_or("the table has no `id` column")?;
        let width = table.columns.len();
        let mut rows = HashMap::new();
        for row in table.data.chunks(width) {
            let id = row[id_column];
            if id < 0.0 || id.fract() != 0.0 || id > u32::MAX as f64 {
                return Err(format!("`id` {id} is not a marker id"));
            }
            let values = row
                .iter()
                .enumerate()
                .filter(|&(k, _)| k != id_column)
                .map(|(_, v)| *v)
                .collect();
            rows.insert(id as u32, values);
        }
        let columns = table
            .columns
            .iter()
            .enumerate()
            .filter(|&(k, _)| k != id_column)
            .map(|(_, c)| c.clone())
            .collect();
        Ok(MarkerNotes { columns, rows })
    }

    /// `name=value; ...` for marker `id`, empty without a row.
    fn description(&self, id: u32) -> String {
        self.rows.get(&id).map_or_else(String::new, |values| {
            self.columns
                .iter()
                .zip(values)
                .map(|(c, v)| format!("{c}={v:.4}"))
                .collect::<Vec<_>>()
                .join("; ")
        })
    }
}

const MARKUPS_SCHEMA: &str = "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#";

/// A Slicer markups file as [`slicer_markups`] writes it: serialised point by
/// point, so writing a million markers holds no copy of them.
#[derive(Serialize)]
pub struct SlicerMarkups<'a> {
    #[serde(rename = "@schema")]
    schema: &'static str,
    markups: [MarkupList<'a>; 1],
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct MarkupList<'a> {
    #[serde(rename = "type")]
    kind: &'static str,
    coordinate_system: &'static str,
    coordinate_units: &'static str,
    locked: bool,
    label_format: &'static str,
    control_points: ControlPoints<'a>,
}

struct ControlPoints<'a> {
    markers: &'a Markers,
    name: &'a str,
    notes: Option<&'a MarkerNotes>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct ControlPointOut {
    id: String,
    label: String,
    #[serde(skip_serializing_if = "String::is_empty")]
    description: String,
    position: [f64; 3],
    position_status: &'static str,
    selected: bool,
    locked: bool,
    visibility: bool,
}

impl Serialize for ControlPoints<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(
            self.markers
                .positions_mm
                .chunks(3)
                .zip(self.markers.ids.iter())
                .map(|(p, id)| ControlPointOut {
                    id: id.to_string(),
                    label: format!("{}-{id}", self.name),
                    description: self.notes.map_or_else(String::new, |n| n.description(*id)),
                    position: [p[0], p[1], p[2]],
                    position_status: "defined",
                    selected: true,
                    locked: false,
                    visibility: true,
                }),
        )
    }
}

/// A Slicer markups fiducial list: every control point `defined`, positions in
/// LPS mm (Slicer converts to its RAS display itself), labelled `name-id`.
/// Serialise it with `serde_json` (to a writer, for large sets). With
/// `notes`, each point's description lists its notes.
pub fn slicer_markups<'a>(
    markers: &'a Markers,
    name: &'a str,
    notes: Option<&'a MarkerNotes>,
) -> SlicerMarkups<'a> {
    SlicerMarkups {
        schema: MARKUPS_SCHEMA,
        markups: [MarkupList {
            kind: "Fiducial",
            coordinate_system: "LPS",
            coordinate_units: "mm",
            locked: false,
            label_format: "%N-%d",
            control_points: ControlPoints {
                markers,
                name,
                notes,
            },
        }],
    }
}

/// Writes the markers as CSV (see [`markers_csv`]) to `out`, row by row;
/// with `notes`, their columns after `frame` (empty for a marker without).
pub fn write_markers_csv(
    markers: &Markers,
    notes: Option<&MarkerNotes>,
    out: &mut impl Write,
) -> std::io::Result<()> {
    write!(out, "id,x_mm,y_mm,z_mm,frame")?;
    let extra = notes.map_or(0, |n| n.columns.len());
    for c in notes.iter().flat_map(|n| &n.columns) {
        write!(out, ",{c}")?;
    }
    writeln!(out)?;
    for (p, id) in markers.positions_mm.chunks(3).zip(markers.ids.iter()) {
        write!(out, "{id},{},{},{},{}", p[0], p[1], p[2], markers.frame)?;
        match notes.and_then(|n| n.rows.get(id)) {
            Some(values) => values.iter().try_for_each(|v| write!(out, ",{v}"))?,
            None => (0..extra).try_for_each(|_| write!(out, ","))?,
        }
        writeln!(out)?;
    }
    Ok(())
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
/// let read = parse_points_csv(&csv).unwrap();
/// assert_eq!(read.points, vec![[1.0, -2.5, 30.0], [4.0, 5.0, 6.0]]);
/// assert_eq!(read.ids, vec![7, 9]);
/// ```
pub fn markers_csv(markers: &Markers) -> String {
    let mut out = Vec::new();
    write_markers_csv(markers, None, &mut out).expect("writing to memory");
    String::from_utf8(out).expect("ASCII")
}

/// Points read from a file, with what the reader assumed or left out.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadPoints {
    /// Positions, mm (LPS for a Slicer file).
    pub points: Vec<[f64; 3]>,
    /// One id per point.
    pub ids: Vec<u32>,
    /// Assumptions and skipped points, for the user.
    pub notes: Vec<String>,
}

#[derive(Deserialize)]
struct MarkupsIn {
    markups: Option<Vec<MarkupListIn>>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct MarkupListIn {
    coordinate_system: Option<String>,
    coordinate_units: Option<Units>,
    #[serde(default)]
    control_points: Vec<ControlPointIn>,
}

/// Slicer writes `coordinateUnits` as one string, or one per axis.
#[derive(Deserialize)]
#[serde(untagged)]
enum Units {
    One(String),
    PerAxis(Vec<String>),
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct ControlPointIn {
    id: Option<String>,
    label: Option<String>,
    position: Option<Vec<f64>>,
    position_status: Option<String>,
}

/// Millimetres per unit of a Slicer `coordinateUnits` value.
fn mm_per_unit(unit: &str) -> Option<f64> {
    match unit.trim() {
        "" | "mm" => Some(1.0),
        "um" | "\u{b5}m" | "\u{3bc}m" => Some(1e-3),
        "cm" => Some(10.0),
        "m" => Some(1e3),
        _ => None,
    }
}

/// The control points of a 3D Slicer markups file (`.mrk.json`), in LPS mm,
/// with their ids (the order in the file when an id is not a number).
///
/// Positions are converted from the file's `coordinateUnits` (mm, um, cm or
/// m) and `coordinateSystem` (LPS or RAS). Points Slicer has not placed
/// (`positionStatus` `undefined` or `preview`) are left out with a note naming
/// them; a list without `coordinateSystem` is taken as LPS with a note. The
/// file is read as it streams, so memory stays near that of the points.
pub fn read_markups(reader: impl Read) -> Result<ReadPoints, String> {
    let doc: MarkupsIn = serde_json::from_reader(std::io::BufReader::new(reader))
        .map_err(|e| format!("not a Slicer markups file: {e}"))?;
    let lists = doc
        .markups
        .ok_or("no `markups` list: not a Slicer markups file")?;
    let (mut points, mut ids, mut notes) = (Vec::new(), Vec::new(), Vec::new());
    let mut unplaced = Vec::new();
    for (l, list) in lists.into_iter().enumerate() {
        // Slicer writes LPS since 4.11; older files and some tools write RAS.
        let ras = match list.coordinate_system.as_deref() {
            Some("LPS") => false,
            Some("RAS") => true,
            None => {
                notes.push(format!(
                    "markups list {l} names no coordinateSystem: read as LPS (Slicer's default since 4.11)"
                ));
                false
            }
            Some(other) => {
                return Err(format!(
                    "markups list {l}: coordinate system {other:?}: expected LPS or RAS"
                ));
            }
        };
        let units: Vec<String> = match list.coordinate_units {
            None => vec!["mm".into(); 3],
            Some(Units::One(u)) => vec![u; 3],
            Some(Units::PerAxis(u)) if u.len() == 3 => u,
            Some(Units::PerAxis(u)) => {
                return Err(format!(
                    "markups list {l}: coordinateUnits has {} entries, expected 1 or 3",
                    u.len()
                ));
            }
        };
        let mut scale = [1.0; 3];
        for (a, u) in units.iter().enumerate() {
            scale[a] = mm_per_unit(u).ok_or_else(|| {
                format!("markups list {l}: coordinateUnits {u:?}: expected mm, um, cm or m")
            })?;
        }
        if scale != [1.0; 3] {
            notes.push(format!(
                "markups list {l}: positions in {} converted to mm",
                units.join(", ")
            ));
        }
        for (i, p) in list.control_points.into_iter().enumerate() {
            let name = || {
                p.label
                    .clone()
                    .or_else(|| p.id.clone())
                    .unwrap_or_else(|| format!("control point {i}"))
            };
            if let Some(status @ ("undefined" | "preview")) = p.position_status.as_deref() {
                unplaced.push(format!("{} ({status})", name()));
                continue;
            }
            let pos = p
                .position
                .as_ref()
                .filter(|a| a.len() == 3 && a.iter().all(|v| v.is_finite()))
                .ok_or_else(|| format!("{}: `position` must be 3 numbers", name()))?;
            let mm = [0, 1, 2].map(|a| pos[a] * scale[a]);
            let [x, y, z] = mm;
            points.push(if ras { [-x, -y, z] } else { [x, y, z] });
            let id = p.id.as_deref().and_then(|s| s.parse::<u32>().ok());
            ids.push(id.unwrap_or(ids.len() as u32));
        }
    }
    if !unplaced.is_empty() {
        let n = unplaced.len();
        let shown = unplaced
            .iter()
            .take(10)
            .cloned()
            .collect::<Vec<_>>()
            .join(", ");
        let more = if n > 10 {
            format!(" and {} more", n - 10)
        } else {
            String::new()
        };
        notes.push(format!(
            "{n} control point(s) not placed in Slicer, left out: {shown}{more}"
        ));
    }
    if points.is_empty() {
        return Err(if unplaced.is_empty() {
            "no control points".into()
        } else {
            "no placed control points (every point's positionStatus is undefined or preview)".into()
        });
    }
    Ok(ReadPoints { points, ids, notes })
}

/// [`read_markups`] on text in memory.
pub fn parse_markups(text: &str) -> Result<ReadPoints, String> {
    read_markups(text.as_bytes())
}

/// The points of a CSV with a header naming `x`, `y`, `z` (or `x_mm` ...)
/// columns and optionally `id`; `#` lines are comments.
pub fn parse_points_csv(text: &str) -> Result<ReadPoints, String> {
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
    Ok(ReadPoints {
        points,
        ids,
        notes: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points_ids(r: ReadPoints) -> (Vec<[f64; 3]>, Vec<u32>) {
        (r.points, r.ids)
    }

    #[test]
    fn markups_are_lps_and_defined() {
        let m = Markers::new(vec![1.0, -2.0, 3.5, 4.0, 5.0, 6.0], vec![1, 2], "mri_lps").unwrap();
        let j = serde_json::to_value(slicer_markups(&m, "M", None)).unwrap();
        let mk = &j["markups"][0];
        assert_eq!(mk["coordinateSystem"], "LPS");
        assert_eq!(mk["coordinateUnits"], "mm");
        assert_eq!(mk["controlPoints"].as_array().unwrap().len(), 2);
        assert_eq!(mk["controlPoints"][0]["position"][1], -2.0);
        assert_eq!(mk["controlPoints"][1]["label"], "M-2");
        assert_eq!(mk["controlPoints"][1]["positionStatus"], "defined");
        assert_eq!(markers_csv(&m).lines().nth(1), Some("1,1,-2,3.5,mri_lps"));
    }

    #[test]
    fn what_write_markers_writes_reads_back() {
        let m = Markers::new(vec![1.0, -2.5, 30.0, 4.0, 5.0, 6.0], vec![7, 9], "mri_lps").unwrap();
        let text = serde_json::to_string_pretty(&slicer_markups(&m, "t", None)).unwrap();
        let read = parse_markups(&text).unwrap();
        assert!(read.notes.is_empty(), "{:?}", read.notes);
        let (p, ids) = points_ids(read);
        assert_eq!(
            (p, ids.clone()),
            (vec![[1.0, -2.5, 30.0], [4.0, 5.0, 6.0]], vec![7, 9])
        );
        let (p, ids2) = points_ids(parse_points_csv(&markers_csv(&m)).unwrap());
        assert_eq!(p[0], [1.0, -2.5, 30.0]);
        assert_eq!(ids2, ids);
    }

    #[test]
    fn ras_files_turn_into_lps_and_bad_files_say_why() {
        let ras = r#"{"markups":[{"coordinateSystem":"RAS","controlPoints":[{"id":"a","position":[1,2,3]}]}]}"#;
        assert_eq!(
            points_ids(parse_markups(ras).unwrap()),
            (vec![[-1.0, -2.0, 3.0]], vec![0])
        );
        assert!(parse_markups("{}").unwrap_err().contains("markups"));
        assert!(
            parse_markups("nope")
                .unwrap_err()
                .contains("not a Slicer markups file")
        );
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
            points_ids(parse_points_csv("# targets\nX,Y,Z\n1,2,3\n").unwrap()),
            (vec![[1.0, 2.0, 3.0]], vec![0])
        );
    }

    #[test]
    fn units_are_converted_to_mm() {
        let file = |units: &str| {
            format!(
                r#"{{"markups":[{{"coordinateSystem":"LPS","coordinateUnits":{units},"controlPoints":[{{"id":"1","position":[1500,-2000,250]}}]}}]}}"#
            )
        };
        let um = parse_markups(&file(r#""um""#)).unwrap();
        assert_eq!(um.points, vec![[1.5, -2.0, 0.25]]);
        assert!(um.notes[0].contains("converted to mm"), "{:?}", um.notes);
        let m = parse_markups(&file(r#""m""#)).unwrap();
        assert_eq!(m.points, vec![[1.5e6, -2.0e6, 2.5e5]]);
        let per_axis = parse_markups(&file(r#"["mm","mm","um"]"#)).unwrap();
        assert_eq!(per_axis.points, vec![[1500.0, -2000.0, 0.25]]);
        let mm = parse_markups(&file(r#""mm""#)).unwrap();
        assert!(mm.notes.is_empty(), "{:?}", mm.notes);
        let err = parse_markups(&file(r#""furlong""#)).unwrap_err();
        assert!(err.contains("\"furlong\""), "{err}");
    }

    #[test]
    fn unplaced_points_are_left_out_and_named() {
        let text = r#"{"markups":[{"coordinateSystem":"LPS","controlPoints":[
            {"id":"1","label":"T-1","position":[1,2,3],"positionStatus":"defined"},
            {"id":"2","label":"T-2","position":[0,0,0],"positionStatus":"undefined"},
            {"id":"3","label":"T-3","position":[4,5,6],"positionStatus":"preview"}]}]}"#;
        let read = parse_markups(text).unwrap();
        assert_eq!(read.points, vec![[1.0, 2.0, 3.0]]);
        assert_eq!(read.ids, vec![1]);
        assert_eq!(read.notes.len(), 1, "{:?}", read.notes);
        assert!(
            read.notes[0].contains("T-2 (undefined)"),
            "{:?}",
            read.notes
        );
        assert!(read.notes[0].contains("T-3 (preview)"), "{:?}", read.notes);
        let none = r#"{"markups":[{"coordinateSystem":"LPS","controlPoints":[{"id":"1","position":[0,0,0],"positionStatus":"undefined"}]}]}"#;
        assert!(
            parse_markups(none)
                .unwrap_err()
                .contains("no placed control points")
        );
    }

    #[test]
    fn a_missing_coordinate_system_is_noted_as_lps() {
        let text = r#"{"markups":[{"controlPoints":[{"id":"1","position":[1,2,3]}]}]}"#;
        let read = parse_markups(text).unwrap();
        assert_eq!(read.points, vec![[1.0, 2.0, 3.0]]);
        assert!(read.notes[0].contains("read as LPS"), "{:?}", read.notes);
    }

    #[test]
    fn notes_become_csv_columns_and_markup_descriptions() {
        let m = Markers::new(
            vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            vec![3, 8],
            "camera_left",
        )
        .unwrap();
        let table = Table::new(
            vec!["predicted_tre_mm".into(), "id".into(), "bound95_mm".into()],
            vec![0.25, 8.0, 0.5],
        )
        .unwrap();
        let notes = MarkerNotes::from_table(&table).unwrap();
        let mut out = Vec::new();
        write_markers_csv(&m, Some(&notes), &mut out).unwrap();
        let csv = String::from_utf8(out).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "id,x_mm,y_mm,z_mm,frame,predicted_tre_mm,bound95_mm"
        );
        assert_eq!(lines[1], "3,1,2,3,camera_left,,", "a marker without notes");
        assert_eq!(lines[2], "8,4,5,6,camera_left,0.25,0.5");
        let j = serde_json::to_value(slicer_markups(&m, "T", Some(&notes))).unwrap();
        let points = &j["markups"][0]["controlPoints"];
        assert!(points[0].get("description").is_none());
        assert_eq!(
            points[1]["description"],
            "predicted_tre_mm=0.2500; bound95_mm=0.5000"
        );
        // Read back, the extra columns are ignored.
        assert_eq!(parse_points_csv(&csv).unwrap().ids, vec![3, 8]);
        let no_id = Table::new(vec!["a".into()], vec![1.0]).unwrap();
        assert!(
            MarkerNotes::from_table(&no_id)
                .unwrap_err()
                .contains("`id`")
        );
        let bad_id = Table::new(vec!["id".into()], vec![1.5]).unwrap();
        assert!(
            MarkerNotes::from_table(&bad_id)
                .unwrap_err()
                .contains("1.5")
        );
    }
}
