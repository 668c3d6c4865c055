//! The pinhole camera with Brown-Conrady distortion, exactly as OpenCV defines it
//! (k1, k2, p1, p2, k3), so parameters can be exchanged with OpenCV unchanged.
//!
//! Frames: camera coordinates in mm, x right, y down, z forward (optical axis).
//! Pixel coordinates in px with integer values at pixel centres (OpenCV).

use fusegraph_engine::value::Camera;
use nalgebra::{Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Intrinsics and distortion of one camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    /// Image width, px.
    pub width: usize,
    /// Image height, px.
    pub height: usize,
    /// Focal length along x, px.
    pub fx: f64,
    /// Focal length along y, px.
    pub fy: f64,
    /// Principal point x, px.
    pub cx: f64,
    /// Principal point y, px.
    pub cy: f64,
    /// k1, k2, p1, p2, k3 (OpenCV order).
    pub distortion: [f64; 5],
}

impl CameraModel {
    /// The model of an engine [`Camera`] value (zero skew).
    pub fn from_value(c: &Camera) -> Self {
        CameraModel {
            width: c.width,
            height: c.height,
            fx: c.k[0][0],
            fy: c.k[1][1],
            cx: c.k[0][2],
            cy: c.k[1][2],
            distortion: c.distortion,
        }
    }

    /// The engine [`Camera`] value of this model.
    pub fn to_value(&self) -> Camera {
        Camera {
            width: self.width,
            height: self.height,
            k: [
                [self.fx, 0.0, self.cx],
                [0.0, self.fy, self.cy],
                [0.0, 0.0, 1.0],
            ],
            distortion: self.distortion,
        }
    }

    /// Applies the lens distortion to ideal normalised coordinates (x/z, y/z).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// The pixel where a point in camera coordinates (mm) appears, or `None`
    /// when it is not in front of the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if p.z <= 0.0 {
            return None;
        }
        let (xd, yd) = self.distort(p.x / p.z, p.y / p.z);
        Some(Point2::new(self.fx * xd + self.cx, self.fy * yd + self.cy))
    }

    /// Ideal normalised coordinates (x/z, y/z) of a pixel: inverts the distortion
    /// by Newton's method with the analytic Jacobian (converges to ~1e-15 in a few
    /// steps for lenses of this kind; stops after 30).
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let (xd, yd) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() < 1e-15 && ey.abs() < 1e-15 {
                break;
            }
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let d_radial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
            let a = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x;
            let b = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y;
            let d = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x;
            let det = a * d - b * b;
            if det.abs() < 1e-12 {
                break;
            }
            x -= (d * ex - b * ey) / det;
            y -= (a * ey - b * ex) / det;
        }
        (x, y)
    }

    /// The unit direction (camera frame) of the ray through pixel (u, v).
    pub fn pixel_ray(&self, u: f64, v: f64) -> Vector3<f64> {
        let (x, y) = self.undistort(u, v);
        Vector3::new(x, y, 1.0).normalize()
    }

    /// Whether pixel (u, v) lies at least `margin_px` inside the image.
    pub fn contains(&self, p: &Point2<f64>, margin_px: f64) -> bool {
        p.x >= margin_px - 0.5
            && p.y >= margin_px - 0.5
            && p.x <= self.width as f64 - 0.5 - margin_px
            && p.y <= self.height as f64 - 0.5 - margin_px
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> CameraModel {
        CameraModel {
            width: 800,
            height: 600,
            fx: 1333.3,
            fy: 1334.1,
            cx: 403.2,
            cy: 297.6,
            distortion: [-0.12, 0.15, 0.0006, -0.0004, 0.01],
        }
    }

    #[test]
    fn distortion_matches_the_opencv_formula_by_hand() {
        let c = camera();
        let (x, y) = (0.2, -0.1);
        let r2: f64 = 0.05;
        let radial = 1.0 - 0.12 * r2 + 0.15 * r2 * r2 + 0.01 * r2 * r2 * r2;
        let xd = x * radial + 2.0 * 0.0006 * x * y + -0.0004 * (r2 + 2.0 * x * x);
        let yd = y * radial + 0.0006 * (r2 + 2.0 * y * y) + 2.0 * -0.0004 * x * y;
        let (dx, dy) = c.distort(x, y);
        assert!((dx - xd).abs() < 1e-15 && (dy - yd).abs() < 1e-15);
    }

    #[test]
    fn undistort_inverts_distort_over_the_whole_image() {
        let c = camera();
        for v in (0..600).step_by(37) {
            for u in (0..800).step_by(41) {
                let (x, y) = c.undistort(u as f64, v as f64);
                let p = c
                    .project(&Point3::new(x * 500.0, y * 500.0, 500.0))
                    .unwrap();
                assert!(
                    (p.x - u as f64).abs() < 1e-9 && (p.y - v as f64).abs() < 1e-9,
                    "{u},{v}: {p}"
                );
            }
        }
    }

    #[test]
    fn camera_value_round_trips() {
        let c = camera();
        assert_eq!(CameraModel::from_value(&c.to_value()), c);
        assert!(c.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }
}
