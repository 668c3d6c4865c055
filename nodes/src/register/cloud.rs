//! Point cloud helpers: nearest-neighbour search (a kiddo k-d tree), sampling a
//! mesh, voxel-grid downsampling and normal estimation by local PCA.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::collections::HashMap;
use std::num::NonZero;

/// A k-d tree over a fixed set of points.
pub struct Nearest {
    tree: ImmutableKdTree<f64, 3>,
}

impl Nearest {
    /// Builds the tree (`None` for an empty set).
    pub fn new(points: &[Point3<f64>]) -> Option<Self> {
        if points.is_empty() {
            return None;
        }
        let raw: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        ImmutableKdTree::new_from_slice(&raw)
            .ok()
            .map(|tree| Nearest { tree })
    }

    /// Index of the nearest point and the squared distance to it.
    pub fn nearest(&self, p: &Point3<f64>) -> (usize, f64) {
        let r = self
            .tree
            .query(&[p.x, p.y, p.z])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (r.item as usize, r.distance)
    }

    /// Indices of the `k` nearest points.
    pub fn knn(&self, p: &Point3<f64>, k: usize) -> Vec<usize> {
        self.tree
            .query(&[p.x, p.y, p.z])
            .nearest_n::<SquaredEuclidean<f64>>(NonZero::new(k.max(1)).expect("k >= 1"))
            .execute()
            .iter()
            .map(|r| r.item as usize)
            .collect()
    }
}

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

/// `n` points spread uniformly by area over a triangle mesh (seeded).
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

/// One point per occupied cube of side `voxel_mm`: the mean of the points in it
/// (in order of first occupation, so the output is deterministic).
pub fn voxel_downsample(points: &[Point3<f64>], voxel_mm: f64) -> Vec<Point3<f64>> {
    if voxel_mm <= 0.0 {
        return points.to_vec();
    }
    let mut cells: HashMap<[i64; 3], usize> = HashMap::new();
    let mut sums: Vec<(Vector3<f64>, usize)> = Vec::new();
    for p in points {
        let key = [p.x, p.y, p.z].map(|c| (c / voxel_mm).floor() as i64);
        let slot = *cells.entry(key).or_insert_with(|| {
            sums.push((Vector3::zeros(), 0));
            sums.len() - 1
        });
        sums[slot].0 += p.coords;
        sums[slot].1 += 1;
    }
    sums.iter()
        .map(|(s, n)| Point3::from(s / *n as f64))
        .collect()
}

/// Unit normals by PCA of each point's `k` nearest neighbours (the direction of
/// least spread), each flipped to face `viewpoint` when given, else away from the
/// cloud's centroid.
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

    #[test]
    fn downsampling_and_sampling() {
        let pts: Vec<Point3<f64>> = (0..1000)
            .map(|i| {
                Point3::new(
                    (i % 10) as f64 * 0.1,
                    (i / 10 % 10) as f64 * 0.1,
                    (i / 100) as f64 * 0.1,
                )
            })
            .collect();
        assert_eq!(voxel_downsample(&pts, 0.5).len(), 8);
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
        let near = Nearest::new(&tri).unwrap();
        assert_eq!(near.nearest(&Point3::new(9.0, 1.0, 0.0)).0, 1);
    }
}
