//! Rigid transforms as nalgebra isometries and as the row-major 4x4 matrices of
//! the engine's values and JSON files.

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};

/// The row-major 4x4 matrix of an isometry.
pub fn isometry_to_matrix(iso: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m: Matrix4<f64> = iso.to_homogeneous();
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// The isometry of a row-major 4x4 matrix whose upper-left 3x3 is a rotation
/// (re-orthonormalised, so matrices read from text keep working).
pub fn isometry_from_matrix(m: &[[f64; 4]; 4]) -> Isometry3<f64> {
    let r = Matrix3::from_fn(|i, j| m[i][j]);
    // Bounded: nalgebra's `from_matrix` iterates until it converges, which a
    // NaN never does.
    let rotation = Rotation3::from_matrix_eps(&r, 1e-15, 100, Rotation3::identity());
    Isometry3::from_parts(
        Translation3::new(m[0][3], m[1][3], m[2][3]),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

/// The camera-to-world pose of a camera at `eye` looking at `target`, with image
/// "up" (-y) as close to `up` as possible. Camera frame: x right, y down, z forward.
pub fn look_at(eye: &Point3<f64>, target: &Point3<f64>, up: &Vector3<f64>) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(
        Translation3::from(eye.coords),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrix_round_trip() {
        let iso = Isometry3::new(Vector3::new(1.0, -2.0, 3.0), Vector3::new(0.1, 0.2, -0.3));
        let back = isometry_from_matrix(&isometry_to_matrix(&iso));
        assert!((back.to_homogeneous() - iso.to_homogeneous()).norm() < 1e-12);
    }

    #[test]
    fn look_at_points_z_at_the_target_with_y_down() {
        let pose = look_at(
            &Point3::new(0.0, -300.0, 400.0),
            &Point3::origin(),
            &Vector3::z(),
        );
        let target_in_camera = pose.inverse() * Point3::origin();
        assert!(target_in_camera.x.abs() < 1e-9 && target_in_camera.y.abs() < 1e-9);
        assert!((target_in_camera.z - 500.0).abs() < 1e-9);
        // World up appears towards the top of the image (negative camera y).
        let up_in_camera = pose.inverse().rotation * Vector3::z();
        assert!(up_in_camera.y < 0.0);
    }
}
