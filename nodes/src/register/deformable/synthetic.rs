//! A synthetic breast for the deformable fit's tests and `fusegraph bench
//! deformable`: a dome on a table (mm, z up from the table), a sag of known
//! size, markers on its skin and points inside it.

use nalgebra::{Point3, Vector3};

/// A dome: a sphere of radius 70 mm cut 25 mm below its centre (apex 95
/// mm above the table z = 0), its skin sampled about every `step_mm`,
/// with outward normals.
pub fn dome(step_mm: f64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let (r, c) = (70.0, Point3::new(0.0, 0.0, 25.0));
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let max_polar = (-25.0f64 / r).acos();
    let rings = (max_polar * r / step_mm).ceil() as usize;
    for i in 0..=rings {
        let polar = max_polar * i as f64 / rings as f64;
        let around = ((2.0 * std::f64::consts::PI * r * polar.sin()) / step_mm)
            .ceil()
            .max(1.0) as usize;
        for k in 0..around {
            let az = 2.0 * std::f64::consts::PI * k as f64 / around as f64;
            let n = Vector3::new(polar.sin() * az.cos(), polar.sin() * az.sin(), polar.cos());
            points.push(c + n * r);
            normals.push(n);
        }
    }
    (points, normals)
}

/// [`dome`] with its flat base: a disc on the table z = 0 sampled every
/// `step_mm`, its normals down.
pub fn dome_with_base(step_mm: f64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
    let (mut points, mut normals) = dome(step_mm);
    let n = (64.0 / step_mm).ceil() as i64;
    for i in -n..=n {
        for j in -n..=n {
            let p = Point3::new(step_mm * i as f64, step_mm * j as f64, 0.0);
            if p.coords.xy().norm() < 64.0 {
                points.push(p);
                normals.push(-Vector3::z());
            }
        }
    }
    (points, normals)
}

/// A sag of `peak_mm` at the apex: down and sideways (+x), growing with
/// height as a smoothstep (none on the table).
pub fn sag(p: &Point3<f64>, peak_mm: f64) -> Vector3<f64> {
    let t = (p.z / 95.0).clamp(0.0, 1.0);
    let w = t * t * (3.0 - 2.0 * t);
    Vector3::new(1.0, 0.0, -1.0).normalize() * (peak_mm * w)
}

/// The dome's skin area above height `z_mm` (0 to 95), mm^2: a spherical
/// cap's, 2 pi r h.
pub fn skin_area_above(z_mm: f64) -> f64 {
    2.0 * std::f64::consts::PI * 70.0 * (95.0 - z_mm.clamp(0.0, 95.0))
}

/// Points inside the dome, 15-40 mm under its skin.
pub fn interior() -> Vec<Point3<f64>> {
    let mut points = Vec::new();
    for &(x, y, z) in &[
        (0.0, 0.0, 55.0),
        (20.0, -10.0, 50.0),
        (-25.0, 15.0, 45.0),
        (10.0, 30.0, 40.0),
        (-15.0, -20.0, 60.0),
    ] {
        points.push(Point3::new(x, y, z));
    }
    points
}

/// Twelve markers on the upper skin: the points of `points` nearest 12
/// places on the dome, six at 0.5 rad from the apex and six at 0.9 (none
/// if `points` is empty).
pub fn markers(points: &[Point3<f64>]) -> Vec<Point3<f64>> {
    (0..12)
        .filter_map(|k| {
            let az = 2.0 * std::f64::consts::PI * k as f64 / 12.0;
            let polar: f64 = if k % 2 == 0 { 0.5 } else { 0.9 };
            let target = Point3::new(0.0, 0.0, 25.0)
                + Vector3::new(polar.sin() * az.cos(), polar.sin() * az.sin(), polar.cos()) * 70.0;
            points
                .iter()
                .min_by(|a, b| (*a - target).norm().total_cmp(&(*b - target).norm()))
                .copied()
        })
        .collect()
}
