//! Normals and local plane covariances by PCA of each point's neighbours.

use super::Nearest;
use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;

/// Unit normals by PCA of each point's `k` nearest neighbours (the direction of
/// least spread), each flipped to face `viewpoint` when given (same frame as
/// the points, mm), else away from the cloud's centroid.
pub fn estimate_normals(
    points: &[Point3<f64>],
    k: usize,
    viewpoint: Option<Point3<f64>>,
) -> Vec<Vector3<f64>> {
    let Some(tree) = Nearest::new(points) else {
        return Vec::new();
    };
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / points.len() as f64;
    points
        .par_iter()
        .map(|p| {
            let mut n = least_spread(&tree, p, k.max(3));
            let towards = match viewpoint {
                Some(v) => v - p,
                None => p.coords - centroid,
            };
            if n.dot(&towards) < 0.0 {
                n = -n;
            }
            n
        })
        .collect()
}

/// The unit direction (either sign) in which the `k` points of `tree`
/// nearest `p` spread least: the local surface's normal.
fn least_spread(tree: &Nearest, p: &Point3<f64>, k: usize) -> Vector3<f64> {
    let idx = tree.knn(p, k);
    let mean = idx
        .iter()
        .fold(Vector3::zeros(), |a, &i| a + tree.point(i).coords)
        / idx.len() as f64;
    let scatter = idx.iter().fold(Matrix3::zeros(), |a, &i| {
        let d = tree.point(i).coords - mean;
        a + d * d.transpose()
    });
    let eig = scatter.symmetric_eigen();
    let (least, _) = eig.eigenvalues.argmin();
    eig.eigenvectors.column(least).into()
}

/// Across-plane variance of a plane covariance, relative to its in-plane
/// variance of 1 (Segal et al. 2009 and small_gicp use 1e-3).
pub const PLANE_COVARIANCE_EPSILON: f64 = 1e-3;

/// Each point's plane covariance (Segal et al. 2009, "plane-to-plane"):
/// the directions of its `k` nearest points in `surface` (the cloud's own
/// tree, or any sampling of the same surface), with the variance along the
/// two directions of most spread set to 1 and across them to
/// [`PLANE_COVARIANCE_EPSILON`]. Unitless: only the ratio matters to
/// generalized ICP. Same frame as the points.
pub fn plane_covariances(points: &[Point3<f64>], surface: &Nearest, k: usize) -> Vec<Matrix3<f64>> {
    points
        .par_iter()
        .map(|p| plane_covariance(p, surface, k))
        .collect()
}

/// One point's plane covariance (see [`plane_covariances`]).
pub fn plane_covariance(p: &Point3<f64>, surface: &Nearest, k: usize) -> Matrix3<f64> {
    let n = least_spread(surface, p, k.max(3));
    Matrix3::identity() - n * n.transpose() * (1.0 - PLANE_COVARIANCE_EPSILON)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_of_a_sphere_point_outward() {
        let pts: Vec<Point3<f64>> = (0..2000)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / 2000.0;
                let a = i as f64 * 2.399963;
                let r = (1.0 - z * z).sqrt();
                Point3::new(30.0 * r * a.cos(), 30.0 * r * a.sin(), 30.0 * z)
            })
            .collect();
        let normals = estimate_normals(&pts, 12, None);
        for (p, n) in pts.iter().zip(&normals) {
            assert!(n.dot(&(p.coords / 30.0)) > 0.99, "{p} {n}");
        }
        let viewed = estimate_normals(&pts, 12, Some(Point3::new(0.0, 0.0, 500.0)));
        assert!(
            viewed
                .iter()
                .zip(&pts)
                .all(|(n, p)| n.dot(&(Point3::new(0.0, 0.0, 500.0) - p)) >= 0.0)
        );
    }

    #[test]
    fn plane_covariances_are_flat_across_the_surface() {
        // A tilted plane z = 0.5 x, sampled on a grid.
        let points: Vec<Point3<f64>> = (0..400)
            .map(|k| {
                let (x, y) = ((k % 20) as f64, (k / 20) as f64);
                Point3::new(x, y, 0.5 * x)
            })
            .collect();
        let tree = Nearest::new(&points).unwrap();
        let normal = Vector3::new(-0.5, 0.0, 1.0).normalize();
        let along = Vector3::new(1.0, 0.0, 0.5).normalize();
        for c in plane_covariances(&points, &tree, 12) {
            assert!((normal.dot(&(c * normal)) - PLANE_COVARIANCE_EPSILON).abs() < 1e-9);
            assert!((along.dot(&(c * along)) - 1.0).abs() < 1e-9);
            assert!((Vector3::y().dot(&(c * Vector3::y())) - 1.0).abs() < 1e-9);
        }
    }
}
