//! The true disparity of a phantom view pair, in the rectified frame of a given
//! (usually *estimated*) rig and rectification: what the rendered images show
//! once `calib.remap` has rectified them, calibration error included.
//!
//! For each left rectified pixel (u, v): back through the estimated left model
//! (R1, P1, distortion: the chain `calib.remap` samples with) to the original
//! left pixel; the *true* left camera's ray through it, cast into the scene the
//! renderer draws (the phantom, and the table plane z = 0 in world); the hit
//! point projected by the *true* right camera to an original right pixel, unless
//! something nearer hides it from the right camera; that pixel through the
//! estimated right model into the right rectified image (x_r, y_r); disparity
//! `u - x_r` px. With a perfect calibration `y_r = v`; otherwise `|v - y_r|` is
//! the rectification's row error at that pixel.

use super::moved_shape::MovedShape;
use super::props::{Prop, first_prop};
use super::shape::Surface;
use super::truth::GroundTruth;
use crate::calib::StereoRectification;
use crate::camera::{CameraModel, isometry_from_matrix};
use nalgebra::{Isometry3, Point2, Point3, Vector3};
use rayon::prelude::*;

/// What a left rectified pixel sees (the values of the `labels` image).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum SceneLabel {
    /// Nothing: the ray misses everything, or the pixel maps outside the
    /// original left image.
    Nothing = 0,
    /// The table (world plane z = 0).
    Table = 1,
    /// The phantom's skin (the dome).
    Skin = 2,
    /// The plastic side wall of a marker.
    MarkerSide = 3,
    /// The coloured outer face of a marker.
    MarkerFace = 4,
    /// Something beside the phantom: a distractor or a tool.
    Prop = 5,
}

/// The scene and the *true* cameras of one view pair.
#[derive(Debug, Clone)]
pub struct ViewScene<'a> {
    /// The phantom in its own frame, as it moved between the scan and this
    /// session.
    pub body: MovedShape,
    /// Things beside the phantom, world frame.
    pub props: Vec<Prop>,
    /// Phantom frame -> world (mm).
    pub phantom_to_world: Isometry3<f64>,
    /// The true left camera.
    pub left: &'a CameraModel,
    /// The true right camera.
    pub right: &'a CameraModel,
    /// True left camera frame -> right camera frame (mm).
    pub left_to_right: Isometry3<f64>,
    /// True left camera frame -> world for this view (mm).
    pub left_to_world: Isometry3<f64>,
}

impl<'a> ViewScene<'a> {
    /// View `view` of a phantom's ground truth.
    pub fn from_truth(truth: &'a GroundTruth, view: usize) -> Result<Self, String> {
        let v = truth.views.get(view).ok_or_else(|| {
            format!(
                "view {view} does not exist (the phantom has {} views)",
                truth.views.len()
            )
        })?;
        Ok(ViewScene {
            body: MovedShape::new(truth.shape.clone(), truth.motion_field()),
            props: truth.props.clone(),
            phantom_to_world: isometry_from_matrix(&truth.phantom_to_world),
            left: &truth.rig.left,
            right: &truth.rig.right,
            left_to_right: isometry_from_matrix(&truth.rig.left_to_right),
            left_to_world: isometry_from_matrix(&v.left_camera_to_world),
        })
    }

    /// The first surface along the ray from `origin` along unit `dir` (world,
    /// mm): its distance (mm) and label, exactly as the renderer's
    /// `PhantomScene::radiance` decides what a ray sees.
    pub fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<(f64, SceneLabel)> {
        let table_t = if dir.z < 0.0 {
            -origin.z / dir.z
        } else {
            f64::INFINITY
        };
        let (o, d) = (
            self.phantom_to_world.inverse_transform_point(origin),
            self.phantom_to_world.inverse_transform_vector(dir),
        );
        let body = self.body.intersect(&o, &d, 1e-6).filter(|h| h.t < table_t);
        if let Some((_, t, _)) = first_prop(&self.props, origin, dir, 1e-6)
            .filter(|h| h.1 < table_t && body.is_none_or(|b| h.1 < b.t))
        {
            return Some((t, SceneLabel::Prop));
        }
        if let Some(hit) = body {
            let label = match hit.surface {
                Surface::Skin => SceneLabel::Skin,
                Surface::MarkerFace(_) => SceneLabel::MarkerFace,
                Surface::MarkerSide => SceneLabel::MarkerSide,
            };
            return Some((hit.t, label));
        }
        table_t.is_finite().then_some((table_t, SceneLabel::Table))
    }
}

/// The true disparity map and what each pixel sees, on the left rectified image.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueDisparity {
    /// Width of the rectified images, px.
    pub width: usize,
    /// Height of the rectified images, px.
    pub height: usize,
    /// Row-major `u - x_r`, px; NaN where unknown (nothing hit, outside either
    /// original image, or hidden from the right camera).
    pub disparity_px: Vec<f32>,
    /// Row-major [`SceneLabel`] of each left rectified pixel.
    pub labels: Vec<u8>,
    /// Row-major 255 where the pixel sees skin and its disparity is known, else 0.
    pub mask: Vec<u8>,
    /// Pixels with a known disparity.
    pub known: usize,
    /// Pixels in `mask`.
    pub skin: usize,
    /// Mean `|v - y_r|` over pixels with a known disparity, px (NaN if none).
    pub row_error_px: f64,
    /// Smallest disparity over `mask`, px (NaN if none).
    pub min_px: f64,
    /// Largest disparity over `mask`, px (NaN if none).
    pub max_px: f64,
}

/// Beyond this distance short of the target point (mm), a hit from the right
/// camera hides it. Far above the ray caster's rounding (~1e-9 mm), far below
/// any structure of the phantom.
const OCCLUSION_TOLERANCE_MM: f64 = 1e-3;

/// Whether pixel `p` lies where `calib.remap` samples an image of `camera`.
fn inside_image(camera: &CameraModel, p: &Point2<f64>) -> bool {
    p.x >= 0.0
        && p.y >= 0.0
        && p.x <= (camera.width as f64 - 1.0)
        && p.y <= (camera.height as f64 - 1.0)
}

/// The true disparity of `scene` in the rectified frame of `rect`, which the
/// images were rectified with through the *estimated* cameras `est_left` and
/// `est_right` (see the module docs). Errors name the input that does not fit.
pub fn true_disparity(
    scene: &ViewScene,
    est_left: &CameraModel,
    est_right: &CameraModel,
    rect: &StereoRectification,
) -> Result<TrueDisparity, String> {
    for (side, est, real) in [
        ("left", est_left, scene.left),
        ("right", est_right, scene.right),
    ] {
        if (est.width, est.height) != (real.width, real.height) {
            return Err(format!(
                "rig: the {side} camera is {} x {} px but the phantom's images are {} x {}",
                est.width, est.height, real.width, real.height
            ));
        }
    }
    let (w, h) = rect.size;
    let (f, cx, cy) = (rect.p1[(0, 0)], rect.p1[(0, 2)], rect.p1[(1, 2)]);
    if w == 0 || h == 0 || !(f.is_finite() && f.abs() > 1e-9 && cx.is_finite() && cy.is_finite()) {
        return Err(format!(
            "rectification: {w} x {h} px with focal length {f} px is not usable"
        ));
    }
    let back = rect.r1.transpose();
    let right_centre = scene.left_to_world * (scene.left_to_right.inverse() * Point3::origin());
    let left_centre = scene.left_to_world * Point3::origin();
    let world_to_right = scene.left_to_right * scene.left_to_world.inverse();

    // One pixel: (disparity, label, row error) with NaNs where unknown.
    let pixel = |u: usize, v: usize| -> (f32, SceneLabel, f64) {
        let unknown = |label| (f32::NAN, label, f64::NAN);
        let ray = back * Vector3::new((u as f64 - cx) / f, (v as f64 - cy) / f, 1.0);
        let Some(p) = est_left.project(&Point3::from(ray)) else {
            return unknown(SceneLabel::Nothing);
        };
        if !inside_image(est_left, &p) {
            return unknown(SceneLabel::Nothing);
        }
        let dir = scene.left_to_world.rotation * scene.left.pixel_ray(p.x, p.y);
        let Some((t, label)) = scene.cast(&left_centre, &dir) else {
            return unknown(SceneLabel::Nothing);
        };
        let x = left_centre + dir * t;
        let Some(q) = scene.right.project(&(world_to_right * x)) else {
            return unknown(label);
        };
        if !inside_image(scene.right, &q) {
            return unknown(label);
        }
        let to_x = x - right_centre;
        let distance = to_x.norm();
        let hidden = scene
            .cast(&right_centre, &(to_x / distance))
            .is_some_and(|(t, _)| t < distance - OCCLUSION_TOLERANCE_MM);
        if hidden {
            return unknown(label);
        }
        let r = StereoRectification::rectify_point(est_right, &rect.r2, &rect.p2, &q);
        ((u as f64 - r.x) as f32, label, (v as f64 - r.y).abs())
    };
    let rows: Vec<Vec<(f32, SceneLabel, f64)>> = (0..h)
        .into_par_iter()
        .map(|v| (0..w).map(|u| pixel(u, v)).collect())
        .collect();

    let mut out = TrueDisparity {
        width: w,
        height: h,
        disparity_px: Vec::with_capacity(w * h),
        labels: Vec::with_capacity(w * h),
        mask: Vec::with_capacity(w * h),
        known: 0,
        skin: 0,
        row_error_px: f64::NAN,
        min_px: f64::NAN,
        max_px: f64::NAN,
    };
    let mut row_error_sum = 0.0;
    for (d, label, row_error) in rows.into_iter().flatten() {
        let known = d.is_finite();
        let skin = known && label == SceneLabel::Skin;
        if known {
            out.known += 1;
            row_error_sum += row_error;
        }
        if skin {
            out.skin += 1;
            out.min_px = out.min_px.min(d as f64);
            out.max_px = out.max_px.max(d as f64);
        }
        out.disparity_px.push(d);
        out.labels.push(label as u8);
        out.mask.push(if skin { 255 } else { 0 });
    }
    if out.known > 0 {
        out.row_error_px = row_error_sum / out.known as f64;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{rectify, remap};
    use crate::phantom::lighting::Lighting;
    use crate::phantom::motion::MotionField;
    use crate::phantom::render::{Renderer, TextureSamples, sharp_params};
    use crate::phantom::rig::{Rig, view_poses};
    use crate::phantom::scenes::PhantomScene;
    use crate::phantom::shape::{PhantomShape, ShapeParams};
    use rand::SeedableRng;

    fn phantom() -> (PhantomShape, Isometry3<f64>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let shape = PhantomShape::build(&ShapeParams::default(), &mut rng).unwrap();
        let to_world = Isometry3::new(Vector3::new(15.0, -10.0, 0.0), Vector3::z() * 0.35);
        (shape, to_world)
    }

    /// A view like the generator's: the rig aimed at the phantom from above.
    fn view_pose(rig: &Rig, to_world: &Isometry3<f64>, index: usize) -> Isometry3<f64> {
        let target = to_world * Point3::new(0.0, 0.0, 24.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        view_poses(rig, &target, 3, &mut rng)[index]
    }

    /// Bilinear sample of a grey u8 image at (x, y); `None` outside.
    fn sample(img: &[u8], w: usize, h: usize, x: f64, y: f64) -> Option<f64> {
        if x < 0.0 || y < 0.0 || x > (w - 1) as f64 || y > (h - 1) as f64 {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (tx, ty) = (x - x0 as f64, y - y0 as f64);
        let s = |x: usize, y: usize| img[y * w + x] as f64;
        Some(
            (s(x0, y0) * (1.0 - tx) + s(x1, y0) * tx) * (1.0 - ty)
                + (s(x0, y1) * (1.0 - tx) + s(x1, y1) * tx) * ty,
        )
    }

    /// View 1 of the test phantom rendered by both true cameras (grey, no noise,
    /// no blur, one sample per pixel).
    struct RenderedPair {
        rig: Rig,
        shape: PhantomShape,
        to_world: Isometry3<f64>,
        left_to_world: Isometry3<f64>,
        left: Vec<u8>,
        right: Vec<u8>,
    }

    impl RenderedPair {
        fn new() -> Self {
            let rig = Rig::paper_rig();
            let (shape, to_world) = phantom();
            let left_to_world = view_pose(&rig, &to_world, 1);
            let render = PhantomScene {
                body: MovedShape::new(shape.clone(), MotionField::still()),
                phantom_to_world: to_world,
                lighting: Lighting::ideal(Vector3::new(0.45, -0.35, 0.82).normalize()),
                skin_texture: 0.6,
                props: Vec::new(),
                seed: 11,
            };
            let params = sharp_params(1, TextureSamples::Grid(1));
            let grey = |rgb: Vec<u8>| -> Vec<u8> { rgb.chunks(3).map(|c| c[1]).collect() };
            let left = grey(Renderer::new(&rig.left).render(&left_to_world, &render, &params));
            let right_to_world = rig.right_pose(&left_to_world);
            let right = grey(Renderer::new(&rig.right).render(&right_to_world, &render, &params));
            RenderedPair {
                rig,
                shape,
                to_world,
                left_to_world,
                left,
                right,
            }
        }

        fn scene(&self) -> ViewScene<'_> {
            ViewScene {
                body: MovedShape::new(self.shape.clone(), MotionField::still()),
                props: Vec::new(),
                phantom_to_world: self.to_world,
                left: &self.rig.left,
                right: &self.rig.right,
                left_to_right: self.rig.left_to_right,
                left_to_world: self.left_to_world,
            }
        }

        /// Both images rectified through `left`, `right` and `rect`.
        fn rectified(
            &self,
            left: &CameraModel,
            right: &CameraModel,
            rect: &StereoRectification,
        ) -> (Vec<u8>, Vec<u8>) {
            (
                remap(&self.left, 1, left, &rect.r1, &rect.p1, rect.size),
                remap(&self.right, 1, right, &rect.r2, &rect.p2, rect.size),
            )
        }
    }

    /// Mean |L(u, v) - R(u - d - shift, v)| over the skin mask of `truth`.
    fn mean_abs_diff(truth: &TrueDisparity, left: &[u8], right: &[u8], shift: f64) -> f64 {
        let (w, h) = (truth.width, truth.height);
        let (mut sum, mut n) = (0.0, 0usize);
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                if truth.mask[i] == 0 {
                    continue;
                }
                let x = u as f64 - truth.disparity_px[i] as f64 - shift;
                if let Some(r) = sample(right, w, h, x, v as f64) {
                    sum += (r - left[i] as f64).abs();
                    n += 1;
                }
            }
        }
        sum / n as f64
    }

    #[test]
    fn rectified_renders_agree_at_the_true_disparity() {
        let pair = RenderedPair::new();
        let (rig, scene) = (&pair.rig, pair.scene());
        let left_to_world = pair.left_to_world;
        let rect = rectify(&rig.left, &rig.right, &rig.left_to_right, 0.0);
        let (w, h) = rect.size;
        let (left_rect, right_rect) = pair.rectified(&rig.left, &rig.right, &rect);
        let truth = true_disparity(&scene, &rig.left, &rig.right, &rect).unwrap();
        assert!(truth.skin > 20_000, "skin pixels {}", truth.skin);
        assert!(
            truth.row_error_px < 1e-6,
            "row error {}",
            truth.row_error_px
        );
        // d = f b / Z, and the skin is 400-600 mm from the cameras.
        let fb = -rect.p2[(0, 3)];
        assert!(
            truth.min_px > fb / 600.0 && truth.max_px < fb / 400.0,
            "{} .. {} px, f b = {fb}",
            truth.min_px,
            truth.max_px
        );
        let at_truth = mean_abs_diff(&truth, &left_rect, &right_rect, 0.0);
        let off_by_one = mean_abs_diff(&truth, &left_rect, &right_rect, 1.0);
        assert!(
            at_truth * 2.0 < off_by_one,
            "mean |L - R| {at_truth} at the true disparity, {off_by_one} one px off"
        );

        // By hand on a few skin pixels: d = -P2[0][3] / Z of the hit point in the
        // left rectified frame.
        let mut checked = 0;
        for i in (0..w * h).step_by(997).filter(|&i| truth.mask[i] != 0) {
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let f = rect.p1[(0, 0)];
            let ray_rect = Vector3::new((u - rect.p1[(0, 2)]) / f, (v - rect.p1[(1, 2)]) / f, 1.0);
            let ray_left = (rect.r1.transpose() * ray_rect).normalize();
            let origin = left_to_world * Point3::origin();
            let (t, label) = scene
                .cast(&origin, &(left_to_world.rotation * ray_left))
                .unwrap();
            assert_eq!(label, SceneLabel::Skin);
            let z_rect = (rect.r1 * (ray_left * t)).z;
            let expected = -rect.p2[(0, 3)] / z_rect;
            let d = truth.disparity_px[i] as f64;
            assert!((d - expected).abs() < 1e-3, "({u}, {v}): {d} vs {expected}");
            checked += 1;
        }
        assert!(checked > 10, "{checked}");
        // Labels: skin, a marker face and the table all appear.
        for label in [SceneLabel::Skin, SceneLabel::MarkerFace, SceneLabel::Table] {
            assert!(truth.labels.contains(&(label as u8)), "{label:?}");
        }
    }

    #[test]
    fn the_truth_includes_the_calibration_error() {
        // The right camera calibrated with its principal point 2 px off: the
        // images are rectified with that error, and the truth must follow it.
        let pair = RenderedPair::new();
        let (rig, scene) = (&pair.rig, pair.scene());
        let est_right = CameraModel {
            cx: rig.right.cx + 2.0,
            ..rig.right.clone()
        };
        let rect = rectify(&rig.left, &est_right, &rig.left_to_right, 0.0);
        let (left_rect, right_rect) = pair.rectified(&rig.left, &est_right, &rect);
        let truth = true_disparity(&scene, &rig.left, &est_right, &rect).unwrap();
        let naive = true_disparity(&scene, &rig.left, &rig.right, &rect).unwrap();
        // A horizontal error of the right camera moves x_r by about 2 px times
        // the rectified-to-original focal ratio (within 10 %: the ratio grows
        // off-axis and with the verging rotation); rows barely move.
        let scale = rect.p1[(0, 0)] / rig.right.fx;
        let (mut shift, mut n) = (0.0, 0);
        for (a, b) in truth.disparity_px.iter().zip(&naive.disparity_px) {
            if a.is_finite() && b.is_finite() {
                shift += (a - b) as f64;
                n += 1;
            }
        }
        let shift = shift / n as f64;
        assert!(
            (shift - 2.0 * scale).abs() < 0.1 * scale,
            "{shift} vs {scale}"
        );
        assert!(truth.row_error_px < 0.1, "{}", truth.row_error_px);
        let with_error = mean_abs_diff(&truth, &left_rect, &right_rect, 0.0);
        let without = mean_abs_diff(&naive, &left_rect, &right_rect, 0.0);
        assert!(
            with_error * 2.0 < without,
            "mean |L - R| {with_error} with the calibration error, {without} without"
        );
    }

    #[test]
    fn pixels_seeing_nothing_or_hidden_have_no_disparity() {
        let rig = Rig::paper_rig();
        let (shape, to_world) = phantom();
        // The rig level with the table, 60 mm above it, looking along world +y at
        // the phantom: the top rows see only sky.
        let eye = Point3::new(15.0, -520.0, 60.0);
        let left_to_world =
            crate::camera::look_at(&eye, &Point3::new(15.0, 0.0, 60.0), &Vector3::z());
        let scene = ViewScene {
            body: MovedShape::new(shape.clone(), MotionField::still()),
            props: Vec::new(),
            phantom_to_world: to_world,
            left: &rig.left,
            right: &rig.right,
            left_to_right: rig.left_to_right,
            left_to_world,
        };
        let rect = rectify(&rig.left, &rig.right, &rig.left_to_right, 0.0);
        let truth = true_disparity(&scene, &rig.left, &rig.right, &rect).unwrap();
        let w = truth.width;
        let top = w / 2;
        assert_eq!(truth.labels[top], SceneLabel::Nothing as u8);
        assert!(truth.disparity_px[top].is_nan());
        assert_eq!(truth.mask[top], 0);
        // Lower rows see the table in front of the phantom: known.
        let bottom = (truth.height - 2) * w + w / 2;
        assert_eq!(truth.labels[bottom], SceneLabel::Table as u8);
        assert!(truth.disparity_px[bottom].is_finite());
        // Table points just left of the dome's silhouette in the left image are
        // hidden from the right camera (55 mm to the right) by the dome.
        let hidden = (0..w * truth.height)
            .filter(|&i| truth.labels[i] == SceneLabel::Table as u8)
            .filter(|&i| truth.disparity_px[i].is_nan())
            .count();
        assert!(hidden > 100, "{hidden}");
    }

    #[test]
    fn cameras_of_another_size_are_an_error() {
        let rig = Rig::paper_rig();
        let (shape, to_world) = phantom();
        let scene = ViewScene {
            body: MovedShape::new(shape.clone(), MotionField::still()),
            props: Vec::new(),
            phantom_to_world: to_world,
            left: &rig.left,
            right: &rig.right,
            left_to_right: rig.left_to_right,
            left_to_world: view_pose(&rig, &to_world, 0),
        };
        let rect = rectify(&rig.left, &rig.right, &rig.left_to_right, 0.0);
        let small = CameraModel {
            width: 640,
            ..rig.right.clone()
        };
        let err = true_disparity(&scene, &rig.left, &small, &rect).unwrap_err();
        assert!(err.contains("right camera is 640 x 600"), "{err}");
        let mut bad = rect.clone();
        bad.size = (0, 600);
        let err = true_disparity(&scene, &rig.left, &rig.right, &bad).unwrap_err();
        assert!(err.contains("rectification"), "{err}");
    }
}
