//! Single-camera calibration: Zhang's closed form for a start, then
//! Levenberg-Marquardt over intrinsics, the free distortion coefficients and
//! every view's pose, minimising the reprojection error in pixels.

use super::homography::homography;
use super::lm::{LeastSquares, levenberg_marquardt};
use super::normal_equations::BlockNormal;
use super::reprojection::{Pose, corner_residual};
use super::uncertainty::{Spread, intrinsics_sd};
use super::zhang::{intrinsics_from_homographies, pose_from_homography};
use crate::camera::CameraModel;
use nalgebra::{
    DVector, Isometry3, Matrix3, Point2, Rotation3, Translation3, UnitQuaternion, Vector3,
};

/// One view of the board: its corners on the board (mm, z = 0) and where they
/// were found in the image (px).
#[derive(Debug, Clone, PartialEq)]
pub struct BoardView {
    /// Corner positions on the board, mm.
    pub board_mm: Vec<Point2<f64>>,
    /// Corner positions in the image, px.
    pub image_px: Vec<Point2<f64>>,
}

/// The calibration solvers' iteration limit (they take 10 to 20 from Zhang's
/// start).
pub(crate) const MAX_ITERATIONS: usize = 200;

/// The calibration solvers' step tolerance (see [`levenberg_marquardt`]):
/// below it, steps are watched for the rounding floor.
pub(crate) const STEP_TOLERANCE: f64 = 1e-9;

/// Where inner corner `k` of a board with `cols` inner corners per row lies
/// on the board (mm, z = 0): the origin at the first corner, x along a row,
/// in the order [`find_chessboard`](super::find_chessboard) returns them.
pub fn board_corner_mm(k: usize, cols: usize, square_mm: f64) -> Point2<f64> {
    Point2::new((k % cols) as f64 * square_mm, (k / cols) as f64 * square_mm)
}

/// Names of the distortion coefficients, in OpenCV order.
pub const DISTORTION_NAMES: [&str; 5] = ["k1", "k2", "p1", "p2", "k3"];

/// The result of a calibration.
#[derive(Debug, Clone)]
pub struct CameraCalibration {
    /// The camera.
    pub camera: CameraModel,
    /// Board -> camera pose of each view.
    pub poses: Vec<Isometry3<f64>>,
    /// Root mean square reprojection error over all corners, px.
    pub rms_px: f64,
    /// RMS reprojection error of each view, px.
    pub view_rms_px: Vec<f64>,
    /// LM iterations.
    pub iterations: usize,
    /// Whether LM reached the minimum (rather than its iteration limit).
    pub converged: bool,
    /// The estimated intrinsics' spread, in `estimated`'s order; `None` when
    /// J^T J is singular at the optimum.
    pub spread: Option<Spread>,
    /// Solver-order indices (fx, fy, cx, cy, k1, k2, p1, p2, k3) of the
    /// estimated intrinsics.
    pub estimated: Vec<usize>,
}

impl CameraCalibration {
    /// Standard deviation of each intrinsic in solver order (fx, fy, cx, cy
    /// in px, then k1, k2, p1, p2, k3), 0 for one held fixed and NaN without
    /// a spread.
    pub fn intrinsics_sd(&self) -> [f64; 9] {
        intrinsics_sd(self.spread.as_ref(), &self.estimated, 0)
    }
}

/// Intrinsic parameters in solver order: fx, fy, cx, cy, k1, k2, p1, p2, k3.
pub(crate) fn intrinsic_vector(c: &CameraModel) -> [f64; 9] {
    let d = c.distortion;
    [c.fx, c.fy, c.cx, c.cy, d[0], d[1], d[2], d[3], d[4]]
}

pub(crate) fn camera_from(v: &[f64; 9], width: usize, height: usize) -> CameraModel {
    CameraModel {
        width,
        height,
        fx: v[0],
        fy: v[1],
        cx: v[2],
        cy: v[3],
        distortion: [v[4], v[5], v[6], v[7], v[8]],
    }
}

pub(crate) fn pose_vector(p: &Isometry3<f64>) -> [f64; 6] {
    let r = p.rotation.scaled_axis();
    let t = p.translation.vector;
    [r.x, r.y, r.z, t.x, t.y, t.z]
}

pub(crate) fn pose_from(v: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(v[3], v[4], v[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(v[0], v[1], v[2])),
    )
}

/// The board point of a corner (mm, z = 0) as a 3-vector.
pub(crate) fn board_point(b: &Point2<f64>) -> Vector3<f64> {
    Vector3::new(b.x, b.y, 0.0)
}

/// Reprojection residuals (px, u then v per corner) of one view seen by a
/// camera (`intrinsics` in solver order); `to_camera` maps a board point (mm)
/// into the camera frame.
pub(crate) fn view_residuals(
    intrinsics: &[f64; 9],
    to_camera: impl Fn(&Vector3<f64>) -> Vector3<f64>,
    view: &BoardView,
    out: &mut Vec<f64>,
) {
    for (b, m) in view.board_mm.iter().zip(&view.image_px) {
        out.extend(corner_residual(intrinsics, &to_camera(&board_point(b)), m).r);
    }
}

/// The solver-order indices of the intrinsics estimated: fx, fy, cx, cy and
/// the free distortion coefficients.
pub(crate) fn free_intrinsics(free_distortion: [bool; 5]) -> Vec<usize> {
    (0..4)
        .chain((0..5).filter(|&d| free_distortion[d]).map(|d| d + 4))
        .collect()
}

/// The intrinsics in solver order with the free ones taken from `x` (the
/// first `free.len()` values from `offset`).
pub(crate) fn intrinsics_with(
    fixed: &[f64; 9],
    free: &[usize],
    x: &DVector<f64>,
    offset: usize,
) -> [f64; 9] {
    let mut v = *fixed;
    for (k, &i) in free.iter().enumerate() {
        v[i] = x[offset + k];
    }
    v
}

/// Closed-form start: Zhang's K and poses, zero distortion.
pub fn initial_guess(
    views: &[BoardView],
    width: usize,
    height: usize,
) -> Result<(CameraModel, Vec<Isometry3<f64>>), String> {
    if views.len() < 3 {
        return Err(format!(
            "{} usable views; calibration needs at least 3",
            views.len()
        ));
    }
    let homographies: Vec<Matrix3<f64>> = views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            homography(&v.board_mm, &v.image_px)
                .ok_or_else(|| format!("view {i}: corners are degenerate (collinear?)"))
        })
        .collect::<Result<_, _>>()?;
    let k = intrinsics_from_homographies(&homographies)
        .ok_or("the views do not determine the intrinsics (boards parallel to each other, or too few orientations)")?;
    let camera = CameraModel {
        width,
        height,
        fx: k[(0, 0)],
        fy: k[(1, 1)],
        cx: k[(0, 2)],
        cy: k[(1, 2)],
        distortion: [0.0; 5],
    };
    let poses = homographies
        .iter()
        .enumerate()
        .map(|(i, h)| {
            let (r, t) = pose_from_homography(&k, h).ok_or_else(|| format!("view {i}: no pose"))?;
            Ok(Isometry3::from_parts(
                Translation3::from(t),
                UnitQuaternion::from_rotation_matrix(&r),
            ))
        })
        .collect::<Result<Vec<_>, String>>()?;
    Ok((camera, poses))
}

struct MonoProblem<'a> {
    views: &'a [BoardView],
    free: Vec<usize>,
    fixed: [f64; 9],
}

impl MonoProblem<'_> {
    fn intrinsics(&self, x: &DVector<f64>) -> [f64; 9] {
        intrinsics_with(&self.fixed, &self.free, x, 0)
    }

    fn pose(&self, x: &DVector<f64>, view: usize) -> Pose {
        let o = self.free.len() + 6 * view;
        Pose::new(&x.as_slice()[o..o + 6])
    }

    fn view_block(&self, x: &DVector<f64>, view: usize) -> Vec<f64> {
        let pose = self.pose(x, view);
        let mut r = Vec::new();
        view_residuals(
            &self.intrinsics(x),
            |b| pose.apply(b),
            &self.views[view],
            &mut r,
        );
        r
    }
}

impl LeastSquares for MonoProblem<'_> {
    type Normal = BlockNormal;

    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_vec(
            (0..self.views.len())
                .flat_map(|v| self.view_block(x, v))
                .collect(),
        )
    }

    fn normal_equations(&self, x: &DVector<f64>, _: &DVector<f64>) -> BlockNormal {
        let intrinsics = self.intrinsics(x);
        let mut normal = BlockNormal::new(self.free.len(), self.views.len());
        let mut d_shared = vec![0.0; self.free.len()];
        for (v, view) in self.views.iter().enumerate() {
            let pose = self.pose(x, v);
            for (b, m) in view.board_mm.iter().zip(&view.image_px) {
                let rotated = pose.rotation * board_point(b);
                let c = corner_residual(&intrinsics, &(rotated + pose.translation), m);
                let d_rotation = c.d_point * pose.d_rotation(&rotated);
                for k in 0..2 {
                    for (d, &i) in d_shared.iter_mut().zip(&self.free) {
                        *d = c.d_intrinsics[(k, i)];
                    }
                    let d_pose = pose_row(&d_rotation, &c.d_point, k);
                    normal.add(v, &d_shared, &d_pose, c.r[k]);
                }
            }
        }
        normal
    }
}

/// Row `k` of d r / d(rotation vector, translation) from its two parts.
pub(crate) fn pose_row(
    d_rotation: &nalgebra::Matrix2x3<f64>,
    d_translation: &nalgebra::Matrix2x3<f64>,
    k: usize,
) -> nalgebra::Vector6<f64> {
    nalgebra::Vector6::new(
        d_rotation[(k, 0)],
        d_rotation[(k, 1)],
        d_rotation[(k, 2)],
        d_translation[(k, 0)],
        d_translation[(k, 1)],
        d_translation[(k, 2)],
    )
}

/// Calibrates one camera (`width x height` px) from board views: Zhang's
/// closed form, refined by Levenberg-Marquardt. `free_distortion` says which
/// of k1, k2, p1, p2, k3 are estimated (the others stay 0).
///
/// # Examples
///
/// Three views of a 9 x 6 board (25 mm squares), projected exactly by a
/// camera without distortion: the calibration finds its focal length again.
///
/// ```
/// use fusegraph_nodes::calib::{BoardView, calibrate_camera};
/// use fusegraph_nodes::camera::CameraModel;
/// use nalgebra::{Isometry3, Point2, Point3, Vector3};
///
/// let truth = CameraModel {
///     width: 800,
///     height: 600,
///     fx: 1300.0,
///     fy: 1300.0,
///     cx: 400.0,
///     cy: 300.0,
///     distortion: [0.0; 5],
/// };
/// let board: Vec<Point2<f64>> = (0..6)
///     .flat_map(|r| (0..9).map(move |c| Point2::new(c as f64 * 25.0, r as f64 * 25.0)))
///     .collect();
/// // Board -> camera poses (mm): tilted three ways, about 0.55 m away.
/// let views: Vec<BoardView> = [[0.3, -0.2, 0.1], [-0.25, 0.35, -0.2], [0.1, 0.4, 0.3]]
///     .into_iter()
///     .map(|rotation| {
///         let pose = Isometry3::new(Vector3::new(-100.0, -60.0, 550.0), Vector3::from(rotation));
///         BoardView {
///             board_mm: board.clone(),
///             image_px: board
///                 .iter()
///                 .map(|b| truth.project(&(pose * Point3::new(b.x, b.y, 0.0))).unwrap())
///                 .collect(),
///         }
///     })
///     .collect();
/// let c = calibrate_camera(&views, 800, 600, [false; 5]).unwrap();
/// assert!(c.rms_px < 1e-6, "{}", c.rms_px);
/// assert!((c.camera.fx - 1300.0).abs() < 1e-3, "{}", c.camera.fx);
/// ```
pub fn calibrate_camera(
    views: &[BoardView],
    width: usize,
    height: usize,
    free_distortion: [bool; 5],
) -> Result<CameraCalibration, String> {
    for (i, v) in views.iter().enumerate() {
        if v.board_mm.len() != v.image_px.len() || v.board_mm.len() < 4 {
            return Err(format!(
                "view {i}: {} board points for {} image points (need 4+ pairs)",
                v.board_mm.len(),
                v.image_px.len()
            ));
        }
    }
    let (start, poses) = initial_guess(views, width, height)?;
    let fixed = intrinsic_vector(&start);
    let free = free_intrinsics(free_distortion);
    let problem = MonoProblem {
        views,
        free: free.clone(),
        fixed,
    };
    let mut x0: Vec<f64> = free.iter().map(|&i| fixed[i]).collect();
    poses.iter().for_each(|p| x0.extend(pose_vector(p)));
    let report = levenberg_marquardt(
        &problem,
        DVector::from_vec(x0),
        MAX_ITERATIONS,
        STEP_TOLERANCE,
    );
    let camera = camera_from(&problem.intrinsics(&report.x), width, height);
    let poses: Vec<Isometry3<f64>> = (0..views.len())
        .map(|v| pose_from(&report.x.as_slice()[free.len() + 6 * v..free.len() + 6 * v + 6]))
        .collect();
    let view_rms_px: Vec<f64> = (0..views.len())
        .map(|v| {
            let r = problem.view_block(&report.x, v);
            (r.iter().map(|e| e * e).sum::<f64>() / (r.len() / 2) as f64).sqrt()
        })
        .collect();
    let corners: usize = views.iter().map(|v| v.board_mm.len()).sum();
    let spread = Spread::at_optimum(&problem, &report);
    Ok(CameraCalibration {
        camera,
        poses,
        rms_px: (report.cost / corners as f64).sqrt(),
        view_rms_px,
        iterations: report.iterations,
        converged: report.converged,
        spread,
        estimated: free,
    })
}

/// Rotation error between two rotations, deg.
pub fn rotation_error_deg(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    // Via quaternions: the trace formula's acos turns NaN for tiny angles.
    UnitQuaternion::from_rotation_matrix(a)
        .angle_to(&UnitQuaternion::from_rotation_matrix(b))
        .to_degrees()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn true_camera() -> CameraModel {
        CameraModel {
            width: 800,
            height: 600,
            fx: 1333.3,
            fy: 1334.4,
            cx: 403.2,
            cy: 297.6,
            distortion: [-0.118, 0.152, 0.00061, -0.00042, 0.0],
        }
    }

    pub(crate) fn board() -> Vec<Point2<f64>> {
        (0..6)
            .flat_map(|r| (0..9).map(move |c| Point2::new(c as f64 * 25.0, r as f64 * 25.0)))
            .collect()
    }

    pub(crate) fn true_poses() -> Vec<Isometry3<f64>> {
        [
            ([0.3, -0.2, 0.1], [-100.0, -60.0, 520.0]),
            ([-0.25, 0.35, -0.2], [-90.0, -80.0, 600.0]),
            ([0.1, 0.4, 0.3], [-120.0, -50.0, 480.0]),
            ([-0.4, -0.1, 0.0], [-80.0, -70.0, 650.0]),
            ([0.05, 0.05, 1.2], [20.0, -90.0, 560.0]),
        ]
        .iter()
        .map(|(r, t)| pose_from(&[r[0], r[1], r[2], t[0], t[1], t[2]]))
        .collect()
    }

    pub(crate) fn views_of(camera: &CameraModel, poses: &[Isometry3<f64>]) -> Vec<BoardView> {
        poses
            .iter()
            .map(|pose| BoardView {
                board_mm: board(),
                image_px: board()
                    .iter()
                    .map(|b| {
                        camera
                            .project(&(pose * nalgebra::Point3::new(b.x, b.y, 0.0)))
                            .unwrap()
                    })
                    .collect(),
            })
            .collect()
    }

    /// `views` with every corner moved by up to `noise_px` in u and v, the
    /// same for a given `seed`.
    pub(crate) fn with_noise(
        mut views: Vec<BoardView>,
        noise_px: f64,
        seed: u64,
    ) -> Vec<BoardView> {
        let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ seed;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2.0 * noise_px
        };
        for v in &mut views {
            for p in &mut v.image_px {
                *p += nalgebra::Vector2::new(next(), next());
            }
        }
        views
    }

    #[test]
    fn its_normal_equations_are_those_of_central_differences() {
        let views = with_noise(views_of(&true_camera(), &true_poses()), 0.2, 3);
        let c = calibrate_camera(&views, 800, 600, [true; 5]).unwrap();
        let problem = MonoProblem {
            views: &views,
            free: free_intrinsics([true; 5]),
            fixed: intrinsic_vector(&c.camera),
        };
        let mut x: Vec<f64> = intrinsic_vector(&c.camera).to_vec();
        c.poses.iter().for_each(|p| x.extend(pose_vector(p)));
        let mut away = DVector::from_vec(x);
        for (i, v) in away.iter_mut().enumerate() {
            *v += 1e-3 * (i as f64).cos() * v.abs().max(1.0);
        }
        crate::calib::lm::assert_normal_equations_match(&problem, &away, 1e-6);
    }

    #[test]
    fn recovers_distortion_and_intrinsics_from_exact_corners() {
        let truth = true_camera();
        let views = views_of(&truth, &true_poses());
        let c = calibrate_camera(&views, 800, 600, [true, true, true, true, false]).unwrap();
        assert!(c.rms_px < 1e-8, "{}", c.rms_px);
        assert!(
            (c.camera.fx - truth.fx).abs() < 1e-6 && (c.camera.cy - truth.cy).abs() < 1e-6,
            "{:?}",
            c.camera
        );
        for d in 0..4 {
            assert!(
                (c.camera.distortion[d] - truth.distortion[d]).abs() < 1e-8,
                "{:?}",
                c.camera.distortion
            );
        }
        let r = rotation_error_deg(
            &c.poses[2].rotation.to_rotation_matrix(),
            &true_poses()[2].rotation.to_rotation_matrix(),
        );
        assert!(r < 1e-5, "{r} deg");
    }

    #[test]
    fn too_few_or_degenerate_views_are_errors() {
        let views = views_of(&true_camera(), &true_poses());
        assert!(
            calibrate_camera(&views[..2], 800, 600, [true; 5])
                .unwrap_err()
                .contains("at least 3")
        );
        let same = vec![views[0].clone(), views[0].clone(), views[0].clone()];
        assert!(calibrate_camera(&same, 800, 600, [true; 5]).is_err());
    }

    /// Mean and sample standard deviation.
    pub(crate) fn mean_and_sd(values: &[f64]) -> (f64, f64) {
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, var.sqrt())
    }

    /// Asserts that an observed spread is within 25 % of the predicted one
    /// (200 draws estimate a standard deviation to about 5 %).
    pub(crate) fn assert_spread(name: &str, predicted: f64, observed: f64) {
        assert!(
            observed > 0.8 * predicted && observed < 1.25 * predicted,
            "{name}: predicted sd {predicted:.4e}, observed over the draws {observed:.4e}"
        );
    }

    #[test]
    fn the_intrinsics_spread_matches_a_monte_carlo_of_the_corners_noise() {
        let truth = true_camera();
        let exact = views_of(&truth, &true_poses());
        let free = [true, true, true, true, false];
        let draws: Vec<CameraCalibration> = (0..200)
            .map(|seed| {
                calibrate_camera(&with_noise(exact.clone(), 0.2, seed), 800, 600, free).unwrap()
            })
            .collect();
        // fx, fy, cx, cy, k1, k2 in solver order.
        for (i, name) in ["fx", "fy", "cx", "cy", "k1", "k2"].iter().enumerate() {
            let predicted =
                draws.iter().map(|c| c.intrinsics_sd()[i]).sum::<f64>() / draws.len() as f64;
            let values: Vec<f64> = draws
                .iter()
                .map(|c| intrinsic_vector(&c.camera)[i])
                .collect();
            assert_spread(name, predicted, mean_and_sd(&values).1);
        }
        // k3 was held: no spread.
        assert_eq!(draws[0].intrinsics_sd()[8], 0.0);
    }
}
