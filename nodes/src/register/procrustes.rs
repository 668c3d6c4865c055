//! Least-squares similarity between corresponding point sets (Umeyama 1991):
//! rotation, translation and optionally one uniform scale, never a reflection.

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};

/// dst = scale * rotation * src + translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// Rotation.
    pub rotation: Rotation3<f64>,
    /// Translation, mm.
    pub translation: Vector3<f64>,
    /// Uniform scale (1 for a rigid transform).
    pub scale: f64,
}

impl Similarity {
    /// Maps a point.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * p.coords * self.scale + self.translation)
    }

    /// The homogeneous 4 x 4 matrix.
    pub fn matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(self.rotation.matrix() * self.scale));
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// The rigid part (exact when scale is 1).
    pub fn isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.translation),
            UnitQuaternion::from_rotation_matrix(&self.rotation),
        )
    }

    /// Root mean square of |dst - T(src)| over the pairs, mm.
    pub fn rmse(&self, src: &[Point3<f64>], dst: &[Point3<f64>]) -> f64 {
        (src.iter()
            .zip(dst)
            .map(|(s, d)| (self.apply(s) - d).norm_squared())
            .sum::<f64>()
            / src.len().max(1) as f64)
            .sqrt()
    }
}

/// The similarity minimising sum w_i |dst_i - T(src_i)|^2 (weights default to
/// 1), mapping `src`'s frame into `dst`'s (mm); `None` with fewer than 3 pairs
/// or collinear points. `with_scale` false keeps the scale exactly 1.
///
/// # Examples
///
/// ```
/// use fusegraph_nodes::register::umeyama;
/// use nalgebra::{Point3, Vector3};
///
/// // Four markers, and the same markers shifted by (10, -5, 2) mm.
/// let src = [
///     Point3::new(0.0, 0.0, 0.0),
///     Point3::new(30.0, 0.0, 0.0),
///     Point3::new(0.0, 20.0, 0.0),
///     Point3::new(0.0, 0.0, 10.0),
/// ];
/// let shift = Vector3::new(10.0, -5.0, 2.0);
/// let dst: Vec<_> = src.iter().map(|p| p + shift).collect();
/// let fit = umeyama(&src, &dst, None, false).unwrap();
/// assert!((fit.translation - shift).norm() < 1e-9);
/// assert!(fit.rotation.angle() < 1e-9);
/// assert_eq!(fit.scale, 1.0);
/// assert!(fit.rmse(&src, &dst) < 1e-9);
/// // Two markers leave the rotation about their line open.
/// assert!(umeyama(&src[..2], &dst[..2], None, false).is_none());
/// ```
pub fn umeyama(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    weights: Option<&[f64]>,
    with_scale: bool,
) -> Option<Similarity> {
    if src.len() < 3 || src.len() != dst.len() {
        return None;
    }
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let total: f64 = (0..src.len()).map(w).sum();
    if total <= 0.0 {
        return None;
    }
    let mean = |pts: &[Point3<f64>]| {
        pts.iter()
            .enumerate()
            .fold(Vector3::zeros(), |acc, (i, p)| acc + p.coords * w(i))
            / total
    };
    let (ms, md) = (mean(src), mean(dst));
    let mut cov = Matrix3::zeros();
    let mut var_src = 0.0;
    for i in 0..src.len() {
        let (a, b) = (src[i].coords - ms, dst[i].coords - md);
        cov += w(i) * b * a.transpose();
        var_src += w(i) * a.norm_squared();
    }
    cov /= total;
    var_src /= total;
    fit_from_moments(&ms, &md, &cov, var_src, with_scale)
}

/// The least-squares similarity (rotation, translation, and with
/// `with_scale` a scale) taking points with weighted mean `ms` onto points
/// with weighted mean `md` (mm), from their weighted cross-covariance
/// `cov` = mean of (dst - md)(src - ms)^T and the source's variance
/// `var_src` (mean squared distance from `ms`, mm^2): Umeyama's solution.
/// `None` when the points are collinear.
pub fn fit_from_moments(
    ms: &Vector3<f64>,
    md: &Vector3<f64>,
    cov: &Matrix3<f64>,
    var_src: f64,
    with_scale: bool,
) -> Option<Similarity> {
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut s = Matrix3::identity();
    if (u.determinant() * v_t.determinant()) < 0.0 {
        s[(2, 2)] = -1.0;
    }
    // Collinear points leave the rotation about their line undetermined.
    let sv = svd.singular_values;
    let mut sorted = [sv[0], sv[1], sv[2]];
    sorted.sort_by(f64::total_cmp);
    if sorted[1] <= 1e-12 * sorted[2].max(1e-300) {
        return None;
    }
    let r = u * s * v_t;
    let scale = if with_scale {
        (sv[0] * s[(0, 0)] + sv[1] * s[(1, 1)] + sv[2] * s[(2, 2)]) / var_src
    } else {
        1.0
    };
    let rotation = Rotation3::from_matrix_unchecked(r);
    Some(Similarity {
        rotation,
        translation: md - rotation * ms * scale,
        scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(40.0, 3.0, -2.0),
            Point3::new(-5.0, 35.0, 8.0),
            Point3::new(12.0, -20.0, 30.0),
            Point3::new(25.0, 18.0, 12.0),
        ]
    }

    #[test]
    fn recovers_a_known_similarity_exactly() {
        let truth = Similarity {
            rotation: Rotation3::from_euler_angles(0.3, -1.1, 2.0),
            translation: Vector3::new(10.0, -200.0, 55.0),
            scale: 1.07,
        };
        let dst: Vec<_> = points().iter().map(|p| truth.apply(p)).collect();
        let got = umeyama(&points(), &dst, None, true).unwrap();
        assert!((got.scale - 1.07).abs() < 1e-12);
        assert!((got.matrix() - truth.matrix()).norm() < 1e-9);
        assert!(got.rmse(&points(), &dst) < 1e-9);
        // Without scale, the best rigid fit keeps scale exactly 1.
        let rigid = umeyama(&points(), &dst, None, false).unwrap();
        assert_eq!(rigid.scale, 1.0);
        assert!(rigid.rmse(&points(), &dst) > 0.1);
    }

    #[test]
    fn never_reflects_and_refuses_degenerate_input() {
        let mirrored: Vec<_> = points()
            .iter()
            .map(|p| Point3::new(-p.x, p.y, p.z))
            .collect();
        let got = umeyama(&points(), &mirrored, None, false).unwrap();
        assert!((got.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
        let line: Vec<_> = (0..5)
            .map(|i| Point3::new(i as f64, 2.0 * i as f64, 0.0))
            .collect();
        assert!(umeyama(&line, &line, None, false).is_none());
        assert!(umeyama(&points()[..2], &points()[..2], None, false).is_none());
    }
}
