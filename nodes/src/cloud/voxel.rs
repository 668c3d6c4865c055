//! Voxel-grid downsampling.

use crate::numeric::floor_i64;
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;

/// One point per occupied cube of side `voxel_mm` (cubes aligned with the
/// frame's axes, corner at the origin): the mean of the points in it, in order
/// of first occupation, so the output is deterministic. `voxel_mm <= 0` keeps
/// every point.
///
/// # Examples
///
/// ```
/// use fusegraph_nodes::cloud::voxel_downsample;
/// use nalgebra::Point3;
///
/// // Two points share the cube [0, 2) mm; the third is alone in its cube.
/// let points = [
///     Point3::new(0.5, 0.5, 0.5),
///     Point3::new(1.5, 0.5, 0.5),
///     Point3::new(5.0, 0.0, 0.0),
/// ];
/// let down = voxel_downsample(&points, 2.0);
/// assert_eq!(down, [Point3::new(1.0, 0.5, 0.5), Point3::new(5.0, 0.0, 0.0)]);
/// assert_eq!(voxel_downsample(&points, 0.0).len(), 3);
/// ```
pub fn voxel_downsample(points: &[Point3<f64>], voxel_mm: f64) -> Vec<Point3<f64>> {
    if voxel_mm <= 0.0 {
        return points.to_vec();
    }
    let mut cells: HashMap<[i64; 3], usize> = HashMap::new();
    let mut sums: Vec<(Vector3<f64>, usize)> = Vec::new();
    for p in points {
        let key = [p.x, p.y, p.z].map(|c| floor_i64(c / voxel_mm));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lattice_downsamples_to_one_point_per_cube() {
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
    }
}
