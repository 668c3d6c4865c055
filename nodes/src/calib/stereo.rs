//! Stereo calibration: both cameras and the rig extrinsics refined together by
//! Levenberg-Marquardt, starting from each camera's own calibration.

use super::camera_calibration::{
    BoardView, CameraCalibration, MAX_ITERATIONS, STEP_TOLERANCE, board_point, calibrate_camera,
    camera_from, free_intrinsics, intrinsic_vector, intrinsics_with, pose_from, pose_row,
    pose_vector, view_residuals,
};
use super::lm::{LeastSquares, levenberg_marquardt};
use super::normal_equations::BlockNormal;
use super::reprojection::{Pose, corner_residual};
use super::uncertainty::{Spread, block3, intrinsics_sd};
use crate::camera::CameraModel;
use nalgebra::{DVector, Isometry3, Matrix3};

/// A calibrated stereo rig.
#[derive(Debug, Clone)]
pub struct StereoCalibration {
    /// Left camera.
    pub left: CameraModel,
    /// Right camera.
    pub right: CameraModel,
    /// Left camera frame -> right camera frame.
    pub left_to_right: Isometry3<f64>,
    /// Board -> left camera pose of each pair.
    pub poses: Vec<Isometry3<f64>>,
    /// RMS reprojection error over both images, px.
    pub rms_px: f64,
    /// RMS of the left and right images, px.
    pub rms_left_right_px: [f64; 2],
    /// RMS of each pair (both images), px.
    pub pair_rms_px: Vec<f64>,
    /// The single-camera calibrations it started from.
    pub mono: [CameraCalibration; 2],
    /// LM iterations of the joint refinement.
    pub iterations: usize,
    /// Whether the joint refinement reached the minimum (rather than its
    /// iteration limit).
    pub converged: bool,
    /// The spread of the left camera's estimated intrinsics, then the
    /// right's (each in `estimated`'s order), then the rig's rotation vector
    /// (rad) and translation (mm); `None` when J^T J is singular at the
    /// optimum.
    pub spread: Option<Spread>,
    /// Solver-order indices of each camera's estimated intrinsics.
    pub estimated: Vec<usize>,
}

/// How well a stereo calibration pins the rig (left -> right).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigSpread {
    /// Covariance of the rotation's small-angle error about the right
    /// camera's x, y, z axes (R' = exp([e]x) R), rad^2.
    pub rotation_rad2: Matrix3<f64>,
    /// Covariance of the translation, mm^2 (right camera frame).
    pub translation_mm2: Matrix3<f64>,
    /// Standard deviation of the baseline |t|, mm.
    pub baseline_sd_mm: f64,
}

impl RigSpread {
    /// Standard deviation of the rotation about each axis, deg.
    pub fn rotation_sd_deg(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.rotation_rad2[(i, i)].max(0.0).sqrt().to_degrees())
    }

    /// Standard deviation of the translation along each axis, mm.
    pub fn translation_sd_mm(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.translation_mm2[(i, i)].max(0.0).sqrt())
    }
}

impl StereoCalibration {
    /// Standard deviation of each intrinsic of camera `side` (0 left, 1
    /// right) in solver order (fx, fy, cx, cy in px, then k1, k2, p1, p2,
    /// k3), 0 for one held fixed and NaN without a spread.
    pub fn intrinsics_sd(&self, side: usize) -> [f64; 9] {
        let offset = side * self.estimated.len();
        intrinsics_sd(self.spread.as_ref(), &self.estimated, offset)
    }

    /// The rig's spread; `None` without one.
    pub fn rig_spread(&self) -> Option<RigSpread> {
        let covariance = self.spread.as_ref()?.covariance()?;
        let o = 2 * self.estimated.len();
        let vector = self.left_to_right.rotation.scaled_axis();
        let rig = Pose::new(&[vector.x, vector.y, vector.z, 0.0, 0.0, 0.0]);
        let rotation_vector = block3(&covariance, o);
        let translation_mm2 = block3(&covariance, o + 3);
        let t = self.left_to_right.translation.vector;
        let along = t / t.norm().max(f64::MIN_POSITIVE);
        Some(RigSpread {
            rotation_rad2: rig.left_jacobian * rotation_vector * rig.left_jacobian.transpose(),
            translation_mm2,
            baseline_sd_mm: (along.transpose() * translation_mm2 * along)[(0, 0)]
                .max(0.0)
                .sqrt(),
        })
    }
}

/// The solver vector: the left camera's free intrinsics, the right's, the rig
/// (left -> right; rotation vector, translation) and each pair's board -> left
/// camera pose.
struct StereoProblem<'a> {
    pairs: &'a [(BoardView, BoardView)],
    free: Vec<usize>,
    fixed: [[f64; 9]; 2],
    size: [(usize, usize); 2],
}

impl StereoProblem<'_> {
    fn intrinsics(&self, x: &DVector<f64>) -> [[f64; 9]; 2] {
        std::array::from_fn(|side| {
            intrinsics_with(&self.fixed[side], &self.free, x, side * self.free.len())
        })
    }

    fn cameras(&self, x: &DVector<f64>) -> [CameraModel; 2] {
        let intrinsics = self.intrinsics(x);
        std::array::from_fn(|side| {
            camera_from(&intrinsics[side], self.size[side].0, self.size[side].1)
        })
    }

    /// The solver vector of both cameras' intrinsics (solver order; the free
    /// ones are taken), the rig and the board -> left camera poses.
    fn vector(
        &self,
        intrinsics: &[[f64; 9]; 2],
        rig: &Isometry3<f64>,
        poses: &[Isometry3<f64>],
    ) -> DVector<f64> {
        let mut x: Vec<f64> = intrinsics
            .iter()
            .flat_map(|side| self.free.iter().map(|&i| side[i]))
            .collect();
        x.extend(pose_vector(rig));
        poses.iter().for_each(|p| x.extend(pose_vector(p)));
        DVector::from_vec(x)
    }

    fn rig_offset(&self) -> usize {
        2 * self.free.len()
    }

    fn shared(&self) -> usize {
        self.rig_offset() + 6
    }

    fn pose_vector_of<'x>(&self, x: &'x DVector<f64>, pair: usize) -> &'x [f64] {
        let o = self.shared() + 6 * pair;
        &x.as_slice()[o..o + 6]
    }

    /// A pair's residuals: the left corners', then the right's.
    fn block(&self, x: &DVector<f64>, pair: usize) -> Vec<f64> {
        let [left, right] = self.intrinsics(x);
        let o = self.rig_offset();
        let rig = Pose::new(&x.as_slice()[o..o + 6]);
        let pose = Pose::new(self.pose_vector_of(x, pair));
        let mut r = Vec::new();
        view_residuals(&left, |b| pose.apply(b), &self.pairs[pair].0, &mut r);
        view_residuals(
            &right,
            |b| rig.apply(&pose.apply(b)),
            &self.pairs[pair].1,
            &mut r,
        );
        r
    }
}

impl LeastSquares for StereoProblem<'_> {
    type Normal = BlockNormal;

    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_vec(
            (0..self.pairs.len())
                .flat_map(|p| self.block(x, p))
                .collect(),
        )
    }

    fn normal_equations(&self, x: &DVector<f64>, _: &DVector<f64>) -> BlockNormal {
        let intrinsics = self.intrinsics(x);
        let (k, o) = (self.free.len(), self.rig_offset());
        let rig = Pose::new(&x.as_slice()[o..o + 6]);
        let mut normal = BlockNormal::new(self.shared(), self.pairs.len());
        let mut d_shared = vec![0.0; self.shared()];
        for (p, (left, right)) in self.pairs.iter().enumerate() {
            let pose = Pose::new(self.pose_vector_of(x, p));
            // Left: its intrinsics and the pose.
            d_shared.fill(0.0);
            for (b, m) in left.board_mm.iter().zip(&left.image_px) {
                let rotated = pose.rotation * board_point(b);
                let c = corner_residual(&intrinsics[0], &(rotated + pose.translation), m);
                let d_rotation = c.d_point * pose.d_rotation(&rotated);
                for row in 0..2 {
                    for (j, &i) in self.free.iter().enumerate() {
                        d_shared[j] = c.d_intrinsics[(row, i)];
                    }
                    normal.add(
                        p,
                        &d_shared,
                        &pose_row(&d_rotation, &c.d_point, row),
                        c.r[row],
                    );
                }
            }
            // Right: its intrinsics, the rig and the pose, through the rig.
            d_shared.fill(0.0);
            for (b, m) in right.board_mm.iter().zip(&right.image_px) {
                let rotated = pose.rotation * board_point(b);
                let in_left = rotated + pose.translation;
                let rig_rotated = rig.rotation * in_left;
                let c = corner_residual(&intrinsics[1], &(rig_rotated + rig.translation), m);
                let d_rig_rotation = c.d_point * rig.d_rotation(&rig_rotated);
                let d_in_left = c.d_point * rig.rotation;
                let d_rotation = d_in_left * pose.d_rotation(&rotated);
                for row in 0..2 {
                    for (j, &i) in self.free.iter().enumerate() {
                        d_shared[k + j] = c.d_intrinsics[(row, i)];
                    }
                    d_shared[o..o + 6]
                        .copy_from_slice(pose_row(&d_rig_rotation, &c.d_point, row).as_slice());
                    normal.add(
                        p,
                        &d_shared,
                        &pose_row(&d_rotation, &d_in_left, row),
                        c.r[row],
                    );
                }
            }
        }
        normal
    }
}

/// Calibrates a stereo rig from board views seen by both cameras (the same
/// corners in the same order in each pair).
pub fn calibrate_stereo(
    pairs: &[(BoardView, BoardView)],
    sizes: [(usize, usize); 2],
    free_distortion: [bool; 5],
) -> Result<StereoCalibration, String> {
    let lefts: Vec<BoardView> = pairs.iter().map(|p| p.0.clone()).collect();
    let rights: Vec<BoardView> = pairs.iter().map(|p| p.1.clone()).collect();
    // The two cameras alone are independent problems.
    let (left, right) = rayon::join(
        || calibrate_camera(&lefts, sizes[0].0, sizes[0].1, free_distortion),
        || calibrate_camera(&rights, sizes[1].0, sizes[1].1, free_distortion),
    );
    let left = left.map_err(|e| format!("left camera: {e}"))?;
    let right = right.map_err(|e| format!("right camera: {e}"))?;
    // Start the rig from the median of the per-pair relative poses.
    let relatives: Vec<Isometry3<f64>> = left
        .poses
        .iter()
        .zip(&right.poses)
        .map(|(l, r)| r * l.inverse())
        .collect();
    let mut candidates: Vec<(f64, usize)> = relatives
        .iter()
        .enumerate()
        .map(|(i, a)| {
            (
                relatives
                    .iter()
                    .map(|b| (a.translation.vector - b.translation.vector).norm())
                    .sum(),
                i,
            )
        })
        .collect();
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let rig0 = relatives[candidates[0].1];
    let free = free_intrinsics(free_distortion);
    let fixed = [
        intrinsic_vector(&left.camera),
        intrinsic_vector(&right.camera),
    ];
    let problem = StereoProblem {
        pairs,
        free: free.clone(),
        fixed,
        size: sizes,
    };
    let x0 = problem.vector(&fixed, &rig0, &left.poses);
    let report = levenberg_marquardt(&problem, x0, MAX_ITERATIONS, STEP_TOLERANCE);
    let [lc, rc] = problem.cameras(&report.x);
    let o = problem.rig_offset();
    let left_to_right = pose_from(&report.x.as_slice()[o..o + 6]);
    let poses: Vec<Isometry3<f64>> = (0..pairs.len())
        .map(|p| pose_from(problem.pose_vector_of(&report.x, p)))
        .collect();
    let spread = Spread::at_optimum(&problem, &report);
    let (mut sums, mut counts) = ([0.0f64; 2], [0usize; 2]);
    let mut pair_rms_px = Vec::with_capacity(pairs.len());
    for (p, (left_view, right_view)) in pairs.iter().enumerate() {
        let r = problem.block(&report.x, p);
        let n_left = 2 * left_view.board_mm.len();
        let (l, rr) = (
            r[..n_left].iter().map(|e| e * e).sum::<f64>(),
            r[n_left..].iter().map(|e| e * e).sum::<f64>(),
        );
        sums[0] += l;
        sums[1] += rr;
        counts[0] += left_view.board_mm.len();
        counts[1] += right_view.board_mm.len();
        let n = left_view.board_mm.len() + right_view.board_mm.len();
        pair_rms_px.push(((l + rr) / n.max(1) as f64).sqrt());
    }
    Ok(StereoCalibration {
        left: lc,
        right: rc,
        left_to_right,
        poses,
        rms_px: ((sums[0] + sums[1]) / (counts[0] + counts[1]) as f64).sqrt(),
        rms_left_right_px: [
            (sums[0] / counts[0] as f64).sqrt(),
            (sums[1] / counts[1] as f64).sqrt(),
        ],
        pair_rms_px,
        mono: [left, right],
        iterations: report.iterations,
        converged: report.converged,
        spread,
        estimated: free,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::camera_calibration::tests::{true_poses, views_of, with_noise};
    use crate::calib::lm::{
        CentralDifferences, assert_normal_equations_match, max_relative_difference,
    };
    use crate::phantom::Rig;

    fn pairs_of(rig: &Rig, noise_px: f64) -> Vec<(BoardView, BoardView)> {
        let poses = true_poses();
        let in_right: Vec<_> = poses.iter().map(|p| rig.left_to_right * p).collect();
        let lefts = with_noise(views_of(&rig.left, &poses), noise_px, 1);
        let rights = with_noise(views_of(&rig.right, &in_right), noise_px, 2);
        lefts.into_iter().zip(rights).collect()
    }

    fn problem_of<'a>(
        pairs: &'a [(BoardView, BoardView)],
        free_distortion: [bool; 5],
        s: &StereoCalibration,
    ) -> (StereoProblem<'a>, DVector<f64>) {
        let fixed = [intrinsic_vector(&s.left), intrinsic_vector(&s.right)];
        let problem = StereoProblem {
            pairs,
            free: free_intrinsics(free_distortion),
            fixed,
            size: [(800, 600); 2],
        };
        let x = problem.vector(&fixed, &s.left_to_right, &s.poses);
        (problem, x)
    }

    #[test]
    fn recovers_the_rig_from_exact_corners() {
        let rig = Rig::paper_rig();
        let pairs = pairs_of(&rig, 0.0);
        let s = calibrate_stereo(&pairs, [(800, 600); 2], [true, true, true, true, false]).unwrap();
        assert!(s.rms_px < 1e-7, "{}", s.rms_px);
        let truth = rig.left_to_right;
        assert!((s.left_to_right.translation.vector - truth.translation.vector).norm() < 1e-6);
        assert!(s.left_to_right.rotation.angle_to(&truth.rotation) < 1e-9);
        assert!((s.right.fx - rig.right.fx).abs() < 1e-5);
    }

    /// The analytic derivatives through both cameras and the rig, summed
    /// block by block, are J^T J and J^T r of central differences.
    #[test]
    fn its_normal_equations_are_those_of_central_differences() {
        let pairs = pairs_of(&Rig::paper_rig(), 0.2);
        let free = [true; 5];
        let s = calibrate_stereo(&pairs, [(800, 600); 2], free).unwrap();
        let (problem, x) = problem_of(&pairs, free, &s);
        // Away from the minimum, where every derivative counts.
        let mut away = x.clone();
        for (i, v) in away.iter_mut().enumerate() {
            *v += 1e-3 * (i as f64).sin() * v.abs().max(1.0);
        }
        assert_normal_equations_match(&problem, &away, 1e-6);
    }

    /// From another start the solver ends on the same minimum to 1e-9; the
    /// former solver (dense central differences) ends no lower, and within
    /// what its differences let it resolve (~1e-5 in the weakly determined
    /// parameters).
    #[test]
    fn ends_on_the_least_squares_minimum() {
        let pairs = pairs_of(&Rig::paper_rig(), 0.2);
        let free = [true, true, true, true, false];
        let s = calibrate_stereo(&pairs, [(800, 600); 2], free).unwrap();
        let (problem, x) = problem_of(&pairs, free, &s);
        let mut start = x.clone();
        start[0] += 3.0; // left fx, px
        start[2 * 8 + 3] += 0.5; // rig x, mm
        start[2 * 8 + 6] += 0.02; // first pose's rotation, rad
        let again = levenberg_marquardt(&problem, start.clone(), MAX_ITERATIONS, STEP_TOLERANCE);
        assert!(again.converged);
        let d = max_relative_difference(&x, &again.x, 1e-3);
        assert!(d < 1e-9, "{d:e}");
        let cost = problem.residuals(&x).norm_squared();
        let reference = levenberg_marquardt(
            &CentralDifferences(&problem),
            start,
            MAX_ITERATIONS,
            STEP_TOLERANCE,
        );
        assert!(
            cost <= reference.cost * (1.0 + 1e-12),
            "{cost} vs {}",
            reference.cost
        );
        let d = max_relative_difference(&x, &reference.x, 1e-3);
        assert!(d < 1e-4, "{d:e}");
    }

    #[test]
    fn the_rigs_spread_matches_a_monte_carlo_of_the_corners_noise() {
        use crate::calib::camera_calibration::tests::{assert_spread, mean_and_sd};
        let rig = Rig::paper_rig();
        let poses = true_poses();
        let in_right: Vec<_> = poses.iter().map(|p| rig.left_to_right * p).collect();
        let (lefts, rights) = (views_of(&rig.left, &poses), views_of(&rig.right, &in_right));
        let free = [true, true, true, true, false];
        let draws: Vec<StereoCalibration> = (0..200)
            .map(|seed| {
                let pairs: Vec<_> = with_noise(lefts.clone(), 0.2, 2 * seed)
                    .into_iter()
                    .zip(with_noise(rights.clone(), 0.2, 2 * seed + 1))
                    .collect();
                calibrate_stereo(&pairs, [(800, 600); 2], free).unwrap()
            })
            .collect();
        let mean = |f: &dyn Fn(&StereoCalibration) -> f64| {
            draws.iter().map(f).sum::<f64>() / draws.len() as f64
        };
        let spread = |f: &dyn Fn(&StereoCalibration) -> f64| {
            mean_and_sd(&draws.iter().map(f).collect::<Vec<f64>>()).1
        };
        let predicted = |f: &dyn Fn(&RigSpread) -> f64| mean(&|s| f(&s.rig_spread().unwrap()));
        assert_spread(
            "baseline",
            predicted(&|r| r.baseline_sd_mm),
            spread(&|s| s.left_to_right.translation.vector.norm()),
        );
        for axis in 0..3 {
            assert_spread(
                &format!("translation {axis}"),
                predicted(&|r| r.translation_sd_mm()[axis]),
                spread(&|s| s.left_to_right.translation.vector[axis]),
            );
            // The small-angle error about each axis, against the truth.
            assert_spread(
                &format!("rotation {axis}"),
                predicted(&|r| r.rotation_sd_deg()[axis]),
                spread(&|s| {
                    let e = (s.left_to_right.rotation * rig.left_to_right.rotation.inverse())
                        .scaled_axis();
                    e[axis].to_degrees()
                }),
            );
        }
        for side in 0..2 {
            assert_spread(
                &format!("fx of camera {side}"),
                mean(&|s| s.intrinsics_sd(side)[0]),
                spread(&|s| if side == 0 { s.left.fx } else { s.right.fx }),
            );
        }
    }
}
