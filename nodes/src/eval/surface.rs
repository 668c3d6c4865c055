//! Distances from a reconstructed surface to the phantom's true skin.

use crate::phantom::{MotionField, PhantomShape};
use nalgebra::{Isometry3, Point3, Vector3};

/// Statistics of vertex-to-skin distances, mm.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceDistances {
    /// Mean distance.
    pub mean_mm: f64,
    /// Mean signed distance, positive outside the skin (along its outward
    /// normal): a reconstruction's common offset (bias), which its mean
    /// distance mixes with its noise.
    pub mean_signed_mm: f64,
    /// Median signed distance: the offset of the bulk of the surface, blind
    /// to stray points.
    pub median_signed_mm: f64,
    /// Root mean square distance.
    pub rms_mm: f64,
    /// 95th percentile.
    pub p95_mm: f64,
    /// Largest.
    pub max_mm: f64,
    /// Vertices measured (the rest lie on markers or the base).
    pub used: usize,
}

/// Distances from `vertices` (in a frame mapped to the phantom frame by
/// `to_phantom`) to the true skin, skipping vertices of other structures: on or
/// near markers or lesions (within `marker_margin_mm` of their extent), on the
/// base (phantom z below `base_margin_mm`), and nearer the base plane (the
/// table a camera sees around the phantom) than the skin. `None` when no vertex
/// is left.
///
/// With `motion`, the vertices lie on the skin as it moved (the camera
/// session): each is mapped back to where it was scanned, and its distance
/// there is scaled by how the motion stretched the skin's normal direction
/// (exact to first order in the distance).
pub fn skin_distances(
    shape: &PhantomShape,
    motion: Option<&MotionField>,
    to_phantom: &Isometry3<f64>,
    vertices: impl Iterator<Item = [f64; 3]>,
    marker_margin_mm: f64,
    base_margin_mm: f64,
) -> Option<SurfaceDistances> {
    let mut d: Vec<f64> = vertices
        .map(|v| to_phantom * Point3::from(v))
        .filter(|p| p.z >= base_margin_mm)
        .map(|p| match motion {
            Some(field) if !field.is_still() => (field.unmoved(&p), Some(field)),
            _ => (p, None),
        })
        .filter(|(p, _)| {
            shape.markers.iter().all(|m| {
                let s = Point3::from(m.skin_point_mm);
                let n = Vector3::from(m.normal);
                let h = (p - s).dot(&n);
                let radial = ((p - s).norm_squared() - h * h).max(0.0).sqrt();
                radial > m.radius_mm + marker_margin_mm
                    || h > m.height_mm + marker_margin_mm
                    || h < -m.below_skin_mm - marker_margin_mm
            })
        })
        .filter(|(p, _)| {
            shape
                .lesions
                .iter()
                .all(|l| (p - Point3::from(l.center_mm)).norm() > l.radius_mm + marker_margin_mm)
        })
        .map(|(p, field)| {
            let d = shape.signed_distance_to_ellipsoid(&p);
            let stretch = field.map_or(1.0, |f| {
                let n = shape.skin_normal(&p);
                1.0 / f.moved_normal_stretch(&p, &n)
            });
            (d * stretch, p.z)
        })
        .filter(|&(skin, above_base)| skin.abs() <= above_base)
        .map(|(skin, _)| skin)
        .collect();
    if d.is_empty() {
        return None;
    }
    let n = d.len() as f64;
    let mean_signed_mm = d.iter().sum::<f64>() / n;
    d.sort_by(f64::total_cmp);
    let median_signed_mm = d[d.len() / 2];
    d.iter_mut().for_each(|x| *x = x.abs());
    d.sort_by(f64::total_cmp);
    Some(SurfaceDistances {
        mean_mm: d.iter().sum::<f64>() / n,
        mean_signed_mm,
        median_signed_mm,
        rms_mm: (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        p95_mm: d[((0.95 * (n - 1.0)).round() as usize).min(d.len() - 1)],
        max_mm: *d.last().expect("non-empty"),
        used: d.len(),
    })
}
