//! `calib.find_chessboard`: the board's inner corners in a folder of photos
//! (or one image).

use crate::calib::tables::{corners_table, views_table};
use crate::calib::{PhotoRecord, find_chessboard, numbered_photos};
use crate::io::{DEFAULT_MAX_PIXELS, grey_of, load_grey_within};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Image, PathValue, Table};
use nalgebra::Point2;
use rayon::prelude::*;
use std::path::PathBuf;

/// Chessboard inner corners, sub-pixel, in every image matching a glob
#[derive(Op)]
#[op(name = "calib.find_chessboard", version = 5)]
pub struct FindChessboard {
    /// Folder of images, relative to the graph
    pub dir: Option<PathBuf>,
    /// Photos to use, e.g. left_*.png; the last number in a name is its view
    /// (left_07.png: 7)
    #[param(default = "*.png")]
    pub glob: String,
    /// Inner corners per row and per column
    #[param(default = [9, 6], min = 2, max = 100)]
    pub pattern: [usize; 2],
    /// Square size
    #[param(default = 25.0, unit = "mm", min = 1e-3)]
    pub square_mm: f64,
    /// Largest image to decode: a file whose header declares more is refused
    /// before decoding
    #[param(
        default = DEFAULT_MAX_PIXELS as f64 / 1e6,
        unit = "Mpixel",
        min = 0.01,
        max = 10_000.0
    )]
    pub max_megapixels: f64,
}

#[derive(Inputs)]
pub struct FindChessboardInputs {
    /// Folder of images (or the `dir` parameter)
    pub dir: Option<Arc<PathValue>>,
    /// A single image instead of a folder (view 0)
    pub image: Option<Arc<Image>>,
}

#[derive(Outputs)]
pub struct FindChessboardOutputs {
    /// view, corner, x_px, y_px, board_x_mm, board_y_mm, width_px, height_px
    pub corners: Table,
    /// Every photo: view, found (1 or 0), width_px, height_px (0 if
    /// unreadable), refusal (calib::Refusal code; 0 found, 1 unreadable)
    pub views: Table,
}

/// A photo's outcome: its corners and image size, or why not (the reason,
/// the image size when it could be read, and the refusal's code).
type Detection = Result<(Vec<Point2<f64>>, usize, usize), (String, (usize, usize), u8)>;

impl RunOp for FindChessboard {
    type Inputs = FindChessboardInputs;
    type Outputs = FindChessboardOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let [cols, rows] = self.pattern;
        let square = self.square_mm;
        if let Some(img) = inputs.image {
            let corners = find_chessboard(&grey_of(&img), img.width, img.height, cols, rows)
                .map_err(|r| OpError::invalid(r.to_string()))?;
            ctx.metric("detected", 1.0);
            ctx.metric("total", 1.0);
            let record = PhotoRecord {
                refusal: PhotoRecord::FOUND,
                size: (img.width, img.height),
            };
            return Ok(FindChessboardOutputs {
                corners: corners_table(&[(0, corners, img.width, img.height)], cols, square)?,
                views: views_table(&[(0, record)])?,
            });
        }
        let dir = match (&self.dir, inputs.dir) {
            (Some(d), None) => d.clone(),
            (None, Some(d)) => d.path.clone(),
            _ => {
                return Err(OpError::invalid(
                    "give the `dir` parameter, the `dir` input or the `image` input",
                ));
            }
        };
        let pattern = glob::Pattern::new(&self.glob)
            .map_err(|e| OpError::invalid(format!("glob: {e}")))?;
        let photos = numbered_photos(&dir, &pattern).map_err(OpError::invalid)?;
        for note in &photos.skipped {
            ctx.note(note.clone());
        }
        let max_pixels = (self.max_megapixels * 1e6) as u64;
        let files: Vec<(u32, &PathBuf)> = photos.files.iter().map(|(v, f)| (*v, f)).collect();
        let results: Vec<Detection> = files
            .par_iter()
            .map(|(_, f)| {
                let img = load_grey_within(f, max_pixels)
                    .map_err(|e| (e.to_string(), (0, 0), PhotoRecord::UNREADABLE))?;
                find_chessboard(&img.levels, img.width, img.height, cols, rows)
                    .map(|c| (c, img.width, img.height))
                    .map_err(|why| (why.to_string(), (img.width, img.height), why.code()))
            })
            .collect();
        let mut found = Vec::new();
        let mut records = Vec::new();
        for ((view, file), result) in files.iter().zip(results) {
            let name = file.file_name().unwrap_or_default().to_string_lossy();
            match result {
                Ok((corners, w, h)) => {
                    records.push((
                        *view,
                        PhotoRecord {
                            refusal: PhotoRecord::FOUND,
                            size: (w, h),
                        },
                    ));
                    found.push((*view, corners, w, h));
                }
                Err((why, size, refusal)) => {
                    let what = if refusal == PhotoRecord::UNREADABLE {
                        "unreadable"
                    } else {
                        "refused"
                    };
                    ctx.note(format!("{name}: {what}: {why}"));
                    records.push((*view, PhotoRecord { refusal, size }));
                }
            }
        }
        ctx.metric("detected", found.len() as f64);
        ctx.metric("total", files.len() as f64);
        if found.is_empty() {
            return Err(OpError::invalid(format!(
                "{}: the {cols} x {rows} board was found in none of the {} photos (see the notes for why)",
                dir.display(),
                files.len()
            )));
        }
        Ok(FindChessboardOutputs {
            corners: corners_table(&found, cols, square)?,
            views: views_table(&records)?,
        })
    }
}
