//! Zhang's closed-form calibration ("A flexible new technique for camera
//! calibration", 2000): intrinsics from the homographies of three or more views
//! of a plane, then each view's pose. Distortion is left to the refinement.

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector3};

fn v(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (hi, hj) = (h.column(i), h.column(j));
    [
        hi[0] * hj[0],
        hi[0] * hj[1] + hi[1] * hj[0],
        hi[1] * hj[1],
        hi[2] * hj[0] + hi[0] * hj[2],
        hi[2] * hj[1] + hi[1] * hj[2],
        hi[2] * hj[2],
    ]
}

/// The intrinsic matrix (zero skew) from plane homographies, or `None` when the
/// views are degenerate (fewer than 3, or all parallel planes).
pub fn intrinsics_from_homographies(homographies: &[Matrix3<f64>]) -> Option<Matrix3<f64>> {
    if homographies.len() < 3 {
        return None;
    }
    // Each view: v12 b = 0 and (v11 - v22) b = 0; plus zero skew: b12 = 0.
    let mut a = DMatrix::<f64>::zeros(2 * homographies.len() + 1, 6);
    for (k, h) in homographies.iter().enumerate() {
        let h = h / h.norm();
        let (v12, v11, v22) = (v(&h, 0, 1), v(&h, 0, 0), v(&h, 1, 1));
        for c in 0..6 {
            a[(2 * k, c)] = v12[c];
            a[(2 * k + 1, c)] = v11[c] - v22[c];
        }
    }
    a[(2 * homographies.len(), 1)] = 1.0;
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let (i, _) = svd.singular_values.argmin();
    let mut b: Vec<f64> = v_t.row(i).iter().copied().collect();
    if b[0] < 0.0 {
        b.iter_mut().for_each(|x| *x = -*x);
    }
    let [b11, b12, b22, b13, b23, b33] = [b[0], b[1], b[2], b[3], b[4], b[5]];
    let d = b11 * b22 - b12 * b12;
    if d <= 0.0 || b11 <= 0.0 {
        return None;
    }
    let cy = (b12 * b13 - b11 * b23) / d;
    let lambda = b33 - (b13 * b13 + cy * (b12 * b13 - b11 * b23)) / b11;
    if lambda / b11 <= 0.0 {
        return None;
    }
    let fx = (lambda / b11).sqrt();
    let fy = (lambda * b11 / d).sqrt();
    let skew = -b12 * fx * fx * fy / lambda;
    let cx = skew * cy / fy - b13 * fx * fx / lambda;
    let k = Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0);
    k.iter().all(|x| x.is_finite()).then_some(k)
}

/// The pose (plane -> camera rotation and translation, mm) of a view with
/// homography `h` for intrinsics `k`; the rotation is the nearest true rotation.
pub fn pose_from_homography(
    k: &Matrix3<f64>,
    h: &Matrix3<f64>,
) -> Option<(Rotation3<f64>, Vector3<f64>)> {
    let k_inv = k.try_inverse()?;
    let m = k_inv * h;
    let scale = 1.0 / m.column(0).norm();
    // The plane must be in front of the camera (t_z > 0).
    let sign = if m[(2, 2)] * scale < 0.0 { -1.0 } else { 1.0 };
    let (r1, r2, t) = (
        m.column(0) * scale * sign,
        m.column(1) * scale * sign,
        m.column(2) * scale * sign,
    );
    let r = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    // Bounded iterations: a degenerate homography must not hang.
    let r = Rotation3::from_matrix_eps(&r, 1e-15, 100, Rotation3::identity());
    (r.matrix().iter().all(|x| x.is_finite()) && t.iter().all(|x| x.is_finite())).then_some((r, t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::homography::homography;
    use nalgebra::{Point2, Point3};

    #[test]
    fn recovers_k_exactly_from_exact_views() {
        let k = Matrix3::new(1333.3, 0.0, 403.2, 0.0, 1334.4, 297.6, 0.0, 0.0, 1.0);
        let plane: Vec<Point2<f64>> = (0..9)
            .flat_map(|i| (0..6).map(move |j| Point2::new(i as f64 * 25.0, j as f64 * 25.0)))
            .collect();
        let poses = [
            (
                Vector3::new(0.3, -0.2, 0.1),
                Vector3::new(-100.0, -60.0, 520.0),
            ),
            (
                Vector3::new(-0.25, 0.35, -0.2),
                Vector3::new(-90.0, -80.0, 600.0),
            ),
            (
                Vector3::new(0.1, 0.4, 0.3),
                Vector3::new(-120.0, -50.0, 480.0),
            ),
            (
                Vector3::new(-0.4, -0.1, 0.0),
                Vector3::new(-80.0, -70.0, 650.0),
            ),
        ];
        let homographies: Vec<Matrix3<f64>> = poses
            .iter()
            .map(|(rv, t)| {
                let r = Rotation3::new(*rv);
                let image: Vec<Point2<f64>> = plane
                    .iter()
                    .map(|p| {
                        let c = r * Point3::new(p.x, p.y, 0.0) + t;
                        Point2::from_homogeneous(k * c.coords).unwrap()
                    })
                    .collect();
                homography(&plane, &image).unwrap()
            })
            .collect();
        let got = intrinsics_from_homographies(&homographies).unwrap();
        assert!((got - k).abs().max() < 1e-6 * k.norm(), "{got}");
        let (r, t) = pose_from_homography(&got, &homographies[1]).unwrap();
        assert!((r.scaled_axis() - poses[1].0).norm() < 1e-8);
        assert!((t - poses[1].1).norm() < 1e-6);
        assert!(intrinsics_from_homographies(&homographies[..2]).is_none());
    }
}
