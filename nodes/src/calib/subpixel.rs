//! Sub-pixel refinement of chessboard corners by gradient orthogonality (the
//! method of OpenCV's cornerSubPix): at the true corner q, the image gradient at
//! every nearby pixel p is orthogonal to p - q (p lies on an edge through q, where
//! the gradient is across the edge, or in a flat square, where it is zero). So q
//! solves the least-squares system sum(g g^T) q = sum(g g^T p), iterated as the
//! window re-centres.

/// The refinement half-window (px) for squares `square_px` pixels across: large
/// enough to hold the corner's edges, small enough to stay inside the four
/// squares around it on tilted views (a window reaching the next corner or the
/// board's border biases the result; see ../shared/CRATES.md).
pub fn window_for_square(square_px: f64) -> usize {
    (0.3 * square_px).round().clamp(2.0, 7.0) as usize
}

/// Refines the corner near `guess` (x, y px; integer = pixel centre) in a grey
/// image (`width x height`, row-major). Returns `None` when the window leaves the
/// image, the gradients do not pin a point (a flat area or a single edge), or
/// the estimate wanders more than a window away from the guess.
pub fn refine_corner(
    grey: &[f32],
    width: usize,
    height: usize,
    guess: (f64, f64),
    half_window: usize,
) -> Option<(f64, f64)> {
    let h = half_window as isize;
    let sigma2 = (h as f64 * 0.6).powi(2).max(1.0);
    let at = |x: isize, y: isize| grey[y as usize * width + x as usize] as f64;
    let (mut qx, mut qy) = guess;
    for _ in 0..40 {
        let (cx, cy) = (qx.round() as isize, qy.round() as isize);
        if cx - h - 1 < 0
            || cy - h - 1 < 0
            || cx + h + 1 >= width as isize
            || cy + h + 1 >= height as isize
        {
            return None;
        }
        let (mut a, mut b, mut c, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
        // The Gaussian weight is separable: one exp per row and per column.
        let weight = |d: f64| (-(d * d) / (2.0 * sigma2)).exp();
        let wx: Vec<f64> = (cx - h..=cx + h).map(|x| weight(x as f64 - qx)).collect();
        for y in cy - h..=cy + h {
            let dy = y as f64 - qy;
            let wy = weight(dy);
            for (x, &wxx) in (cx - h..=cx + h).zip(&wx) {
                let gx = 0.5 * (at(x + 1, y) - at(x - 1, y));
                let gy = 0.5 * (at(x, y + 1) - at(x, y - 1));
                let dx = x as f64 - qx;
                let w = wxx * wy;
                let (gxx, gxy, gyy) = (w * gx * gx, w * gx * gy, w * gy * gy);
                a += gxx;
                b += gxy;
                c += gyy;
                bx += gxx * dx + gxy * dy;
                by += gxy * dx + gyy * dy;
            }
        }
        let det = a * c - b * b;
        // Both gradient directions must be present (a corner, not an edge).
        if det <= 1e-9 * (a + c).powi(2).max(1e-30) || !det.is_finite() {
            return None;
        }
        let (sx, sy) = ((c * bx - b * by) / det, (a * by - b * bx) / det);
        (qx, qy) = (qx + sx, qy + sy);
        if ((qx - guess.0).powi(2) + (qy - guess.1).powi(2)).sqrt() > h as f64 {
            return None;
        }
        if (sx * sx + sy * sy).sqrt() < 1e-5 {
            break;
        }
    }
    Some((qx, qy))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An anti-aliased corner of a chessboard at (x0, y0), rotated by `angle`,
    /// rendered with 32 x 32 samples per pixel (edge quantisation 1/64 px) and
    /// blurred like a lens (sigma 0.7 px).
    fn corner_image(x0: f64, y0: f64, angle: f64) -> Vec<f32> {
        let (w, h) = (40, 40);
        let (s, c) = angle.sin_cos();
        let mut img = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for sy in 0..32 {
                    for sx in 0..32 {
                        let px = x as f64 + (sx as f64 + 0.5) / 32.0 - 0.5 - x0;
                        let py = y as f64 + (sy as f64 + 0.5) / 32.0 - 0.5 - y0;
                        let (u, v) = (c * px + s * py, -s * px + c * py);
                        acc += if (u > 0.0) == (v > 0.0) { 0.1 } else { 0.9 };
                    }
                }
                img[x + y * w] = (acc / 1024.0) as f32;
            }
        }
        // Lens blur: real images are never box-sharp, and the method assumes a
        // symmetric point spread.
        crate::calib::detect::gaussian(&img, w, h, 0.7)
    }

    #[test]
    fn finds_a_known_sub_pixel_corner() {
        // The gradient method leans towards the far pixel of an edge by a few
        // hundredths of a pixel, depending on the sub-pixel phase: 0.03 px per
        // axis at phase 0.3, where OpenCV's cornerSubPix (5 x 5 window) gives
        // 0.044 px on the same image. (Corners sit on multiples of 1/64 px where
        // the 32 x 32 supersampling puts the edges exactly.)
        for (x0, y0, angle) in [
            (20.3125, 19.6875, 0.0),
            (18.71, 21.18, 0.4),
            (20.05, 20.5, -0.9),
            (20.0, 20.0, 0.2),
        ] {
            let img = corner_image(x0, y0, angle);
            let (x, y) =
                refine_corner(&img, 40, 40, (x0.round() + 1.0, y0.round() - 1.0), 5).unwrap();
            let err = ((x - x0).powi(2) + (y - y0).powi(2)).sqrt();
            assert!(err < 0.05, "({x}, {y}) vs ({x0}, {y0}): {err} px");
        }
        // On a pixel centre the pairs are symmetric and the answer is exact.
        let img = corner_image(20.0, 20.0, 0.0);
        let (x, y) = refine_corner(&img, 40, 40, (21.0, 19.0), 5).unwrap();
        assert!(
            (x - 20.0).abs() < 2e-3 && (y - 20.0).abs() < 2e-3,
            "({x}, {y})"
        );
    }

    #[test]
    fn refuses_flat_areas_edges_and_borders() {
        let flat = vec![0.5f32; 40 * 40];
        assert!(refine_corner(&flat, 40, 40, (20.0, 20.0), 4).is_none());
        let edge: Vec<f32> = (0..1600)
            .map(|i| if i % 40 < 20 { 0.1 } else { 0.9 })
            .collect();
        assert!(refine_corner(&edge, 40, 40, (20.0, 20.0), 4).is_none());
        let img = corner_image(20.0, 20.0, 0.0);
        assert!(refine_corner(&img, 40, 40, (2.0, 20.0), 4).is_none());
    }

    #[test]
    fn window_follows_square_size() {
        assert_eq!(window_for_square(10.0), 3);
        assert_eq!(window_for_square(67.0), 7);
        assert_eq!(window_for_square(4.0), 2);
    }
}
