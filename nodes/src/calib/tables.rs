//! The tables of `calib.find_chessboard` (`corners` and `views`): written from
//! detections, and read back by the calibration ops.

use super::{BoardView, PhotoRecord, board_corner_mm};
use fusegraph_engine::OpError;
use fusegraph_engine::value::Table;
use nalgebra::Point2;
use std::collections::BTreeMap;

/// Columns of the corners table: per corner, its view, index, image position
/// (px), board position (mm, z = 0) and the image size (px).
pub(crate) const CORNER_COLUMNS: [&str; 8] = [
    "view",
    "corner",
    "x_px",
    "y_px",
    "board_x_mm",
    "board_y_mm",
    "width_px",
    "height_px",
];

/// Columns of the views table: per photo, its view, whether the board was
/// found (1 or 0), the image size (px) and the refusal code.
pub(crate) const VIEW_COLUMNS: [&str; 5] = ["view", "found", "width_px", "height_px", "refusal"];

/// Boards by view number, each with its image's width and height (px).
pub(crate) type Boards = BTreeMap<u32, (BoardView, (usize, usize))>;

/// The corners table of boards found: (view, corners in px, width, height)
/// for a board of `cols` inner corners per row and squares of `square_mm`.
pub(crate) fn corners_table(
    found: &[(u32, Vec<Point2<f64>>, usize, usize)],
    cols: usize,
    square_mm: f64,
) -> Result<Table, OpError> {
    let mut data = Vec::new();
    for (view, corners, w, h) in found {
        for (k, c) in corners.iter().enumerate() {
            let b = board_corner_mm(k, cols, square_mm);
            data.extend([
                *view as f64,
                k as f64,
                c.x,
                c.y,
                b.x,
                b.y,
                *w as f64,
                *h as f64,
            ]);
        }
    }
    Table::new(CORNER_COLUMNS.iter().map(|s| s.to_string()).collect(), data)
        .map_err(|e| OpError::invalid(e.0))
}

/// The views table of every photo's record, by view number.
pub(crate) fn views_table(records: &[(u32, PhotoRecord)]) -> Result<Table, OpError> {
    let data: Vec<f64> = records
        .iter()
        .flat_map(|(v, r)| {
            let found = if r.found() { 1.0 } else { 0.0 };
            [
                *v as f64,
                found,
                r.size.0 as f64,
                r.size.1 as f64,
                r.refusal as f64,
            ]
        })
        .collect();
    Table::new(VIEW_COLUMNS.iter().map(|s| s.to_string()).collect(), data)
        .map_err(|e| OpError::invalid(e.0))
}

/// Boards by view number, from a corners table.
pub(crate) fn boards_from_table(t: &Table) -> Result<Boards, OpError> {
    if t.columns.iter().map(String::as_str).ne(CORNER_COLUMNS) {
        return Err(OpError::invalid(format!(
            "not a corners table (columns {:?})",
            t.columns
        )));
    }
    let mut boards: Boards = BTreeMap::new();
    for r in 0..t.row_count() {
        let row = t.row(r);
        let (v, _) = boards.entry(row[0] as u32).or_insert_with(|| {
            (
                BoardView {
                    board_mm: Vec::new(),
                    image_px: Vec::new(),
                },
                (row[6] as usize, row[7] as usize),
            )
        });
        v.image_px.push(Point2::new(row[2], row[3]));
        v.board_mm.push(Point2::new(row[4], row[5]));
    }
    Ok(boards)
}

/// Every photo's record by view number, from a views table.
pub(crate) fn photos_from_table(t: &Table) -> Result<BTreeMap<u32, PhotoRecord>, OpError> {
    if t.columns.iter().map(String::as_str).ne(VIEW_COLUMNS) {
        return Err(OpError::invalid(format!(
            "not a views table from calib.find_chessboard (columns {:?})",
            t.columns
        )));
    }
    Ok((0..t.row_count())
        .map(|r| {
            let row = t.row(r);
            let record = PhotoRecord {
                refusal: row[4] as u8,
                size: (row[2] as usize, row[3] as usize),
            };
            (row[0] as u32, record)
        })
        .collect())
}
