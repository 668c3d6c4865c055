//! Nearest-neighbour search over a fixed set of points (a kiddo k-d tree).

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use std::num::NonZero;

/// A k-d tree over a fixed set of points (any one frame, mm).
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

    /// Index of the nearest point and the squared distance to it (mm²).
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
