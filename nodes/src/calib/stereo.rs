//! Stereo calibration: both cameras and the rig extrinsics refined together by
//! Levenberg-Marquardt, starting from each camera's own calibration.

use super::camera_calibration::{
    BoardView, CameraCalibration, calibrate_camera, camera_from, intrinsic_vector, pose_from,
    pose_vector, view_residuals,
};
use super::lm::{LeastSquares, levenberg_marquardt};
use crate::camera::CameraModel;
use nalgebra::{DMatrix, DVector, Isometry3};

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
}

struct StereoProblem<'a> {
    pairs: &'a [(BoardView, BoardView)],
    free: Vec<usize>,
    fixed: [[f64; 9]; 2],
    size: [(usize, usize); 2],
}

impl StereoProblem<'_> {
    fn cameras(&self, x: &DVector<f64>) -> [CameraModel; 2] {
        std::array::from_fn(|side| {
            let mut v = self.fixed[side];
            for (k, &i) in self.free.iter().enumerate() {
                v[i] = x[side * self.free.len() + k];
            }
            camera_from(&v, self.size[side].0, self.size[side].1)
        })
    }

    fn rig_offset(&self) -> usize {
        2 * self.free.len()
    }

    fn block(&self, x: &DVector<f64>, pair: usize) -> Vec<f64> {
        let [left, right] = self.cameras(x);
        let o = self.rig_offset();
        let rig = pose_from(&x.as_slice()[o..o + 6]);
        let pose = pose_from(&x.as_slice()[o + 6 + 6 * pair..o + 12 + 6 * pair]);
        let mut r = Vec::new();
        view_residuals(&left, &pose, &self.pairs[pair].0, &mut r);
        view_residuals(&right, &(rig * pose), &self.pairs[pair].1, &mut r);
        r
    }
}

impl LeastSquares for StereoProblem<'_> {
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_vec(
            (0..self.pairs.len())
                .flat_map(|p| self.block(x, p))
                .collect(),
        )
    }

    fn jacobian(&self, x: &DVector<f64>) -> DMatrix<f64> {
        let rows: usize = self
            .pairs
            .iter()
            .map(|(l, r)| 2 * (l.board_mm.len() + r.board_mm.len()))
            .sum();
        let mut j = DMatrix::zeros(rows, x.len());
        let o = self.rig_offset();
        let mut row = 0;
        for p in 0..self.pairs.len() {
            let n = 2 * (self.pairs[p].0.board_mm.len() + self.pairs[p].1.board_mm.len());
            // A pair depends on both cameras, the rig and its own pose.
            for c in (0..o + 6).chain(o + 6 + 6 * p..o + 12 + 6 * p) {
                let h = 1e-6 * x[c].abs().max(1e-2);
                let (mut plus, mut minus) = (x.clone(), x.clone());
                plus[c] += h;
                minus[c] -= h;
                let (a, b) = (self.block(&plus, p), self.block(&minus, p));
                for k in 0..n {
                    j[(row + k, c)] = (a[k] - b[k]) / (2.0 * h);
                }
            }
            row += n;
        }
        j
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
    let left = calibrate_camera(&lefts, sizes[0].0, sizes[0].1, free_distortion)
        .map_err(|e| format!("left camera: {e}"))?;
    let right = calibrate_camera(&rights, sizes[1].0, sizes[1].1, free_distortion)
        .map_err(|e| format!("right camera: {e}"))?;
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
    let free: Vec<usize> = (0..4)
        .chain((0..5).filter(|&d| free_distortion[d]).map(|d| d + 4))
        .collect();
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
    let mut x0: Vec<f64> = free.iter().map(|&i| fixed[0][i]).collect();
    x0.extend(free.iter().map(|&i| fixed[1][i]));
    x0.extend(pose_vector(&rig0));
    left.poses.iter().for_each(|p| x0.extend(pose_vector(p)));
    let report = levenberg_marquardt(&problem, DVector::from_vec(x0), 200, 1e-14);
    let [lc, rc] = problem.cameras(&report.x);
    let o = problem.rig_offset();
    let left_to_right = pose_from(&report.x.as_slice()[o..o + 6]);
    let poses: Vec<Isometry3<f64>> = (0..pairs.len())
        .map(|p| pose_from(&report.x.as_slice()[o + 6 + 6 * p..o + 12 + 6 * p]))
        .collect();
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
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::camera_calibration::tests::{true_poses, views_of};

    #[test]
    fn recovers_the_rig_from_exact_corners() {
        let crate::phantom::Rig {
            left,
            right,
            left_to_right: rig,
        } = crate::phantom::Rig::paper_rig();
        let poses = true_poses();
        let lefts = views_of(&left, &poses);
        let rights = views_of(&right, &poses.iter().map(|p| rig * p).collect::<Vec<_>>());
        let pairs: Vec<_> = lefts.into_iter().zip(rights).collect();
        let s = calibrate_stereo(&pairs, [(800, 600); 2], [true, true, true, true, false]).unwrap();
        assert!(s.rms_px < 1e-7, "{}", s.rms_px);
        assert!((s.left_to_right.translation.vector - rig.translation.vector).norm() < 1e-6);
        assert!(s.left_to_right.rotation.angle_to(&rig.rotation) < 1e-9);
        assert!((s.right.fx - right.fx).abs() < 1e-5);
    }
}
