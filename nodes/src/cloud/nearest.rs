//! Nearest-neighbour search over a fixed set of points (a kiddo k-d tree).

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use std::num::NonZero;

/// kiddo's recommended immutable layout, over f32 coordinates.
type Tree = ImmutableKdTree<f32, 3>;

/// A k-d tree over a fixed set of points (any one frame, mm).
///
/// The tree holds the points in f32 (1e-5 mm at a metre: far below any
/// scanner's noise), half the memory an f64 tree walks per query, so a
/// search is faster; distances are then computed in f64 from the points
/// themselves, so what callers see is exact. Only a near tie closer than
/// f32 can tell apart may pick the other of two points.
pub struct Nearest {
    tree: Tree,
    points: Vec<Point3<f64>>,
}

impl Nearest {
    /// Builds the tree (`None` for an empty set).
    pub fn new(points: &[Point3<f64>]) -> Option<Self> {
        if points.is_empty() {
            return None;
        }
        let raw: Vec<[f32; 3]> = points
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        Tree::new_from_slice(&raw).ok().map(|tree| Nearest {
            tree,
            points: points.to_vec(),
        })
    }

    /// Index of the nearest point and the squared distance to it (mm²).
    pub fn nearest(&self, p: &Point3<f64>) -> (usize, f64) {
        let r = self
            .tree
            .query(&[p.x as f32, p.y as f32, p.z as f32])
            .nearest_one::<SquaredEuclidean<f32>>()
            .execute();
        let item = r.item as usize;
        (item, (self.points[item] - p).norm_squared())
    }

    /// The nearest point (index, squared distance mm²) and the squared
    /// distance to the second nearest (infinite for a one-point set).
    pub fn nearest_two(&self, p: &Point3<f64>) -> ((usize, f64), f64) {
        let found = self
            .tree
            .query(&[p.x as f32, p.y as f32, p.z as f32])
            .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(2).expect("2 > 0"))
            .execute();
        let exact = |k: usize| {
            found.get(k).map_or(f64::INFINITY, |r| {
                (self.points[r.item as usize] - p).norm_squared()
            })
        };
        let (a, b) = (exact(0), exact(1));
        // f32 may order two near ties either way: the nearer by f64 first.
        if b < a {
            ((found[1].item as usize, b), a)
        } else {
            ((found[0].item as usize, a), b)
        }
    }

    /// Point `index` of the set, mm.
    pub fn point(&self, index: usize) -> Point3<f64> {
        self.points[index]
    }

    /// Indices of the `k` nearest points.
    pub fn knn(&self, p: &Point3<f64>, k: usize) -> Vec<usize> {
        self.tree
            .query(&[p.x as f32, p.y as f32, p.z as f32])
            .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(k.max(1)).expect("k >= 1"))
            .execute()
            .iter()
            .map(|r| r.item as usize)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_nearest_point() {
        let tri = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(10.0, 0.0, 0.0),
            Point3::new(0.0, 10.0, 0.0),
        ];
        let near = Nearest::new(&tri).unwrap();
        assert_eq!(near.nearest(&Point3::new(9.0, 1.0, 0.0)).0, 1);
        assert!(Nearest::new(&[]).is_none());
    }
}
