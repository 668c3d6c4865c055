//! Normal estimation by local PCA.

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
            let idx = tree.knn(p, k.max(3));
            let mean = idx
                .iter()
                .fold(Vector3::zeros(), |a, &i| a + points[i].coords)
                / idx.len() as f64;
            let cov = idx.iter().fold(Matrix3::zeros(), |a, &i| {
                let d = points[i].coords - mean;
                a + d * d.transpose()
            });
            let eig = cov.symmetric_eigen();
            let (min_i, _) = eig.eigenvalues.argmin();
            let mut n: Vector3<f64> = eig.eigenvectors.column(min_i).into();
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
}
