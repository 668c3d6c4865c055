//! The dominant plane of a cloud (a table under the object) by RANSAC, refined
//! by least squares on its inliers, so a scene's support can be removed before
//! registration: a large plane lets ICP slide along it.
//!
//! Written here: a few lines over nalgebra; no crate of the field does just
//! this (Open3D's `segment_plane` is the model).

use fusegraph_engine::value::{Table, ValueError};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rand::{Rng, SeedableRng};

/// A plane `normal . p = offset` (unit normal, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vector3<f64>,
    /// Signed distance of the plane from the origin along the normal, mm.
    pub offset: f64,
}

impl Plane {
    /// Signed distance of `p` from the plane, mm.
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.offset
    }

    /// The same plane in another frame: where `motion` takes this frame's
    /// points (`normal . p = offset` becomes `R normal . q = offset + R
    /// normal . t` for q = R p + t).
    pub fn moved_by(&self, motion: &Isometry3<f64>) -> Plane {
        let normal = motion.rotation * self.normal;
        Plane {
            normal,
            offset: self.offset + normal.dot(&motion.translation.vector),
        }
    }

    /// The least-squares plane through `points` (at least 3, not collinear).
    pub fn fit(points: &[Point3<f64>]) -> Option<Plane> {
        if points.len() < 3 {
            return None;
        }
        let centre = points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len() as f64;
        let mut cov = Matrix3::zeros();
        for p in points {
            let d = p.coords - centre;
            cov += d * d.transpose();
        }
        let eig = cov.symmetric_eigen();
        let (i, _) = eig.eigenvalues.argmin();
        let normal = eig.eigenvectors.column(i).into_owned();
        normal.iter().all(|v| v.is_finite()).then(|| Plane {
            normal,
            offset: normal.dot(&centre),
        })
    }
}

/// The plane holding most points of `points` within `threshold_mm`, from
/// `iterations` random triples (seeded: the same cloud gives the same plane),
/// refined on its inliers; `None` for fewer than 3 points.
pub fn dominant_plane(
    points: &[Point3<f64>],
    threshold_mm: f64,
    iterations: usize,
    seed: u64,
) -> Option<(Plane, usize)> {
    let n = points.len();
    if n < 3 {
        return None;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    // Count inliers on a sample of the cloud: plenty to rank candidates.
    let stride = (n / 20_000).max(1);
    let count = |plane: &Plane| {
        points
            .iter()
            .step_by(stride)
            .filter(|p| plane.distance(p).abs() <= threshold_mm)
            .count()
    };
    let mut best: Option<(Plane, usize)> = None;
    for _ in 0..iterations {
        let [a, b, c] = [0; 3].map(|_| points[rng.random_range(0..n)]);
        let normal = (b - a).cross(&(c - a));
        let Some(normal) = normal.try_normalize(1e-9) else {
            continue;
        };
        let plane = Plane {
            normal,
            offset: normal.dot(&a.coords),
        };
        let votes = count(&plane);
        if best.is_none_or(|(_, v)| votes > v) {
            best = Some((plane, votes));
        }
    }
    let (rough, _) = best?;
    let inliers: Vec<Point3<f64>> = points
        .iter()
        .copied()
        .filter(|p| rough.distance(p).abs() <= threshold_mm)
        .collect();
    let plane = Plane::fit(&inliers).unwrap_or(rough);
    let held = points
        .iter()
        .filter(|p| plane.distance(p).abs() <= threshold_mm)
        .count();
    Some((plane, held))
}

/// Which points of `points` (in a camera frame: the camera at the origin, mm)
/// stay when the table under an object is removed: when the dominant plane
/// ([`dominant_plane`] with `threshold_mm`, `iterations` and `seed`) holds at
/// least `min_fraction` of the points, those more than `threshold_mm` off it
/// on the camera's side; else every point. Also the table (its normal
/// towards the camera) and the fraction of the points it held (`None` and 0
/// when none was removed).
pub fn off_table(
    points: &[Point3<f64>],
    threshold_mm: f64,
    min_fraction: f64,
    iterations: usize,
    seed: u64,
) -> (Vec<bool>, Option<Plane>, f64) {
    match dominant_plane(points, threshold_mm, iterations, seed) {
        Some((plane, held)) if held as f64 >= min_fraction * points.len() as f64 => {
            // The camera's side of the plane is where the origin is.
            let towards_camera = plane.distance(&Point3::origin()).signum();
            let table = Plane {
                normal: plane.normal * towards_camera,
                offset: plane.offset * towards_camera,
            };
            let keep = points
                .iter()
                .map(|p| table.distance(p) > threshold_mm)
                .collect();
            (keep, Some(table), held as f64 / points.len() as f64)
        }
        _ => (vec![true; points.len()], None, 0.0),
    }
}

/// The columns of a plane as a table: normal_x, normal_y, normal_z, offset_mm.
pub const PLANE_COLUMNS: [&str; 4] = ["normal_x", "normal_y", "normal_z", "offset_mm"];

/// A plane as a one-row table ([`PLANE_COLUMNS`]); no rows for `None`.
pub fn plane_table(plane: Option<&Plane>) -> Result<Table, ValueError> {
    let data: Vec<f64> = plane
        .map(|p| vec![p.normal.x, p.normal.y, p.normal.z, p.offset])
        .unwrap_or_default();
    Table::new(PLANE_COLUMNS.map(String::from).to_vec(), data)
}

/// The plane a [`plane_table`] holds: `Ok(None)` without rows, an error
/// naming what is wrong for other columns, several rows or a normal that is
/// not a unit vector.
pub fn plane_from_table(table: &Table) -> Result<Option<Plane>, String> {
    if table.columns != PLANE_COLUMNS {
        return Err(format!(
            "a plane's columns are {}, not {}",
            PLANE_COLUMNS.join(", "),
            table.columns.join(", ")
        ));
    }
    match table.row_count() {
        0 => Ok(None),
        1 => {
            let r = table.row(0);
            let normal = Vector3::new(r[0], r[1], r[2]);
            if !((normal.norm() - 1.0).abs() < 1e-6 && r[3].is_finite()) {
                return Err(format!(
                    "the plane's normal {normal:?} is not a unit vector"
                ));
            }
            Ok(Some(Plane {
                normal,
                offset: r[3],
            }))
        }
        n => Err(format!("a plane is one row, not {n}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_table_under_a_dome_and_its_distance() {
        // A tilted table z = 600 + 0.1 x (mm) with noise, a dome above it.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut pts = Vec::new();
        for _ in 0..20_000 {
            let (x, y) = (
                rng.random_range(-200.0..200.0),
                rng.random_range(-200.0..200.0),
            );
            pts.push(Point3::new(
                x,
                y,
                600.0 + 0.1 * x + rng.random_range(-0.5..0.5),
            ));
        }
        for _ in 0..8_000 {
            let (t, r): (f64, f64) = (
                rng.random_range(0.0..std::f64::consts::TAU),
                rng.random_range(0.0..60.0),
            );
            let (x, y) = (r * t.cos(), r * t.sin());
            let h = (3600.0 - r * r).sqrt();
            pts.push(Point3::new(x, y, 600.0 + 0.1 * x - h));
        }
        let (plane, held) = dominant_plane(&pts, 1.5, 200, 1).unwrap();
        let expect = Vector3::new(-0.1, 0.0, 1.0).normalize();
        assert!(plane.normal.dot(&expect).abs() > 0.9999, "{plane:?}");
        assert!((20_000..20_500).contains(&held), "{held}");
        assert!((plane.distance(&Point3::new(0.0, 0.0, 600.0))).abs() < 0.1);
        assert!(dominant_plane(&pts[..2], 1.0, 10, 1).is_none());
    }

    #[test]
    fn the_table_and_what_lies_beyond_it_go() {
        // A table at z = 500 mm seen from the origin, a point above it (on the
        // camera's side) and one below it.
        let mut pts: Vec<Point3<f64>> = (0..400)
            .map(|i| Point3::new((i % 20) as f64 * 5.0, (i / 20) as f64 * 5.0, 500.0))
            .collect();
        pts.extend([
            Point3::new(10.0, 10.0, 480.0),
            Point3::new(10.0, 10.0, 520.0),
        ]);
        let (keep, table, fraction) = off_table(&pts, 1.0, 0.5, 50, 1);
        assert_eq!(keep.iter().filter(|k| **k).count(), 1);
        assert!(keep[400] && !keep[401]);
        assert!((fraction - 400.0 / 402.0).abs() < 1e-12);
        // The table faces the camera: z = 500 with its normal along -z.
        let table = table.unwrap();
        assert!((table.normal - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-9);
        assert!((table.offset + 500.0).abs() < 1e-9);
        assert!(table.distance(&Point3::origin()) > 0.0);
        // Too small a share of the points: nothing goes.
        let (keep, table, fraction) = off_table(&pts, 1.0, 0.999, 50, 1);
        assert_eq!((keep, table, fraction), (vec![true; 402], None, 0.0));
    }

    #[test]
    fn a_plane_goes_through_a_table_and_back() {
        let plane = Plane {
            normal: Vector3::new(0.0, 0.6, -0.8),
            offset: -412.5,
        };
        let table = plane_table(Some(&plane)).unwrap();
        assert_eq!(plane_from_table(&table).unwrap(), Some(plane));
        assert_eq!(plane_from_table(&plane_table(None).unwrap()).unwrap(), None);
        let stretched = Table::new(
            PLANE_COLUMNS.map(String::from).to_vec(),
            vec![0.0, 0.0, 2.0, 1.0],
        )
        .unwrap();
        assert!(plane_from_table(&stretched).unwrap_err().contains("unit"));
        let other = Table::new(vec!["x".into()], vec![1.0]).unwrap();
        assert!(plane_from_table(&other).unwrap_err().contains("columns"));
    }

    #[test]
    fn a_moved_plane_holds_the_moved_points() {
        let plane = Plane {
            normal: Vector3::new(0.0, 0.6, -0.8),
            offset: -412.5,
        };
        let motion = Isometry3::new(Vector3::new(12.0, -40.0, 7.5), Vector3::new(0.3, -0.2, 1.1));
        let moved = plane.moved_by(&motion);
        // Points on the plane and 3 mm off it keep their signed distance.
        let on = Point3::new(10.0, -250.0, 328.125);
        assert!(plane.distance(&on).abs() < 1e-9);
        for off in [0.0, 3.0] {
            let p = on + plane.normal * off;
            assert!((moved.distance(&(motion * p)) - off).abs() < 1e-9);
        }
    }
}
