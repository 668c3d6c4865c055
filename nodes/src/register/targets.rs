//! Targets marked in one frame (lesions in MRI) carried into another (the
//! camera's, where the robot acts) by a registration.

use super::convert::transform_isometry;
use super::pose_spread::mapped_point_covariance;
use fusegraph_engine::value::Transform;
use nalgebra::{Matrix3, Matrix3x6, Matrix6, Point3};

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

/// The covariance (mm^2, in the frame the targets map to) of each of
/// `targets` (mm, in frame `from`) mapped through `transform`, whose pose
/// has covariance `pose` (a small turn and shift applied after it in its
/// `to` frame; see [`PoseSpread`](super::PoseSpread)), either way as
/// [`map_targets`].
pub fn mapped_target_covariances(
    targets: &[Point3<f64>],
    from: &str,
    transform: &Transform,
    pose: &Matrix6<f64>,
) -> Result<Vec<Matrix3<f64>>, String> {
    let iso = transform_isometry(transform);
    if transform.to == from {
        return Ok(targets
            .iter()
            .map(|q| mapped_point_covariance(&iso, pose, q))
            .collect());
    }
    // Forward: exp(x) T p = m + w x m + t, a change of [-[m]x, I] x.
    let (mapped, _) = map_targets(targets, from, transform)?;
    Ok(mapped
        .iter()
        .map(|m| {
            let mut a = Matrix3x6::zeros();
            a.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-m.coords.cross_matrix()));
            a.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            a * pose * a.transpose()
        })
        .collect())
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

    #[test]
    fn a_targets_covariance_is_the_spread_of_its_mapping_either_way() {
        // Poses drawn from a covariance by hand: the mapped target's sample
        // covariance over 20,000 draws matches the first-order one, for a
        // target mapped forward and one mapped back.
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let iso = Isometry3::new(
            Vector3::new(10.0, -5.0, 400.0),
            Vector3::new(0.1, 0.2, -0.3),
        );
        let t = Transform {
            matrix: isometry_to_matrix(&iso),
            from: "camera_left".into(),
            to: "mri_lps".into(),
        };
        let sd = nalgebra::Vector6::new(2e-3, 1e-3, 3e-3, 0.2, 0.1, 0.3);
        let pose = Matrix6::from_diagonal(&sd.component_mul(&sd));
        let mut rng = rand::rngs::StdRng::seed_from_u64(4);
        for (from, q) in [
            ("mri_lps", Point3::new(30.0, -20.0, 50.0)),
            ("camera_left", Point3::new(-20.0, 10.0, 600.0)),
        ] {
            let predicted = mapped_target_covariances(&[q], from, &t, &pose).unwrap()[0];
            let draws: Vec<Vector3<f64>> = (0..20_000)
                .map(|_| {
                    let x = nalgebra::Vector6::from_fn(|_, _| StandardNormal.sample(&mut rng))
                        .component_mul(&sd);
                    let step = Isometry3::new(
                        Vector3::new(x[3], x[4], x[5]),
                        Vector3::new(x[0], x[1], x[2]),
                    );
                    let moved = step * iso;
                    let m = if from == "mri_lps" {
                        moved.inverse() * q
                    } else {
                        moved * q
                    };
                    m.coords
                })
                .collect();
            let mean = draws.iter().sum::<Vector3<f64>>() / draws.len() as f64;
            let sample = draws.iter().fold(Matrix3::zeros(), |c, d| {
                c + (d - mean) * (d - mean).transpose()
            }) / (draws.len() - 1) as f64;
            assert!(
                (sample - predicted).amax() < 0.05 * predicted.amax(),
                "{from}: {sample} vs {predicted}"
            );
        }
    }
}
