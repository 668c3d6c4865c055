//! Node adapters of the calibration stage.

use super::*;
use crate::camera::{CameraModel, isometry_from_matrix, isometry_to_matrix};
use crate::io::{grey_of, load_grey};
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

/// Board views by view id, and the image size (px).
type ViewsBySize = (BTreeMap<u32, BoardView>, (usize, usize));

/// A found board's corners and its image's width and height, or why not.
type Detection = Result<(Vec<Point2<f64>>, usize, usize), String>;

/// Board views by view id, with the image size, from a corners table.
pub(crate) fn views_from_table(t: &Table) -> Result<ViewsBySize, OpError> {
    if t.columns.iter().map(String::as_str).ne(CORNER_COLUMNS) {
        return Err(OpError::invalid(format!(
            "not a corners table (columns {:?})",
            t.columns
        )));
    }
    let mut views: BTreeMap<u32, BoardView> = BTreeMap::new();
    let mut size = (0, 0);
    for r in 0..t.row_count() {
        let row = t.row(r);
        let v = views.entry(row[0] as u32).or_insert_with(|| BoardView {
            board_mm: Vec::new(),
            image_px: Vec::new(),
        });
        v.image_px.push(Point2::new(row[2], row[3]));
        v.board_mm.push(Point2::new(row[4], row[5]));
        size = (row[6] as usize, row[7] as usize);
    }
    Ok((views, size))
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
                4,
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
                "File names to use, e.g. left_*.png (sorted; their order is the view id)",
            ))
            .param(
                ParamSpec::int_list(
                    "pattern",
                    &[9, 6],
                    "",
                    "Inner corners per row and per column",
                )
                .range(2.0, 100.0),
            )
            .param(ParamSpec::float("square_mm", 25.0, "mm", "Square size").at_least(1e-3))
            .output(
                "corners",
                ValueType::Table,
                "view, corner, x_px, y_px, board_x_mm, board_y_mm, width_px, height_px",
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
        let table = |found: Vec<(usize, Vec<Point2<f64>>, usize, usize)>| {
            let mut data = Vec::new();
            for (view, corners, w, h) in found {
                for (k, c) in corners.iter().enumerate() {
                    let (bx, by) = ((k % cols) as f64 * square, (k / cols) as f64 * square);
                    data.extend([view as f64, k as f64, c.x, c.y, bx, by, w as f64, h as f64]);
                }
            }
            Table::new(CORNER_COLUMNS.iter().map(|s| s.to_string()).collect(), data)
                .map_err(|e| OpError::invalid(e.0))
        };
        if let Some(img) = inputs.optional::<Image>("image")? {
            let corners = find_chessboard(&grey_of(&img), img.width, img.height, cols, rows)
                .map_err(OpError::invalid)?;
            ctx.metric("detected", 1.0);
            ctx.metric("total", 1.0);
            return Ok(
                Outputs::new().with("corners", table(vec![(0, corners, img.width, img.height)])?)
            );
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
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .map_err(|e| OpError::io(&dir, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .is_some_and(|n| pattern.matches(&n.to_string_lossy()))
            })
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(OpError::invalid(format!(
                "{}: no file matches {:?}",
                dir.display(),
                pattern.as_str()
            )));
        }
        let results: Vec<Detection> = files
            .par_iter()
            .map(|f| {
                let img = load_grey(f).map_err(|e| e.to_string())?;
                find_chessboard(&img.levels, img.width, img.height, cols, rows)
                    .map(|c| (c, img.width, img.height))
            })
            .collect();
        let mut found = Vec::new();
        for (view, (file, result)) in files.iter().zip(results).enumerate() {
            match result {
                Ok((corners, w, h)) => found.push((view, corners, w, h)),
                Err(why) => {
                    tracing::info!(node = %ctx.node_id(), "{}: skipped: {why}", file.display())
                }
            }
        }
        ctx.metric("detected", found.len() as f64);
        ctx.metric("total", files.len() as f64);
        Ok(Outputs::new().with("corners", table(found)?))
    }
}

impl CalibrateCameraOp {
    pub(crate) fn new() -> Self {
        CalibrateCameraOp(
            OpSpec::new(
                "calib.calibrate_camera",
                1,
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
        let (views, (w, h)) = views_from_table(&*inputs.get::<Table>("corners")?)?;
        let ids: Vec<u32> = views.keys().copied().collect();
        let views: Vec<BoardView> = views.into_values().collect();
        let c =
            calibrate_camera(&views, w, h, distortion_mask(params)?).map_err(OpError::invalid)?;
        ctx.metric("rms_px", c.rms_px);
        ctx.metric("views", views.len() as f64);
        for (id, e) in ids.iter().zip(&c.view_rms_px) {
            ctx.metric(&format!("view_{id}_rms_px"), *e);
        }
        Ok(Outputs::new().with("camera", c.camera.to_value()))
    }
}

impl StereoCalibrateOp {
    pub(crate) fn new() -> Self {
        StereoCalibrateOp(
            OpSpec::new(
                "calib.stereo_calibrate",
                1,
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
                "Right corners; views pair by id (file order)",
            )
            .param(ParamSpec::string_list(
                "free",
                &["k1", "k2", "p1", "p2"],
                "Distortion coefficients to estimate (others 0)",
            ))
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
        let (left, lsize) = views_from_table(&*inputs.get::<Table>("left")?)?;
        let (mut right, rsize) = views_from_table(&*inputs.get::<Table>("right")?)?;
        let pairs: Vec<(BoardView, BoardView)> = left
            .into_iter()
            .filter_map(|(id, l)| right.remove(&id).map(|r| (l, r)))
            .collect();
        let s = calibrate_stereo(&pairs, [lsize, rsize], distortion_mask(params)?)
            .map_err(OpError::invalid)?;
        ctx.metric("pairs", pairs.len() as f64);
        ctx.metric("rms_px", s.rms_px);
        ctx.metric("rms_left_px", s.rms_left_right_px[0]);
        ctx.metric("rms_right_px", s.rms_left_right_px[1]);
        ctx.metric("baseline_mm", s.left_to_right.translation.vector.norm());
        ctx.metric("verging_deg", s.left_to_right.rotation.angle().to_degrees());
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
