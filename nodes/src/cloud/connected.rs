//! A cloud's connected surfaces: points closer than a link distance belong
//! to one surface (single-linkage clustering, PCL's Euclidean cluster
//! extraction), found by union-find over the k-d tree's radius queries.
//! Written here: no crate clusters 3D points by distance on our tree.

use super::Nearest;
use nalgebra::Point3;
use rayon::prelude::*;

/// The connected surfaces of `points` (any one frame, mm) whose points lie
/// within `link_mm` of one another: each point's surface as an index into
/// the returned sizes, surfaces numbered by their first point.
pub fn connected_surfaces(points: &[Point3<f64>], link_mm: f64) -> (Vec<usize>, Vec<usize>) {
    let Some(tree) = Nearest::new(points) else {
        return (Vec::new(), Vec::new());
    };
    // Each point's neighbours after it (so each link is listed once), in
    // parallel; joined in point order, so the result does not depend on the
    // thread count.
    let links: Vec<Vec<usize>> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let mut after: Vec<usize> = tree
                .within(p, link_mm)
                .into_iter()
                .filter(|&j| j > i)
                .collect();
            after.sort_unstable();
            after
        })
        .collect();
    let mut parent: Vec<usize> = (0..points.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (i, after) in links.iter().enumerate() {
        for &j in after {
            let (a, b) = (root(&mut parent, i), root(&mut parent, j));
            // The smaller index is the root: a surface's root is its first point.
            if a != b {
                let (low, high) = (a.min(b), a.max(b));
                parent[high] = low;
            }
        }
    }
    let mut surface_of_root = vec![usize::MAX; points.len()];
    let mut sizes = Vec::new();
    let labels = (0..points.len())
        .map(|i| {
            let r = root(&mut parent, i);
            if surface_of_root[r] == usize::MAX {
                surface_of_root[r] = sizes.len();
                sizes.push(0);
            }
            sizes[surface_of_root[r]] += 1;
            surface_of_root[r]
        })
        .collect();
    (labels, sizes)
}

/// Which points of `points` to keep: those of the surfaces (linked within
/// `link_mm`) holding at least `min_share` as many points as the largest
/// one. Patches matched at a wrong disparity float apart from the true
/// surface, and a few hundred points stand no comparison with it.
pub fn keep_main_surfaces(points: &[Point3<f64>], link_mm: f64, min_share: f64) -> Vec<bool> {
    let (labels, sizes) = connected_surfaces(points, link_mm);
    let largest = sizes.iter().copied().max().unwrap_or(0);
    let kept: Vec<bool> = sizes
        .iter()
        .map(|&n| n as f64 >= min_share * largest as f64)
        .collect();
    labels.iter().map(|&l| kept[l]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `n` x `n` grid of points `spacing` mm apart in the plane z = `z`,
    /// from (`x0`, 0).
    fn sheet(x0: f64, z: f64, n: usize, spacing: f64) -> Vec<Point3<f64>> {
        (0..n * n)
            .map(|k| Point3::new(x0 + (k % n) as f64 * spacing, (k / n) as f64 * spacing, z))
            .collect()
    }

    #[test]
    fn two_sheets_apart_are_two_surfaces_and_a_chain_is_one() {
        let mut points = sheet(0.0, 0.0, 20, 1.0);
        points.extend(sheet(0.0, 30.0, 5, 1.0));
        let (labels, sizes) = connected_surfaces(&points, 1.5);
        assert_eq!(sizes, vec![400, 25]);
        assert!(labels[..400].iter().all(|&l| l == 0));
        assert!(labels[400..].iter().all(|&l| l == 1));
        // Points 1.4 mm apart in a line link end to end; 1.6 mm apart, not.
        let line = |step: f64| -> Vec<Point3<f64>> {
            (0..50)
                .map(|k| Point3::new(k as f64 * step, 0.0, 0.0))
                .collect()
        };
        assert_eq!(connected_surfaces(&line(1.4), 1.5).1, vec![50]);
        assert_eq!(connected_surfaces(&line(1.6), 1.5).1.len(), 50);
        assert_eq!(connected_surfaces(&[], 1.5), (vec![], vec![]));
    }

    #[test]
    fn a_floating_patch_goes_and_a_surface_cut_in_two_stays() {
        // The skin cut in two by a tool's shadow (two large sheets 5 mm
        // apart), and a small patch floating 60 mm above.
        let mut points = sheet(0.0, 0.0, 30, 1.0);
        points.extend(sheet(34.0, 0.0, 25, 1.0));
        points.extend(sheet(10.0, 60.0, 6, 1.0));
        let keep = keep_main_surfaces(&points, 3.0, 0.1);
        assert!(keep[..900 + 625].iter().all(|&k| k));
        assert!(keep[900 + 625..].iter().all(|&k| !k));
        // Asking each surface to hold as many points as the largest keeps
        // the largest alone.
        let keep = keep_main_surfaces(&points, 3.0, 1.0);
        assert_eq!(keep.iter().filter(|&&k| k).count(), 900);
    }

    #[test]
    fn the_surfaces_do_not_depend_on_the_thread_count() {
        let points: Vec<Point3<f64>> = (0..3000)
            .map(|k| {
                let t = k as f64 * 0.37;
                Point3::new(t.sin() * 40.0, (t * 1.3).cos() * 40.0, (k % 97) as f64)
            })
            .collect();
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| connected_surfaces(&points, 2.0))
        };
        let one = on(1);
        assert!(one.1.len() > 1, "{} surfaces", one.1.len());
        assert_eq!(one, on(2));
    }
}
