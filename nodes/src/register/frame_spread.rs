//! How well the markers pin the views of a merged set to the first view:
//! the joint least-squares adjustment of every other view's pose and every
//! marker's position from all sightings, linearised where the merge left
//! them, each sighting weighed as the merge weighed it. The first view's
//! pose is held (it is the merged set's frame), so its sightings' errors
//! move every other view: the covariance of the others' mean pose is how
//! far the merged set may sit from the first view's true frame.
//!
//! Only the markers count. The surfaces' pairs are many, but their errors
//! are smooth over each view and biased along its rays, so they pin the
//! views' relative poses far less than their number says; on the built-in
//! phantom (lab preset, true rig) the merged set's frame follows the
//! markers' noise alone (observed 0.167 mm RMS, 0.147 mm from the markers'
//! adjustment, seeds 41-48). Where the surfaces do hold the views, the
//! figure errs on the wide side.

use super::pairs::motion_jacobian;
use nalgebra::{DMatrix, Matrix3, Matrix6, Point3};

/// One sighting of a marker: the view that saw it, and where the merge put
/// it, its covariance and the covariance the merge weighed it by, all in the
/// poses' frame (mm, mm^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sighting {
    /// The view that saw it (0: the view the others are held to).
    pub view: usize,
    /// Where the merge put it, mm.
    pub position: Point3<f64>,
    /// The covariance of its error.
    pub covariance: Matrix3<f64>,
    /// The covariance whose inverse weighed it (`covariance` for the best
    /// weighing).
    pub weighed_as: Matrix3<f64>,
}

/// The covariance (rad, mm; rotation first) of the mean small motion
/// `p -> p + w x p + t` (in the poses' frame) of views `1..views` relative
/// to view 0, from the sightings of each marker (`markers[k]`: every
/// sighting of marker k): H^-1 (sum J^T W C W J) H^-1 over the whole
/// adjustment (H = sum J^T W J, W the inverse of `weighed_as`, C the
/// `covariance`). An error when the sightings do not pin every view (each
/// needs three markers it shares with the others, not in a line) or a
/// covariance is not positive definite.
pub fn markers_frame_covariance(
    markers: &[Vec<Sighting>],
    views: usize,
) -> Result<Matrix6<f64>, String> {
    if views < 2 {
        return Err("one view: no frame to pin".into());
    }
    for v in 1..views {
        let shared = markers
            .iter()
            .filter(|m| m.iter().any(|s| s.view == v) && m.iter().any(|s| s.view != v))
            .count();
        if shared < 3 {
            return Err(format!(
                "view {v} shares {shared} markers with the others: three pin a view"
            ));
        }
    }
    let poses = 6 * (views - 1);
    let n = poses + 3 * markers.len();
    let (mut h, mut meat) = (DMatrix::<f64>::zeros(n, n), DMatrix::<f64>::zeros(n, n));
    for (k, sightings) in markers.iter().enumerate() {
        for s in sightings {
            if s.view >= views {
                return Err(format!("a sighting of view {} of {views}", s.view));
            }
            let w = s
                .weighed_as
                .cholesky()
                .map(|c| c.inverse())
                .ok_or_else(|| {
                    format!(
                        "view {}: a sighting's weight is not positive definite",
                        s.view
                    )
                })?;
            // J: how the sighting's residual moves with its view's pose and
            // its marker's position.
            let mut j = DMatrix::<f64>::zeros(3, n);
            if s.view > 0 {
                j.view_mut((0, 6 * (s.view - 1)), (3, 6))
                    .copy_from(&motion_jacobian(&s.position));
            }
            j.view_mut((0, poses + 3 * k), (3, 3))
                .copy_from(&(-Matrix3::identity()));
            let jw = j.transpose() * dense(&w);
            h += &jw * &j;
            meat += &jw * dense(&s.covariance) * jw.transpose();
        }
    }
    // Three markers in a line leave a turn about it free.
    let eigenvalues = h.clone().symmetric_eigenvalues();
    let (low, high) = (eigenvalues.min(), eigenvalues.max());
    if low.is_nan() || low <= 1e-12 * high {
        return Err("the markers do not pin every view (in a line?)".into());
    }
    let h_inverse = h
        .cholesky()
        .ok_or("the markers do not pin every view (in a line?)")?
        .inverse();
    // The views' mean motion: M x, M = [I I ... I 0] / (views - 1).
    let mut m = DMatrix::<f64>::zeros(6, n);
    for v in 0..views - 1 {
        m.view_mut((0, 6 * v), (6, 6))
            .copy_from(&(DMatrix::identity(6, 6) / (views - 1) as f64));
    }
    let a = m * &h_inverse;
    let c = &a * meat * a.transpose();
    Ok(Matrix6::from_fn(|r, col| c[(r, col)]))
}

fn dense(m: &Matrix3<f64>) -> DMatrix<f64> {
    DMatrix::from_column_slice(3, 3, m.as_slice())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::register::mapped_point_covariance;
    use nalgebra::{Isometry3, Vector3, Vector6};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Ten markers on a dome 60 mm across.
    fn dome() -> Vec<Point3<f64>> {
        (0..10)
            .map(|k| {
                let a = k as f64 * 0.7;
                let r = 15.0 + 3.0 * k as f64;
                Point3::new(r * a.cos(), r * a.sin(), 40.0 - 0.01 * r * r)
            })
            .collect()
    }

    /// Each of `points` seen by views `0..views` with covariance `c`.
    fn seen_by_all(points: &[Point3<f64>], views: usize, c: Matrix3<f64>) -> Vec<Vec<Sighting>> {
        points
            .iter()
            .map(|&position| {
                (0..views)
                    .map(|view| Sighting {
                        view,
                        position,
                        covariance: c,
                        weighed_as: c,
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn two_views_of_every_marker_pin_the_middle_by_the_mean_of_their_differences() {
        // Every marker seen by both views with 0.2 mm of noise in every
        // direction: at the markers' centroid the second view's shift has
        // the variance of the mean of K differences, 2 sigma^2 / K per axis.
        let points = dome();
        let markers = seen_by_all(&points, 2, Matrix3::identity() * 0.04);
        let frame = markers_frame_covariance(&markers, 2).unwrap();
        let centroid = Point3::from(points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / 10.0);
        let at = mapped_point_covariance(&Isometry3::identity(), &frame, &centroid);
        let expected = Matrix3::identity() * (2.0 * 0.04 / 10.0);
        assert!((at - expected).amax() < 1e-9, "{at}");
    }

    #[test]
    fn the_views_mean_motion_spreads_as_a_joint_fit_of_noisy_sightings_does() {
        // Four views around the dome, each marker seen by three of them,
        // each sighting ten times less certain along its view's line of
        // sight, and weighed as if it were less lopsided (as the merge does
        // when the calibration's spread joins the weights). 2,000 draws of
        // the sightings' noise, each adjusted by a plain weighted
        // least-squares solve of the whole system (poses and markers),
        // against the model.
        let points = dome();
        let eyes = [
            Vector3::new(0.0, 0.0, 500.0),
            Vector3::new(300.0, 0.0, 400.0),
            Vector3::new(-150.0, 260.0, 400.0),
            Vector3::new(-150.0, -260.0, 400.0),
        ];
        let markers: Vec<Vec<Sighting>> = points
            .iter()
            .enumerate()
            .map(|(k, &position)| {
                (0..4)
                    .filter(|v| (k + v) % 4 != 3)
                    .map(|view| {
                        let sight = (eyes[view] - position.coords).normalize();
                        let covariance =
                            Matrix3::identity() * 0.01 + sight * sight.transpose() * 0.99;
                        Sighting {
                            view,
                            position,
                            covariance,
                            weighed_as: covariance + Matrix3::identity() * 0.1,
                        }
                    })
                    .collect()
            })
            .collect();
        let model = markers_frame_covariance(&markers, 4).unwrap();
        // The whole system: 18 pose unknowns, then 3 per marker.
        let unknowns = 18 + 3 * points.len();
        let mut rows: Vec<(DMatrix<f64>, Matrix3<f64>, Matrix3<f64>)> = Vec::new();
        for (k, sightings) in markers.iter().enumerate() {
            for s in sightings {
                let mut j = DMatrix::zeros(3, unknowns);
                if s.view > 0 {
                    j.view_mut((0, 6 * (s.view - 1)), (3, 6))
                        .copy_from(&motion_jacobian(&s.position));
                }
                j.view_mut((0, 18 + 3 * k), (3, 3))
                    .copy_from(&(-Matrix3::identity()));
                let root = s.covariance.cholesky().unwrap().l();
                rows.push((j, s.weighed_as.try_inverse().unwrap(), root));
            }
        }
        let h = rows
            .iter()
            .fold(DMatrix::zeros(unknowns, unknowns), |h, (j, w, _)| {
                h + j.transpose() * DMatrix::from_column_slice(3, 3, w.as_slice()) * j
            });
        let h_inverse = h.try_inverse().unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(8);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let (mut sum, mut outer) = (Vector6::zeros(), Matrix6::zeros());
        for _ in 0..2000 {
            let mut g = nalgebra::DVector::zeros(unknowns);
            for (j, w, root) in &rows {
                let noise = root * Vector3::from_fn(|_, _| unit.sample(&mut rng));
                g += j.transpose() * nalgebra::DVector::from_column_slice((w * noise).as_slice());
            }
            let x = -(&h_inverse * g);
            let mean = (0..3).fold(Vector6::zeros(), |m, v| m + x.fixed_rows::<6>(6 * v) / 3.0);
            sum += mean;
            outer += mean * mean.transpose();
        }
        let mean = sum / 2000.0;
        let observed = outer / 2000.0 - mean * mean.transpose();
        let target = Point3::new(5.0, -10.0, -20.0);
        let (o, m) = (
            mapped_point_covariance(&Isometry3::identity(), &observed, &target).trace(),
            mapped_point_covariance(&Isometry3::identity(), &model, &target).trace(),
        );
        assert!((m / o - 1.0).abs() < 0.08, "model {m} vs observed {o}");
    }

    #[test]
    fn a_view_that_shares_too_few_markers_is_an_error() {
        let points = dome();
        let c = Matrix3::identity() * 0.04;
        let mut markers = seen_by_all(&points, 2, c);
        // View 2 sees two markers the others see.
        for m in markers.iter_mut().take(2) {
            let third = Sighting { view: 2, ..m[0] };
            m.push(third);
        }
        let e = markers_frame_covariance(&markers, 3).unwrap_err();
        assert!(e.contains("view 2 shares 2 markers"), "{e}");
        // Three that lie in a line leave it free to turn about the line.
        let line: Vec<Point3<f64>> = (0..3)
            .map(|k| Point3::new(10.0 * k as f64, 0.0, 0.0))
            .collect();
        let e = markers_frame_covariance(&seen_by_all(&line, 2, c), 2).unwrap_err();
        assert!(e.contains("in a line"), "{e}");
        assert!(markers_frame_covariance(&markers, 1).is_err());
    }
}
