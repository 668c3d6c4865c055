//! Several views of one object into one cloud (the paper's camera-to-camera
//! registration): pairwise ICP around the ring of views from their rough poses,
//! chained from the first view, then a global adjustment in which every view is
//! registered in turn onto all the others together, for a few rounds, so the
//! loop's error is spread over every view instead of piling up at the end.
//!
//! Markers seen in two views anchor both stages ([`super::icp::Anchors`]):
//! a pair of views that share 3 markers starts from the markers' fit, not the
//! robot's rough poses, and surface pairs cannot slide the views along the
//! nearly symmetric dome (which weak skin texture or noise otherwise lets
//! them do: the merged markers then come apart).

use super::icp::{Anchors, IcpParams, icp, icp_anchored};
use super::pose_spread;
use super::{MergedMarker, Sighting, ViewMarkers, markers_frame_covariance};
use crate::cloud::Nearest;
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Vector3};

/// One view: its points and normals in its own (camera) frame.
#[derive(Debug, Clone)]
pub struct View {
    /// Points, mm.
    pub points: Vec<Point3<f64>>,
    /// Unit normals (for point-to-plane).
    pub normals: Vec<Vector3<f64>>,
}

/// The result.
#[derive(Debug, Clone)]
pub struct Multiview {
    /// View -> world pose of each view (view 0 keeps its rough pose).
    pub poses: Vec<Isometry3<f64>>,
    /// RMSE of each pairwise ICP around the ring (i + 1 onto i, last onto 0), mm.
    pub pairwise_rmse_mm: Vec<f64>,
    /// RMSE of each view against all the others after adjustment, mm.
    pub view_rmse_mm: Vec<f64>,
}

fn to_world(view: &View, pose: &Isometry3<f64>) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    (
        view.points.iter().map(|p| pose * p).collect(),
        view.normals.iter().map(|n| pose.rotation * n).collect(),
    )
}

/// How markers seen in several views take part in [`register_views`].
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerAnchoring {
    /// Each view's markers in its own frame (empty: none seen).
    pub markers: Vec<Vec<Point3<f64>>>,
    /// Tolerance of marker matching between views (distances between
    /// markers), and of a sighting's distance to another view's marker in
    /// the adjustment, mm.
    pub tolerance_mm: f64,
    /// Weight of a view's markers together against its surface pairs.
    pub weight: f64,
    /// In the adjustment, a sighting farther than this from the median of
    /// the other views' sightings near it (two or more) anchors nothing, mm.
    pub outlier_mm: f64,
    /// Each view's markers' covariances in its own frame (mm^2), one per
    /// marker in `markers`' order, or `None`. Where both sightings of a pair
    /// have one, the pair pins each direction by the inverse of their summed
    /// covariance ([`Anchors::information`]): a stereo marker's depth is far
    /// less certain than its place across the line of sight, and weighed
    /// alike it would pull the other views along the first view's depth
    /// errors. Empty: none given.
    pub covariances: Vec<Option<Vec<Matrix3<f64>>>>,
}

impl MarkerAnchoring {
    /// The covariance of view `view`'s marker `k` in its frame, if given.
    fn covariance(&self, view: usize, k: usize) -> Option<Matrix3<f64>> {
        self.covariances.get(view)?.as_ref()?.get(k).copied()
    }
}

/// The markers view `j` shares with view `i`, matched by their distances to
/// each other (no pose needed), when at least 3 fit within the tolerance
/// and their fit is not far from `rough` (j -> i; a symmetric layout can
/// match itself turned): the anchors and the fit.
fn shared_markers(
    anchoring: &MarkerAnchoring,
    j: usize,
    i: usize,
    rough: &Isometry3<f64>,
) -> Option<(Anchors, Isometry3<f64>)> {
    let (mj, mi) = (anchoring.markers.get(j)?, anchoring.markers.get(i)?);
    let m = super::match_markers(mj, mi, anchoring.tolerance_mm, false)?;
    let fit = Isometry3::from_parts(
        m.transform.translation.into(),
        nalgebra::UnitQuaternion::from_rotation_matrix(&m.transform.rotation),
    );
    // The robot's poses are off by millimetres and a few degrees, not more.
    let centre = mj.iter().map(|p| p.coords).sum::<Vector3<f64>>() / mj.len() as f64;
    let disagreement = (fit * Point3::from(centre) - rough * Point3::from(centre)).norm();
    (m.pairs.len() >= 3 && disagreement < 50.0).then(|| {
        let turn = fit.rotation.to_rotation_matrix();
        let summed: Option<Vec<Matrix3<f64>>> = m
            .pairs
            .iter()
            .map(|&(a, b)| {
                let (cj, ci) = (anchoring.covariance(j, a)?, anchoring.covariance(i, b)?);
                Some(turn * cj * turn.transpose() + ci)
            })
            .collect();
        let anchors = Anchors::weighed_by(
            m.pairs.iter().map(|&(a, _)| mj[a]).collect(),
            m.pairs.iter().map(|&(_, b)| mi[b]).collect(),
            anchoring.weight,
            summed,
        );
        (anchors, fit)
    })
}

/// View `i`'s markers paired with the nearest marker of any other view
/// (world frame, under the current poses) within the tolerance, but for a
/// sighting the other views (two or more) put more than `outlier_mm` away.
fn adjustment_anchors(
    anchoring: &MarkerAnchoring,
    i: usize,
    poses: &[Isometry3<f64>],
) -> Option<Anchors> {
    let own = anchoring.markers.get(i)?;
    // Every other view's sightings in the world, with their view and index.
    let others: Vec<(Point3<f64>, usize, usize)> = anchoring
        .markers
        .iter()
        .enumerate()
        .filter(|(k, _)| *k != i)
        .flat_map(|(k, m)| m.iter().enumerate().map(move |(n, p)| (poses[k] * p, k, n)))
        .collect();
    let (mut source, mut target, mut summed) = (Vec::new(), Vec::new(), Vec::new());
    let world_covariance = |view: usize, k: usize| {
        let turn = poses[view].rotation.to_rotation_matrix();
        anchoring
            .covariance(view, k)
            .map(|c| turn * c * turn.transpose())
    };
    for (n, p) in own.iter().enumerate() {
        let world = poses[i] * p;
        let near: Vec<&(Point3<f64>, usize, usize)> = others
            .iter()
            .filter(|q| (q.0 - world).norm() < anchoring.tolerance_mm)
            .collect();
        // A sighting the others (two or more) put elsewhere is off itself
        // (a marker cut by a tool): it must not pull its view.
        if near.len() >= 2
            && (super::marker_merge::median_point(near.iter().map(|q| &q.0)) - world).norm()
                > anchoring.outlier_mm
        {
            continue;
        }
        if let Some(&&(q, view, k)) = near
            .iter()
            .min_by(|a, b| (a.0 - world).norm().total_cmp(&(b.0 - world).norm()))
        {
            source.push(*p);
            target.push(q);
            summed.push(
                world_covariance(i, n)
                    .zip(world_covariance(view, k))
                    .map(|(a, b)| a + b),
            );
        }
    }
    (source.len() >= 3).then(|| {
        let summed = summed.into_iter().collect::<Option<Vec<_>>>();
        Anchors::weighed_by(source, target, anchoring.weight, summed)
    })
}

/// Registers `views` given rough view -> world poses, anchored by the
/// markers they share when `anchoring` gives them.
pub fn register_views(
    views: &[View],
    rough: &[Isometry3<f64>],
    p: &IcpParams,
    rounds: usize,
    anchoring: Option<&MarkerAnchoring>,
) -> Result<Multiview, String> {
    let n = views.len();
    if n < 2 || rough.len() != n {
        return Err(format!(
            "{n} views and {} poses: need at least 2 views, one pose each",
            rough.len()
        ));
    }
    // Pairwise around the ring.
    let mut relative = Vec::with_capacity(n);
    let mut pairwise_rmse_mm = Vec::with_capacity(n);
    for i in 0..n {
        let j = (i + 1) % n;
        let tree = Nearest::new(&views[i].points).ok_or_else(|| format!("view {i} is empty"))?;
        let rough_relative = rough[i].inverse() * rough[j];
        let shared = anchoring.and_then(|a| shared_markers(a, j, i, &rough_relative));
        // From the shared markers' fit, anchored by them; if that fails (a
        // marker found wrongly), from the rough poses on the surfaces alone.
        let anchored = shared.as_ref().map(|(anchors, fit)| {
            icp_anchored(
                &views[j].points,
                &views[i].points,
                Some(&views[i].normals),
                &tree,
                fit,
                p,
                Some(anchors),
            )
        });
        let r = match anchored {
            Some(Ok(r)) => r,
            first => icp(
                &views[j].points,
                &views[i].points,
                Some(&views[i].normals),
                &tree,
                &rough_relative,
                p,
            )
            .map_err(|e| match first {
                Some(Err(a)) => {
                    format!("view {j} onto view {i}: from the shared markers: {a}; from the rough poses: {e}")
                }
                _ => format!("view {j} onto view {i}: {e}"),
            })?,
        };
        relative.push(r.transform);
        pairwise_rmse_mm.push(r.rmse_mm);
    }
    // Chain from view 0 (the ring's closing pair is left to the adjustment).
    let mut poses = vec![rough[0]];
    for i in 0..n - 1 {
        let next = poses[i] * relative[i];
        poses.push(next);
    }
    // Global adjustment: each view onto the union of the others.
    let mut view_rmse_mm = vec![0.0; n];
    for _ in 0..rounds.max(1) {
        for i in 1..n {
            let (pts, nrm) = others(views, &poses, i);
            let tree = Nearest::new(&pts).ok_or("no points")?;
            let anchors = anchoring.and_then(|a| adjustment_anchors(a, i, &poses));
            let r = icp_anchored(
                &views[i].points,
                &pts,
                Some(&nrm),
                &tree,
                &poses[i],
                p,
                anchors.as_ref(),
            )
            .map_err(|e| format!("view {i} onto the others: {e}"))?;
            poses[i] = r.transform;
            view_rmse_mm[i] = r.rmse_mm;
        }
    }
    // View 0's fit against the adjusted others, for the report.
    let (pts, nrm) = others(views, &poses, 0);
    let tree = Nearest::new(&pts).ok_or("no points")?;
    let fixed = IcpParams {
        max_iterations: 1,
        ..p.clone()
    };
    view_rmse_mm[0] = icp(&views[0].points, &pts, Some(&nrm), &tree, &poses[0], &fixed)
        .map(|r| r.trace[0].rmse_mm)
        .unwrap_or(f64::NAN);
    Ok(Multiview {
        poses,
        pairwise_rmse_mm,
        view_rmse_mm,
    })
}

/// The points and normals of every view but `skip`, at `poses` (world).
fn others(
    views: &[View],
    poses: &[Isometry3<f64>],
    skip: usize,
) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let (mut pts, mut nrm) = (Vec::new(), Vec::new());
    for (k, v) in views.iter().enumerate().filter(|(k, _)| *k != skip) {
        let (a, b) = to_world(v, &poses[k]);
        pts.extend(a);
        nrm.extend(b);
    }
    (pts, nrm)
}

/// How well the views' own data pin the first view against the others, after
/// [`register_views`]: the covariance (rad, mm; rotation first; world
/// frame, applied after `poses[0]`) of view 0's pose fitted onto the others
/// at their adjusted poses, with its markers as in the adjustment: from the
/// residuals block by block ([`pose_spread`] over `block_mm` cubes).
///
/// View 0 holds the frame: the adjustment moves every other view onto it, so
/// where its own data sit off the truth (its surface's noise, its markers'
/// depth errors), the whole merged set follows them. That common motion
/// does not show in a later registration's residuals; this is its spread,
/// as far as view 0's residuals against the others show it (an offset its
/// whole surface shares with every other view, such as a matcher's bias,
/// they cannot). An error when the pairs do not pin it.
pub fn first_view_spread(
    views: &[View],
    poses: &[Isometry3<f64>],
    p: &IcpParams,
    anchoring: Option<&MarkerAnchoring>,
    block_mm: f64,
) -> Result<Matrix6<f64>, String> {
    let (pts, nrm) = others(views, poses, 0);
    let tree = Nearest::new(&pts).ok_or("the other views have no points")?;
    let anchors = anchoring.and_then(|a| adjustment_anchors(a, 0, poses));
    let spread = pose_spread(
        &views[0].points,
        &pts,
        Some(&nrm),
        &tree,
        &poses[0],
        p,
        anchors.as_ref(),
        block_mm,
        None,
    )?;
    Ok(spread.covariance)
}

/// The covariance of the merged set's frame from the markers' noise alone
/// (see [`markers_frame_covariance`]): `merged` as
/// [`merge_markers_weighted`](super::merge_markers_weighted) gave it from
/// `sets` (each set's markers and its view's pose), the sightings'
/// covariances `noise` and those the merge weighed them by `weights` (each
/// set's view frame, mm^2), `views_of_sets[set]` the view a set came from,
/// of `views`. An error when a sighting has no covariance or the markers do
/// not pin every view.
pub fn markers_frame_spread(
    merged: &[MergedMarker],
    sets: &[ViewMarkers],
    noise: &[Option<Vec<Matrix3<f64>>>],
    weights: &[Option<Vec<Matrix3<f64>>>],
    views_of_sets: &[usize],
    views: usize,
) -> Result<Matrix6<f64>, String> {
    let markers = merged
        .iter()
        .map(|m| {
            m.sightings
                .iter()
                .map(|&(set, marker)| {
                    let (points, pose) = &sets[set];
                    let turn = pose.rotation.to_rotation_matrix();
                    let in_poses_frame = |table: &[Option<Vec<Matrix3<f64>>>]| {
                        table
                            .get(set)
                            .and_then(|c| c.as_ref()?.get(marker))
                            .map(|c| turn * c * turn.transpose())
                            .ok_or_else(|| {
                                format!(
                                    "view {}: a sighting without a covariance",
                                    views_of_sets[set]
                                )
                            })
                    };
                    Ok(Sighting {
                        view: views_of_sets[set],
                        position: pose * points[marker],
                        covariance: in_poses_frame(noise)?,
                        weighed_as: in_poses_frame(weights)?,
                    })
                })
                .collect::<Result<Vec<_>, String>>()
        })
        .collect::<Result<Vec<_>, String>>()?;
    markers_frame_covariance(&markers, views)
}

/// Rough view -> first-view poses from the markers alone, for a rig with no
/// pose readings: each view's markers registered onto the previous view's
/// (correspondences by [`super::match_markers`], rigid), chained from view 0
/// (identity). Each neighbour pair must share 3 markers; the error names the
/// pair that does not.
pub fn poses_from_markers(
    markers: &[Vec<Point3<f64>>],
    tolerance_mm: f64,
) -> Result<Vec<Isometry3<f64>>, String> {
    let mut poses = vec![Isometry3::identity()];
    for i in 1..markers.len() {
        let m = super::match_markers(&markers[i], &markers[i - 1], tolerance_mm, false)
            .filter(|m| m.pairs.len() >= 3)
            .ok_or_else(|| {
                format!(
                    "views {} and {i} share fewer than 3 markers that fit within {tolerance_mm} mm: \
                     connect the rig's poses (pose{} ...) instead",
                    i - 1,
                    i - 1
                )
            })?;
        let t = &m.transform;
        let step = Isometry3::from_parts(
            t.translation.into(),
            nalgebra::UnitQuaternion::from_rotation_matrix(&t.rotation),
        );
        let previous = poses[i - 1];
        poses.push(previous * step);
    }
    Ok(poses)
}

/// Point-to-plane settings that converge fully on the tests' bowls.
#[cfg(test)]
fn bowl_icp_params() -> IcpParams {
    IcpParams {
        method: super::icp::IcpMethod::PointToPlane,
        max_distance_mm: 5.0,
        trim_ratio: 1.0,
        kernel: super::icp::Kernel::None,
        max_iterations: 30,
        tolerance: 1e-9,
        voxel_sizes_mm: vec![],
    }
}

#[cfg(test)]
mod anchor_tests {
    use super::*;

    #[test]
    fn a_sighting_the_others_put_elsewhere_anchors_nothing() {
        let at = |x: f64| Point3::new(x, 0.0, 500.0);
        let shared = [at(-40.0), at(-20.0), at(0.0)];
        // Marker A at x = 30: views 1 and 2 see it there, view 0 3 mm off.
        let seen = |a: f64| {
            let mut m = shared.to_vec();
            m.push(at(a));
            m
        };
        let anchoring = MarkerAnchoring {
            markers: vec![seen(33.0), seen(30.0), seen(30.0)],
            tolerance_mm: 4.0,
            weight: 1.0,
            outlier_mm: 2.5,
            covariances: Vec::new(),
        };
        let poses = vec![Isometry3::identity(); 3];
        let view0 = adjustment_anchors(&anchoring, 0, &poses).unwrap();
        assert_eq!(view0.source, shared.to_vec(), "A off: not an anchor");
        // View 1's A is 1.5 mm from the others' median (30 and 33): kept.
        let view1 = adjustment_anchors(&anchoring, 1, &poses).unwrap();
        assert_eq!(view1.source.len(), 4);
        assert_eq!(view1.target[3], at(30.0), "the nearest sighting");
    }
}

#[cfg(test)]
mod spread_tests {
    use super::*;
    use nalgebra::Vector6;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A small motion (turn, shift; rad, mm) close to `pose`.
    fn small_motion(pose: &Isometry3<f64>) -> Vector6<f64> {
        let (w, t) = (pose.rotation.scaled_axis(), pose.translation.vector);
        Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z)
    }

    #[test]
    fn the_merged_set_follows_the_first_views_noise_as_its_spread_says() {
        // View 0 is the bowl with independent noise along its normals, view 1
        // the bowl itself; both start at the truth. The adjustment moves view
        // 1 onto view 0's data, so its pose scatters over draws as view 0's
        // spread predicts.
        let (points, normals) = super::super::pose_spread::uneven_bowl(60, 1.5);
        let p = bowl_icp_params();
        let noise = Normal::new(0.0, 0.3).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let rough = vec![Isometry3::identity(); 2];
        let draws = 150;
        let (mut observed, mut predicted) =
            (nalgebra::Matrix6::zeros(), nalgebra::Matrix6::zeros());
        for _ in 0..draws {
            let noisy: Vec<Point3<f64>> = points
                .iter()
                .zip(&normals)
                .map(|(x, n)| x + n * noise.sample(&mut rng))
                .collect();
            let views = vec![
                View {
                    points: noisy,
                    normals: normals.clone(),
                },
                View {
                    points: points.clone(),
                    normals: normals.clone(),
                },
            ];
            let m = register_views(&views, &rough, &p, 1, None).unwrap();
            let e = small_motion(&m.poses[1]);
            observed += e * e.transpose() / draws as f64;
            predicted += first_view_spread(&views, &m.poses, &p, None, 0.0).unwrap() / draws as f64;
        }
        let sd = |c: &nalgebra::Matrix6<f64>, from: usize| {
            (from..from + 3).map(|i| c[(i, i)]).sum::<f64>().sqrt()
        };
        for (part, from) in [("turn", 0), ("shift", 3)] {
            let ratio = sd(&observed, from) / sd(&predicted, from);
            assert!(
                (0.8..1.25).contains(&ratio),
                "{part}: observed {:.3e}, predicted {:.3e}",
                sd(&observed, from),
                sd(&predicted, from)
            );
        }
    }
}

#[cfg(test)]
mod chain_tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn poses_chain_through_shared_markers() {
        // Eight markers in the world, irregularly placed (a symmetric layout
        // would match itself turned, as real markers are not); three views,
        // each seeing six of them.
        let world: Vec<Point3<f64>> = (0..8)
            .map(|k| {
                let a = k as f64 * 0.7 + 0.05 * (k * k) as f64;
                let r = 60.0 + 7.0 * ((k * 5) % 3) as f64;
                Point3::new(r * a.cos(), r * a.sin(), 17.0 * ((k * k) % 5) as f64)
            })
            .collect();
        let poses: Vec<Isometry3<f64>> = (0..3)
            .map(|i| {
                Isometry3::from_parts(
                    Translation3::new(10.0 * i as f64, -5.0, 500.0),
                    UnitQuaternion::from_euler_angles(0.1 * i as f64, 0.3 * i as f64, 0.0),
                )
            })
            .collect();
        let seen: Vec<Vec<Point3<f64>>> = (0..3)
            .map(|i| {
                world[i..i + 6]
                    .iter()
                    .map(|p| poses[i].inverse() * p)
                    .collect()
            })
            .collect();
        let found = poses_from_markers(&seen, 1.0).unwrap();
        for i in 0..3 {
            let truth = poses[0].inverse() * poses[i];
            let err = (found[i].translation.vector - truth.translation.vector).norm()
                + found[i].rotation.angle_to(&truth.rotation);
            assert!(err < 1e-6, "view {i}: {err}");
        }
        let lonely = vec![seen[0].clone(), seen[2][..2].to_vec()];
        assert!(
            poses_from_markers(&lonely, 1.0)
                .unwrap_err()
                .contains("views 0 and 1")
        );
    }
}

#[cfg(test)]
mod weighting_tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn markers_weighed_by_their_covariances_do_not_drag_the_views_along_their_depth_errors() {
        // Two views of one bowl, both exact and at the truth; six markers
        // on it, each sighting off by stereo-like noise: 0.3 mm along the
        // line of sight (z), 0.03 mm across. View 1 is adjusted onto view 0:
        // weighed alike, view 0's markers' depth errors tilt it; weighed by
        // their covariances, the surface holds the depth and they the rest.
        let (points, normals) = super::super::pose_spread::uneven_bowl(50, 1.6);
        let on_bowl =
            |x: f64, y: f64| Point3::new(x, y, (x * x + 0.6 * y * y) / 120.0 + 0.0002 * x * y * y);
        let truth: Vec<Point3<f64>> = [
            (-25.0, -20.0),
            (20.0, -25.0),
            (30.0, 10.0),
            (-5.0, 28.0),
            (-30.0, 15.0),
            (5.0, 0.0),
        ]
        .iter()
        .map(|&(x, y)| on_bowl(x, y))
        .collect();
        let covariance = Matrix3::from_diagonal(&Vector3::new(
            0.03f64.powi(2),
            0.03f64.powi(2),
            0.3f64.powi(2),
        ));
        let (across, along) = (
            Normal::new(0.0, 0.03).unwrap(),
            Normal::new(0.0, 0.3).unwrap(),
        );
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let p = bowl_icp_params();
        let views = vec![
            View {
                points: points.clone(),
                normals: normals.clone(),
            },
            View { points, normals },
        ];
        let rough = vec![Isometry3::identity(); 2];
        let centre = on_bowl(0.0, 0.0);
        let draws = 30;
        let (mut alike, mut weighed) = (0.0, 0.0);
        for _ in 0..draws {
            let mut sighting = || -> Vec<Point3<f64>> {
                truth
                    .iter()
                    .map(|t| {
                        t + Vector3::new(
                            across.sample(&mut rng),
                            across.sample(&mut rng),
                            along.sample(&mut rng),
                        )
                    })
                    .collect()
            };
            let markers = vec![sighting(), sighting()];
            for (covariances, sum) in [
                (Vec::new(), &mut alike),
                (vec![Some(vec![covariance; 6]); 2], &mut weighed),
            ] {
                let anchoring = MarkerAnchoring {
                    markers: markers.clone(),
                    tolerance_mm: 4.0,
                    weight: 1.0,
                    outlier_mm: 2.5,
                    covariances,
                };
                let m = register_views(&views, &rough, &p, 1, Some(&anchoring)).unwrap();
                *sum += (m.poses[1] * centre - centre).norm_squared() / draws as f64;
            }
        }
        let (alike, weighed) = (alike.sqrt(), weighed.sqrt());
        assert!(
            weighed < 0.5 * alike,
            "view 1's error at the bowl's centre: weighed alike {alike:.4} mm, by covariance {weighed:.4} mm"
        );
    }
}
