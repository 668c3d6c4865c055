//! The simulated stereo rig (like the paper's: 6 um pixels, 800 x 600, 8 mm
//! lenses, 55 mm baseline, verging so the optical axes cross 400 mm ahead) and
//! the poses it is shown things in: chessboard poses for calibration and rig
//! poses around the phantom (the robot arm moving).

use super::scenes::Chessboard;
use crate::camera::{CameraModel, look_at};
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;

/// Distance from the left camera at which the optical axes cross, mm.
pub const CONVERGENCE_MM: f64 = 400.0;
/// Baseline between the camera centres, mm.
pub const BASELINE_MM: f64 = 55.0;

/// Pixel pitch of the paper rig's sensors, mm (6 um).
pub const PIXEL_MM: f64 = 0.006;

/// Both cameras and the rig extrinsics (left camera frame -> right camera frame).
#[derive(Debug, Clone)]
pub struct Rig {
    /// Left camera.
    pub left: CameraModel,
    /// Right camera.
    pub right: CameraModel,
    /// X_right = left_to_right * X_left (mm).
    pub left_to_right: Isometry3<f64>,
}

impl Rig {
    /// Two slightly different 8 mm cameras with 6 um pixels and mild distortion,
    /// the right one verged by theta = atan(b / 400 mm) towards the left.
    pub fn paper_rig() -> Self {
        let pixel_mm = PIXEL_MM;
        let left = CameraModel {
            width: 800,
            height: 600,
            fx: 8.0 / pixel_mm,
            fy: 8.0 / pixel_mm * 1.0008,
            cx: 403.2,
            cy: 297.6,
            distortion: [-0.118, 0.152, 0.00061, -0.00042, 0.0],
        };
        let right = CameraModel {
            width: 800,
            height: 600,
            fx: 8.03 / pixel_mm,
            fy: 8.03 / pixel_mm * 0.9995,
            cx: 396.5,
            cy: 302.9,
            distortion: [-0.109, 0.131, -0.00048, 0.00033, 0.0],
        };
        let theta = (BASELINE_MM / CONVERGENCE_MM).atan();
        // The right camera sits at +b along the left x axis, turned by -theta
        // about y; its frame maps X_right = R_y(theta) (X_left - C_right).
        let rotation = Rotation3::from_axis_angle(&Vector3::y_axis(), theta);
        let translation = -(rotation * Vector3::new(BASELINE_MM, 0.0, 0.0));
        Rig {
            left,
            right,
            left_to_right: Isometry3::from_parts(
                Translation3::from(translation),
                UnitQuaternion::from_rotation_matrix(&rotation),
            ),
        }
    }

    /// The paper rig knocked slightly out of line (a roll and a vertical
    /// offset of the right camera), so rectification has work to do: a test
    /// fixture for rectification and triangulation.
    #[cfg(test)]
    pub(crate) fn misaligned_paper_rig() -> Self {
        let rig = Self::paper_rig();
        Rig {
            left_to_right: Isometry3::from_parts(
                Translation3::new(0.0, 0.4, 0.0),
                UnitQuaternion::from_euler_angles(0.01, 0.0, -0.004),
            ) * rig.left_to_right,
            ..rig
        }
    }

    /// The right camera's pose given the left camera's (both camera-to-world).
    pub fn right_pose(&self, left_to_world: &Isometry3<f64>) -> Isometry3<f64> {
        left_to_world * self.left_to_right.inverse()
    }

    /// The left camera's pose for a rig whose midpoint is at `midpoint`, aimed so
    /// that `target` (world) appears near the centre of both images (each camera
    /// turned half the verging angle from the line to the target), image up
    /// towards world +z.
    pub fn aim(&self, midpoint: &Point3<f64>, target: &Point3<f64>) -> Isometry3<f64> {
        let bisector = look_at(midpoint, target, &Vector3::z());
        let theta = (BASELINE_MM / CONVERGENCE_MM).atan();
        let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.5 * theta);
        let rotation = bisector.rotation * turn;
        let x_left = rotation * Vector3::x();
        let centre = midpoint - x_left * (0.5 * BASELINE_MM);
        Isometry3::from_parts(Translation3::from(centre.coords), rotation)
    }
}

/// A calibration pose and whether a detector should find the whole board.
#[derive(Debug, Clone)]
pub struct BoardPose {
    /// Board frame -> left camera frame.
    pub board_to_left: Isometry3<f64>,
    /// Whether every corner is visible and well resolved in both images.
    pub detectable: bool,
    /// Why not, when not.
    pub note: String,
}

/// Projections of the board corners into both cameras, if all are in front.
fn project_corners(
    rig: &Rig,
    board: &Chessboard,
    pose: &Isometry3<f64>,
) -> Option<[Vec<nalgebra::Point2<f64>>; 2]> {
    let corners = board.corners();
    let left: Option<Vec<_>> = corners
        .iter()
        .map(|c| rig.left.project(&(pose * c)))
        .collect();
    let right: Option<Vec<_>> = corners
        .iter()
        .map(|c| rig.right.project(&(rig.left_to_right * (pose * c))))
        .collect();
    Some([left?, right?])
}

/// Board poses: `good` fully visible in both cameras at 430-700 mm with tilts up
/// to 40 deg, then two partly out of frame and one too oblique to resolve.
pub fn board_poses(
    rig: &Rig,
    board: &Chessboard,
    good: usize,
    rng: &mut impl Rng,
) -> Vec<BoardPose> {
    let centre_offset = Vector3::new(
        0.5 * (board.cols - 1) as f64 * board.square_mm,
        0.5 * (board.rows - 1) as f64 * board.square_mm,
        0.0,
    );
    let sample = |rng: &mut dyn rand::RngCore, max_tilt_deg: f64, reach: f64| {
        let z = rng.random_range(430.0..700.0);
        let (x, y) = (
            rng.random_range(-reach..reach) * z / 1333.0,
            rng.random_range(-reach..reach) * 0.75 * z / 1333.0,
        );
        let tilt_axis = rng.random_range(0.0..std::f64::consts::TAU);
        let tilt = rng.random_range(0.0..max_tilt_deg).to_radians();
        let axis = Vector3::new(tilt_axis.cos(), tilt_axis.sin(), 0.0);
        let spin = rng.random_range(-20.0f64..20.0).to_radians();
        let rotation = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), tilt)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), spin);
        // The board centre at (x, y, z) in the left camera frame.
        let centre = Vector3::new(x, y, z);
        Isometry3::from_parts(
            Translation3::from(centre - rotation * centre_offset),
            rotation,
        )
    };
    let all_inside = |pose: &Isometry3<f64>, margin: f64| {
        project_corners(rig, board, pose).is_some_and(|[l, r]| {
            l.iter().all(|p| rig.left.contains(p, margin))
                && r.iter().all(|p| rig.right.contains(p, margin))
        })
    };
    let mut poses = Vec::new();
    while poses.len() < good {
        let pose = sample(rng, 40.0, 260.0);
        if all_inside(&pose, 25.0) {
            poses.push(BoardPose {
                board_to_left: pose,
                detectable: true,
                note: String::new(),
            });
        }
    }
    let mut out_of_frame = 0;
    while out_of_frame < 2 {
        let pose = sample(rng, 25.0, 520.0);
        let Some([l, r]) = project_corners(rig, board, &pose) else {
            continue;
        };
        let outside = l.iter().filter(|p| !rig.left.contains(p, 0.0)).count()
            + r.iter().filter(|p| !rig.right.contains(p, 0.0)).count();
        if outside >= 6 && outside <= l.len() {
            poses.push(BoardPose {
                board_to_left: pose,
                detectable: false,
                note: format!(
                    "partly out of frame: {outside} corner projections outside the images"
                ),
            });
            out_of_frame += 1;
        }
    }
    loop {
        let tilt = 84.0f64;
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), tilt.to_radians());
        let centre = Vector3::new(0.0, 0.0, 520.0);
        let pose = Isometry3::from_parts(
            Translation3::from(centre - rotation * centre_offset),
            rotation,
        );
        if all_inside(&pose, 5.0) {
            poses.push(BoardPose {
                board_to_left: pose,
                detectable: false,
                note: format!("too oblique: board tilted {tilt} deg from the image plane"),
            });
            break;
        }
    }
    poses
}

/// Left-camera poses (camera-to-world) of the rig around a phantom centred at
/// `target`: evenly spread azimuths, elevations 50-62 deg, 470-520 mm away.
pub fn view_poses(
    rig: &Rig,
    target: &Point3<f64>,
    count: usize,
    rng: &mut impl Rng,
) -> Vec<Isometry3<f64>> {
    (0..count)
        .map(|v| {
            let azimuth = (-75.0
                + 150.0 * v as f64 / (count.max(2) - 1) as f64
                + rng.random_range(-5.0..5.0))
            .to_radians();
            let elevation =
                (50.0 + 12.0 * ((v % 3) as f64 / 2.0) + rng.random_range(-2.0..2.0)).to_radians();
            let distance = rng.random_range(470.0..520.0);
            let midpoint = target
                + Vector3::new(
                    elevation.cos() * azimuth.sin(),
                    -elevation.cos() * azimuth.cos(),
                    elevation.sin(),
                ) * distance;
            rig.aim(&midpoint, target)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn rig_matches_the_paper_design() {
        let rig = Rig::paper_rig();
        assert!((rig.left.fx - 1333.333).abs() < 1e-3, "8 mm / 6 um");
        let t = rig.left_to_right.translation.vector;
        assert!((t.norm() - 55.0).abs() < 1e-9);
        let angle = rig.left_to_right.rotation.angle().to_degrees();
        assert!((angle - 7.8291).abs() < 1e-3, "{angle}");
        // The optical axes cross 400 mm in front of the left camera.
        let p = Point3::new(0.0, 0.0, CONVERGENCE_MM);
        let in_right = rig.left_to_right * p;
        assert!(in_right.x.abs() < 1e-9 && in_right.y.abs() < 1e-9);
    }

    #[test]
    fn aiming_points_the_bisector_at_the_target() {
        let rig = Rig::paper_rig();
        let target = Point3::new(0.0, 0.0, 30.0);
        let left = rig.aim(&Point3::new(100.0, -400.0, 350.0), &target);
        let right = rig.right_pose(&left);
        let (l, r) = (left.inverse() * target, right.inverse() * target);
        // The target lies beyond the 400 mm convergence point, so each camera
        // sees it a little towards the other camera's side, near the centre.
        assert!(l.x < 0.0 && r.x > 0.0, "{l} {r}");
        assert!(
            (l.x / l.z).abs() < 0.03 && (r.x / r.z).abs() < 0.03,
            "{l} {r}"
        );
        assert!(l.y.abs() < 1e-9 && r.y.abs() < 1e-9);
        let baseline = (right.translation.vector - left.translation.vector).norm();
        assert!((baseline - 55.0).abs() < 1e-9);
    }

    #[test]
    fn board_poses_are_visible_or_flagged() {
        let rig = Rig::paper_rig();
        let board = Chessboard {
            cols: 9,
            rows: 6,
            square_mm: 25.0,
            margin_mm: 20.0,
        };
        let poses = board_poses(
            &rig,
            &board,
            15,
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(2),
        );
        assert_eq!(poses.len(), 18);
        assert_eq!(poses.iter().filter(|p| p.detectable).count(), 15);
        for p in poses.iter().filter(|p| p.detectable) {
            let z = p.board_to_left.translation.vector.z;
            assert!((300.0..800.0).contains(&z));
        }
    }
}
