//! Generalized ICP (Segal, Haehnel & Thrun 2009, "plane-to-plane"): each
//! pair's residual `d = m - q` (moved source point minus target point) is
//! weighed by the inverse of the sum of the two points' plane covariances,
//! the source's turned by the current rotation: `d^T (C_q + R C_s R^T)^-1 d`.
//! Both surfaces' shapes count, so pairs slide along the surfaces freely
//! and pin them across, as point-to-plane does with the target's normals
//! alone. Linearised in a small turn w and shift t applied after the
//! transform (`m -> m + w x m + t`), as point-to-plane is.

use super::pairs::{Kernel, Pairs, motion_jacobian, normal_equations_over};
use crate::cloud::{Nearest, plane_covariance, plane_covariances};
use nalgebra::{Matrix3, Matrix6, Point3, Rotation3, Vector6};
use std::sync::OnceLock;

/// Neighbours whose spread gives a point's plane covariance (Segal et al.
/// take 20).
pub const GICP_NEIGHBOURS: usize = 20;

/// What generalized ICP keeps through a fit: a tree over the
/// full-resolution source (each scale's source points take their
/// covariances from their neighbours in it) and the target's covariances,
/// each estimated the first time a pair needs it (a partial view pairs
/// with part of the target only).
pub(crate) struct GicpSurfaces<'a> {
    source_surface: Nearest,
    target_tree: &'a Nearest,
    target: Vec<OnceLock<Matrix3<f64>>>,
}

impl<'a> GicpSurfaces<'a> {
    /// The source's tree, and room for the target's covariances (`tree` is
    /// the target's); an error for an empty source.
    pub(crate) fn new(source: &[Point3<f64>], tree: &'a Nearest) -> Result<Self, String> {
        Ok(GicpSurfaces {
            source_surface: Nearest::new(source).ok_or("the source cloud is empty")?,
            target_tree: tree,
            target: (0..tree.len()).map(|_| OnceLock::new()).collect(),
        })
    }

    /// The covariances of `points` of the source (one scale's; source
    /// frame).
    pub(crate) fn source_covariances(&self, points: &[Point3<f64>]) -> Vec<Matrix3<f64>> {
        plane_covariances(points, &self.source_surface, GICP_NEIGHBOURS)
    }

    /// Target point `j`'s covariance (target frame).
    pub(crate) fn target_covariance(&self, j: usize) -> &Matrix3<f64> {
        self.target[j].get_or_init(|| {
            plane_covariance(
                &self.target_tree.point(j),
                self.target_tree,
                GICP_NEIGHBOURS,
            )
        })
    }
}

/// The information matrix of one pair, `(C_q + R C_s R^T)^-1`, or `None`
/// where the sum is singular (it is not for plane covariances, whose
/// least variance is positive).
pub(crate) fn pair_information(
    target_covariance: &Matrix3<f64>,
    source_covariance: &Matrix3<f64>,
    rotation: &Rotation3<f64>,
) -> Option<Matrix3<f64>> {
    let r = rotation.matrix();
    (target_covariance + r * source_covariance * r.transpose()).try_inverse()
}

/// The normal equations of one step: `sum J^T W J`, `sum J^T W d` and the
/// sum of the kernel weights, over `pairs` of `moved` source points (target
/// frame) and `target` points, with `W` each pair's information times its
/// kernel weight (taken on the pair's distance, mm), and `source_covariances`
/// one per source point. Summed as point-to-plane's are (fixed chunks, in
/// order).
pub(crate) fn normal_equations(
    pairs: &Pairs,
    moved: &[Point3<f64>],
    target: &[Point3<f64>],
    source_covariances: &[Matrix3<f64>],
    surfaces: &GicpSurfaces<'_>,
    rotation: &Rotation3<f64>,
    kernel: Kernel,
) -> (Matrix6<f64>, Vector6<f64>, f64) {
    normal_equations_over(pairs, |i, j, distance| {
        let w = kernel.weight(distance);
        let info = pair_information(
            surfaces.target_covariance(j),
            &source_covariances[i],
            rotation,
        )?;
        let jac = motion_jacobian(&moved[i]);
        let jtw = jac.transpose() * (info * w);
        Some((jtw * jac, jtw * (moved[i] - target[j]), w))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn the_jacobian_is_the_linearised_motion() {
        let m = Point3::new(3.0, -2.0, 5.0);
        let x = Vector6::new(0.01, -0.02, 0.03, 0.5, -0.25, 1.0);
        let (w, t) = (
            Vector3::new(x[0], x[1], x[2]),
            Vector3::new(x[3], x[4], x[5]),
        );
        assert!((motion_jacobian(&m) * x - (w.cross(&m.coords) + t)).norm() < 1e-12);
    }

    #[test]
    fn a_pair_of_planes_is_pinned_across_them_only() {
        // Both planes z = const: information is large along z, about 1/2
        // along x and y (the two in-plane variances of 1 add).
        let flat = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1e-3));
        let info = pair_information(&flat, &flat, &Rotation3::identity()).unwrap();
        assert!((info[(0, 0)] - 0.5).abs() < 1e-12 && (info[(1, 1)] - 0.5).abs() < 1e-12);
        assert!((info[(2, 2)] - 500.0).abs() < 1e-9);
        // The source plane turned 90 deg about x lies in y = const: the sum
        // is then 1 + 1e-3 along y and z, 2 along x.
        let turn = Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
        let info = pair_information(&flat, &flat, &turn).unwrap();
        assert!((info[(0, 0)] - 0.5).abs() < 1e-9);
        assert!((info[(1, 1)] - 1.0 / 1.001).abs() < 1e-9);
        assert!((info[(2, 2)] - 1.0 / 1.001).abs() < 1e-9);
    }
}
