//! The baseline study: how reliably a verging two-camera rig triangulates as
//! its baseline grows. For each baseline, 3D points in the working volume are
//! projected into both cameras, image noise is added many times over, and each
//! noisy pair is triangulated by the linear (DLT) method; the spread of the
//! estimates is the triangulation's variance.

use nalgebra::{Matrix3x4, Matrix4, Point3, Rotation3, Vector2, Vector3, Vector4};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

/// The study's set-up.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyParams {
    /// Baselines to compare, mm.
    pub baselines_mm: Vec<f64>,
    /// Lens focal length, mm.
    pub focal_mm: f64,
    /// Pixel pitch, mm.
    pub pixel_mm: f64,
    /// Image size, px.
    pub image_px: [usize; 2],
    /// Distance at which the optical axes cross (verging: theta = atan(b / D)), mm.
    pub converge_mm: f64,
    /// Working range along the left optical axis, mm.
    pub range_mm: [f64; 2],
    /// Points per baseline.
    pub points: usize,
    /// Noisy repetitions per point.
    pub repetitions: usize,
    /// Image noise standard deviation, px (both coordinates, both images).
    pub noise_px: f64,
    /// Seed.
    pub seed: u64,
}

impl BaselineStudy {
    /// Least-squares slope of log(var z) against log(baseline), if there are
    /// at least two baselines (-2 for depth error ~ Z^2 / (f b)).
    pub fn loglog_slope_z(&self) -> Option<f64> {
        if self.rows.len() < 2 {
            return None;
        }
        let xs: Vec<f64> = self.rows.iter().map(|r| r.baseline_mm.ln()).collect();
        let ys: Vec<f64> = self.rows.iter().map(|r| r.variance_mm2[2].ln()).collect();
        let n = xs.len() as f64;
        let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
        let covariance: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        Some(covariance / xs.iter().map(|x| (x - mx).powi(2)).sum::<f64>())
    }
}

/// Mean variance of the estimates (mm^2) for one baseline.
#[derive(Debug, Clone, PartialEq)]
pub struct VarianceRow {
    /// Baseline, mm.
    pub baseline_mm: f64,
    /// Verging angle, deg.
    pub verging_deg: f64,
    /// Mean over points of the variance of x, y, z (left camera frame), mm^2.
    pub variance_mm2: [f64; 3],
}

/// The study's result, one row per baseline.
#[derive(Debug, Clone, PartialEq)]
pub struct BaselineStudy {
    /// Rows in baseline order.
    pub rows: Vec<VarianceRow>,
}

fn projection(
    k: &nalgebra::Matrix3<f64>,
    world_to_camera: &Rotation3<f64>,
    centre: &Point3<f64>,
) -> Matrix3x4<f64> {
    let r = world_to_camera.matrix();
    let t = -(r * centre.coords);
    let mut rt = Matrix3x4::zeros();
    rt.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    rt.set_column(3, &t);
    k * rt
}

/// Linear triangulation (DLT): the point whose projections best satisfy
/// x P3 - P1 = 0 and y P3 - P2 = 0 in both images, as the smallest singular
/// vector of the 4 x 4 system.
pub fn triangulate_dlt(
    p1: &Matrix3x4<f64>,
    p2: &Matrix3x4<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Option<Point3<f64>> {
    let mut a = Matrix4::zeros();
    for (row, (p, x)) in [(p1, x1), (p2, x2)].into_iter().enumerate() {
        a.set_row(2 * row, &(p.row(2) * x.x - p.row(0)));
        a.set_row(2 * row + 1, &(p.row(2) * x.y - p.row(1)));
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let (i, _) = svd.singular_values.argmin();
    let h: Vector4<f64> = v_t.row(i).transpose();
    (h.w.abs() > 1e-12).then(|| Point3::new(h.x / h.w, h.y / h.w, h.z / h.w))
}

fn project(p: &Matrix3x4<f64>, x: &Point3<f64>) -> Vector2<f64> {
    let h = p * x.to_homogeneous();
    Vector2::new(h.x / h.z, h.y / h.z)
}

/// The most triangulations a study may run (minutes on 2 cores): a bound on
/// `points x repetitions x baselines` that keeps a run within the machine.
pub const MAX_TRIANGULATIONS: f64 = 1e9;

/// Runs the study. Points are drawn once (so every baseline sees the same
/// points), uniformly in the part of the left camera's view between the range
/// limits that every rig also sees in its right camera. Deterministic for a
/// seed; parallel over points. A reversed range or a study too large for the
/// machine is an error.
pub fn baseline_study(p: &StudyParams) -> Result<BaselineStudy, String> {
    let [near, far] = p.range_mm;
    if !(near.is_finite() && far.is_finite() && near < far) {
        return Err(format!(
            "range_mm = [{near}, {far}]: give the near then the far end of the working range"
        ));
    }
    // Each repetition triangulates every point once per baseline.
    let work = (p.points as f64) * (p.repetitions as f64) * (p.baselines_mm.len() as f64);
    if work > MAX_TRIANGULATIONS {
        return Err(format!(
            "{} points x {} repetitions x {} baselines = {work:.3e} triangulations, above {MAX_TRIANGULATIONS:.0e}: fewer points or repetitions",
            p.points,
            p.repetitions,
            p.baselines_mm.len()
        ));
    }
    let f_px = p.focal_mm / p.pixel_mm;
    let [w, h] = p.image_px.map(|v| v as f64);
    let k = nalgebra::Matrix3::new(f_px, 0.0, w / 2.0, 0.0, f_px, h / 2.0, 0.0, 0.0, 1.0);
    let rigs: Vec<(f64, Matrix3x4<f64>, Matrix3x4<f64>)> = p
        .baselines_mm
        .iter()
        .map(|&b| {
            let theta = (b / p.converge_mm).atan();
            // Left camera at the origin looking along +z; right camera at +b on x,
            // turned by theta towards the left so the axes cross at converge_mm.
            let left = projection(&k, &Rotation3::identity(), &Point3::origin());
            let right_orientation = Rotation3::from_axis_angle(&Vector3::y_axis(), -theta);
            let right = projection(&k, &right_orientation.inverse(), &Point3::new(b, 0.0, 0.0));
            (theta.to_degrees(), left, right)
        })
        .collect();
    let inside = |x: &Vector2<f64>| x.x >= 0.0 && x.y >= 0.0 && x.x <= w && x.y <= h;
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let mut points = Vec::with_capacity(p.points);
    let mut attempts = 0;
    while points.len() < p.points {
        attempts += 1;
        if attempts > 1000 * p.points.max(1) {
            return Err(
                "no point of the working range is seen by both cameras of every rig".into(),
            );
        }
        let z = rng.random_range(p.range_mm[0]..=p.range_mm[1]);
        let (u, v) = (rng.random_range(0.0..w), rng.random_range(0.0..h));
        let x = Point3::new((u - w / 2.0) / f_px * z, (v - h / 2.0) / f_px * z, z);
        if rigs.iter().all(|(_, _, right)| {
            let in_front = (right.row(2) * x.to_homogeneous())[0] > 0.0;
            in_front && inside(&project(right, &x))
        }) {
            points.push(x);
        }
    }
    let noise = Normal::new(0.0, p.noise_px).map_err(|e| format!("noise_px: {e}"))?;
    let rows = rigs
        .iter()
        .enumerate()
        .map(|(bi, (verging_deg, left, right))| {
            let sums: Vec<[f64; 3]> = points
                .par_iter()
                .enumerate()
                .map(|(pi, x)| {
                    let mut rng = ChaCha8Rng::seed_from_u64(
                        p.seed ^ ((bi as u64) << 40) ^ ((pi as u64) << 20) ^ 0xC0FFEE,
                    );
                    let (c1, c2) = (project(left, x), project(right, x));
                    let estimates: Vec<Point3<f64>> = (0..p.repetitions)
                        .filter_map(|_| {
                            let mut jitter =
                                || Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng));
                            let (n1, n2) = (jitter(), jitter());
                            triangulate_dlt(left, right, &(c1 + n1), &(c2 + n2))
                        })
                        .collect();
                    let n = estimates.len() as f64;
                    let mean = estimates
                        .iter()
                        .fold(Vector3::zeros(), |acc, e| acc + e.coords)
                        / n;
                    let var = estimates.iter().fold(Vector3::zeros(), |acc, e| {
                        let d = e.coords - mean;
                        acc + d.component_mul(&d)
                    }) / (n - 1.0);
                    [var.x, var.y, var.z]
                })
                .collect();
            let n = sums.len() as f64;
            let variance_mm2 = std::array::from_fn(|a| sums.iter().map(|s| s[a]).sum::<f64>() / n);
            VarianceRow {
                baseline_mm: p.baselines_mm[bi],
                verging_deg: *verging_deg,
                variance_mm2,
            }
        })
        .collect();
    Ok(BaselineStudy { rows })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> StudyParams {
        StudyParams {
            baselines_mm: vec![50.0, 100.0, 150.0, 200.0, 250.0],
            focal_mm: 8.0,
            pixel_mm: 0.006,
            image_px: [800, 600],
            converge_mm: 400.0,
            range_mm: [400.0, 700.0],
            points: 100,
            repetitions: 200,
            noise_px: 1.0,
            seed: 7,
        }
    }

    #[test]
    fn a_reversed_range_or_an_oversized_study_is_an_error() {
        let reversed = StudyParams {
            range_mm: [700.0, 400.0],
            ..params()
        };
        let e = baseline_study(&reversed).unwrap_err();
        assert!(e.contains("range_mm = [700, 400]"), "{e}");
        let huge = StudyParams {
            points: 1_000_000,
            repetitions: 100_000,
            ..params()
        };
        let e = baseline_study(&huge).unwrap_err();
        assert!(e.contains("triangulations, above 1e9"), "{e}");
    }

    #[test]
    fn dlt_is_exact_without_noise() {
        let k = nalgebra::Matrix3::new(1000.0, 0.0, 400.0, 0.0, 1000.0, 300.0, 0.0, 0.0, 1.0);
        let p1 = projection(&k, &Rotation3::identity(), &Point3::origin());
        let p2 = projection(
            &k,
            &Rotation3::from_euler_angles(0.01, 0.2, -0.03),
            &Point3::new(80.0, 5.0, -3.0),
        );
        let x = Point3::new(12.0, -30.0, 520.0);
        let back = triangulate_dlt(&p1, &p2, &project(&p1, &x), &project(&p2, &x)).unwrap();
        assert!((back - x).norm() < 1e-8, "{back}");
    }

    #[test]
    fn depth_variance_falls_about_as_one_over_b_squared() {
        let study = baseline_study(&params()).unwrap();
        let z: Vec<f64> = study.rows.iter().map(|r| r.variance_mm2[2]).collect();
        assert!(z.windows(2).all(|w| w[1] < w[0]), "{z:?}");
        let slope = study.loglog_slope_z().unwrap();
        assert!((-2.6..=-1.4).contains(&slope), "slope {slope}");
        // Lateral precision changes little with baseline; depth dominates.
        assert!(
            study
                .rows
                .iter()
                .all(|r| r.variance_mm2[2] > r.variance_mm2[0])
        );
    }

    #[test]
    fn deterministic_and_scaling_with_noise_squared() {
        let a = baseline_study(&params()).unwrap();
        assert_eq!(a, baseline_study(&params()).unwrap());
        let serial = crate::on_threads(1, || baseline_study(&params()).unwrap());
        assert_eq!(
            a,
            crate::on_threads(3, || baseline_study(&params()).unwrap())
        );
        assert_eq!(a, serial, "one thread and several");
        let half = baseline_study(&StudyParams {
            noise_px: 0.5,
            ..params()
        })
        .unwrap();
        let ratio = half.rows[1].variance_mm2[2] / a.rows[1].variance_mm2[2];
        assert!((ratio - 0.25).abs() < 0.03, "{ratio}");
    }
}
