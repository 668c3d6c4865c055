//! Points on surfaces: a mesh sampled uniformly by area (with the normal of
//! each sample's triangle), and a synthetic bumpy ellipsoid for ICP tests and
//! benchmarks.

use super::Nearest;
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};

/// `n` points of a bumpy ellipsoid (semi-axes about 60, 45, 35 mm) with no
/// symmetry, spread by a golden-angle spiral whose start `phase` (0..1) shifts
/// the samples: a shape for ICP tests and benchmarks.
pub fn bumpy_ellipsoid(n: usize, phase: f64) -> Vec<Point3<f64>> {
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + phase) / n as f64;
            let a = (i as f64 + phase) * 2.399963;
            let r = (1.0 - z * z).sqrt();
            let (x, y) = (r * a.cos(), r * a.sin());
            let bump =
                1.0 + 0.12 * (3.0 * x + 1.0).sin() * (2.0 * y).cos() + 0.08 * (4.0 * z * x).sin();
            Point3::new(60.0 * x * bump, 45.0 * y * bump, 35.0 * z * bump)
        })
        .collect()
}

/// `n` points spread uniformly by area over a triangle mesh (seeded), in the
/// mesh's frame.
pub fn sample_mesh(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    n: usize,
    seed: u64,
) -> Vec<Point3<f64>> {
    let areas: Vec<f64> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .collect();
    let mut cumulative = Vec::with_capacity(areas.len());
    let mut total = 0.0;
    for a in &areas {
        total += a;
        cumulative.push(total);
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .filter_map(|_| {
            let pick = rng.random_range(0.0..total.max(1e-300));
            let t = cumulative
                .partition_point(|&c| c < pick)
                .min(triangles.len().checked_sub(1)?);
            let [a, b, c] = triangles[t].map(|i| vertices[i as usize]);
            let (mut u, mut v): (f64, f64) = (rng.random(), rng.random());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            Some(a + (b - a) * u + (c - a) * v)
        })
        .collect()
}

/// Area-uniform samples as [`sample_mesh`] gives them, each with the unit
/// normal of the triangle whose centroid is nearest (+z for a mesh without
/// triangles).
pub fn sample_mesh_with_normals(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    n: usize,
    seed: u64,
) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let points = sample_mesh(vertices, triangles, n, seed);
    // The sampled triangle is not returned; take the normal of the nearest
    // vertex's surroundings by PCA-free means: the nearest triangle centroid.
    let centroids: Vec<Point3<f64>> = triangles
        .iter()
        .map(|t| {
            Point3::from(
                (vertices[t[0] as usize].coords
                    + vertices[t[1] as usize].coords
                    + vertices[t[2] as usize].coords)
                    / 3.0,
            )
        })
        .collect();
    let tree = Nearest::new(&centroids);
    let normals = points
        .iter()
        .map(|p| {
            let Some(tree) = &tree else {
                return Vector3::z();
            };
            let t = triangles[tree.nearest(p).0];
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            (b - a)
                .cross(&(c - a))
                .try_normalize(1e-30)
                .unwrap_or(Vector3::z())
        })
        .collect();
    (points, normals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_lie_on_the_triangle_with_its_normal() {
        let tri = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 0.0),
            Point3::new(0.0, 10.0, 0.0),
        ];
        let s = sample_mesh(&tri, &[[0, 1, 2]], 500, 3);
        assert_eq!(s.len(), 500);
        assert!(
            s.iter()
                .all(|p| p.x >= 0.0 && p.y >= 0.0 && p.x + p.y <= 10.0 + 1e-9 && p.z == 0.0)
        );
        let (points, normals) = sample_mesh_with_normals(&tri, &[[0, 1, 2]], 20, 3);
        assert_eq!(points, sample_mesh(&tri, &[[0, 1, 2]], 20, 3));
        assert!(normals.iter().all(|n| (n - Vector3::z()).norm() < 1e-12));
    }
}
