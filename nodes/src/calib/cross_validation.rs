//! Cross-validation of a camera calibration, as mrcal does it: the views are
//! split into two disjoint halves (alternate views, so both span the poses),
//! each half is calibrated alone, and the two models are compared where it
//! matters, in projection: a pixel is unprojected by one model and
//! projected by the other, over a grid across the image. Two models that
//! differ by far more than their noise say the calibration is not pinned
//! down by its views (too few, too alike, or a model with more freedom than
//! they constrain, such as k3 on few views), whatever its RMS says.
//!
//! A small rotation between the two models' camera frames is fitted away
//! first (Kabsch on the two models' rays): the extrinsics absorb it, so it
//! moves no projected point (mrcal's fit of the implied transformation, the
//! rotation only, so the difference holds at any distance).

use super::camera_calibration::{BoardView, CameraCalibration, calibrate_camera};
use crate::camera::CameraModel;
use nalgebra::{Matrix3, Point3, Vector3};

/// Two half-calibrations compared across the image.
#[derive(Debug, Clone)]
pub struct CrossValidation {
    /// The two calibrations: from the even-numbered views (0, 2, ...) and
    /// from the odd ones (1, 3, ...) of the input order.
    pub halves: [CameraCalibration; 2],
    /// Grid cell centres (u, v, px) and the distance between the two
    /// models' projections there, px; row-major, `columns` wide.
    pub differences: Vec<(f64, f64, f64)>,
    /// Grid columns.
    pub columns: usize,
    /// Mean, 95th percentile and largest difference, px.
    pub mean_px: f64,
    /// 95th percentile of the differences, px.
    pub p95_px: f64,
    /// Largest difference, px.
    pub max_px: f64,
}

/// Calibrates the two halves of `views` (each needs 3 or more) with
/// `free_distortion` and compares them on a grid of `columns` cells across
/// (rows in proportion), a rotation between them fitted away when
/// `fit_rotation`.
pub fn cross_validate(
    views: &[BoardView],
    width: usize,
    height: usize,
    free_distortion: [bool; 5],
    columns: usize,
    fit_rotation: bool,
) -> Result<CrossValidation, String> {
    if views.len() < 6 {
        return Err(format!(
            "{} views: cross-validation calibrates two disjoint halves of 3 or more",
            views.len()
        ));
    }
    let half = |parity: usize| -> Vec<BoardView> {
        views.iter().skip(parity).step_by(2).cloned().collect()
    };
    let a = calibrate_camera(&half(0), width, height, free_distortion)
        .map_err(|e| format!("the even views: {e}"))?;
    let b = calibrate_camera(&half(1), width, height, free_distortion)
        .map_err(|e| format!("the odd views: {e}"))?;
    let columns = columns.max(2);
    let rows = ((columns * height) as f64 / width as f64).round().max(2.0) as usize;
    let cells: Vec<(f64, f64)> = (0..rows)
        .flat_map(|r| {
            (0..columns).map(move |c| {
                (
                    (c as f64 + 0.5) * width as f64 / columns as f64,
                    (r as f64 + 0.5) * height as f64 / rows as f64,
                )
            })
        })
        .collect();
    let ray = |m: &CameraModel, (u, v): (f64, f64)| {
        let (x, y) = m.undistort(u, v);
        Vector3::new(x, y, 1.0).normalize()
    };
    let rotation = if fit_rotation {
        let pairs: Vec<(Vector3<f64>, Vector3<f64>)> = cells
            .iter()
            .map(|&q| (ray(&a.camera, q), ray(&b.camera, q)))
            .collect();
        kabsch(&pairs)
    } else {
        Matrix3::identity()
    };
    let differences: Vec<(f64, f64, f64)> = cells
        .iter()
        .map(|&(u, v)| {
            let p = Point3::from(rotation * ray(&a.camera, (u, v)));
            let d = b
                .camera
                .project(&p)
                .map_or(f64::INFINITY, |q| (q.x - u).hypot(q.y - v));
            (u, v, d)
        })
        .collect();
    let mut sorted: Vec<f64> = differences.iter().map(|d| d.2).collect();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    Ok(CrossValidation {
        halves: [a, b],
        mean_px: sorted.iter().sum::<f64>() / n as f64,
        p95_px: sorted[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1],
        max_px: sorted[n - 1],
        differences,
        columns,
    })
}

/// The rotation R minimising sum |R a - b|^2 over unit vector pairs (a, b).
fn kabsch(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Matrix3<f64> {
    let h: Matrix3<f64> = pairs.iter().map(|(a, b)| b * a.transpose()).sum();
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u.expect("asked for U"), svd.v_t.expect("asked for V^T"));
    let d = (u * v_t).determinant().signum();
    u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::camera_calibration::pose_from;
    use crate::calib::camera_calibration::tests::{true_camera, views_of, with_noise};
    use nalgebra::{Isometry3, Rotation3};

    /// `n` board poses about 0.5 m away, tilted every way.
    fn poses(n: usize) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|k| {
                let k = k as f64;
                pose_from(&[
                    0.35 * (1.7 * k).sin(),
                    0.35 * (1.3 * k).cos(),
                    0.3 * (0.7 * k).sin(),
                    -100.0 + 25.0 * (0.9 * k).sin(),
                    -70.0 + 20.0 * (1.1 * k).cos(),
                    480.0 + 12.0 * k,
                ])
            })
            .collect()
    }

    #[test]
    fn exact_corners_give_two_equal_models() {
        let views = views_of(&true_camera(), &poses(8));
        let c =
            cross_validate(&views, 800, 600, [true, true, true, true, false], 16, true).unwrap();
        assert!(c.max_px < 1e-6, "{}", c.max_px);
        assert_eq!(c.differences.len(), 16 * 12);
    }

    #[test]
    fn too_few_views_show_in_the_difference_not_in_the_rms() {
        let free = [true, true, true, true, false];
        let noisy = |n| with_noise(views_of(&true_camera(), &poses(n)), 0.3, 4);
        let diff =
            |views: &[BoardView], free| cross_validate(views, 800, 600, free, 16, true).unwrap();
        let many = diff(&noisy(20), free);
        let few = diff(&noisy(6), free);
        // Both fit their corners alike (RMS 0.24 px), but three views a
        // half leave the model loose: 2.1 px apart on average (0.35 px from
        // ten views a half), 4.2 px at worst.
        let rms = |c: &CrossValidation| c.halves[0].rms_px.max(c.halves[1].rms_px);
        assert!((rms(&many) - rms(&few)).abs() < 0.1 * rms(&many));
        assert!(
            many.mean_px < 0.25 * few.mean_px,
            "{} vs {}",
            many.mean_px,
            few.mean_px
        );
        assert!(few.max_px > 2.0, "{}", few.max_px);
    }

    #[test]
    fn a_rotated_frame_is_fitted_away_and_too_few_views_are_refused() {
        let b = true_camera();
        let turn = Rotation3::from_euler_angles(0.002, -0.003, 0.001);
        let rays: Vec<(Vector3<f64>, Vector3<f64>)> =
            [(0.1, 0.2), (-0.3, 0.1), (0.2, -0.25), (0.0, 0.0)]
                .iter()
                .map(|&(x, y)| {
                    let a = Vector3::new(x, y, 1.0).normalize();
                    (a, turn * a)
                })
                .collect();
        assert!((kabsch(&rays) - turn.matrix()).norm() < 1e-12);
        let views = views_of(&b, &poses(5));
        let e = cross_validate(&views, 800, 600, [true; 5], 16, true).unwrap_err();
        assert!(e.contains("5 views"), "{e}");
    }
}
