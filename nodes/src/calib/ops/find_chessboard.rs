//! `calib.find_chessboard`: the board's inner corners in a folder of photos
//! (or one image).

use crate::calib::tables::{corners_table, views_table};
use crate::calib::{PhotoRecord, Refusal, find_chessboard, numbered_photos};
use crate::io::{ImageSizeLimit, grey_of, load_grey_within};
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Image, PathValue, Table};
use nalgebra::Point2;
use rayon::prelude::*;
use std::path::PathBuf;

/// Chessboard inner corners, sub-pixel, in every image matching a glob
#[derive(Op)]
#[op(name = "calib.find_chessboard", version = 7)]
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
    /// The largest image decoded.
    #[param(flatten)]
    pub limit: ImageSizeLimit,
}

#[derive(Inputs)]
pub struct FindChessboardInputs {
    /// Folder of images (or the `dir` parameter)
    pub dir: Option<Arc<PathValue>>,
    /// A single image instead of a folder (view 0)
    pub image: Option<Arc<Image>>,
}

#[derive(Debug, Outputs)]
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

    fn check(&self, wired: Wired) -> Vec<(&'static str, String)> {
        let mut problems = Vec::new();
        let [cols, rows] = self.pattern;
        if cols % 2 == rows % 2 {
            let why = Refusal::AmbiguousPattern { cols, rows };
            problems.push(("pattern", why.to_string()));
        }
        problems.extend(exactly_one_source(&[
            ("dir", self.dir.is_some()),
            ("in.dir", wired.has("dir")),
            ("in.image", wired.has("image")),
        ]));
        if let Err(e) = glob::Pattern::new(&self.glob) {
            problems.push(("glob", e.to_string()));
        }
        problems
    }

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
        let pattern =
            glob::Pattern::new(&self.glob).map_err(|e| OpError::invalid(format!("glob: {e}")))?;
        let photos = numbered_photos(&dir, &pattern).map_err(OpError::invalid)?;
        for note in &photos.skipped {
            ctx.note(note.clone());
        }
        let max_pixels = self.limit.max_pixels();
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

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::value::Pixels;

    /// A 5 x 4 square board (4 x 3 inner corners, squares 12 px) on white,
    /// 88 x 76 px grey.
    fn board() -> Image {
        let (w, h) = (88, 76);
        let pixels: Vec<u8> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64 - 12.5, (i / w) as f64 - 12.5);
                let (c, r) = ((x / 12.0).floor(), (y / 12.0).floor());
                let on_board = (0.0..5.0).contains(&c) && (0.0..4.0).contains(&r);
                if on_board && (c + r) % 2.0 == 0.0 {
                    25
                } else {
                    230
                }
            })
            .collect();
        Image::new(w, h, 1, Pixels::U8(pixels.into())).unwrap()
    }

    fn op(pattern: [usize; 2]) -> FindChessboard {
        FindChessboard {
            dir: None,
            glob: "*.png".into(),
            pattern,
            square_mm: 10.0,
            limit: ImageSizeLimit {
                max_megapixels: 100.0,
            },
        }
    }

    #[test]
    fn one_image_gives_view_0_and_its_corners_in_mm() {
        let mut ctx = RunCtx::new("find", std::path::Path::new("."));
        let inputs = FindChessboardInputs {
            dir: None,
            image: Some(Arc::new(board())),
        };
        let out = op([4, 3]).run(inputs, &mut ctx).unwrap();
        assert_eq!(out.corners.row_count(), 12);
        // Corner 5: the second of the second row, one square from corner 0.
        let row = out.corners.row(5);
        assert_eq!((row[0], row[1], row[4], row[5]), (0.0, 5.0, 10.0, 10.0));
        assert!((row[2] - 36.5).abs() < 0.05 && (row[3] - 36.5).abs() < 0.05);
        assert_eq!(out.views.row(0), [0.0, 1.0, 88.0, 76.0, 0.0]);
        assert_eq!(ctx.metrics()["detected"], 1.0);
    }

    #[test]
    fn no_source_or_no_board_is_an_error() {
        let mut ctx = RunCtx::new("find", std::path::Path::new("."));
        let none = FindChessboardInputs {
            dir: None,
            image: None,
        };
        let e = op([4, 3]).run(none, &mut ctx).unwrap_err();
        assert!(e.to_string().contains("give the `dir` parameter"), "{e}");
        let wrong = FindChessboardInputs {
            dir: None,
            image: Some(Arc::new(board())),
        };
        assert!(op([5, 4]).run(wrong, &mut ctx).is_err());
    }
}
