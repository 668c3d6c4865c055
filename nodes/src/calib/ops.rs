//! Node adapters of the calibration stage.

use super::*;
use crate::camera::{CameraModel, isometry_from_matrix, isometry_to_matrix};
use crate::io::{grey_of, load_grey_within, max_megapixels_param, max_pixels};
use fusegraph_engine::value::{Camera, Image, PathValue, Pixels, Rectification, StereoRig, Table};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};
use nalgebra::{Matrix3, Point2};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::Arc;

const CORNER_COLUMNS: [&str; 8] = [
    "view",
    "corner",
    "x_px",
    "y_px",
    "board_x_mm",
    "board_y_mm",
    "width_px",
    "height_px",
];

const VIEW_COLUMNS: [&str; 5] = ["view", "found", "width_px", "height_px", "refusal"];

/// Boards by view number, each with its image's width and height (px).
type Boards = BTreeMap<u32, (BoardView, (usize, usize))>;

/// A photo's outcome: its corners and image size, or why not (the reason,
/// the image size when it could be read, and the refusal's code).
type Detection = Result<(Vec<Point2<f64>>, usize, usize), (String, (usize, usize), u8)>;

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
fn photos_from_table(t: &Table) -> Result<BTreeMap<u32, PhotoRecord>, OpError> {
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

/// Refuses a calibration whose reprojection error says it is garbage (a
/// mispaired or mis-detected view), naming the worst views.
fn check_rms(
    what: &str,
    rms_px: f64,
    max_rms_px: f64,
    views: &[u32],
    view_rms_px: &[f64],
) -> Result<(), OpError> {
    if rms_px.is_finite() && rms_px <= max_rms_px {
        return Ok(());
    }
    let mut worst: Vec<(f64, u32)> = view_rms_px
        .iter()
        .copied()
        .zip(views.iter().copied())
        .collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    let listed: Vec<String> = worst
        .iter()
        .take(3)
        .map(|(e, v)| format!("view {v} {e:.2} px"))
        .collect();
    Err(OpError::invalid(format!(
        "{what} RMS reprojection error {rms_px:.3} px is above max_rms_px = {max_rms_px} px: \
         a view is probably mispaired or its board mis-detected (worst: {})",
        listed.join(", ")
    )))
}

fn max_rms_param() -> ParamSpec {
    ParamSpec::float(
        "max_rms_px",
        2.0,
        "px",
        "Fail when the RMS reprojection error exceeds this (a garbage calibration)",
    )
    .at_least(0.0)
}

fn distortion_mask(params: &Params) -> Result<[bool; 5], OpError> {
    let free = params.string_list("free")?;
    for f in &free {
        if !DISTORTION_NAMES.contains(&f.as_str()) {
            return Err(OpError::invalid(format!(
                "free: unknown coefficient {f:?}; use {}",
                DISTORTION_NAMES.join(", ")
            )));
        }
    }
    Ok(std::array::from_fn(|i| {
        free.iter().any(|f| f == DISTORTION_NAMES[i])
    }))
}

fn mat3(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

macro_rules! op_struct {
    ($($name:ident),*) => { $(pub(crate) struct $name(OpSpec);)* };
}
op_struct!(
    FindChessboardOp,
    CalibrateCameraOp,
    StereoCalibrateOp,
    RectifyOp,
    RemapOp
);

impl FindChessboardOp {
    pub(crate) fn new() -> Self {
        FindChessboardOp(
            OpSpec::new(
                "calib.find_chessboard",
                5,
                "Chessboard inner corners, sub-pixel, in every image matching a glob",
            )
            .optional_input(
                "dir",
                &[ValueType::Path],
                "Folder of images (or the `dir` parameter)",
            )
            .optional_input(
                "image",
                &[ValueType::Image],
                "A single image instead of a folder (view 0)",
            )
            .param(ParamSpec::optional_path(
                "dir",
                "Folder of images, relative to the graph",
            ))
            .param(ParamSpec::string(
                "glob",
                "*.png",
                "Photos to use, e.g. left_*.png; the last number in a name is its view (left_07.png: 7)",
            ))
            .param(
                ParamSpec::int_list(
                    "pattern",
                    &[9, 6],
                    "",
                    "Inner corners per row and per column",
                )
                .range(2.0, 100.0)
                .length(2),
            )
            .param(ParamSpec::float("square_mm", 25.0, "mm", "Square size").at_least(1e-3))
            .param(max_megapixels_param())
            .output(
                "corners",
                ValueType::Table,
                "view, corner, x_px, y_px, board_x_mm, board_y_mm, width_px, height_px",
            )
            .output(
                "views",
                ValueType::Table,
                "Every photo: view, found (1 or 0), width_px, height_px (0 if unreadable), refusal (calib::Refusal code; 0 found, 1 unreadable)",
            ),
        )
    }
}

impl Op for FindChessboardOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let size = params.int_list("pattern")?;
        let &[cols, rows] = size.as_slice() else {
            return Err(OpError::invalid(
                "pattern takes two numbers: inner corners per row and per column",
            ));
        };
        let (cols, rows) = (cols as usize, rows as usize);
        let square = params.float("square_mm")?;
        let corners_table = |found: &[(u32, Vec<Point2<f64>>, usize, usize)]| {
            let mut data = Vec::new();
            for (view, corners, w, h) in found {
                for (k, c) in corners.iter().enumerate() {
                    let b = board_corner_mm(k, cols, square);
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
        };
        let views_table = |records: &[(u32, PhotoRecord)]| {
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
        };
        if let Some(img) = inputs.optional::<Image>("image")? {
            let corners = find_chessboard(&grey_of(&img), img.width, img.height, cols, rows)
                .map_err(|r| OpError::invalid(r.to_string()))?;
            ctx.metric("detected", 1.0);
            ctx.metric("total", 1.0);
            let record = PhotoRecord {
                refusal: PhotoRecord::FOUND,
                size: (img.width, img.height),
            };
            return Ok(Outputs::new()
                .with(
                    "corners",
                    corners_table(&[(0, corners, img.width, img.height)])?,
                )
                .with("views", views_table(&[(0, record)])?));
        }
        let from_input: Option<Arc<PathValue>> = inputs.optional("dir")?;
        let dir = match (params.optional_path("dir")?, from_input) {
            (Some(d), None) => d,
            (None, Some(d)) => d.path.clone(),
            _ => {
                return Err(OpError::invalid(
                    "give the `dir` parameter, the `dir` input or the `image` input",
                ));
            }
        };
        let pattern = glob::Pattern::new(&params.string("glob")?)
            .map_err(|e| OpError::invalid(format!("glob: {e}")))?;
        let photos = numbered_photos(&dir, &pattern).map_err(OpError::invalid)?;
        for note in &photos.skipped {
            ctx.note(note.clone());
        }
        let max_pixels = max_pixels(params)?;
        let files: Vec<(u32, &std::path::PathBuf)> =
            photos.files.iter().map(|(v, f)| (*v, f)).collect();
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
        Ok(Outputs::new()
            .with("corners", corners_table(&found)?)
            .with("views", views_table(&records)?))
    }
}

impl CalibrateCameraOp {
    pub(crate) fn new() -> Self {
        CalibrateCameraOp(
            OpSpec::new(
                "calib.calibrate_camera",
                // 3: analytic Jacobians, stopped on the exact minimum.
                3,
                "Zhang calibration refined by Levenberg-Marquardt -> Camera",
            )
            .input(
                "corners",
                &[ValueType::Table],
                "Corners from calib.find_chessboard",
            )
            .param(ParamSpec::string_list(
                "free",
                &["k1", "k2", "p1", "p2"],
                "Distortion coefficients to estimate (others 0)",
            ))
            .param(max_rms_param())
            .output(
                "camera",
                ValueType::Camera,
                "Intrinsics (px) and distortion",
            ),
        )
    }
}

impl Op for CalibrateCameraOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let mut boards = boards_from_table(&*inputs.get::<Table>("corners")?)?;
        let sizes = boards.iter().map(|(v, b)| (*v, b.1)).collect();
        let ((w, h), odd) = usual_size(&sizes);
        for v in odd {
            let (ow, oh) = sizes[&v];
            ctx.note(format!(
                "view {v}: the photo is {ow} x {oh} px, the others {w} x {h}: left out"
            ));
            boards.remove(&v);
        }
        let ids: Vec<u32> = boards.keys().copied().collect();
        let views: Vec<BoardView> = boards.into_values().map(|b| b.0).collect();
        let c =
            calibrate_camera(&views, w, h, distortion_mask(params)?).map_err(OpError::invalid)?;
        ctx.metric("rms_px", c.rms_px);
        ctx.metric("views", views.len() as f64);
        ctx.metric("iterations", c.iterations as f64);
        if !c.converged {
            ctx.note(format!(
                "the solver stopped after {} iterations short of the minimum: check the corners",
                c.iterations
            ));
        }
        for (id, e) in ids.iter().zip(&c.view_rms_px) {
            ctx.metric(&format!("view_{id}_rms_px"), *e);
        }
        check_rms(
            "camera",
            c.rms_px,
            params.float("max_rms_px")?,
            &ids,
            &c.view_rms_px,
        )?;
        Ok(Outputs::new().with("camera", c.camera.to_value()))
    }
}

impl StereoCalibrateOp {
    pub(crate) fn new() -> Self {
        StereoCalibrateOp(
            OpSpec::new(
                "calib.stereo_calibrate",
                // 3: analytic Jacobians, stopped on the exact minimum.
                3,
                "Both cameras and the rig extrinsics, refined jointly -> StereoRig",
            )
            .input(
                "left",
                &[ValueType::Table],
                "Left corners (calib.find_chessboard)",
            )
            .input(
                "right",
                &[ValueType::Table],
                "Right corners; views pair by number (left_07 with right_07)",
            )
            .optional_input(
                "left_views",
                &[ValueType::Table],
                "The left find_chessboard's `views`: tells a refused photo from a missing one",
            )
            .optional_input(
                "right_views",
                &[ValueType::Table],
                "The right find_chessboard's `views`",
            )
            .param(ParamSpec::string_list(
                "free",
                &["k1", "k2", "p1", "p2"],
                "Distortion coefficients to estimate (others 0)",
            ))
            .param(max_rms_param())
            .output(
                "rig",
                ValueType::StereoRig,
                "Cameras and R, T (left -> right, mm)",
            ),
        )
    }
}

impl Op for StereoCalibrateOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let side = |corners: &str, views: &str| -> Result<Side, OpError> {
            Ok(Side {
                boards: boards_from_table(&*inputs.get::<Table>(corners)?)?,
                photos: inputs
                    .optional::<Table>(views)?
                    .map(|t| photos_from_table(&t))
                    .transpose()?,
            })
        };
        let (left, right) = (side("left", "left_views")?, side("right", "right_views")?);
        let pairing = pair_views(&left, &right, 3).map_err(OpError::invalid)?;
        for dropped in &pairing.dropped {
            ctx.note(format!("{dropped}: pair left out"));
        }
        let s = calibrate_stereo(&pairing.pairs, pairing.sizes, distortion_mask(params)?)
            .map_err(OpError::invalid)?;
        ctx.metric("pairs", pairing.pairs.len() as f64);
        ctx.metric("iterations", s.iterations as f64);
        if !s.converged {
            ctx.note(format!(
                "the solver stopped after {} iterations short of the minimum: check the corners",
                s.iterations
            ));
        }
        ctx.metric("pairs_left_out", pairing.dropped.len() as f64);
        ctx.metric("rms_px", s.rms_px);
        ctx.metric("rms_left_px", s.rms_left_right_px[0]);
        ctx.metric("rms_right_px", s.rms_left_right_px[1]);
        ctx.metric("baseline_mm", s.left_to_right.translation.vector.norm());
        ctx.metric("verging_deg", s.left_to_right.rotation.angle().to_degrees());
        check_rms(
            "stereo",
            s.rms_px,
            params.float("max_rms_px")?,
            &pairing.views,
            &s.pair_rms_px,
        )?;
        let m = isometry_to_matrix(&s.left_to_right);
        let rig = StereoRig {
            left: s.left.to_value(),
            right: s.right.to_value(),
            rotation: std::array::from_fn(|r| std::array::from_fn(|c| m[r][c])),
            translation_mm: [m[0][3], m[1][3], m[2][3]],
        };
        Ok(Outputs::new().with("rig", rig))
    }
}

/// The rig's left -> right isometry.
pub(crate) fn rig_isometry(rig: &StereoRig) -> nalgebra::Isometry3<f64> {
    let mut m = [[0.0; 4]; 4];
    for (r, row) in m.iter_mut().take(3).enumerate() {
        row[..3].copy_from_slice(&rig.rotation[r]);
        row[3] = rig.translation_mm[r];
    }
    m[3][3] = 1.0;
    isometry_from_matrix(&m)
}

impl RectifyOp {
    pub(crate) fn new() -> Self {
        RectifyOp(
            OpSpec::new(
                "calib.rectify",
                1,
                "Bouguet rectification (R1, R2, P1, P2, Q) of a stereo rig",
            )
            .input("rig", &[ValueType::StereoRig], "The rig")
            .param(
                ParamSpec::float(
                    "alpha",
                    0.0,
                    "",
                    "0: only valid pixels; 1: every source pixel",
                )
                .range(0.0, 1.0),
            )
            .output(
                "rectification",
                ValueType::Rectification,
                "Rotations and projections (px; P2 translation f Tx)",
            ),
        )
    }
}

impl Op for RectifyOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let rig = inputs.get::<StereoRig>("rig")?;
        let (l, r) = (
            CameraModel::from_value(&rig.left),
            CameraModel::from_value(&rig.right),
        );
        let rect = rectify(&l, &r, &rig_isometry(&rig), params.float("alpha")?);
        ctx.metric("focal_px", rect.p1[(0, 0)]);
        ctx.metric("baseline_mm", -rect.p2[(0, 3)] / rect.p2[(0, 0)]);
        let m34 = |m: &nalgebra::Matrix3x4<f64>| {
            std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
        };
        let value = Rectification {
            width: rect.size.0,
            height: rect.size.1,
            r1: mat3(&rect.r1),
            r2: mat3(&rect.r2),
            p1: m34(&rect.p1),
            p2: m34(&rect.p2),
            q: std::array::from_fn(|r| std::array::from_fn(|c| rect.q[(r, c)])),
        };
        Ok(Outputs::new().with("rectification", value))
    }
}

/// A rectification value as the solver's type.
pub(crate) fn rectification_of(v: &Rectification) -> StereoRectification {
    StereoRectification {
        size: (v.width, v.height),
        r1: Matrix3::from_fn(|r, c| v.r1[r][c]),
        r2: Matrix3::from_fn(|r, c| v.r2[r][c]),
        p1: nalgebra::Matrix3x4::from_fn(|r, c| v.p1[r][c]),
        p2: nalgebra::Matrix3x4::from_fn(|r, c| v.p2[r][c]),
        q: nalgebra::Matrix4::from_fn(|r, c| v.q[r][c]),
    }
}

impl RemapOp {
    pub(crate) fn new() -> Self {
        RemapOp(
            OpSpec::new(
                "calib.remap",
                1,
                "Undistort and rectify one image of a pair (bilinear)",
            )
            .input("image", &[ValueType::Image], "Image from the `side` camera")
            .input("rig", &[ValueType::StereoRig], "The rig")
            .input(
                "rectification",
                &[ValueType::Rectification],
                "calib.rectify's output",
            )
            .param(ParamSpec::choice(
                "side",
                &["left", "right"],
                "Which camera took the image",
            ))
            .output("image", ValueType::Image, "Rectified image"),
        )
    }
}

impl Op for RemapOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
        let img = inputs.get::<Image>("image")?;
        let rig = inputs.get::<StereoRig>("rig")?;
        let rect = rectification_of(&*inputs.get::<Rectification>("rectification")?);
        let left = params.string("side")? == "left";
        let camera: &Camera = if left { &rig.left } else { &rig.right };
        let camera = CameraModel::from_value(camera);
        if (img.width, img.height) != (camera.width, camera.height) {
            return Err(OpError::invalid(format!(
                "image is {} x {} px but the camera is {} x {}",
                img.width, img.height, camera.width, camera.height
            )));
        }
        let Pixels::U8(src) = &img.pixels else {
            return Err(OpError::invalid("calib.remap takes 8-bit images"));
        };
        let (r, p) = if left {
            (&rect.r1, &rect.p1)
        } else {
            (&rect.r2, &rect.p2)
        };
        let out = remap(src, img.channels, &camera, r, p, rect.size);
        let image = Image::new(
            rect.size.0,
            rect.size.1,
            img.channels,
            Pixels::U8(out.into()),
        )
        .map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new().with("image", image))
    }
}
