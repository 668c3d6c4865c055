//! Plane-to-image homographies by the normalised direct linear transform
//! (Hartley's normalisation, then SVD).

use nalgebra::{DMatrix, Matrix3, Point2};

/// Translation and scale taking `points` to zero mean and mean distance sqrt(2).
fn normaliser(points: &[Point2<f64>]) -> Matrix3<f64> {
    let n = points.len() as f64;
    let (mx, my) = (
        points.iter().map(|p| p.x).sum::<f64>() / n,
        points.iter().map(|p| p.y).sum::<f64>() / n,
    );
    let mean_dist = points
        .iter()
        .map(|p| ((p.x - mx).powi(2) + (p.y - my).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if mean_dist > 0.0 {
        2f64.sqrt() / mean_dist
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// The homography H with `image ~ H * plane` from at least 4 correspondences
/// (no three collinear), or `None` when they are degenerate.
pub fn homography(plane: &[Point2<f64>], image: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    if plane.len() < 4 || plane.len() != image.len() {
        return None;
    }
    let (tp, ti) = (normaliser(plane), normaliser(image));
    let mut a = DMatrix::<f64>::zeros(2 * plane.len().max(5), 9);
    for (k, (p, q)) in plane.iter().zip(image).enumerate() {
        let p = tp * p.to_homogeneous();
        let q = ti * q.to_homogeneous();
        let (x, y, u, v) = (p.x / p.z, p.y / p.z, q.x / q.z, q.y / q.z);
        let r = 2 * k;
        a.row_mut(r)
            .copy_from_slice(&[-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u]);
        a.row_mut(r + 1)
            .copy_from_slice(&[0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v]);
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let (i, _) = svd.singular_values.argmin();
    // The null vector must be the only one: a second small singular value means
    // the points do not pin a homography (collinear points).
    let mut sorted: Vec<f64> = svd.singular_values.iter().copied().collect();
    sorted.sort_by(f64::total_cmp);
    if sorted[1] < 1e-9 * sorted[8].max(1e-300) {
        return None;
    }
    let h = v_t.row(i);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let h = ti.try_inverse()? * hn * tp;
    (h[(2, 2)].abs() > 1e-300).then(|| h / h[(2, 2)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_an_exact_homography() {
        let h = Matrix3::new(1.2, 0.1, 300.0, -0.05, 0.9, 200.0, 1e-4, -2e-4, 1.0);
        let plane: Vec<Point2<f64>> = (0..5)
            .flat_map(|i| (0..4).map(move |j| Point2::new(i as f64 * 25.0, j as f64 * 25.0)))
            .collect();
        let image: Vec<Point2<f64>> = plane
            .iter()
            .map(|p| Point2::from_homogeneous(h * p.to_homogeneous()).unwrap())
            .collect();
        let got = homography(&plane, &image).unwrap();
        assert!((got - h).norm() < 1e-9 * h.norm(), "{got}");
        // Four points suffice.
        let got4 = homography(
            &plane[..4].iter().step_by(1).cloned().collect::<Vec<_>>(),
            &image[..4],
        )
        .is_none();
        assert!(
            got4,
            "the first four are collinear (one column of the grid)"
        );
        let corners = [plane[0], plane[3], plane[16], plane[19]];
        let img = [image[0], image[3], image[16], image[19]];
        assert!((homography(&corners, &img).unwrap() - h).norm() < 1e-9 * h.norm());
    }
}
