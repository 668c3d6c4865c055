//! Targets marked in one frame (lesions in MRI) carried into another (the
//! camera's, where the robot acts) by a registration.

use super::convert::transform_isometry;
use fusegraph_engine::value::Transform;
use nalgebra::Point3;

/// `targets` (mm, in frame `from`) through `transform` in whichever direction
/// starts at `from`: the mapped points and the frame they are in. A transform
/// that touches neither end at `from` is an error naming the frames.
pub fn map_targets(
    targets: &[Point3<f64>],
    from: &str,
    transform: &Transform,
) -> Result<(Vec<Point3<f64>>, String), String> {
    let iso = transform_isometry(transform);
    let (iso, to) = if transform.from == from {
        (iso, transform.to.clone())
    } else if transform.to == from {
        (iso.inverse(), transform.from.clone())
    } else {
        return Err(format!(
            "the targets are in `{from}` but the transform maps `{}` -> `{}`",
            transform.from, transform.to
        ));
    };
    Ok((targets.iter().map(|p| iso * p).collect(), to))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::isometry_to_matrix;
    use nalgebra::{Isometry3, Vector3};

    #[test]
    fn targets_go_through_the_transform_either_way() {
        let iso = Isometry3::new(Vector3::new(10.0, -5.0, 400.0), Vector3::new(0.0, 0.2, 0.0));
        let t = Transform {
            matrix: isometry_to_matrix(&iso),
            from: "mri_lps".into(),
            to: "camera_left".into(),
        };
        let p = [Point3::new(1.0, 2.0, 3.0)];
        let (m, frame) = map_targets(&p, "mri_lps", &t).unwrap();
        assert_eq!(frame, "camera_left");
        assert!((m[0] - iso * p[0]).norm() < 1e-12);
        let (back, frame) = map_targets(&m, "camera_left", &t).unwrap();
        assert_eq!(frame, "mri_lps");
        assert!((back[0] - p[0]).norm() < 1e-9);
        let e = map_targets(&p, "world", &t).unwrap_err();
        assert!(e.contains("`world`"), "{e}");
    }
}
