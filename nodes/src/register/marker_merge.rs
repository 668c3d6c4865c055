//! Sightings of the markers in several registered views as one marker set,
//! robust to a sighting that is off: a marker partly hidden by a tool, or cut
//! by a highlight, is measured on what is left of its face and can be a few
//! mm off where the other views put it. Such a sighting is dropped (and
//! reported), not averaged in.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

/// One marker seen in several views.
#[derive(Debug, Clone, PartialEq)]
pub struct MergedMarker {
    /// Mean of its sightings that agree, in the frame of the poses, mm:
    /// weighted by their inverse covariances where every one has a
    /// covariance ([`merge_markers_weighted`]).
    pub position: Point3<f64>,
    /// Views whose sightings agree.
    pub views: usize,
    /// Largest distance of such a sighting from the mean, mm.
    pub spread_mm: f64,
    /// The sightings merged: (set, marker) indices into the input.
    pub sightings: Vec<(usize, usize)>,
}

/// A sighting left out of the merge.
#[derive(Debug, Clone, PartialEq)]
pub struct DroppedSighting {
    /// Index of its set (view) in the input, and of the marker in the set.
    pub set: usize,
    pub marker: usize,
    /// Its distance from where the views that agree put the marker, mm.
    pub off_mm: f64,
}

/// One view's markers (in its frame) and that view's pose.
pub type ViewMarkers = (Vec<Point3<f64>>, Isometry3<f64>);

/// How sightings merge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeParams {
    /// Sightings closer than this to a marker already gathered join it, mm.
    pub merge_mm: f64,
    /// A sighting farther than this from the median of a marker's sightings
    /// (seen in 3 views or more) is dropped; so is a marker seen in one view
    /// within twice `merge_mm` of one seen in two or more (a stray sighting
    /// of it), mm.
    pub outlier_mm: f64,
}

/// Markers found in several views (each set in its view's frame, with that
/// view's pose) as one set: sightings closer than `merge_mm` to a marker
/// already gathered join it (its position the running mean); the others start
/// new markers. Then the sightings that disagree go (see
/// [`MergeParams::outlier_mm`]). Views are taken in order, so the result
/// depends on nothing but the input.
pub fn merge_markers(
    sets: &[ViewMarkers],
    params: &MergeParams,
) -> (Vec<MergedMarker>, Vec<DroppedSighting>) {
    merge_markers_weighted(sets, &[], params)
}

/// [`merge_markers`], each marker's position then the mean of its sightings
/// weighted by their inverse covariances when every one of them has a
/// covariance (`covariances[set]`: one per marker of that set, in its
/// view's frame, mm^2; missing or empty: none). A stereo sighting is about
/// ten times less certain along its line of sight than across it, so views
/// that see a marker from different sides fix each other's depth. Which
/// sightings gather and which go does not change.
pub fn merge_markers_weighted(
    sets: &[ViewMarkers],
    covariances: &[Option<Vec<Matrix3<f64>>>],
    params: &MergeParams,
) -> (Vec<MergedMarker>, Vec<DroppedSighting>) {
    // Each gathered marker: its sightings as (set, marker, position).
    let mut gathered: Vec<Vec<(usize, usize, Point3<f64>)>> = Vec::new();
    for (s, (points, pose)) in sets.iter().enumerate() {
        for (k, p) in points.iter().map(|p| pose * p).enumerate() {
            let nearest = gathered
                .iter()
                .enumerate()
                .map(|(i, g)| (i, (mean(g) - p).norm()))
                .filter(|(_, d)| *d < params.merge_mm)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match nearest {
                Some((i, _)) => gathered[i].push((s, k, p)),
                None => gathered.push(vec![(s, k, p)]),
            }
        }
    }
    let mut dropped = Vec::new();
    for g in gathered.iter_mut().filter(|g| g.len() >= 3) {
        let centre = median(g);
        g.retain(|&(set, marker, p)| {
            let off_mm = (p - centre).norm();
            let keep = off_mm <= params.outlier_mm;
            if !keep {
                dropped.push(DroppedSighting {
                    set,
                    marker,
                    off_mm,
                });
            }
            keep
        });
    }
    let seen_twice: Vec<Point3<f64>> = gathered
        .iter()
        .filter(|g| g.len() >= 2)
        .map(|g| mean(g))
        .collect();
    gathered.retain(|g| {
        if g.len() != 1 {
            return true;
        }
        let (set, marker, p) = g[0];
        let near = seen_twice
            .iter()
            .map(|c| (p - c).norm())
            .fold(f64::INFINITY, f64::min);
        let stray = near <= 2.0 * params.merge_mm;
        if stray {
            dropped.push(DroppedSighting {
                set,
                marker,
                off_mm: near,
            });
        }
        !stray
    });
    let merged = gathered
        .iter()
        .map(|g| {
            let position = weighted_mean(g, sets, covariances).unwrap_or_else(|| mean(g));
            MergedMarker {
                position,
                views: g.len(),
                spread_mm: g
                    .iter()
                    .map(|(_, _, p)| (p - position).norm())
                    .fold(0.0, f64::max),
                sightings: g.iter().map(|&(set, marker, _)| (set, marker)).collect(),
            }
        })
        .collect();
    (merged, dropped)
}

/// The sightings' mean weighted by their inverse covariances (turned into
/// the poses' frame), or `None` unless every sighting has a positive-definite
/// one.
fn weighted_mean(
    g: &[(usize, usize, Point3<f64>)],
    sets: &[ViewMarkers],
    covariances: &[Option<Vec<Matrix3<f64>>>],
) -> Option<Point3<f64>> {
    let (mut information, mut weighted) = (Matrix3::zeros(), Vector3::zeros());
    for &(set, marker, p) in g {
        let c = covariances.get(set)?.as_ref()?.get(marker)?;
        let turn = sets[set].1.rotation.to_rotation_matrix();
        let w = (turn * c * turn.transpose()).try_inverse()?;
        information += w;
        weighted += w * p.coords;
    }
    information
        .cholesky()
        .map(|l| Point3::from(l.solve(&weighted)))
}

fn mean(g: &[(usize, usize, Point3<f64>)]) -> Point3<f64> {
    Point3::from(g.iter().map(|(_, _, p)| p.coords).sum::<Vector3<f64>>() / g.len() as f64)
}

/// The median of each coordinate.
fn median(g: &[(usize, usize, Point3<f64>)]) -> Point3<f64> {
    median_point(g.iter().map(|(_, _, p)| p))
}

/// The median of each coordinate of `points` (at least one).
pub(crate) fn median_point<'a>(
    points: impl Iterator<Item = &'a Point3<f64>> + Clone,
) -> Point3<f64> {
    let mid = |axis: usize| {
        let mut v: Vec<f64> = points.clone().map(|p| p[axis]).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    Point3::new(mid(0), mid(1), mid(2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    const PARAMS: MergeParams = MergeParams {
        merge_mm: 4.0,
        outlier_mm: 2.5,
    };

    #[test]
    fn sightings_of_one_marker_merge_and_others_stay_apart() {
        // Two views 100 mm apart, seeing two markers (one in both).
        let pose0 = Isometry3::identity();
        let pose1 = Isometry3::from_parts(
            Translation3::new(100.0, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        );
        let shared = Point3::new(10.0, 20.0, 500.0);
        let other = Point3::new(40.0, 20.0, 500.0);
        let noise = Vector3::new(0.2, 0.0, 0.0);
        let sets = vec![
            (vec![shared, other], pose0),
            (vec![pose1.inverse() * (shared + noise)], pose1),
        ];
        let (merged, dropped) = merge_markers(&sets, &PARAMS);
        assert!(dropped.is_empty());
        assert_eq!(merged.len(), 2);
        assert_eq!(merged[0].views, 2);
        assert!((merged[0].position - (shared + noise * 0.5)).norm() < 1e-9);
        assert!((merged[0].spread_mm - 0.1).abs() < 1e-9);
        assert_eq!((merged[1].views, merged[1].position), (1, other));
        // A merge radius wider than their spacing joins them.
        let wide = MergeParams {
            merge_mm: 40.0,
            outlier_mm: 100.0,
        };
        assert_eq!(merge_markers(&sets, &wide).0.len(), 1);
    }

    #[test]
    fn a_sighting_off_the_others_is_dropped_not_averaged() {
        let at = Point3::new(0.0, 0.0, 500.0);
        let id = Isometry3::identity();
        let off = |x: f64, z: f64| at + Vector3::new(x, 0.0, z);
        // Four views agree within 0.3 mm; a fifth sees it 3.5 mm deeper (it
        // joins the group, within merge_mm of the running mean), a sixth 6 mm
        // off (too far to join: a stray marker of its own).
        let sets = vec![
            (vec![off(0.3, 0.0)], id),
            (vec![off(-0.3, 0.0)], id),
            (vec![off(0.0, 0.3)], id),
            (vec![off(0.0, -0.3)], id),
            (vec![off(0.0, 3.5)], id),
            (vec![off(6.0, 0.0)], id),
        ];
        let (merged, dropped) = merge_markers(&sets, &PARAMS);
        assert_eq!(merged.len(), 1, "{merged:?}");
        assert_eq!(merged[0].views, 4);
        assert!((merged[0].position - at).norm() < 1e-9);
        let which: Vec<(usize, usize)> = dropped.iter().map(|d| (d.set, d.marker)).collect();
        assert_eq!(which, [(4, 0), (5, 0)]);
        assert!((dropped[0].off_mm - 3.5).abs() < 1e-9, "{dropped:?}");
        assert!((dropped[1].off_mm - 6.0).abs() < 1e-9, "{dropped:?}");
    }

    #[test]
    fn a_marker_seen_once_far_from_the_others_stays() {
        let id = Isometry3::identity();
        let a = Point3::new(0.0, 0.0, 500.0);
        let b = Point3::new(20.0, 0.0, 500.0);
        let (merged, dropped) = merge_markers(&[(vec![a, b], id), (vec![a], id)], &PARAMS);
        assert!(dropped.is_empty());
        assert_eq!(merged.iter().map(|m| m.views).collect::<Vec<_>>(), [2, 1]);
    }
}

#[cfg(test)]
mod weighted_tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    #[test]
    fn sightings_from_two_sides_fix_each_others_depth() {
        // One marker at (10, 20, 500), seen by a view looking along z and by
        // one turned 90 degrees about y (looking along x): each sighting 1 mm
        // off along its own line of sight, where it is ten times less
        // certain than across it.
        let truth = Point3::new(10.0, 20.0, 500.0);
        let covariance = Matrix3::from_diagonal(&Vector3::new(0.01, 0.01, 1.0));
        let front = Isometry3::identity();
        let side = Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, std::f64::consts::FRAC_PI_2, 0.0),
        );
        let sighting = |pose: &Isometry3<f64>| pose.inverse() * truth + Vector3::new(0.0, 0.0, 1.0);
        let sets = vec![
            (vec![sighting(&front)], front),
            (vec![sighting(&side)], side),
        ];
        let params = MergeParams {
            merge_mm: 4.0,
            outlier_mm: 2.5,
        };
        let (plain, _) = merge_markers(&sets, &params);
        let (weighted, _) = merge_markers_weighted(
            &sets,
            &[Some(vec![covariance]), Some(vec![covariance])],
            &params,
        );
        assert_eq!((plain.len(), weighted.len()), (1, 1));
        assert!(
            (plain[0].position - truth).norm() > 0.7,
            "the plain mean is off by half of each"
        );
        // Each axis: one sighting off by 1 mm at weight 1, the other exact at
        // weight 100: 1 / 101 mm.
        let expected = 2f64.sqrt() / 101.0;
        let off = (weighted[0].position - truth).norm();
        assert!(
            (off - expected).abs() < 1e-9,
            "{off} mm, expected {expected}"
        );
        // Without a covariance for one sighting: the plain mean.
        let (partial, _) = merge_markers_weighted(&sets, &[Some(vec![covariance]), None], &params);
        assert_eq!(partial[0].position, plain[0].position);
    }
}
