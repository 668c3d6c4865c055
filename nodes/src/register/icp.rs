//! Iterative closest point, point-to-point (Besl & McKay, with Umeyama's
//! closed form), point-to-plane (Chen & Medioni, linearised) and generalized
//! ICP (Segal et al., linearised; see the `gicp` module), with a maximum
//! correspondence distance, trimming and robust kernels, optionally over a
//! coarse-to-fine list of voxel sizes.
//!
//! Landmarks ([`Anchors`], e.g. markers matched between the clouds) may join
//! the surface pairs as point-to-point terms with a weight: a nearly
//! symmetric surface (a dome) pins its tangential motion weakly, and a surface
//! reconstructed from weak texture pins it wrongly, where three landmarks pin
//! it outright.
//!
//! On smooth surfaces point-to-point has a small basin: on the tests' bumpy
//! ellipsoid it settles several degrees off from a 5-10 deg start, as pairs slide
//! along the surface, where point-to-plane converges; prefer point-to-plane for
//! surfaces.

use super::gicp::{self, GicpSurfaces};
pub use super::pairs::Kernel;
use super::pairs::{Pairs, REDUCTION_CHUNK, normal_equations_over};
use super::procrustes::fit_from_moments;
use crate::cloud::{Nearest, voxel_downsample};
use fusegraph_plugin_api::derive::Choice;
use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6,
};
use rayon::prelude::*;

/// Error metric (also the `method` parameter of `register.icp`: its
/// choices, in this order, are `point_to_plane`, `point_to_point` and
/// `gicp`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum IcpMethod {
    /// Distance along the target's normal.
    PointToPlane,
    /// Distance between points.
    PointToPoint,
    /// Generalized ICP (Segal et al. 2009): the distance weighed by both
    /// surfaces' local plane covariances (see the `gicp` module); needs no
    /// normals.
    Gicp,
}

/// ICP settings.
#[derive(Debug, Clone, PartialEq)]
pub struct IcpParams {
    /// Error metric.
    pub method: IcpMethod,
    /// Pairs farther apart are ignored, mm.
    pub max_distance_mm: f64,
    /// Fraction of the closest pairs kept each iteration (1 = no trimming).
    pub trim_ratio: f64,
    /// Robust kernel.
    pub kernel: Kernel,
    /// Iterations per scale.
    pub max_iterations: usize,
    /// Stop when RMSE and fitness change by less than this, relative.
    pub tolerance: f64,
    /// Coarse-to-fine voxel sizes for the source, mm (empty = full resolution).
    pub voxel_sizes_mm: Vec<f64>,
}

impl IcpParams {
    /// The source voxel sizes of the scales, coarse to fine (0 = full).
    pub(crate) fn scales(&self) -> Vec<f64> {
        if self.voxel_sizes_mm.is_empty() {
            vec![0.0]
        } else {
            self.voxel_sizes_mm.clone()
        }
    }

    /// The source at one scale's voxel size, and that scale's maximum
    /// pair distance (mm).
    pub(crate) fn scale(&self, source: &[Point3<f64>], voxel_mm: f64) -> (Vec<Point3<f64>>, f64) {
        let points = if voxel_mm > 0.0 {
            voxel_downsample(source, voxel_mm)
        } else {
            source.to_vec()
        };
        (points, self.max_distance_mm.max(2.0 * voxel_mm))
    }
}

/// Each source point's nearest target point from its last search, reused
/// while it is provably still the nearest. Searched from `at` with the
/// nearest at distance d1 and the second nearest at d2 (or a lower bound on
/// it), a point moved less than (d2 - d1) / 2 from `at` has the same
/// nearest: that one is at most d1 + moved away, every other at least
/// d2 - moved. ICP's later steps move points by microns, so most searches
/// are skipped, and the pairs are those a full search finds (a tie aside).
///
/// A point that moved further is searched again. Where it moved little
/// against its distance to the old nearest or the target's typical spacing,
/// the search is confined to a ball that must hold the nearest (the old
/// nearest's distance) and wide enough to give slack for a move as large
/// again (plus twice the move): it finds the two nearest in the ball, and
/// the confinement makes it cost about what an unconfined search for one
/// does. Where it moved much (ICP's first steps), the ball would be wide
/// and slow, so the search is for the nearest alone, kept with no slack:
/// the next, smaller step will search the ball. A point's first search
/// finds the nearest alone.
#[derive(Debug, Clone)]
pub(crate) struct NearestCache {
    entries: Vec<Option<CachedNearest>>,
    /// The target's typical spacing, mm.
    spacing_mm: f64,
}

#[derive(Debug, Clone, Copy)]
struct CachedNearest {
    /// Where the point was when searched, mm.
    at: Point3<f64>,
    /// Its nearest target point there.
    nearest: usize,
    /// How far it may move and keep that nearest, mm: half the gap
    /// between the nearest and second-nearest distances (0 when only the
    /// nearest was searched).
    slack_mm: f64,
}

/// Target points sampled for the target's typical spacing.
const SPACING_SAMPLE: usize = 256;

impl NearestCache {
    /// An empty cache for `n` source points searched in `tree`.
    pub(crate) fn new(n: usize, tree: &Nearest) -> Self {
        NearestCache {
            entries: vec![None; n],
            spacing_mm: tree.typical_spacing_mm(SPACING_SAMPLE),
        }
    }
}

impl CachedNearest {
    /// The nearest target point to a source point now at `m`, the squared
    /// distance to it (mm²), and whether `cached` (its last search) gave
    /// it; otherwise a new search, which `cached` keeps. A search is
    /// confined to a ball when the move is small against the old nearest's
    /// distance or `spacing_mm` (the target's typical spacing).
    fn nearest(
        cached: &mut Option<Self>,
        tree: &Nearest,
        m: &Point3<f64>,
        spacing_mm: f64,
    ) -> ((usize, f64), bool) {
        let mut confined = None;
        if let Some(c) = cached {
            let moved_mm = (m - c.at).norm();
            let old_mm = (tree.point(c.nearest) - m).norm();
            if moved_mm < c.slack_mm {
                return ((c.nearest, old_mm * old_mm), true);
            }
            if 2.0 * moved_mm <= old_mm.max(spacing_mm) {
                confined = tree.nearest_two_within(m, old_mm + 2.0 * moved_mm);
            }
        }
        let ((j, d1), d2) = confined.unwrap_or_else(|| {
            let one = tree.nearest(m);
            (one, one.1)
        });
        *cached = Some(CachedNearest {
            at: *m,
            nearest: j,
            slack_mm: 0.5 * (d2.sqrt() - d1.sqrt()),
        });
        ((j, d1), false)
    }
}

/// Each moved source point's nearest target point within `max_d` (mm) as
/// (source index, target index, distance mm), the closest `trim_ratio` of
/// them kept, and the fraction of source points that had one (fitness).
pub(crate) fn correspondences(
    moved: &[Point3<f64>],
    tree: &Nearest,
    max_d: f64,
    trim_ratio: f64,
    cache: Option<&mut NearestCache>,
) -> Result<(Pairs, f64), String> {
    let within =
        |(i, (j, d2)): (usize, (usize, f64))| (d2 <= max_d * max_d).then(|| (i, j, d2.sqrt()));
    let mut pairs: Vec<(usize, usize, f64)> = match cache {
        Some(cache) => {
            assert_eq!(
                cache.entries.len(),
                moved.len(),
                "one entry per source point"
            );
            let spacing_mm = cache.spacing_mm;
            let found: Vec<((usize, f64), bool)> = moved
                .par_iter()
                .zip(cache.entries.par_iter_mut())
                .map(|(m, c)| CachedNearest::nearest(c, tree, m, spacing_mm))
                .collect();
            found
                .into_iter()
                .enumerate()
                .filter_map(|(i, (nearest, _))| within((i, nearest)))
                .collect()
        }
        None => moved
            .par_iter()
            .enumerate()
            .filter_map(|(i, m)| within((i, tree.nearest(m))))
            .collect(),
    };
    let fitness = pairs.len() as f64 / moved.len().max(1) as f64;
    if pairs.len() < 6 {
        return Err(format!(
            "only {} pairs within {max_d} mm: the start is too far off",
            pairs.len()
        ));
    }
    if trim_ratio < 1.0 {
        // Stable, as the serial sort: ties keep source order.
        pairs.par_sort_by(|a, b| a.2.total_cmp(&b.2));
        pairs.truncate(((pairs.len() as f64 * trim_ratio).ceil() as usize).max(6));
    }
    Ok((pairs, fitness))
}

/// One iteration's figures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IcpStep {
    /// Voxel size of this scale (0 = full).
    pub voxel_mm: f64,
    /// RMSE of the kept pairs, mm.
    pub rmse_mm: f64,
    /// Fraction of source points with a pair within the maximum distance.
    pub fitness: f64,
    /// Pairs used.
    pub pairs: usize,
}

/// The result.
#[derive(Debug, Clone, PartialEq)]
pub struct IcpResult {
    /// Source -> target.
    pub transform: Isometry3<f64>,
    /// RMSE of the kept pairs at the end, mm.
    pub rmse_mm: f64,
    /// Fitness at the end.
    pub fitness: f64,
    /// Iterations over all scales.
    pub iterations: usize,
    /// Every iteration.
    pub trace: Vec<IcpStep>,
}

/// Landmark pairs that join the surface pairs: `source[k]` (source frame)
/// belongs at `target[k]` (target frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Anchors {
    /// Landmarks in the source frame, mm.
    pub source: Vec<Point3<f64>>,
    /// The same landmarks in the target frame, mm.
    pub target: Vec<Point3<f64>>,
    /// The weight of all landmarks together relative to all surface pairs of
    /// an iteration (1: as much as the whole surface).
    pub weight: f64,
    /// The target surface's unit normal at each target landmark (target
    /// frame), or `None`. Given, a landmark pins only the two directions
    /// across its normal, and the surface pins the third: right for
    /// landmarks whose two sides are different points of one object along
    /// the normal (a marker's face seen by a camera, its gel's centroid in
    /// MRI, a few mm deeper). Point-to-plane only; point-to-point fits
    /// landmarks in full.
    pub normals: Option<Vec<Vector3<f64>>>,
    /// Each landmark pair's weight matrix (target frame), relative: the
    /// inverse of its residual's covariance, scaled as
    /// [`relative_information`] does, or `None` (every direction alike).
    /// Given, a landmark pins each direction by how well it is measured
    /// there (a stereo marker's depth is about ten times less certain than
    /// its position across the line of sight), and `normals` is not used.
    /// Point-to-plane only.
    pub information: Option<Vec<Matrix3<f64>>>,
}

/// Relative weight matrices of landmark pairs whose residuals have the
/// covariances `covariances` (mm^2): their inverses, scaled so their mean
/// trace is 3, which leaves the landmarks' total weight what three unit
/// directions each give ([`Anchors::each`] stays the weight of one
/// direction on average). `None` when a covariance is not positive definite.
pub fn relative_information(covariances: &[Matrix3<f64>]) -> Option<Vec<Matrix3<f64>>> {
    let inverses: Vec<Matrix3<f64>> = covariances
        .iter()
        .map(|c| c.cholesky().map(|l| l.inverse()))
        .collect::<Option<_>>()?;
    let mean_trace = inverses.iter().map(|m| m.trace()).sum::<f64>() / inverses.len() as f64;
    (mean_trace.is_finite() && mean_trace > 0.0)
        .then(|| inverses.iter().map(|m| m * (3.0 / mean_trace)).collect())
}

impl Anchors {
    /// Landmark pairs weighed by their residuals' covariances (target
    /// frame, mm^2; see [`relative_information`]), or alike in every
    /// direction when `covariances` is `None` or one is not positive
    /// definite.
    pub fn weighed_by(
        source: Vec<Point3<f64>>,
        target: Vec<Point3<f64>>,
        weight: f64,
        covariances: Option<Vec<Matrix3<f64>>>,
    ) -> Anchors {
        Anchors {
            source,
            target,
            weight,
            normals: None,
            information: covariances.as_deref().and_then(relative_information),
        }
    }

    /// The directions landmark `k`'s residual is fitted along, each scaled
    /// by the square root of its weight: the three axes, the two across its
    /// normal, or the eigenvectors of its weight matrix.
    pub(crate) fn directions(&self, k: usize) -> Vec<Vector3<f64>> {
        if let Some(w) = self.information.as_ref().and_then(|w| w.get(k)) {
            let e = w.symmetric_eigen();
            return (0..3)
                .filter(|&j| e.eigenvalues[j] > 0.0)
                .map(|j| e.eigenvectors.column(j) * e.eigenvalues[j].sqrt())
                .collect();
        }
        match self.normals.as_ref().and_then(|n| n.get(k)) {
            Some(n) => {
                let a = if n.x.abs() < 0.9 {
                    Vector3::x()
                } else {
                    Vector3::y()
                };
                let t1 = a.cross(n).normalize();
                vec![t1, n.cross(&t1)]
            }
            None => vec![Vector3::x(), Vector3::y(), Vector3::z()],
        }
    }

    /// Each landmark pair's weight when `surface_weight` is the surface
    /// pairs' total.
    pub(crate) fn each(&self, surface_weight: f64) -> f64 {
        self.weight * surface_weight / self.source.len().max(1) as f64
    }
}

/// The surface's orientation at each of `at` (mm): the mean of the unit
/// normals of its `k` nearest surface points (`tree` over the points whose
/// `normals` these are), normalised. Averaging over a patch wider than a
/// marker gives the skin's normal around it, not its cap's.
pub fn normals_near(
    tree: &Nearest,
    normals: &[Vector3<f64>],
    at: &[Point3<f64>],
    k: usize,
) -> Vec<Vector3<f64>> {
    at.iter()
        .map(|p| {
            let sum: Vector3<f64> = tree.knn(p, k).iter().map(|&j| normals[j]).sum();
            sum.try_normalize(1e-12).unwrap_or_else(Vector3::z)
        })
        .collect()
}

/// Weighted sums over point pairs (source point, target point, both taken
/// relative to one origin near them, mm) that the rigid least-squares fit
/// needs: accumulated pair by pair, merged chunk by chunk.
#[derive(Debug, Clone, Copy)]
struct PairMoments {
    total: f64,
    source: Vector3<f64>,
    target: Vector3<f64>,
    /// Sum of w * target * source^T.
    cross: Matrix3<f64>,
}

impl Default for PairMoments {
    fn default() -> Self {
        PairMoments {
            total: 0.0,
            source: Vector3::zeros(),
            target: Vector3::zeros(),
            cross: Matrix3::zeros(),
        }
    }
}

impl PairMoments {
    fn add(self, source: &Vector3<f64>, target: &Vector3<f64>, w: f64) -> Self {
        PairMoments {
            total: self.total + w,
            source: self.source + source * w,
            target: self.target + target * w,
            cross: self.cross + target * source.transpose() * w,
        }
    }

    fn merge(self, other: &Self) -> Self {
        PairMoments {
            total: self.total + other.total,
            source: self.source + other.source,
            target: self.target + other.target,
            cross: self.cross + other.cross,
        }
    }

    /// The rotation and translation taking the sources onto the targets
    /// (`origin` added back), `None` for no weight or collinear points.
    fn fit(&self, origin: &Point3<f64>) -> Option<Isometry3<f64>> {
        if self.total <= 0.0 {
            return None;
        }
        let (ms, md) = (self.source / self.total, self.target / self.total);
        let cov = self.cross / self.total - md * ms.transpose();
        fit_from_moments(
            &(ms + origin.coords),
            &(md + origin.coords),
            &cov,
            1.0,
            false,
        )
        .map(|s| s.isometry())
    }
}

/// The sums of point-to-plane's normal equations: `sum w a a^T`,
/// `sum w a r` and `sum w`, with `r = n . (m - q)` each pair's distance
/// along the target normal, `a = (m x n, n)` its row and `w` its kernel
/// weight.
fn point_to_plane_equations(
    pairs: &Pairs,
    moved: &[Point3<f64>],
    target: &[Point3<f64>],
    normals: &[Vector3<f64>],
    kernel: Kernel,
) -> (Matrix6<f64>, Vector6<f64>, f64) {
    normal_equations_over(pairs, |i, j, _| {
        let (m, q, n) = (moved[i], target[j], normals[j]);
        let r = n.dot(&(m - q));
        let w = kernel.weight(r);
        let c = m.coords.cross(&n);
        let row = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
        Some((row * row.transpose() * w, row * (r * w), w))
    })
}

/// The step (a small turn w and shift t, applied after `transform`) that
/// solves linearised normal equations `ata x = -atb` of the surface pairs
/// (whose kernel weights sum to `surface_weight`), with the landmarks'
/// rows added: one per direction each is fitted along, of the linearised
/// residual `m + w x m + t - q`. `None` where they do not pin the pose.
fn linearised_step(
    mut ata: Matrix6<f64>,
    mut atb: Vector6<f64>,
    surface_weight: f64,
    anchors: Option<&Anchors>,
    transform: &Isometry3<f64>,
) -> Option<Isometry3<f64>> {
    if let Some(anchors) = anchors {
        let each = anchors.each(surface_weight);
        for (k, (s, q)) in anchors.source.iter().zip(&anchors.target).enumerate() {
            let m = transform * s;
            let r = m - q;
            for e in anchors.directions(k) {
                let c = m.coords.cross(&e);
                let row = Vector6::new(c.x, c.y, c.z, e.x, e.y, e.z);
                ata += row * row.transpose() * each;
                atb += row * (r.dot(&e) * each);
            }
        }
    }
    ata.cholesky().map(|c| {
        let x = c.solve(&(-atb));
        Isometry3::from_parts(
            Translation3::new(x[3], x[4], x[5]),
            UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2])),
        )
    })
}

/// Registers `source` onto `target` (whose k-d tree is `tree`; normals needed
/// for point-to-plane), starting from `init` (source frame -> target frame,
/// mm). The same inputs give the same bits on any number of threads.
///
/// # Examples
///
/// ```
/// use fusegraph_nodes::cloud::{Nearest, bumpy_ellipsoid, estimate_normals};
/// use fusegraph_nodes::register::{IcpMethod, IcpParams, Kernel, icp};
/// use nalgebra::{Isometry3, Vector3};
///
/// // A surface, and the same surface moved about 2 mm and 3 degrees away.
/// let target = bumpy_ellipsoid(2000, 0.5);
/// let offset = Isometry3::new(Vector3::new(2.0, 0.0, -1.0), Vector3::new(0.0, 0.0, 0.05));
/// let source: Vec<_> = target.iter().map(|p| offset.inverse() * p).collect();
/// let params = IcpParams {
///     method: IcpMethod::PointToPlane,
///     max_distance_mm: 10.0,
///     trim_ratio: 1.0,
///     kernel: Kernel::None,
///     max_iterations: 50,
///     tolerance: 1e-9,
///     voxel_sizes_mm: vec![],
/// };
/// let normals = estimate_normals(&target, 10, None);
/// let tree = Nearest::new(&target).unwrap();
/// let r = icp(&source, &target, Some(&normals), &tree, &Isometry3::identity(), &params).unwrap();
/// // ICP finds the offset that maps the source back onto the target.
/// assert!((r.transform.translation.vector - offset.translation.vector).norm() < 1e-3);
/// assert!(r.transform.rotation.angle_to(&offset.rotation) < 1e-5);
/// assert!(r.rmse_mm < 1e-3);
/// ```
pub fn icp(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    target_normals: Option<&[Vector3<f64>]>,
    tree: &Nearest,
    init: &Isometry3<f64>,
    p: &IcpParams,
) -> Result<IcpResult, String> {
    icp_anchored(source, target, target_normals, tree, init, p, None)
}

/// [`icp`] with landmark pairs joining the surface pairs (see [`Anchors`]);
/// `None` is plain ICP.
pub fn icp_anchored(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    target_normals: Option<&[Vector3<f64>]>,
    tree: &Nearest,
    init: &Isometry3<f64>,
    p: &IcpParams,
    anchors: Option<&Anchors>,
) -> Result<IcpResult, String> {
    if let Some(a) = anchors
        && a.source.len() != a.target.len()
    {
        return Err(format!(
            "{} source landmarks and {} target landmarks: they pair one to one",
            a.source.len(),
            a.target.len()
        ));
    }
    let anchors = anchors.filter(|a| !a.source.is_empty() && a.weight > 0.0);
    if p.method == IcpMethod::PointToPlane && target_normals.is_none_or(|n| n.len() != target.len())
    {
        return Err("point-to-plane ICP needs a normal for every target point".into());
    }
    let mut transform = *init;
    let mut trace = Vec::new();
    let gicp_surfaces = (p.method == IcpMethod::Gicp)
        .then(|| GicpSurfaces::new(source, tree))
        .transpose()?;
    for voxel in p.scales() {
        let (src, max_d) = p.scale(source, voxel);
        let source_covariances = gicp_surfaces.as_ref().map(|g| g.source_covariances(&src));
        let mut previous: Option<(f64, f64)> = None;
        let mut cache = NearestCache::new(src.len(), tree);
        for _ in 0..p.max_iterations {
            let moved: Vec<Point3<f64>> = src.par_iter().map(|s| transform * s).collect();
            let (pairs, fitness) =
                correspondences(&moved, tree, max_d, p.trim_ratio, Some(&mut cache))?;
            let rmse = (pairs.iter().map(|q| q.2 * q.2).sum::<f64>() / pairs.len() as f64).sqrt();
            trace.push(IcpStep {
                voxel_mm: voxel,
                rmse_mm: rmse,
                fitness,
                pairs: pairs.len(),
            });
            if let Some((r0, f0)) = previous
                && (r0 - rmse).abs() <= p.tolerance * r0.max(1e-12)
                && (f0 - fitness).abs() <= p.tolerance
            {
                break;
            }
            previous = Some((rmse, fitness));
            let step = match p.method {
                IcpMethod::PointToPoint => {
                    // Sums over fixed chunks, as for point-to-plane below.
                    let origin = moved[pairs[0].0];
                    let partials: Vec<PairMoments> = pairs
                        .par_chunks(REDUCTION_CHUNK)
                        .map(|chunk| {
                            chunk
                                .iter()
                                .fold(PairMoments::default(), |sums, &(i, j, d)| {
                                    sums.add(
                                        &(moved[i] - origin),
                                        &(target[j] - origin),
                                        p.kernel.weight(d),
                                    )
                                })
                        })
                        .collect();
                    let mut sums = partials
                        .iter()
                        .fold(PairMoments::default(), |a, b| a.merge(b));
                    if let Some(anchors) = anchors {
                        let each = anchors.each(sums.total);
                        for (s, t) in anchors.source.iter().zip(&anchors.target) {
                            sums = sums.add(&(transform * s - origin), &(t - origin), each);
                        }
                    }
                    sums.fit(&origin)
                }
                IcpMethod::PointToPlane => {
                    let normals = target_normals.expect("checked above");
                    let (ata, atb, surface_weight) =
                        point_to_plane_equations(&pairs, &moved, target, normals, p.kernel);
                    linearised_step(ata, atb, surface_weight, anchors, &transform)
                }
                IcpMethod::Gicp => {
                    let (ata, atb, surface_weight) = gicp::normal_equations(
                        &pairs,
                        &moved,
                        target,
                        source_covariances
                            .as_deref()
                            .expect("estimated for this scale"),
                        gicp_surfaces.as_ref().expect("estimated above"),
                        &transform.rotation.to_rotation_matrix(),
                        p.kernel,
                    );
                    linearised_step(ata, atb, surface_weight, anchors, &transform)
                }
            };
            let step = step.ok_or("degenerate pairs: the surfaces do not pin the transform")?;
            transform = step * transform;
        }
    }
    let last = *trace.last().expect("at least one iteration");
    Ok(IcpResult {
        transform,
        rmse_mm: last.rmse_mm,
        fitness: last.fitness,
        iterations: trace.len(),
        trace,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::{bumpy_ellipsoid, estimate_normals};

    #[test]
    fn relative_information_inverts_and_keeps_the_mean_weight() {
        let covariances = [
            Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 4.0)),
            Matrix3::from_diagonal(&Vector3::new(2.0, 2.0, 2.0)),
        ];
        let w = relative_information(&covariances).unwrap();
        // Inverses diag(1, 1, 0.25) and diag(0.5, 0.5, 0.5), mean trace
        // 1.875, so scaled by 3 / 1.875 = 1.6.
        assert!((w[0] - Matrix3::from_diagonal(&Vector3::new(1.6, 1.6, 0.4))).norm() < 1e-12);
        assert!((w[1] - Matrix3::from_diagonal(&Vector3::new(0.8, 0.8, 0.8))).norm() < 1e-12);
        // A landmark's rows rebuild its weight matrix.
        let turned = UnitQuaternion::from_euler_angles(0.3, -0.2, 0.7).to_rotation_matrix();
        let weight = turned * w[0] * turned.transpose();
        let anchors = Anchors {
            source: vec![Point3::origin()],
            target: vec![Point3::origin()],
            weight: 1.0,
            normals: Some(vec![Vector3::z()]),
            information: Some(vec![weight]),
        };
        let rebuilt = anchors
            .directions(0)
            .iter()
            .fold(Matrix3::zeros(), |m, e| m + e * e.transpose());
        assert!((rebuilt - weight).norm() < 1e-12, "{rebuilt}");
        assert!(
            relative_information(&[Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0))])
                .is_none()
        );
    }

    fn surface() -> Vec<Point3<f64>> {
        bumpy_ellipsoid(6000, 0.5)
    }

    fn check(method: IcpMethod, partial: bool, offset_deg: f64, offset_mm: f64) {
        let target = surface();
        let normals = estimate_normals(&target, 10, None);
        let tree = Nearest::new(&target).unwrap();
        let truth = Isometry3::new(
            Vector3::new(offset_mm, -offset_mm, 0.0) / 2f64.sqrt(),
            Vector3::new(0.0, 0.0, offset_deg.to_radians()),
        );
        // Source: the part a camera would see (one side), displaced by the
        // inverse offset, so truth maps it back onto the target.
        let source: Vec<Point3<f64>> = target
            .iter()
            .step_by(2)
            .filter(|p| !partial || (p.x > -10.0 && p.z > -15.0))
            .map(|p| truth.inverse() * p)
            .collect();
        let params = IcpParams {
            method,
            max_distance_mm: 30.0,
            trim_ratio: if partial { 0.9 } else { 1.0 },
            kernel: if partial {
                Kernel::Huber(2.0)
            } else {
                Kernel::None
            },
            max_iterations: 200,
            tolerance: 1e-10,
            voxel_sizes_mm: vec![],
        };
        let r = icp(
            &source,
            &target,
            Some(&normals),
            &tree,
            &Isometry3::identity(),
            &params,
        )
        .unwrap();
        let err_t = (r.transform.translation.vector - truth.translation.vector).norm();
        let err_r = r.transform.rotation.angle_to(&truth.rotation).to_degrees();
        assert!(
            err_t < 0.1 && err_r < 0.05,
            "{method:?}: {err_t} mm, {err_r} deg after {} iterations",
            r.iterations
        );
        assert!(r.rmse_mm < 0.2, "{}", r.rmse_mm);
    }

    /// The cache gives the pairs a full search gives, iteration after
    /// iteration, as points move a lot (every search) and then little
    /// (most searches skipped), in both search modes.
    #[test]
    fn cached_nearest_gives_the_full_searchs_pairs() {
        let target = surface();
        let tree = Nearest::new(&target).unwrap();
        let source: Vec<Point3<f64>> = target.iter().step_by(3).copied().collect();
        let mut cache = NearestCache::new(source.len(), &tree);
        let mut mostly_skipped = 0;
        for k in 0..14 {
            // Steps shrinking from 2 mm to microns, like ICP's.
            let step = 2.0 * 0.4f64.powi(k);
            let pose = Isometry3::new(
                Vector3::new(step, -0.5 * step, 0.3 * step),
                Vector3::new(0.0, 0.002 * step, 0.001 * step),
            );
            let moved: Vec<Point3<f64>> = source.iter().map(|s| pose * s).collect();
            let searched_at: Vec<Option<Point3<f64>>> =
                cache.entries.iter().map(|e| e.map(|c| c.at)).collect();
            let (cached, _) = correspondences(&moved, &tree, 5.0, 1.0, Some(&mut cache)).unwrap();
            let (full, _) = correspondences(&moved, &tree, 5.0, 1.0, None).unwrap();
            assert_eq!(cached, full, "iteration {k}");
            // A skipped search leaves its entry where it was searched.
            let skipped = cache
                .entries
                .iter()
                .zip(&searched_at)
                .filter(|(e, before)| e.map(|c| c.at) == **before)
                .count();
            if 2 * skipped > source.len() {
                mostly_skipped += 1;
            }
        }
        // Late iterations skipped most searches, early ones searched again.
        assert!((4..14).contains(&mostly_skipped), "{mostly_skipped}");
    }

    /// A spherical cap (radius 60 mm, above z = 10 mm) with its normals
    /// and k-d tree, the turn of 0.2 rad about its axis, and the cap turned
    /// back by it (the source that turn registers onto the cap).
    #[allow(clippy::type_complexity)]
    fn turned_cap() -> (
        Vec<Point3<f64>>,
        Vec<Vector3<f64>>,
        Nearest,
        Isometry3<f64>,
        Vec<Point3<f64>>,
    ) {
        let cap: Vec<Point3<f64>> = (0..4000)
            .map(|k| {
                let (u, v) = ((k % 80) as f64 / 80.0, (k / 80) as f64 / 50.0);
                let (theta, phi) = (u * std::f64::consts::TAU, 0.15 + 0.9 * v);
                Point3::new(
                    60.0 * phi.sin() * theta.cos(),
                    60.0 * phi.sin() * theta.sin(),
                    60.0 * phi.cos(),
                )
            })
            .filter(|p| p.z > 10.0)
            .collect();
        let normals: Vec<Vector3<f64>> = cap.iter().map(|p| p.coords.normalize()).collect();
        let tree = Nearest::new(&cap).unwrap();
        let truth = Isometry3::new(Vector3::zeros(), Vector3::new(0.0, 0.0, 0.2));
        let source: Vec<Point3<f64>> = cap.iter().map(|p| truth.inverse() * p).collect();
        (cap, normals, tree, truth, source)
    }

    #[test]
    fn landmarks_pin_the_turn_a_symmetric_surface_cannot() {
        // A spherical cap: turning it about its axis moves no point off the
        // surface, so surface pairs alone leave that turn where it starts.
        // Three landmarks on the cap fix it.
        let (cap, normals, tree, truth, source) = turned_cap();
        let landmarks = [cap[7], cap[1500], cap[2900]];
        let anchors = Anchors {
            source: landmarks.iter().map(|p| truth.inverse() * p).collect(),
            target: landmarks.to_vec(),
            weight: 1.0,
            normals: None,
            information: None,
        };
        let params = IcpParams {
            method: IcpMethod::PointToPlane,
            max_distance_mm: 20.0,
            trim_ratio: 1.0,
            kernel: Kernel::None,
            max_iterations: 100,
            tolerance: 1e-12,
            voxel_sizes_mm: vec![],
        };
        let run = |anchors: Option<&Anchors>, method: IcpMethod| {
            let p = IcpParams {
                method,
                ..params.clone()
            };
            let init = Isometry3::identity();
            icp_anchored(&source, &cap, Some(&normals), &tree, &init, &p, anchors)
                .unwrap()
                .transform
                .rotation
                .angle_to(&truth.rotation)
                .to_degrees()
        };
        assert!(
            run(None, IcpMethod::PointToPlane) > 10.0,
            "the surface alone cannot"
        );
        for method in [IcpMethod::PointToPlane, IcpMethod::PointToPoint] {
            let err = run(Some(&anchors), method);
            assert!(err < 0.01, "{method:?}: {err} deg off");
        }
        let lopsided = Anchors {
            target: landmarks[..2].to_vec(),
            ..anchors.clone()
        };
        let init = Isometry3::identity();
        let e = icp_anchored(
            &source,
            &cap,
            Some(&normals),
            &tree,
            &init,
            &params,
            Some(&lopsided),
        );
        assert!(e.unwrap_err().contains("pair one to one"));
    }

    #[test]
    fn tangential_landmarks_fix_the_turn_without_pulling_along_the_normal() {
        // The cap again, turned 0.2 rad about its axis. Each source landmark
        // lies 3 mm off the surface along the normal (a marker's face) and
        // its target on the surface (the gel under it): fitted in full they
        // pull the cap off along the normals; fitted across the normal only
        // they fix the turn and leave the surface's fit alone.
        let (cap, normals, tree, truth, source) = turned_cap();
        let on_skin = [cap[7], cap[1500], cap[2900]];
        let faces: Vec<Point3<f64>> = on_skin
            .iter()
            .map(|p| truth.inverse() * (p + p.coords.normalize() * 3.0))
            .collect();
        // The mean normal of a patch is the sphere's within a degree or two
        // (the patch is lopsided where the sampling grid is).
        for p in &on_skin {
            let n = normals_near(&tree, &normals, &[*p], 30)[0];
            assert!(n.dot(&p.coords.normalize()) > 0.999, "{n:?} at {p:?}");
        }
        let surface_normals: Vec<Vector3<f64>> =
            on_skin.iter().map(|p| p.coords.normalize()).collect();
        let params = IcpParams {
            method: IcpMethod::PointToPlane,
            max_distance_mm: 20.0,
            trim_ratio: 1.0,
            kernel: Kernel::None,
            max_iterations: 100,
            tolerance: 1e-12,
            voxel_sizes_mm: vec![],
        };
        let run = |normals_given: bool| {
            let anchors = Anchors {
                source: faces.clone(),
                target: on_skin.to_vec(),
                weight: 1.0,
                normals: normals_given.then(|| surface_normals.clone()),
                information: None,
            };
            let init = Isometry3::identity();
            let t = icp_anchored(
                &source,
                &cap,
                Some(&normals),
                &tree,
                &init,
                &params,
                Some(&anchors),
            )
            .unwrap()
            .transform;
            let off_mm = (t.translation.vector - truth.translation.vector).norm();
            (t.rotation.angle_to(&truth.rotation).to_degrees(), off_mm)
        };
        let (turn, off) = run(true);
        assert!(
            turn < 0.01 && off < 0.01,
            "across the normal: {turn} deg, {off} mm off"
        );
        // In full, the 3 mm offsets pull the cap 1.6 mm off (weight 1).
        let (turn, off) = run(false);
        assert!(off > 1.0, "in full: {turn} deg, {off} mm off");
    }

    #[test]
    fn point_to_plane_converges_from_10_deg_and_10_mm_on_a_partial_view() {
        check(IcpMethod::PointToPlane, true, 10.0, 10.0);
    }

    #[test]
    fn generalized_icp_converges_from_10_deg_and_10_mm_on_a_partial_view() {
        check(IcpMethod::Gicp, true, 10.0, 10.0);
    }

    #[test]
    fn the_same_clouds_give_the_same_bits_on_any_thread_count() {
        // Enough pairs for several reduction chunks and rayon splits.
        let target = bumpy_ellipsoid(30_000, 0.5);
        let normals = estimate_normals(&target, 10, None);
        let tree = Nearest::new(&target).unwrap();
        let offset = Isometry3::new(Vector3::new(2.0, -1.0, 0.5), Vector3::new(0.0, 0.02, 0.03));
        let source: Vec<Point3<f64>> = bumpy_ellipsoid(20_000, 0.25)
            .iter()
            .map(|p| offset * p)
            .collect();
        let bits = |threads: usize, method: IcpMethod| {
            let params = IcpParams {
                method,
                max_distance_mm: 10.0,
                trim_ratio: 0.9,
                kernel: Kernel::Huber(1.0),
                max_iterations: 8,
                tolerance: 0.0,
                voxel_sizes_mm: vec![],
            };
            let r = crate::on_threads(threads, || {
                icp(
                    &source,
                    &target,
                    Some(&normals),
                    &tree,
                    &Isometry3::identity(),
                    &params,
                )
            })
            .unwrap();
            let m = r.transform.to_homogeneous();
            (
                m.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                r.rmse_mm.to_bits(),
            )
        };
        for method in [IcpMethod::PointToPlane, IcpMethod::PointToPoint] {
            let one = bits(1, method);
            assert_eq!(bits(2, method), one, "{method:?}");
            assert_eq!(bits(3, method), one, "{method:?}");
        }
    }

    #[test]
    fn kernels_down_weight_large_residuals() {
        assert_eq!(Kernel::Huber(1.0).weight(0.5), 1.0);
        assert_eq!(Kernel::Huber(1.0).weight(4.0), 0.25);
        assert_eq!(Kernel::Tukey(2.0).weight(3.0), 0.0);
        assert!((Kernel::Tukey(2.0).weight(1.0) - 0.5625).abs() < 1e-12);
    }
}

#[cfg(test)]
mod sanity {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn point_to_point_recovers_an_offset_exactly_on_a_scattered_cloud() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let target: Vec<Point3<f64>> = (0..3000)
            .map(|_| {
                Point3::new(
                    rng.random_range(-50.0..50.0),
                    rng.random_range(-30.0..30.0),
                    rng.random_range(-20.0..20.0),
                )
            })
            .collect();
        let tree = Nearest::new(&target).unwrap();
        let truth = Isometry3::new(
            Vector3::new(3.0, -2.0, 1.0),
            Vector3::new(0.02, -0.03, 0.08),
        );
        let source: Vec<Point3<f64>> = target
            .iter()
            .step_by(2)
            .map(|p| truth.inverse() * p)
            .collect();
        let params = IcpParams {
            method: IcpMethod::PointToPoint,
            max_distance_mm: 30.0,
            trim_ratio: 1.0,
            kernel: Kernel::None,
            max_iterations: 200,
            tolerance: 1e-10,
            voxel_sizes_mm: vec![],
        };
        let r = icp(
            &source,
            &target,
            None,
            &tree,
            &Isometry3::identity(),
            &params,
        )
        .unwrap();
        let err = (r.transform.translation.vector - truth.translation.vector).norm();
        assert!(
            err < 1e-6 && r.transform.rotation.angle_to(&truth.rotation) < 1e-8,
            "{err} mm"
        );
        assert!(r.rmse_mm < 1e-6);
    }
}
