//! Triangulation of rectified correspondences: a left rectified pixel and its
//! disparity -> a 3D point in mm in the original (unrectified) left camera frame.
//!
//! Through Q, `(x, y, d, 1)` maps to homogeneous coordinates in the left
//! *rectified* frame, whose origin is the left camera centre; undoing the
//! rectifying rotation R1 gives the left camera frame `camera_left`.

use crate::calib::StereoRectification;
use nalgebra::{Point3, Vector4};
use rayon::prelude::*;

/// The point seen at left rectified pixel (`x_px`, `y_px`) with disparity
/// `d_px` (`x_left - x_right`), in mm in the original left camera frame; `None`
/// when the disparity puts it at or behind infinity (d of the wrong sign or 0)
/// or the inputs are not finite.
pub fn point_from_disparity(
    rect: &StereoRectification,
    x_px: f64,
    y_px: f64,
    d_px: f64,
) -> Option<Point3<f64>> {
    let h = rect.q * Vector4::new(x_px, y_px, d_px, 1.0);
    if !(h.w.is_finite() && h.w.abs() > 1e-12) {
        return None;
    }
    let rectified = Point3::new(h.x / h.w, h.y / h.w, h.z / h.w);
    if rectified.z.is_nan() || rectified.z <= 0.0 || !rectified.coords.iter().all(|c| c.is_finite())
    {
        return None;
    }
    Some(Point3::from(rect.r1.transpose() * rectified.coords))
}

/// The points (mm, original left camera frame) of every valid disparity whose
/// depth lies in `min_depth_mm..=max_depth_mm`, with the pixel each came from;
/// `disparity` is a map on the left rectified image, `width` px wide, px
/// (NaN = invalid).
pub fn triangulate_disparity(
    disparity: &[f32],
    width: usize,
    rect: &StereoRectification,
    min_depth_mm: f64,
    max_depth_mm: f64,
) -> Vec<(usize, Point3<f64>)> {
    disparity
        .par_iter()
        .enumerate()
        .filter_map(|(i, &d)| {
            if d.is_nan() {
                return None;
            }
            let p = point_from_disparity(rect, (i % width) as f64, (i / width) as f64, d as f64)?;
            (min_depth_mm..=max_depth_mm)
                .contains(&p.z)
                .then_some((i, p))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::rectify;

    #[test]
    fn inverts_a_projection_to_1e_9() {
        let crate::phantom::Rig {
            left,
            right,
            left_to_right: rig,
        } = crate::phantom::Rig::misaligned_paper_rig();
        let rect = rectify(&left, &right, &rig, 0.0);
        for x in [-90.0, 0.0, 70.0] {
            for y in [-60.0, 15.0, 45.0] {
                for z in [400.0, 550.0, 700.0] {
                    let p = Point3::new(x, y, z);
                    // Project into both rectified images directly.
                    let project = |r: &nalgebra::Matrix3<f64>,
                                   proj: &nalgebra::Matrix3x4<f64>,
                                   q: &Point3<f64>| {
                        let h = proj * (r * q.coords).push(1.0);
                        (h.x / h.z, h.y / h.z)
                    };
                    let (xl, yl) = project(&rect.r1, &rect.p1, &p);
                    // The right camera sees the point in its own frame; its
                    // rectified frame differs from the left's by the baseline.
                    let pr = rig * p;
                    let hr = rect.p2.fixed_view::<3, 3>(0, 0) * (rect.r2 * pr.coords);
                    let (xr, yr) = (hr.x / hr.z, hr.y / hr.z);
                    assert!((yl - yr).abs() < 1e-9, "rows {yl} {yr}");
                    let back = point_from_disparity(&rect, xl, yl, xl - xr).unwrap();
                    assert!((back - p).norm() < 1e-9 * z, "{back} vs {p}");
                }
            }
        }
        assert!(point_from_disparity(&rect, 100.0, 100.0, 0.0).is_none());
        assert!(point_from_disparity(&rect, 100.0, 100.0, -5.0).is_none());
        assert!(point_from_disparity(&rect, 100.0, 100.0, f64::NAN).is_none());
    }
}
