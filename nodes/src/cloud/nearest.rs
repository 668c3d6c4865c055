//! Nearest-neighbour search over a fixed set of points (a kiddo k-d tree).

use kiddo::SquaredEuclidean;
use nalgebra::Point3;
use std::num::NonZero;

/// Points per leaf. kiddo's `ImmutableKdTree` takes 32; on a surface's
/// points (100k of an ellipsoid) 16 answers a query on the surface 12-15 %
/// faster and one a few millimetres off it (ICP's first steps) 3 % faster,
/// where 8 is slower off the surface (more leaves to visit) and twice as
/// slow to build. The nearest found is the same (a tie aside: the main
/// job's figures are identical).
const LEAF_POINTS: usize = 16;

/// Points from which the tree is built on the thread pool (kiddo's default
/// is 262 144). kiddo's parallel construction gives the serial one's tree,
/// stems and leaves alike (kiddo tests it; so does a test here); from about
/// 10 000 points it is faster on two threads, and the deformable fit builds
/// a tree of its 20 000 moved scan points at each of its steps, serially
/// before.
const PARALLEL_BUILD_POINTS: usize = 8192;

/// kiddo's recommended immutable layout (Eytzinger stems, arena leaves),
/// over f32 coordinates, with [`LEAF_POINTS`] points per leaf.
type Tree = kiddo::kd_tree::KdTree<
    f32,
    u32,
    kiddo::stem_strategies::Eytzinger,
    kiddo::leaf_strategies::VecOfArenas<f32, u32, 3, LEAF_POINTS>,
    3,
    LEAF_POINTS,
>;

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
        Self::build(&raw, PARALLEL_BUILD_POINTS)
            .ok()
            .map(|tree| Nearest {
                tree,
                points: points.to_vec(),
            })
    }

    /// The tree over `raw`, built in parallel from `parallel_from` points.
    fn build(
        raw: &[[f32; 3]],
        parallel_from: usize,
    ) -> Result<Tree, kiddo::kd_tree::ConstructionError> {
        Tree::builder()
            .with_parallel_construction_threshold(parallel_from)
            .build_from_slice(raw)
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

    /// The nearest point to `p` among those within `radius_mm` of it
    /// (index, squared distance mm²) and a lower bound on the squared
    /// distance to the second nearest: that distance if it lies within
    /// `radius_mm` too, else `radius_mm²` (less the f32 rounding of the
    /// tree). `None` when no point lies within `radius_mm`.
    ///
    /// Where a tight bound on the nearest distance is known (the distance to
    /// a point of the set that was nearest a moment ago), the radius prunes
    /// the search: within 1.05 times the nearest distance it costs less
    /// than [`Nearest::nearest`], within twice about as much, while
    /// [`Nearest::nearest_two`] costs about twice as much.
    pub fn nearest_two_within(
        &self,
        p: &Point3<f64>,
        radius_mm: f64,
    ) -> Option<((usize, f64), f64)> {
        // The tree rounds points and the query to f32: a point this much
        // inside the radius may still be left out, so the bound is cut by it.
        let rounding_mm = 8.0 * f32::EPSILON as f64 * (p.coords.amax() + radius_mm);
        let radius_f32 = (radius_mm + rounding_mm) as f32;
        let found = self
            .tree
            .query(&[p.x as f32, p.y as f32, p.z as f32])
            .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(2).expect("2 > 0"))
            .within(radius_f32 * radius_f32)
            .unsorted()
            .execute();
        let beyond = (radius_mm - rounding_mm).max(0.0);
        let exact = |k: usize| {
            found.get(k).map(|r| {
                let item = r.item as usize;
                (item, (self.points[item] - p).norm_squared())
            })
        };
        // A point just outside the radius may have been left out while one
        // the f32 rounding let in lies beyond it: past `beyond`, only
        // `beyond` itself is a sure bound.
        let (nearest, second) = match (exact(0)?, exact(1)) {
            (a, Some(b)) if b.1 < a.1 => (b, a.1),
            (a, Some(b)) => (a, b.1),
            (a, None) => (a, f64::INFINITY),
        };
        Some((nearest, second.min(beyond * beyond).max(nearest.1)))
    }

    /// The median distance from a point of the set to its nearest other
    /// point (mm), over an even sample of at most `sample` points: the
    /// set's typical spacing (0 for a one-point set).
    pub fn typical_spacing_mm(&self, sample: usize) -> f64 {
        let stride = self.points.len().div_ceil(sample.max(1)).max(1);
        let mut gaps: Vec<f64> = self
            .points
            .iter()
            .step_by(stride)
            .map(|p| self.nearest_two(p).1.sqrt())
            .filter(|d| d.is_finite())
            .collect();
        if gaps.is_empty() {
            return 0.0;
        }
        let mid = gaps.len() / 2;
        *gaps.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    /// How many points the set holds.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the set is empty (never: [`Nearest::new`] refuses one).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Point `index` of the set, mm.
    pub fn point(&self, index: usize) -> Point3<f64> {
        self.points[index]
    }

    /// Indices of the points within `radius_mm` of `p` (distances checked
    /// in f64, so exactly those), in no particular order.
    pub fn within(&self, p: &Point3<f64>, radius_mm: f64) -> Vec<usize> {
        // The tree rounds points and the query to f32: searched a little
        // wider, then each candidate's own distance decides.
        let rounding_mm = 8.0 * f32::EPSILON as f64 * (p.coords.amax() + radius_mm);
        let search = (radius_mm + rounding_mm) as f32;
        let radius_squared = radius_mm * radius_mm;
        self.tree
            .query(&[p.x as f32, p.y as f32, p.z as f32])
            .within::<SquaredEuclidean<f32>>(search * search)
            .unsorted()
            .execute()
            .iter()
            .map(|r| r.item as usize)
            .filter(|&i| (self.points[i] - p).norm_squared() <= radius_squared)
            .collect()
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

    /// Exactly the points within the radius, on a lattice where many lie
    /// on its boundary (in f64; the tree's f32 must not lose or add any).
    #[test]
    fn within_finds_exactly_the_points_in_the_radius() {
        let points: Vec<Point3<f64>> = (0..1000)
            .map(|k| {
                Point3::new(
                    (k % 10) as f64,
                    ((k / 10) % 10) as f64,
                    (k / 100) as f64 + 500.0,
                )
            })
            .collect();
        let near = Nearest::new(&points).unwrap();
        for (q, r) in [
            (Point3::new(4.0, 4.0, 504.0), 1.0),
            (Point3::new(4.0, 4.0, 504.0), 2f64.sqrt()),
            (Point3::new(0.3, 9.1, 500.2), 2.5),
            (Point3::new(50.0, 50.0, 50.0), 3.0),
        ] {
            let mut found = near.within(&q, r);
            found.sort_unstable();
            let expected: Vec<usize> = (0..points.len())
                .filter(|&i| (points[i] - q).norm_squared() <= r * r)
                .collect();
            assert_eq!(found, expected, "{q} within {r}");
        }
    }

    #[test]
    fn the_parallel_build_is_the_serial_tree() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        // A dome's skin with many exact ties (a lattice's rows), as scans give.
        let raw: Vec<[f32; 3]> = (0..30_000)
            .map(|k| {
                let (a, b) = ((k % 200) as f32, (k / 200) as f32);
                [
                    a * 0.5,
                    b * 0.5,
                    (a * 0.03).sin() * 20.0 + rng.random::<f32>() * 1e-3,
                ]
            })
            .collect();
        let serial = Nearest::build(&raw, usize::MAX).unwrap();
        let parallel = Nearest::build(&raw, 1024).unwrap();
        assert_eq!(
            serial.iter().collect::<Vec<_>>(),
            parallel.iter().collect::<Vec<_>>()
        );
        for k in 0..2000 {
            let q = [k as f32 * 0.05, (k % 150) as f32 * 0.5 + 0.25, 3.0];
            let ask = |t: &Tree| t.query(&q).nearest_one::<SquaredEuclidean<f32>>().execute();
            assert_eq!(ask(&serial), ask(&parallel), "query {q:?}");
        }
    }

    #[test]
    fn typical_spacing_of_a_grid_is_its_step() {
        let grid: Vec<Point3<f64>> = (0..400)
            .map(|k| Point3::new((k % 20) as f64 * 0.7, (k / 20) as f64 * 0.7, 3.0))
            .collect();
        let near = Nearest::new(&grid).unwrap();
        assert!((near.typical_spacing_mm(50) - 0.7).abs() < 1e-12);
        let one = Nearest::new(&grid[..1]).unwrap();
        assert_eq!(one.typical_spacing_mm(50), 0.0);
    }

    /// A scattered set and queries near and far: the radius search's
    /// nearest is the full search's, and its second-nearest bound is the
    /// true second distance when that lies inside the radius, else at most
    /// the radius and never above the true second distance.
    #[test]
    fn nearest_two_within_agrees_with_the_full_search() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(12345);
        let mut uniform = || rng.random::<f64>();
        let points: Vec<Point3<f64>> = (0..2000)
            .map(|_| Point3::new(uniform() * 50.0, uniform() * 50.0 + 100.0, uniform() * 5.0))
            .collect();
        let near = Nearest::new(&points).unwrap();
        let mut bounded = 0;
        for _ in 0..500 {
            let q = Point3::new(
                uniform() * 60.0 - 5.0,
                uniform() * 60.0 + 95.0,
                uniform() * 9.0 - 2.0,
            );
            let ((j, d1), d2) = near.nearest_two(&q);
            let radius_mm = d1.sqrt() * (1.0 + 2.0 * uniform()) + 1e-3;
            let ((k, e1), e2) = near.nearest_two_within(&q, radius_mm).unwrap();
            assert_eq!((k, e1), (j, d1));
            if d2.sqrt() < radius_mm - 1e-3 {
                assert_eq!(e2, d2);
            } else {
                bounded += 1;
                assert!(
                    e2 <= d2 && e2 <= radius_mm * radius_mm,
                    "{e2} {d2} {radius_mm}"
                );
                assert!(
                    e2.sqrt() > radius_mm - 1e-3,
                    "the bound is the radius, less rounding"
                );
            }
        }
        assert!(bounded > 50, "both cases occur ({bounded} bounded)");
        assert!(
            near.nearest_two_within(&Point3::new(-50.0, 0.0, 0.0), 1.0)
                .is_none()
        );
    }
}
