//! Reprojection of board corners with analytic derivatives: with respect to
//! the intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3, OpenCV's model, as in
//! [`CameraModel::distort`](crate::camera::CameraModel::distort)) and to the
//! point in the camera frame, and of a posed point with respect to its pose
//! (rotation vector, translation). The calibration solvers chain these instead
//! of differencing the residuals numerically.

use nalgebra::{Matrix2x3, Matrix3, Point2, SMatrix, Vector3};

/// The pixel of a point in front of the camera and its derivatives.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Projected {
    /// The pixel (u, v), px.
    pub px: Point2<f64>,
    /// d(u, v) / d(fx, fy, cx, cy, k1, k2, p1, p2, k3).
    pub d_intrinsics: SMatrix<f64, 2, 9>,
    /// d(u, v) / d(point in the camera frame, mm).
    pub d_point: Matrix2x3<f64>,
}

/// Projects `p` (camera frame, mm) with `intrinsics` (solver order, see
/// [`intrinsic_vector`](super::camera_calibration::intrinsic_vector));
/// `None` when it is not in front of the camera.
pub(crate) fn project(intrinsics: &[f64; 9], p: &Vector3<f64>) -> Option<Projected> {
    if p.z <= 0.0 {
        return None;
    }
    let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = *intrinsics;
    let inv_z = 1.0 / p.z;
    let (x, y) = (p.x * inv_z, p.y * inv_z);
    let (xx, yy, xy) = (x * x, y * y, x * y);
    let r2 = xx + yy;
    let (r4, r6) = (r2 * r2, r2 * r2 * r2);
    let radial = 1.0 + k1 * r2 + k2 * r4 + k3 * r6;
    let xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx);
    let yd = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy;
    #[rustfmt::skip]
    let d_intrinsics = SMatrix::<f64, 2, 9>::from_row_slice(&[
        xd, 0.0, 1.0, 0.0, fx * x * r2, fx * x * r4, fx * 2.0 * xy, fx * (r2 + 2.0 * xx), fx * x * r6,
        0.0, yd, 0.0, 1.0, fy * y * r2, fy * y * r4, fy * (r2 + 2.0 * yy), fy * 2.0 * xy, fy * y * r6,
    ]);
    // d(xd, yd) / d(x, y), then d(x, y) / d(point).
    let d_radial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4;
    let a = radial + 2.0 * xx * d_radial + 2.0 * p1 * y + 6.0 * p2 * x;
    let b = 2.0 * xy * d_radial + 2.0 * p1 * x + 2.0 * p2 * y;
    let d = radial + 2.0 * yy * d_radial + 6.0 * p1 * y + 2.0 * p2 * x;
    let (du_dx, du_dy, dv_dx, dv_dy) = (fx * a, fx * b, fy * b, fy * d);
    #[rustfmt::skip]
    let d_point = Matrix2x3::new(
        du_dx * inv_z, du_dy * inv_z, -(du_dx * x + du_dy * y) * inv_z,
        dv_dx * inv_z, dv_dy * inv_z, -(dv_dx * x + dv_dy * y) * inv_z,
    );
    Some(Projected {
        px: Point2::new(fx * xd + cx, fy * yd + cy),
        d_intrinsics,
        d_point,
    })
}

/// The residual of a corner behind the camera, px per coordinate: large and
/// constant, so the solver steps back towards poses that see the board.
const BEHIND_CAMERA_PX: f64 = 1e4;

/// A corner's two residuals (predicted - measured, px) and their derivatives.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CornerResidual {
    /// u and v residuals, px.
    pub r: [f64; 2],
    /// d r / d(fx, fy, cx, cy, k1, k2, p1, p2, k3).
    pub d_intrinsics: SMatrix<f64, 2, 9>,
    /// d r / d(point in the camera frame, mm).
    pub d_point: Matrix2x3<f64>,
}

/// The residual of a corner found at `measured` (px) whose board point lies
/// at `p` in the camera frame (mm).
pub(crate) fn corner_residual(
    intrinsics: &[f64; 9],
    p: &Vector3<f64>,
    measured: &Point2<f64>,
) -> CornerResidual {
    match project(intrinsics, p) {
        Some(q) => CornerResidual {
            r: [q.px.x - measured.x, q.px.y - measured.y],
            d_intrinsics: q.d_intrinsics,
            d_point: q.d_point,
        },
        None => CornerResidual {
            r: [BEHIND_CAMERA_PX; 2],
            d_intrinsics: SMatrix::zeros(),
            d_point: Matrix2x3::zeros(),
        },
    }
}

/// A pose given as a rotation vector (rad) and a translation (mm), with what
/// its derivatives need.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pose {
    /// The rotation matrix of the rotation vector.
    pub rotation: Matrix3<f64>,
    /// The translation, mm.
    pub translation: Vector3<f64>,
    /// The left Jacobian of SO(3) at the rotation vector:
    /// R(r + e) = exp([J e]x) R(r) to first order.
    pub left_jacobian: Matrix3<f64>,
}

impl Pose {
    /// The pose of a solver vector (rx, ry, rz, tx, ty, tz).
    pub fn new(v: &[f64]) -> Self {
        let r = Vector3::new(v[0], v[1], v[2]);
        Self {
            rotation: nalgebra::Rotation3::from_scaled_axis(r).into_inner(),
            translation: Vector3::new(v[3], v[4], v[5]),
            left_jacobian: so3_left_jacobian(&r),
        }
    }

    /// The pose applied to `p`.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// d(R p + t) / d(rotation vector), given `rotated` = R p.
    pub fn d_rotation(&self, rotated: &Vector3<f64>) -> Matrix3<f64> {
        -rotated.cross_matrix() * self.left_jacobian
    }
}

/// J(r) = I + (1 - cos t) / t^2 [r]x + (t - sin t) / t^3 [r]x^2, t = |r|, with
/// the series near 0 where the closed form loses digits.
fn so3_left_jacobian(r: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = r.norm_squared();
    let (a, b) = if t2 < 1e-8 {
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t = t2.sqrt();
        ((1.0 - t.cos()) / t2, (t - t.sin()) / (t2 * t))
    };
    let k = r.cross_matrix();
    Matrix3::identity() + k * a + k * k * b
}

#[cfg(test)]
mod tests {
    use super::*;

    const INTRINSICS: [f64; 9] = [
        1333.3, 1334.4, 403.2, 297.6, -0.118, 0.152, 0.00061, -0.00042, 0.031,
    ];

    fn pixel(intrinsics: &[f64; 9], p: &Vector3<f64>) -> Point2<f64> {
        project(intrinsics, p).unwrap().px
    }

    /// The pixel equals CameraModel::project's, the model the rest of the
    /// code uses.
    #[test]
    fn projects_as_the_camera_model() {
        let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = INTRINSICS;
        let camera = crate::camera::CameraModel {
            width: 800,
            height: 600,
            fx,
            fy,
            cx,
            cy,
            distortion: [k1, k2, p1, p2, k3],
        };
        let p = Vector3::new(-60.0, 45.0, 480.0);
        let ours = pixel(&INTRINSICS, &p);
        let theirs = camera.project(&p.into()).unwrap();
        assert!((ours - theirs).norm() < 1e-10, "{ours} vs {theirs}");
        assert!(project(&INTRINSICS, &Vector3::new(1.0, 1.0, -1.0)).is_none());
    }

    /// Every derivative agrees with central differences (step 1e-6
    /// relative: truncation and rounding both near 1e-9 relative).
    #[test]
    fn derivatives_match_central_differences() {
        let p = Vector3::new(-60.0, 45.0, 480.0);
        let got = project(&INTRINSICS, &p).unwrap();
        for i in 0..9 {
            let h = 1e-6 * INTRINSICS[i].abs().max(1e-3);
            let (mut a, mut b) = (INTRINSICS, INTRINSICS);
            a[i] += h;
            b[i] -= h;
            let numeric = (pixel(&a, &p) - pixel(&b, &p)) / (2.0 * h);
            let analytic = got.d_intrinsics.column(i);
            assert!(
                (numeric - analytic).norm() <= 1e-6 * analytic.norm().max(1.0),
                "intrinsic {i}: {numeric} vs {analytic}"
            );
        }
        for i in 0..3 {
            let mut e = Vector3::zeros();
            e[i] = 1e-4;
            let numeric =
                (pixel(&INTRINSICS, &(p + e)) - pixel(&INTRINSICS, &(p - e))) / (2.0 * e[i]);
            let analytic = got.d_point.column(i);
            assert!(
                (numeric - analytic).norm() <= 1e-7 * analytic.norm().max(1.0),
                "point {i}: {numeric} vs {analytic}"
            );
        }
    }

    #[test]
    fn the_rotation_derivative_matches_central_differences() {
        let point = Vector3::new(75.0, -25.0, 10.0);
        // A large rotation and one within the series' reach of zero.
        for v in [
            [0.3, -1.9, 0.7, 5.0, 6.0, 7.0],
            [1e-5, -2e-5, 3e-6, 0.0, 0.0, 0.0],
        ] {
            let pose = Pose::new(&v);
            let analytic = pose.d_rotation(&(pose.rotation * point));
            for i in 0..3 {
                let (mut a, mut b) = (v, v);
                a[i] += 1e-6;
                b[i] -= 1e-6;
                let numeric = (Pose::new(&a).apply(&point) - Pose::new(&b).apply(&point)) / 2e-6;
                assert!(
                    (numeric - analytic.column(i)).norm() < 1e-7,
                    "{v:?}, component {i}: {numeric} vs {}",
                    analytic.column(i)
                );
            }
        }
    }
}
