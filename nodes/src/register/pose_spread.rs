//! How well an ICP result pins the pose: the covariance of a small turn w
//! (rad) and shift t (mm) applied after it in the target frame
//! (`p -> p + w x p + t`), from the final normal equations.
//!
//! Two sources of error are counted:
//!
//! - **The surfaces' own noise**, from the final residuals. Reconstructed
//!   surfaces are not independently noisy point by point: a stereo surface's
//!   errors are smooth over its matching windows and its smoothing, so the
//!   textbook sigma^2 (J^T J)^-1, which counts every pair as independent, is
//!   too small by about the number of pairs per correlated patch. The
//!   cluster-robust ("sandwich") estimate H^-1 (sum_b g_b g_b^T) H^-1 (Liang &
//!   Zeger 1986), with g_b the sum of weighted residual times Jacobian over
//!   a block of `block_mm` of the target frame, needs no model of the
//!   correlation, only blocks wider than it; each landmark is a block of its
//!   own.
//! - **A spread of the source's points that the residuals cannot show**: a
//!   shift field common to the whole source (a stereo rig's calibration
//!   error moves every triangulated point along a smooth field, largely a
//!   rigid motion ICP follows without a trace in its residuals). Given the
//!   field's shift at each point for each of a set of directions (one
//!   standard deviation each, their outer products summing to the field's
//!   covariance), each direction's response of the pose is -H^-1 sum_i w_i
//!   J_i (e_i . R dX_i), and their outer products add.

use super::gicp::{GicpSurfaces, pair_information};
use super::icp::{Anchors, IcpMethod, IcpParams, correspondences};
use crate::cloud::Nearest;
use crate::numeric::floor_i64;
use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};
use rayon::prelude::*;
use std::collections::HashMap;

/// A shift field common to the source: a source-frame point's shift
/// (source frame, mm) along each of the field's standard-deviation
/// directions, `None` where it has none. Every point must give the same
/// number of directions.
pub type ShiftField<'a> =
    dyn Fn(&Point3<f64>, ShiftedPoint) -> Option<Vec<Vector3<f64>>> + Sync + 'a;

/// What kind of source point a shift field is asked about: a field may move
/// the surface and the landmarks differently (a matcher's bias moves the
/// dense surface, not markers found in the images on their own).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShiftedPoint {
    /// A point of the source cloud.
    Surface,
    /// A source landmark.
    Landmark,
}

/// What a term of the final fit is a residual of.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Origin {
    /// Source point `i` paired with the target surface.
    Surface(usize),
    /// Landmark `k`.
    Landmark(usize),
}

/// One row of the final normal equations: its residual `e . (m - q)` (mm)
/// along the direction `e`, its Jacobian `(m x e, e)` and weight, and where
/// its block is taken.
#[derive(Debug, Clone, Copy)]
struct Term {
    origin: Origin,
    moved: Point3<f64>,
    /// The target point it pairs with: blocks are taken there, not at the
    /// moved source point, whose own noise would sort it into the block on
    /// its side of a boundary and bias the blocks' sums.
    anchor: Point3<f64>,
    direction: Vector3<f64>,
    residual: f64,
    weight: f64,
}

impl Term {
    fn row(&self) -> Vector6<f64> {
        let c = self.moved.coords.cross(&self.direction);
        let e = self.direction;
        Vector6::new(c.x, c.y, c.z, e.x, e.y, e.z)
    }
}

/// The pose's covariance and its parts, rad and mm (rotation first).
#[derive(Debug, Clone, PartialEq)]
pub struct PoseSpread {
    /// Everything counted: `noise + shift`.
    pub covariance: Matrix6<f64>,
    /// From the residuals, block by block.
    pub noise: Matrix6<f64>,
    /// From the residuals as if every term were independent (each its own
    /// block): what the textbook formula gives, for comparison.
    pub independent: Matrix6<f64>,
    /// From the given shift field (zero without one).
    pub shift: Matrix6<f64>,
    /// The pose's response (rad, mm; rotation first) to each of the shift
    /// field's directions, in its order: `shift` is the sum of their outer
    /// products.
    pub shift_responses: Vec<Vector6<f64>>,
    /// Blocks with residuals in them.
    pub blocks: usize,
    /// Terms of the final fit.
    pub terms: usize,
}

/// Terms per shift evaluation at most: the shift field is smooth, so a
/// regular subset of the surface terms (reweighted to the same total) gives
/// its response to well under a per cent.
const SHIFT_TERMS: usize = 8192;

/// The spread of `transform`, an ICP result of `source` onto `target` with
/// the settings and landmarks it was fitted with (see
/// [`icp_anchored`](super::icp_anchored)): the final scale's pairs are taken
/// again at it. `shifts`, given, tells for a source-frame point (a source
/// point or a source landmark) its shift (source frame, mm) along each of
/// the field's directions, `None` where it has none. An error when the
/// final pairs are too few or do not pin the pose.
#[allow(clippy::too_many_arguments)]
pub fn pose_spread(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    target_normals: Option<&[Vector3<f64>]>,
    tree: &Nearest,
    transform: &Isometry3<f64>,
    p: &IcpParams,
    anchors: Option<&Anchors>,
    block_mm: f64,
    shifts: Option<&ShiftField>,
) -> Result<PoseSpread, String> {
    let voxel = *p.scales().last().expect("at least one scale");
    let (src, max_d) = p.scale(source, voxel);
    let moved: Vec<Point3<f64>> = src.iter().map(|s| transform * s).collect();
    let (pairs, _) = correspondences(&moved, tree, max_d, p.trim_ratio, None)?;
    let gicp = match p.method {
        IcpMethod::Gicp => {
            let surfaces = GicpSurfaces::new(source, tree)?;
            let source_covariances = surfaces.source_covariances(&src);
            Some((surfaces, source_covariances))
        }
        _ => None,
    };
    let rotation = transform.rotation.to_rotation_matrix();
    // Each pair's terms, appended to `out`.
    let pair_terms =
        |&(i, j, distance): &(usize, usize, f64), out: &mut Vec<Term>| -> Result<(), String> {
            let q = target[j];
            // Each term's direction and weight, with None to weigh the residual
            // along it by the kernel (GICP weighs the pair by its distance).
            let directions: Vec<(Vector3<f64>, Option<f64>)> = match (&gicp, target_normals) {
                (Some((surfaces, source_covariances)), _) => {
                    // The pair's information split along its eigenvectors: the
                    // terms' rows then sum to J^T W J, as the fit's.
                    let info = pair_information(
                        surfaces.target_covariance(j),
                        &source_covariances[i],
                        &rotation,
                    )
                    .ok_or("a pair's covariances are singular")?;
                    let eig = info.symmetric_eigen();
                    let w = p.kernel.weight(distance);
                    (0..3)
                        .map(|k| {
                            (
                                eig.eigenvectors.column(k).into(),
                                Some(w * eig.eigenvalues[k]),
                            )
                        })
                        .collect()
                }
                (None, Some(n)) if p.method == IcpMethod::PointToPlane => vec![(n[j], None)],
                _ => [Vector3::x(), Vector3::y(), Vector3::z()]
                    .map(|e| (e, None))
                    .to_vec(),
            };
            out.extend(directions.into_iter().map(|(e, weight)| {
                let residual = e.dot(&(moved[i] - q));
                Term {
                    origin: Origin::Surface(i),
                    moved: moved[i],
                    anchor: q,
                    direction: e,
                    residual,
                    weight: weight.unwrap_or_else(|| p.kernel.weight(residual)),
                }
            }));
            Ok(())
        };
    // In parallel by chunks, appended in pair order, a bounded batch at a
    // time (no second copy of all the terms at once).
    let mut terms: Vec<Term> = Vec::with_capacity(pairs.len());
    for batch in pairs.chunks(TERM_BATCH) {
        let parts: Vec<Result<Vec<Term>, String>> = batch
            .par_chunks(TERM_CHUNK)
            .map(|chunk| {
                let mut out = Vec::with_capacity(chunk.len());
                for pair in chunk {
                    pair_terms(pair, &mut out)?;
                }
                Ok(out)
            })
            .collect();
        for part in parts {
            terms.extend(part?);
        }
    }
    let surface_weight: f64 = terms.iter().map(|t| t.weight).sum();
    if let Some(a) = anchors.filter(|a| !a.source.is_empty() && a.weight > 0.0) {
        let each = a.each(surface_weight);
        for (k, (s, q)) in a.source.iter().zip(&a.target).enumerate() {
            let m = transform * s;
            let directions = match p.method {
                IcpMethod::PointToPlane | IcpMethod::Gicp => a.directions(k),
                IcpMethod::PointToPoint => vec![Vector3::x(), Vector3::y(), Vector3::z()],
            };
            for e in directions {
                terms.push(Term {
                    origin: Origin::Landmark(k),
                    moved: m,
                    anchor: *q,
                    direction: e,
                    residual: e.dot(&(m - q)),
                    weight: each,
                });
            }
        }
    }
    let h_inverse = normal_matrix(terms.iter().map(|t| (t, 1.0)))
        .try_inverse()
        .filter(|m| m.iter().all(|x| x.is_finite()))
        .ok_or("the final pairs do not pin the pose (J^T J is singular)")?;
    // The residuals at the final pairs' own optimum: ICP stops when its
    // figures change little, which leaves a smooth part of the last step in
    // them that blocks would take for correlated noise.
    let step = -(h_inverse
        * terms.iter().fold(Vector6::zeros(), |g, t| {
            g + t.row() * (t.weight * t.residual)
        }));
    for t in &mut terms {
        t.residual += t.row().dot(&step);
    }
    let ((noise, blocks), ((independent, _), shift_responses)) = rayon::join(
        || noise_covariance(&terms, &h_inverse, block_mm),
        || {
            rayon::join(
                || noise_covariance(&terms, &h_inverse, 0.0),
                || match shifts {
                    Some(f) => shift_responses(&terms, &src, anchors, transform, f),
                    None => Ok(Vec::new()),
                },
            )
        },
    );
    let shift_responses = shift_responses?;
    let shift = shift_responses
        .iter()
        .fold(Matrix6::zeros(), |c, r| c + r * r.transpose());
    Ok(PoseSpread {
        covariance: noise + shift,
        noise,
        independent,
        shift,
        shift_responses,
        blocks,
        terms: terms.len(),
    })
}

/// sum of w J J^T over terms, each weight scaled by its factor.
fn normal_matrix<'a>(terms: impl Iterator<Item = (&'a Term, f64)>) -> Matrix6<f64> {
    terms.fold(Matrix6::zeros(), |h, (t, scale)| {
        let row = t.row();
        h + row * row.transpose() * (t.weight * scale)
    })
}

/// Pairs whose terms are made side by side (in chunks of [`TERM_CHUNK`])
/// before they are appended in order.
const TERM_BATCH: usize = 16384;
const TERM_CHUNK: usize = 1024;

/// Cluster scores computed side by side before they are summed in order.
const SCORE_BATCH: usize = 4096;

/// The cluster-robust covariance H^-1 (sum_b g_b g_b^T) H^-1 over blocks
/// of `block_mm` (0: each term its own block; each landmark is always one
/// block), and the number of blocks. Each cluster's residuals are first
/// divided by its leverage, (I - H_gg)^-1/2 (Bell & McCaffrey's CR2): the
/// fit draws a cluster's residuals towards zero by the share of the pose it
/// pins, which would make the noise look smaller than it is; a dozen
/// landmarks each pin much of it; the clusters' leverages sum to the six
/// parameters, so G clusters that share them evenly would give about
/// (G - 6) / G of the truth.
fn noise_covariance(
    terms: &[Term],
    h_inverse: &Matrix6<f64>,
    block_mm: f64,
) -> (Matrix6<f64>, usize) {
    let root = h_inverse.cholesky().map(|c| c.l());
    let score = |cluster: &[&Term]| {
        let s = cluster_score(cluster, root.as_ref());
        s * s.transpose()
    };
    let mut clusters: HashMap<(i64, i64, i64, i64), Vec<&Term>> = HashMap::new();
    let mut singles = Vec::new();
    for t in terms {
        let key = match t.origin {
            Origin::Landmark(k) => (i64::MIN, k as i64, 0, 0),
            // Each its own block, after the landmarks', in term order.
            Origin::Surface(_) if block_mm <= 0.0 => {
                singles.push(t);
                continue;
            }
            Origin::Surface(_) => {
                let c = t.anchor.coords / block_mm;
                (0, floor_i64(c.x), floor_i64(c.y), floor_i64(c.z))
            }
        };
        clusters.entry(key).or_default().push(t);
    }
    // Blocks in a fixed order: the same bits however the map iterates.
    let mut keys: Vec<_> = clusters.keys().copied().collect();
    keys.sort_unstable();
    // The scores in parallel, summed in that order (the same bits as one
    // thread), a bounded batch at a time.
    let mut meat = Matrix6::zeros();
    for batch in keys.chunks(SCORE_BATCH) {
        let scores: Vec<Matrix6<f64>> = batch.par_iter().map(|k| score(&clusters[k])).collect();
        meat = scores.iter().fold(meat, |m, s| m + s);
    }
    for batch in singles.chunks(SCORE_BATCH) {
        let scores: Vec<Matrix6<f64>> = batch
            .par_iter()
            .map(|t| score(std::slice::from_ref(t)))
            .collect();
        meat = scores.iter().fold(meat, |m, s| m + s);
    }
    (h_inverse * meat * h_inverse, clusters.len() + singles.len())
}

/// A cluster's sum of w r J with its residuals corrected for their leverage
/// (see [`noise_covariance`]), given L with L L^T = H^-1 (`None`: plain).
///
/// With u_i = sqrt(w_i) J_i and s_i = sqrt(w_i) r_i, the corrected score is
/// U^T (I - U H^-1 U^T)^-1/2 s. The leverage U H^-1 U^T has rank at most 6:
/// with A = U^T U and L^T A L = Q diag(l) Q^T, it is E diag(l) E^T for
/// E = U L Q diag(l)^-1/2, and the score is g0 + A L Q F Q^T L^T g0 with
/// g0 = U^T s and F = diag(((1 - l)^-1/2 - 1) / l): 6 x 6 work for a
/// cluster of any size.
fn cluster_score(terms: &[&Term], root: Option<&Matrix6<f64>>) -> Vector6<f64> {
    let plain = terms.iter().fold(Vector6::zeros(), |g, t| {
        g + t.row() * (t.weight * t.residual)
    });
    let Some(l) = root else {
        return plain;
    };
    if let [t] = terms {
        // One term: its leverage is the scalar w J^T H^-1 J, and the
        // correction below reduces to dividing by (1 - leverage)^1/2.
        let leverage = (l.transpose() * t.row()).norm_squared() * t.weight;
        return if leverage >= 1.0 - 1e-6 {
            plain
        } else {
            plain / (1.0 - leverage).sqrt()
        };
    }
    let a = terms.iter().fold(Matrix6::zeros(), |a, t| {
        let row = t.row();
        a + row * row.transpose() * t.weight
    });
    let e = (l.transpose() * a * l).symmetric_eigen();
    if e.eigenvalues.iter().any(|&x| x >= 1.0 - 1e-6) {
        // The cluster alone pins a direction of the pose: its residuals
        // there are zero whatever the noise, and no correction restores it.
        return plain;
    }
    let f = e.eigenvalues.map(|x| {
        if x > 1e-12 {
            ((1.0 - x).sqrt().recip() - 1.0) / x
        } else {
            0.5
        }
    });
    let q = &e.eigenvectors;
    plain + a * l * q * Matrix6::from_diagonal(&f) * q.transpose() * l.transpose() * plain
}

/// The pose's response to each direction of the shift field; on a regular
/// subset of at most [`SHIFT_TERMS`] surface terms (and every landmark
/// term), whose normal matrix it uses too.
fn shift_responses(
    terms: &[Term],
    source: &[Point3<f64>],
    anchors: Option<&Anchors>,
    transform: &Isometry3<f64>,
    shifts: &ShiftField,
) -> Result<Vec<Vector6<f64>>, String> {
    let surface = terms
        .iter()
        .filter(|t| matches!(t.origin, Origin::Surface(_)))
        .count();
    let stride = surface.div_ceil(SHIFT_TERMS).max(1);
    let chosen: Vec<(&Term, f64)> = terms
        .iter()
        .enumerate()
        .filter_map(|(n, t)| match t.origin {
            Origin::Surface(_) => (n % stride == 0).then_some((t, stride as f64)),
            Origin::Landmark(_) => Some((t, 1.0)),
        })
        .collect();
    let h_inverse = normal_matrix(chosen.iter().copied())
        .try_inverse()
        .ok_or("the final pairs do not pin the pose (J^T J is singular)")?;
    let rotation = transform.rotation;
    // Each term's share of the gradient along every direction of the field.
    let gradients: Vec<Option<Vec<Vector6<f64>>>> = chosen
        .par_iter()
        .map(|&(t, scale)| {
            let (point, kind) = match t.origin {
                Origin::Surface(i) => (source[i], ShiftedPoint::Surface),
                Origin::Landmark(k) => (
                    anchors.expect("landmark terms have anchors").source[k],
                    ShiftedPoint::Landmark,
                ),
            };
            let row = t.row() * (t.weight * scale);
            shifts(&point, kind).map(|s| {
                s.iter()
                    .map(|d| row * t.direction.dot(&(rotation * d)))
                    .collect()
            })
        })
        .collect();
    let mut total: Vec<Vector6<f64>> = Vec::new();
    for g in gradients.into_iter().flatten() {
        if total.is_empty() {
            total = vec![Vector6::zeros(); g.len()];
        }
        if g.len() != total.len() {
            return Err("the shift field gave points different numbers of directions".into());
        }
        total.iter_mut().zip(&g).for_each(|(a, b)| *a += b);
    }
    Ok(total.iter().map(|g| -(h_inverse * g)).collect())
}

/// A pose covariance carried through `iso`: the covariance, in the frame
/// `iso` maps to, of a small turn and shift (rad, mm; rotation first) that
/// has covariance `covariance` in the frame `iso` maps from. A motion
/// `p -> p + w x p + t` before `iso` is `q -> q + (R w) x q + (t_iso x R w +
/// R t)` after it (the adjoint of `iso`). So a source whose own frame is
/// known to within `covariance` gives the registration that follows it the
/// carried covariance.
pub fn carried_pose_covariance(iso: &Isometry3<f64>, covariance: &Matrix6<f64>) -> Matrix6<f64> {
    let r = iso.rotation.to_rotation_matrix().into_inner();
    let mut adjoint = Matrix6::zeros();
    adjoint.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    adjoint.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    adjoint
        .fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(iso.translation.vector.cross_matrix() * r));
    adjoint * covariance * adjoint.transpose()
}

/// The covariance (mm^2, in the frame `transform` maps from) of where a
/// target-frame point `target` maps back through the inverse of
/// `transform` when the pose has covariance `covariance` (see
/// [`PoseSpread::covariance`]).
pub fn mapped_point_covariance(
    transform: &Isometry3<f64>,
    covariance: &Matrix6<f64>,
    target: &Point3<f64>,
) -> nalgebra::Matrix3<f64> {
    // T' = exp(x) T maps q back to T^-1 (q - w x q - t): a change of
    // R^T (q x w ... ) = R^T ([q]x w - t).
    let q = target.coords;
    let mut a = nalgebra::Matrix3x6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&q.cross_matrix());
    a.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(-nalgebra::Matrix3::identity()));
    let r = transform.rotation.to_rotation_matrix().into_inner();
    let m = r.transpose() * a;
    m * covariance * m.transpose()
}

/// A test surface that pins every turn and shift: an uneven quadratic bowl
/// of `side` x `side` points `spacing_mm` apart (centred on the origin),
/// with its unit normals.
#[cfg(test)]
pub(crate) fn uneven_bowl(side: usize, spacing_mm: f64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let (mut points, mut normals) = (Vec::new(), Vec::new());
    let half = 0.5 * side as f64 * spacing_mm;
    for i in 0..side {
        for j in 0..side {
            let (x, y) = (spacing_mm * i as f64 - half, spacing_mm * j as f64 - half);
            let z = (x * x + 0.6 * y * y) / 120.0 + 0.0002 * x * y * y;
            let n = Vector3::new(
                -(2.0 * x) / 120.0 - 0.0002 * y * y,
                -(1.2 * y) / 120.0 - 0.0004 * x * y,
                1.0,
            );
            points.push(Point3::new(x, y, z));
            normals.push(n.normalize());
        }
    }
    (points, normals)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::register::{IcpMethod, IcpParams, Kernel, icp};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn a_single_terms_leverage_correction_is_the_general_ones() {
        // One term of weight w against the same term twice at w / 2: the
        // same leverage, which the second finds by the eigen route.
        let h_inverse = Matrix6::from_diagonal(&Vector6::new(0.02, 0.03, 0.01, 0.4, 0.5, 0.3));
        let root = h_inverse.cholesky().map(|c| c.l()).unwrap();
        let term = |weight| Term {
            origin: Origin::Surface(0),
            moved: Point3::new(3.0, -2.0, 5.0),
            anchor: Point3::new(3.0, -2.0, 5.0),
            direction: Vector3::new(0.2, 0.3, 0.9).normalize(),
            residual: 0.7,
            weight,
        };
        let one = cluster_score(&[&term(0.8)], Some(&root));
        let halves = cluster_score(&[&term(0.4), &term(0.4)], Some(&root));
        let plain = cluster_score(&[&term(0.8)], None);
        assert!(
            (one - halves).norm() < 1e-12 * one.norm(),
            "{one} against {halves}"
        );
        // And the correction is not empty here (a leverage of about 0.4).
        assert!(one.norm() > 1.2 * plain.norm());
    }

    #[test]
    fn a_carried_covariance_moves_points_as_the_motion_before_it_does() {
        let iso = Isometry3::new(
            Vector3::new(30.0, -12.0, 480.0),
            Vector3::new(0.3, -0.5, 0.2),
        );
        let (w, t) = (
            Vector3::new(2e-5, -1e-5, 3e-5),
            Vector3::new(0.01, 0.02, -0.015),
        );
        let delta = Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z);
        let carried = carried_pose_covariance(&iso, &(delta * delta.transpose()));
        for p in [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(40.0, -25.0, 10.0),
            Point3::new(-60.0, 35.0, 70.0),
        ] {
            // The point moved before iso, against the carried motion after it.
            let shift = iso * (p + w.cross(&p.coords) + t) - iso * p;
            // How far a point moves under the carried motion (at the
            // identity, mapped_point_covariance is J C J^T, J = [-[q]x, I]).
            let predicted = mapped_point_covariance(&Isometry3::identity(), &carried, &(iso * p));
            let expected = shift * shift.transpose();
            assert!(
                (predicted - expected).norm() < 1e-3 * expected.norm(),
                "{predicted} vs {expected}"
            );
        }
    }

    /// A gently curved patch (a quadratic bowl over 80 x 80 mm) with its
    /// normals, and its tree.
    fn bowl() -> (Vec<Point3<f64>>, Vec<Vector3<f64>>, Nearest) {
        let (points, normals) = uneven_bowl(80, 1.0);
        let tree = Nearest::new(&points).unwrap();
        (points, normals, tree)
    }

    fn params_for(method: IcpMethod) -> IcpParams {
        IcpParams {
            method,
            max_distance_mm: 5.0,
            trim_ratio: 1.0,
            kernel: Kernel::None,
            max_iterations: 50,
            tolerance: 1e-10,
            voxel_sizes_mm: vec![],
        }
    }

    /// The source: the bowl's points each moved along its normal by noise,
    /// independent (`patch` 1) or shared by square patches of `patch` x
    /// `patch` points.
    fn noisy(
        points: &[Point3<f64>],
        normals: &[Vector3<f64>],
        patch: usize,
        seed: u64,
    ) -> Vec<Point3<f64>> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 0.3).unwrap();
        let cells = 80usize.div_ceil(patch);
        let draws: Vec<f64> = (0..cells * cells).map(|_| noise.sample(&mut rng)).collect();
        points
            .iter()
            .zip(normals)
            .enumerate()
            .map(|(k, (p, n))| {
                let (i, j) = (k / 80, k % 80);
                p + n * draws[(i / patch) * cells + j / patch]
            })
            .collect()
    }

    /// ICP of `source` onto the bowl from the identity, and its spread.
    fn fit_and_spread(
        source: &[Point3<f64>],
        block_mm: f64,
        field: Option<&ShiftField>,
    ) -> (crate::register::IcpResult, PoseSpread) {
        fit_and_spread_by(IcpMethod::PointToPlane, source, block_mm, field)
    }

    fn fit_and_spread_by(
        method: IcpMethod,
        source: &[Point3<f64>],
        block_mm: f64,
        field: Option<&ShiftField>,
    ) -> (crate::register::IcpResult, PoseSpread) {
        let (bowl, normals, tree) = bowl();
        let start = Isometry3::identity();
        let params = params_for(method);
        let r = icp(source, &bowl, Some(&normals), &tree, &start, &params).unwrap();
        let s = pose_spread(
            source,
            &bowl,
            Some(&normals),
            &tree,
            &r.transform,
            &params,
            None,
            block_mm,
            field,
        )
        .unwrap();
        (r, s)
    }

    /// Monte Carlo: the spread of a target mapped back through 300
    /// point-to-plane fits of noisy sources against what each fit's own
    /// spread predicts.
    fn check(patch: usize, block_mm: f64) -> (f64, f64, f64) {
        check_by(IcpMethod::PointToPlane, patch, block_mm, 300)
    }

    /// [`check`] with `method` over `fits` fits.
    fn check_by(method: IcpMethod, patch: usize, block_mm: f64, fits: u64) -> (f64, f64, f64) {
        let (bowl, normals, _) = bowl();
        let q = Point3::new(5.0, -10.0, -60.0);
        // The fits on every core (the suite's longest tests), summed in
        // seed order.
        let each: Vec<(f64, f64, Point3<f64>)> = (0..fits)
            .into_par_iter()
            .map(|seed| {
                let source = noisy(&bowl, &normals, patch, seed);
                let (r, s) = fit_and_spread_by(method, &source, block_mm, None);
                (
                    mapped_point_covariance(&r.transform, &s.covariance, &q).trace(),
                    mapped_point_covariance(&r.transform, &s.independent, &q).trace(),
                    r.transform.inverse() * q,
                )
            })
            .collect();
        let mut mapped = Vec::new();
        let mut predicted = 0.0;
        let mut textbook = 0.0;
        for (blocks, independent, point) in each {
            predicted += blocks;
            textbook += independent;
            mapped.push(point);
        }
        let n = mapped.len() as f64;
        let mean = mapped.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
        let observed = mapped
            .iter()
            .map(|p| (p.coords - mean).norm_squared())
            .sum::<f64>()
            / (n - 1.0);
        (
            observed.sqrt(),
            (predicted / n).sqrt(),
            (textbook / n).sqrt(),
        )
    }

    #[test]
    fn independent_noise_is_predicted_by_the_textbook_and_the_blocks_alike() {
        let (observed, blocks, textbook) = check(1, 8.0);
        assert!(
            (textbook / observed - 1.0).abs() < 0.15,
            "{textbook} vs {observed}"
        );
        assert!(
            (blocks / observed - 1.0).abs() < 0.2,
            "{blocks} vs {observed}"
        );
    }

    #[test]
    fn correlated_noise_is_predicted_by_the_blocks_not_the_textbook() {
        // Noise shared by 5 x 5 mm patches: the textbook formula counts 25
        // times too many independent pairs (about 5 times too small a
        // spread); 20 mm blocks see it.
        let (observed, blocks, textbook) = check(5, 20.0);
        assert!(textbook < 0.4 * observed, "{textbook} vs {observed}");
        assert!(
            (blocks / observed - 1.0).abs() < 0.25,
            "{blocks} vs {observed}"
        );
    }

    #[test]
    fn generalized_icps_spread_is_predicted_by_its_own_terms() {
        // GICP weighs a pair by both surfaces' plane covariances, not by
        // the noise's spread: the sandwich still predicts the spread, from
        // each pair's information split along its eigenvectors.
        let (observed, blocks, textbook) = check_by(IcpMethod::Gicp, 1, 8.0, 120);
        assert!(
            (textbook / observed - 1.0).abs() < 0.2,
            "{textbook} vs {observed}"
        );
        assert!(
            (blocks / observed - 1.0).abs() < 0.25,
            "{blocks} vs {observed}"
        );
    }

    #[test]
    fn a_common_shift_moves_the_pose_with_it() {
        // Every source point shifted by the same (1, 0, 0.5) mm per standard
        // deviation: ICP follows it in full, so the target moves by as much.
        let field = |_: &Point3<f64>, _| Some(vec![Vector3::new(1.0, 0.0, 0.5)]);
        let (r, s) = fit_and_spread(&bowl().0, 10.0, Some(&field));
        let c = mapped_point_covariance(&r.transform, &s.shift, &Point3::new(3.0, 4.0, -50.0));
        let expected = nalgebra::Matrix3::new(1.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.5, 0.0, 0.25);
        assert!((c - expected).amax() < 1e-3, "{c}");
        assert!(s.noise.amax() < 1e-12, "a perfect fit has no noise");
    }

    #[test]
    fn the_low_rank_leverage_correction_is_the_full_one() {
        // Bell & McCaffrey's correction written out with the n x n matrix
        // (I - U H^-1 U^T)^-1/2, against the 6 x 6 form, for clusters of 3
        // to 40 terms out of a fit of 120.
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let mut draw = || unit.sample(&mut rng);
        let terms: Vec<Term> = (0..120)
            .map(|i| Term {
                origin: Origin::Surface(i),
                moved: Point3::new(30.0 * draw(), 30.0 * draw(), 10.0 * draw()),
                anchor: Point3::origin(),
                direction: Vector3::new(draw(), draw(), 1.0).normalize(),
                residual: draw(),
                weight: 0.5 + draw().abs(),
            })
            .collect();
        let h_inverse = normal_matrix(terms.iter().map(|t| (t, 1.0)))
            .try_inverse()
            .unwrap();
        let root = h_inverse.cholesky().unwrap().l();
        for n in [3, 12, 40] {
            let cluster: Vec<&Term> = terms[..n].iter().collect();
            let u: Vec<Vector6<f64>> = cluster.iter().map(|t| t.row() * t.weight.sqrt()).collect();
            let m = nalgebra::DMatrix::from_fn(n, n, |i, j| {
                f64::from(u8::from(i == j)) - (u[i].transpose() * h_inverse * u[j])[(0, 0)]
            });
            let e = m.symmetric_eigen();
            let root_inverse = &e.eigenvectors
                * nalgebra::DMatrix::from_diagonal(&e.eigenvalues.map(|l| 1.0 / l.sqrt()))
                * e.eigenvectors.transpose();
            let scaled = nalgebra::DVector::from_fn(n, |i, _| {
                cluster[i].weight.sqrt() * cluster[i].residual
            });
            let corrected = root_inverse * scaled;
            let full = (0..n).fold(Vector6::zeros(), |g, i| g + u[i] * corrected[i]);
            let low_rank = cluster_score(&cluster, Some(&root));
            let plain = cluster_score(&cluster, None);
            assert!(
                (full - low_rank).amax() < 1e-9 * full.amax(),
                "{n}: {full} vs {low_rank}"
            );
            assert!(
                (full - plain).amax() > 1e-3 * full.amax(),
                "{n}: a correction"
            );
        }
    }

    #[test]
    fn a_few_landmarks_noise_is_not_taken_for_less_than_it_is() {
        // Six landmarks fitted in full (three directions each) with 0.5 mm
        // of noise: the fitted residuals are smaller than the noise (18
        // residuals, 6 parameters), so the plain cluster estimate is about
        // 12 / 18 of the true variance; with the leverage correction it is
        // right on average (2,000 draws).
        let points = [
            Point3::new(40.0, 0.0, 10.0),
            Point3::new(-35.0, 10.0, 5.0),
            Point3::new(0.0, 45.0, 20.0),
            Point3::new(5.0, -40.0, 15.0),
            Point3::new(20.0, 20.0, 45.0),
            Point3::new(-20.0, -15.0, 40.0),
        ];
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.5).unwrap();
        let (mut corrected, mut plain) = (0.0, 0.0);
        let mut true_variance = 0.0;
        for _ in 0..2000 {
            let mut terms: Vec<Term> = Vec::new();
            for (k, p) in points.iter().enumerate() {
                for e in [Vector3::x(), Vector3::y(), Vector3::z()] {
                    terms.push(Term {
                        origin: Origin::Landmark(k),
                        moved: *p,
                        anchor: *p,
                        direction: e,
                        residual: noise.sample(&mut rng),
                        weight: 1.0,
                    });
                }
            }
            let h_inverse = normal_matrix(terms.iter().map(|t| (t, 1.0)))
                .try_inverse()
                .unwrap();
            let step = -(h_inverse
                * terms
                    .iter()
                    .fold(Vector6::zeros(), |g, t| g + t.row() * t.residual));
            true_variance = (h_inverse * 0.25).trace();
            for t in &mut terms {
                t.residual += t.row().dot(&step);
            }
            corrected += noise_covariance(&terms, &h_inverse, 10.0).0.trace();
            let meat = (0..points.len()).fold(Matrix6::zeros(), |m, k| {
                let g = terms
                    .iter()
                    .filter(|t| t.origin == Origin::Landmark(k))
                    .fold(Vector6::zeros(), |g, t| g + t.row() * t.residual);
                m + g * g.transpose()
            });
            plain += (h_inverse * meat * h_inverse).trace();
        }
        let (corrected, plain) = (corrected / 2000.0, plain / 2000.0);
        assert!(
            (corrected / true_variance - 1.0).abs() < 0.08,
            "{corrected} vs {true_variance}"
        );
        assert!(plain < 0.8 * true_variance, "{plain} vs {true_variance}");
    }
}
