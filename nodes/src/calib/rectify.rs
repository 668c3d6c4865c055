//! Bouguet's stereo rectification (as OpenCV's stereoRectify with zero
//! disparity at infinity): rotate each camera half-way towards the other, then
//! both so the baseline is the x axis; one pinhole for both rectified images,
//! scaled by `alpha` between "only valid pixels" (0) and "every source pixel"
//! (1). And remapping an image through it, with bilinear interpolation.

use crate::camera::CameraModel;
use crate::numeric::{floor_usize, round_to_u8};
use nalgebra::{Isometry3, Matrix3, Matrix3x4, Matrix4, Point2, Rotation3, Vector3};
use rayon::prelude::*;

/// Rectifying rotations and projections.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoRectification {
    /// Output image size, px.
    pub size: (usize, usize),
    /// Left camera frame -> left rectified frame.
    pub r1: Matrix3<f64>,
    /// Right camera frame -> right rectified frame.
    pub r2: Matrix3<f64>,
    /// Left rectified projection.
    pub p1: Matrix3x4<f64>,
    /// Right rectified projection (`P2[0][3]` = f Tx).
    pub p2: Matrix3x4<f64>,
    /// Disparity-to-depth matrix.
    pub q: Matrix4<f64>,
}

/// Rectifies the rig `left_to_right` (X_right = R X_left + T).
pub fn rectify(
    left: &CameraModel,
    right: &CameraModel,
    left_to_right: &Isometry3<f64>,
    alpha: f64,
) -> StereoRectification {
    let om = left_to_right.rotation.scaled_axis();
    let r_r = Rotation3::new(-om * 0.5);
    let r_l = r_r.inverse();
    let t = r_r * left_to_right.translation.vector;
    // Turn the baseline onto the x axis.
    let target = Vector3::new(t.x.signum(), 0.0, 0.0);
    let axis = t.cross(&target);
    let angle = (t.x.abs() / t.norm()).clamp(-1.0, 1.0).acos();
    let wr = if axis.norm() > 1e-15 {
        Rotation3::new(axis.normalize() * angle)
    } else {
        Rotation3::identity()
    };
    let r1 = (wr * r_l).into_inner();
    let r2 = (wr * r_r).into_inner();
    let tx = (wr * t).x;
    let (w, h) = (left.width, left.height);
    // Rectified normalised coordinates of points along each image's border.
    let border = |camera: &CameraModel, r: &Matrix3<f64>| -> Vec<Point2<f64>> {
        let n = 16;
        let (cw, ch) = (camera.width as f64 - 1.0, camera.height as f64 - 1.0);
        let mut pts = Vec::new();
        for i in 0..=n {
            let s = i as f64 / n as f64;
            for (u, v) in [(s * cw, 0.0), (s * cw, ch), (0.0, s * ch), (cw, s * ch)] {
                let ray = camera.pixel_ray(u, v);
                let q = r * ray;
                pts.push(Point2::new(q.x / q.z, q.y / q.z));
            }
        }
        pts
    };
    let sides = [border(left, &r1), border(right, &r2)];
    let f0 = left.fy.min(right.fy);
    // Inner box (valid in both images) and outer box (everything), normalised.
    let inner_outer = |pts: &[Point2<f64>]| {
        let xs_left = pts
            .iter()
            .skip(2)
            .step_by(4)
            .map(|p| p.x)
            .fold(f64::MIN, f64::max);
        let xs_right = pts
            .iter()
            .skip(3)
            .step_by(4)
            .map(|p| p.x)
            .fold(f64::MAX, f64::min);
        let ys_top = pts.iter().step_by(4).map(|p| p.y).fold(f64::MIN, f64::max);
        let ys_bottom = pts
            .iter()
            .skip(1)
            .step_by(4)
            .map(|p| p.y)
            .fold(f64::MAX, f64::min);
        let outer = pts
            .iter()
            .fold((f64::MAX, f64::MAX, f64::MIN, f64::MIN), |b, p| {
                (b.0.min(p.x), b.1.min(p.y), b.2.max(p.x), b.3.max(p.y))
            });
        ((xs_left, ys_top, xs_right, ys_bottom), outer)
    };
    let (i0, o0) = inner_outer(&sides[0]);
    let (i1, o1) = inner_outer(&sides[1]);
    let inner = (
        i0.0.max(i1.0),
        i0.1.max(i1.1),
        i0.2.min(i1.2),
        i0.3.min(i1.3),
    );
    let outer = (
        o0.0.min(o1.0),
        o0.1.min(o1.1),
        o0.2.max(o1.2),
        o0.3.max(o1.3),
    );
    let (wf, hf) = (w as f64 - 1.0, h as f64 - 1.0);
    // alpha 0: the inner box fills the image; alpha 1: the outer box fits in it.
    let s0 = (wf / ((inner.2 - inner.0) * f0)).max(hf / ((inner.3 - inner.1) * f0));
    let s1 = (wf / ((outer.2 - outer.0) * f0)).min(hf / ((outer.3 - outer.1) * f0));
    let a = alpha.clamp(0.0, 1.0);
    let f = f0 * (s0 + a * (s1 - s0));
    let centre_of = |b: (f64, f64, f64, f64)| ((b.0 + b.2) * 0.5, (b.1 + b.3) * 0.5);
    let (ci, co) = (centre_of(inner), centre_of(outer));
    let (mx, my) = (ci.0 + a * (co.0 - ci.0), ci.1 + a * (co.1 - ci.1));
    let (cx, cy) = (wf * 0.5 - f * mx, hf * 0.5 - f * my);
    let p1 = Matrix3x4::new(f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0);
    let p2 = Matrix3x4::new(f, 0.0, cx, f * tx, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0);
    let q = Matrix4::new(
        1.0,
        0.0,
        0.0,
        -cx,
        0.0,
        1.0,
        0.0,
        -cy,
        0.0,
        0.0,
        0.0,
        f,
        0.0,
        0.0,
        -1.0 / tx,
        0.0,
    );
    StereoRectification {
        size: (w, h),
        r1,
        r2,
        p1,
        p2,
        q,
    }
}

impl StereoRectification {
    /// Where pixel `p` of the original image of camera `camera` (rotated by
    /// `r` = r1 or r2, projected by `p` = p1 or p2) lands in the rectified image.
    pub fn rectify_point(
        camera: &CameraModel,
        r: &Matrix3<f64>,
        proj: &Matrix3x4<f64>,
        p: &Point2<f64>,
    ) -> Point2<f64> {
        let q = r * camera.pixel_ray(p.x, p.y);
        let h = proj.fixed_view::<3, 3>(0, 0) * (q / q.z);
        Point2::new(h.x / h.z, h.y / h.z)
    }
}

/// Resamples a grey or RGB image (`channels` interleaved, u8) of `camera` into
/// the rectified view given by rotation `r` and projection `proj`; pixels that
/// fall outside the source are black.
pub fn remap(
    src: &[u8],
    channels: usize,
    camera: &CameraModel,
    r: &Matrix3<f64>,
    proj: &Matrix3x4<f64>,
    size: (usize, usize),
) -> Vec<u8> {
    let (w, h) = size;
    let (sw, sh) = (camera.width, camera.height);
    let (f, cx, cy) = (proj[(0, 0)], proj[(0, 2)], proj[(1, 2)]);
    let back = r.transpose();
    let mut out = vec![0u8; w * h * channels];
    out.par_chunks_mut(w * channels)
        .enumerate()
        .for_each(|(v, row)| {
            for u in 0..w {
                let ray = back * Vector3::new((u as f64 - cx) / f, (v as f64 - cy) / f, 1.0);
                let Some(p) = camera.project(&nalgebra::Point3::from(ray)) else {
                    continue;
                };
                if p.x < 0.0 || p.y < 0.0 || p.x > (sw - 1) as f64 || p.y > (sh - 1) as f64 {
                    continue;
                }
                let (x0, y0) = (floor_usize(p.x), floor_usize(p.y));
                let (x1, y1) = ((x0 + 1).min(sw - 1), (y0 + 1).min(sh - 1));
                let (tx, ty) = (p.x - x0 as f64, p.y - y0 as f64);
                for c in 0..channels {
                    let s = |x: usize, y: usize| src[(y * sw + x) * channels + c] as f64;
                    let v = (s(x0, y0) * (1.0 - tx) + s(x1, y0) * tx) * (1.0 - ty)
                        + (s(x0, y1) * (1.0 - tx) + s(x1, y1) * tx) * ty;
                    row[u * channels + c] = round_to_u8(v);
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn corresponding_points_share_a_row_after_rectification() {
        let crate::phantom::Rig {
            left,
            right,
            left_to_right: rig,
        } = crate::phantom::Rig::misaligned_paper_rig();
        for alpha in [0.0, 0.5, 1.0] {
            let rect = rectify(&left, &right, &rig, alpha);
            let mut worst: f64 = 0.0;
            for x in [-80.0, 0.0, 60.0] {
                for y in [-50.0, 10.0, 40.0] {
                    for z in [420.0, 550.0, 700.0] {
                        let pl = left.project(&Point3::new(x, y, z)).unwrap();
                        let pr = right.project(&(rig * Point3::new(x, y, z))).unwrap();
                        let a = StereoRectification::rectify_point(&left, &rect.r1, &rect.p1, &pl);
                        let b = StereoRectification::rectify_point(&right, &rect.r2, &rect.p2, &pr);
                        worst = worst.max((a.y - b.y).abs());
                        // Depth from disparity through Q.
                        let d = a.x - b.x;
                        let h = rect.q * nalgebra::Vector4::new(a.x, a.y, d, 1.0);
                        let depth = h.z / h.w;
                        let in_rect = rect.r1 * Vector3::new(x, y, z);
                        assert!(
                            (depth - in_rect.z).abs() < 1e-6 * z,
                            "depth {depth} vs {}",
                            in_rect.z
                        );
                    }
                }
            }
            assert!(worst < 1e-6, "alpha {alpha}: rows differ by {worst} px");
        }
    }
}
