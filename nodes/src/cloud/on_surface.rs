//! Whether a marker found in a stereo view sits on the reconstructed skin
//! around it, seen whole: green things on the table (a sticker, a cup) lie off
//! the skin, and a marker partly hidden by a tool between it and the camera is
//! measured on what is left of its face, a few mm off. Both are refused here,
//! from the view's own cloud, before any of them joins a registration.
//!
//! The test, per marker (camera at the origin):
//! 1. The skin patch: cloud points within `support_radius_mm` of the marker,
//!    and the plane most of them lie on (RANSAC, [`dominant_plane`]). Skin
//!    must surround the marker on `min_sides` of 8 sides of that plane, and
//!    the marker must lie within `max_off_surface_mm` of it.
//! 2. Nothing in front: no more than `min_hidden_fraction` of the points in
//!    the marker's line of sight (within `occluder_radius_mm` of its ray, at
//!    its range) nearer the camera than the marker and the plane by more than
//!    `min_front_mm`. A tool the matcher could not reconstruct (untextured)
//!    leaves a hole here instead: the merge of the views drops the sighting it
//!    puts off (`register.multiview`).
//!
//! Written here: a few lines over nalgebra and our plane fit.

use super::{Plane, dominant_plane};
use fusegraph_engine::typed::declared_defaults;
use fusegraph_plugin_api::derive::Params;
use nalgebra::{Point3, Vector3};
use std::f64::consts::TAU;

/// What a marker must have around it (a parameter group, flattened into
/// `cloud.markers_on_surface`).
#[derive(Debug, Clone, Copy, PartialEq, Params)]
pub struct SurfaceTest {
    /// Radius of the skin patch around a marker (beyond the hole its face and walls leave in the cloud)
    #[param(default = 20.0, unit = "mm", min = 1e-3)]
    pub support_radius_mm: f64,
    /// Sides, of 8 around a marker, that must hold skin
    #[param(default = 5, min = 0, max = 8)]
    pub min_sides: usize,
    /// Largest distance of a marker from the skin patch's plane (its face stands its height above the skin)
    #[param(default = 10.0, unit = "mm", min = 0.0)]
    pub max_off_surface_mm: f64,
    /// Points this close to the patch's plane are skin
    #[param(default = 3.0, unit = "mm", min = 1e-3)]
    pub plane_tolerance_mm: f64,
    /// Radius about a marker's line of sight, at its range, in which something nearer the camera hides part of it
    #[param(default = 10.0, unit = "mm", min = 0.0)]
    pub occluder_radius_mm: f64,
    /// How far in front of the skin a point must be to hide a marker
    #[param(default = 8.0, unit = "mm", min = 0.0)]
    pub min_front_mm: f64,
    /// Above this fraction of the points in its line of sight in front of it, a marker is hidden (below, they are stereo's stray mismatches)
    #[param(default = 0.02, min = 0.0, max = 1.0)]
    pub min_hidden_fraction: f64,
}

impl Default for SurfaceTest {
    /// The declared defaults.
    fn default() -> Self {
        declared_defaults().expect("every parameter has a default")
    }
}

/// A side holds skin with at least this many points.
const POINTS_PER_SIDE: usize = 3;
/// RANSAC trials of the patch's plane (seeded: the same cloud, the same
/// verdicts).
const PLANE_TRIALS: usize = 100;

/// The verdict on one marker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OnSurface {
    /// On the skin, `off_mm` in front of its plane, nothing in front of it.
    Kept { off_mm: f64 },
    /// Skin on only `sides` of 8 sides (a thing on the table, or at the edge
    /// of what the view reconstructed).
    Unsupported { sides: usize },
    /// `off_mm` from the skin's plane (signed, + towards the camera).
    OffSurface { off_mm: f64 },
    /// `points` of the `of` in its line of sight in front of it, nearer than
    /// it and the skin by more than `min_front_mm`: partly hidden.
    Occluded { points: usize, of: usize },
}

impl OnSurface {
    /// Whether the marker stays.
    pub fn kept(&self) -> bool {
        matches!(self, OnSurface::Kept { .. })
    }

    /// Why a refused marker went, in words.
    pub fn reason(&self, test: &SurfaceTest) -> String {
        match *self {
            OnSurface::Kept { off_mm } => format!("on the skin ({off_mm:.1} mm above it)"),
            OnSurface::Unsupported { sides } => format!(
                "skin on {sides} of 8 sides within {} mm (needs {}): not on the skin \
                 (a green thing on the table?)",
                test.support_radius_mm, test.min_sides
            ),
            OnSurface::OffSurface { off_mm } => format!(
                "{off_mm:.1} mm off the skin around it (at most {} mm): not on the skin",
                test.max_off_surface_mm
            ),
            OnSurface::Occluded { points, of } => format!(
                "{points} of the {of} points in its line of sight are more than {} mm nearer \
                 the camera than it and the skin: partly hidden (by a tool?), so its centre \
                 would be off",
                test.min_front_mm
            ),
        }
    }
}

/// The verdict on each of `markers` against the skin cloud `skin` (both in
/// one camera frame, the camera at the origin, mm; the cloud without the
/// table: the markers' own faces and walls may be in it).
pub fn markers_on_surface(
    markers: &[Point3<f64>],
    skin: &[Point3<f64>],
    test: &SurfaceTest,
) -> Vec<OnSurface> {
    markers.iter().map(|m| verdict(m, skin, test)).collect()
}

fn verdict(marker: &Point3<f64>, skin: &[Point3<f64>], test: &SurfaceTest) -> OnSurface {
    let r2 = test.support_radius_mm.powi(2);
    let patch: Vec<Point3<f64>> = skin
        .iter()
        .filter(|p| (*p - marker).norm_squared() <= r2)
        .copied()
        .collect();
    let Some((plane, _)) = dominant_plane(&patch, test.plane_tolerance_mm, PLANE_TRIALS, 1) else {
        return OnSurface::Unsupported { sides: 0 };
    };
    // + towards the camera.
    let plane = if plane.distance(&Point3::origin()) < 0.0 {
        Plane {
            normal: -plane.normal,
            offset: -plane.offset,
        }
    } else {
        plane
    };
    let on_plane: Vec<&Point3<f64>> = patch
        .iter()
        .filter(|p| plane.distance(p).abs() <= test.plane_tolerance_mm)
        .collect();
    let sides = sides_held(marker, &plane, &on_plane);
    if sides < test.min_sides {
        return OnSurface::Unsupported { sides };
    }
    let off_mm = plane.distance(marker);
    if off_mm.abs() > test.max_off_surface_mm {
        return OnSurface::OffSurface { off_mm };
    }
    let (points, of) = in_front(marker, &plane, skin, test);
    if points as f64 > test.min_hidden_fraction * of as f64 {
        return OnSurface::Occluded { points, of };
    }
    OnSurface::Kept { off_mm }
}

/// How many of 8 sides around `marker`, in `plane`, hold skin points.
fn sides_held(marker: &Point3<f64>, plane: &Plane, points: &[&Point3<f64>]) -> usize {
    let n = plane.normal;
    let u = n
        .cross(&Vector3::x())
        .try_normalize(1e-6)
        .unwrap_or_else(|| n.cross(&Vector3::y()).normalize());
    let v = n.cross(&u);
    let mut count = [0usize; 8];
    for p in points {
        let d = *p - marker;
        let angle = d.dot(&v).atan2(d.dot(&u)).rem_euclid(TAU);
        count[((angle / TAU * 8.0) as usize).min(7)] += 1;
    }
    count.iter().filter(|c| **c >= POINTS_PER_SIDE).count()
}

/// Of the points of `cloud` in `marker`'s line of sight (within the occluder
/// radius of its ray, scaled to its range), how many are nearer the camera
/// than both the marker and the skin's `plane` by more than the test's
/// `min_front_mm`, and how many there are.
fn in_front(
    marker: &Point3<f64>,
    plane: &Plane,
    cloud: &[Point3<f64>],
    test: &SurfaceTest,
) -> (usize, usize) {
    let range = marker.coords.norm();
    let ray = marker.coords / range;
    let (mut front, mut all) = (0, 0);
    for p in cloud {
        let along = p.coords.dot(&ray);
        if along <= 0.0 {
            continue;
        }
        let lateral_at_marker = (p.coords - ray * along).norm() * range / along;
        if lateral_at_marker > test.occluder_radius_mm {
            continue;
        }
        all += 1;
        // Its own face (tilted, up to about its radius nearer) is not in
        // front of it.
        if along < range - test.min_front_mm && plane.distance(p) > test.min_front_mm {
            front += 1;
        }
    }
    (front, all)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A skin patch: the plane z = 500 + 0.5 x (mm) facing the camera at the
    /// origin, points every mm from -60 to 60, without the holes a marker's
    /// face and walls leave (12 mm about each of `holes`).
    fn skin(holes: &[Point3<f64>]) -> Vec<Point3<f64>> {
        let mut points = Vec::new();
        for i in -60..=60 {
            for j in -60..=60 {
                let (x, y) = (i as f64, j as f64);
                let p = Point3::new(x, y, 500.0 + 0.5 * x);
                if holes.iter().all(|h| (p - h).xy().norm() > 12.0) {
                    points.push(p);
                }
            }
        }
        points
    }

    /// A marker's face at (x, y), its height above the slanted skin.
    fn face(x: f64, y: f64, height_mm: f64) -> Point3<f64> {
        let normal = Vector3::new(0.5, 0.0, -1.0).normalize();
        Point3::new(x, y, 500.0 + 0.5 * x) + normal * height_mm
    }

    /// The face of a marker 6 mm in radius, 5 mm above the skin at (x, y),
    /// as stereo sees it: points every mm.
    fn face_points(x: f64, y: f64) -> Vec<Point3<f64>> {
        let mut points = Vec::new();
        for i in -6..=6 {
            for j in -6..=6 {
                if i * i + j * j <= 36 {
                    points.push(face(x + i as f64, y + j as f64, 5.0));
                }
            }
        }
        points
    }

    #[test]
    fn a_marker_on_the_skin_stays_and_one_beside_it_goes() {
        let test = SurfaceTest::default();
        let on = face(0.0, 0.0, 5.0);
        // A sticker past the patch's edge: skin on one side only.
        let beside = Point3::new(75.0, 0.0, 537.5);
        // Floating 15 mm in front of intact skin.
        let floating = face(-30.0, 30.0, 15.0);
        // The first marker's own face is in the cloud.
        let mut cloud = skin(&[on]);
        cloud.extend(face_points(0.0, 0.0));
        let v = markers_on_surface(&[on, beside, floating], &cloud, &test);
        match v[0] {
            OnSurface::Kept { off_mm } => assert!((off_mm - 5.0).abs() < 0.1, "{off_mm}"),
            other => panic!("{other:?}"),
        }
        assert!(
            matches!(v[1], OnSurface::Unsupported { sides } if sides <= 3),
            "{:?}",
            v[1]
        );
        assert!(
            matches!(v[2], OnSurface::OffSurface { off_mm } if (off_mm - 15.0).abs() < 0.1),
            "{:?}",
            v[2]
        );
    }

    #[test]
    fn a_marker_behind_a_tool_goes_and_one_beside_the_tool_stays() {
        let test = SurfaceTest::default();
        let (hidden, clear) = (face(0.0, 0.0, 5.0), face(0.0, 40.0, 5.0));
        let mut cloud = skin(&[hidden, clear]);
        cloud.extend(face_points(0.0, 0.0));
        cloud.extend(face_points(0.0, 40.0));
        // A rod 30 mm in front of the skin crossing the first marker's line of
        // sight (x = 4 mm at its range), along y from -15 to 15 mm.
        let s = 470.0 / 500.0;
        for j in -15..=15 {
            cloud.push(Point3::new(4.0 * s, j as f64 * s, 470.0));
        }
        let v = markers_on_surface(&[hidden, clear], &cloud, &test);
        assert!(
            matches!(v[0], OnSurface::Occluded { points, of } if points >= 10 && of > 100),
            "{:?}",
            v[0]
        );
        assert!(v[1].kept(), "{:?}", v[1]);
        assert!(v[0].reason(&test).contains("partly hidden"));
    }

    #[test]
    fn an_empty_cloud_supports_nothing() {
        let v = markers_on_surface(
            &[Point3::new(0.0, 0.0, 500.0)],
            &[],
            &SurfaceTest::default(),
        );
        assert_eq!(v, [OnSurface::Unsupported { sides: 0 }]);
    }
}
