//! A simulated stereo reconstruction of one phantom view, built from the truth
//! alone: the skin and markers seen by both cameras, with depth noise and a few
//! outliers, and noisy camera-space marker centres with some markers missing and
//! a spurious one. It lets registration be built and measured before dense
//! stereo exists. Output frame: the left camera of the chosen view (mm).

use super::moved_shape::MovedShape;
use super::truth::GroundTruth;
use crate::camera::{CameraModel, isometry_from_matrix};
use fusegraph_plugin_api::derive::Params;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// How to degrade the true surface: noise along and across the viewing rays
/// (stereo depth and lateral error), a fraction of outliers displaced 5-30 mm
/// along their ray (bad matches), isotropic noise on each marker centre, some
/// visible markers dropped and spurious ones added (on the skin, away from
/// real ones). The parameters of `phantom.camera_surface` (flattened into
/// it), declared here once.
#[derive(Debug, Clone, PartialEq, Params)]
pub struct SurfaceSimParams {
    /// Which view pair
    #[param(default = 0, min = 0)]
    pub view: usize,
    /// Sample every this many left-image pixels
    #[param(default = 3, unit = "px", min = 1, max = 64)]
    pub step_px: usize,
    /// Noise along the viewing ray
    #[param(default = 0.5, unit = "mm", min = 0.0, max = 10.0)]
    pub depth_noise_mm: f64,
    /// Noise across the viewing ray
    #[param(default = 0.1, unit = "mm", min = 0.0, max = 10.0)]
    pub lateral_noise_mm: f64,
    /// Fraction of points 5-30 mm off
    #[param(default = 0.03, min = 0.0, max = 0.5)]
    pub outlier_fraction: f64,
    /// Noise of each marker centre
    #[param(default = 0.3, unit = "mm", min = 0.0, max = 10.0)]
    pub marker_noise_mm: f64,
    /// Visible markers to drop
    #[param(default = 2, min = 0, max = 30)]
    pub missing_markers: usize,
    /// Spurious markers to add
    #[param(default = 1, min = 0, max = 10)]
    pub spurious_markers: usize,
    /// Seed of the noise
    #[param(default = 1, min = 0)]
    pub seed: u64,
}

/// The simulated reconstruction, in the left camera frame (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct SimulatedSurface {
    /// Surface points.
    pub points: Vec<[f32; 3]>,
    /// How many of them are outliers.
    pub outliers: usize,
    /// Marker centres (centres of the coloured faces), shuffled.
    pub markers: Vec<[f64; 3]>,
    /// For each marker, the true marker id, or `None` for a spurious one.
    pub marker_truth_ids: Vec<Option<u32>>,
}

/// Simulates the reconstruction of view `p.view` of `truth`.
pub fn simulate_camera_surface(
    truth: &GroundTruth,
    p: &SurfaceSimParams,
) -> Result<SimulatedSurface, String> {
    let view = truth.views.get(p.view).ok_or_else(|| {
        format!(
            "view {} does not exist (the phantom has {})",
            p.view,
            truth.views.len()
        )
    })?;
    let shape = MovedShape::new(truth.shape.clone(), truth.motion_field());
    let phantom_to_world = isometry_from_matrix(&truth.phantom_to_world);
    let left_to_world = isometry_from_matrix(&view.left_camera_to_world);
    let left_to_right = isometry_from_matrix(&truth.rig.left_to_right);
    let left_to_phantom = phantom_to_world.inverse() * left_to_world;
    let right_centre = left_to_phantom * (left_to_right.inverse() * Point3::origin());
    let left_centre = left_to_phantom * Point3::origin();
    let mut rng = ChaCha8Rng::seed_from_u64(p.seed);
    let normal = |s: f64| Normal::new(0.0, s.max(0.0)).expect("finite sigma");
    let (depth, lateral) = (normal(p.depth_noise_mm), normal(p.lateral_noise_mm));
    let camera: &CameraModel = &truth.rig.left;
    let step = p.step_px.max(1);
    let mut points = Vec::new();
    let mut outliers = 0;
    for v in (0..camera.height).step_by(step) {
        for u in (0..camera.width).step_by(step) {
            let ray_left = camera.pixel_ray(u as f64, v as f64);
            let dir = left_to_phantom.rotation * ray_left;
            let Some(hit) = shape.intersect(&left_centre, &dir, 0.0) else {
                continue;
            };
            let point = left_centre + dir * hit.t;
            if !seen_from(
                &shape,
                &right_centre,
                &point,
                &truth.rig.right,
                &(left_to_right * left_to_phantom.inverse()),
            ) {
                continue;
            }
            let mut t = hit.t + depth.sample(&mut rng);
            if rng.random_bool(p.outlier_fraction.clamp(0.0, 1.0)) {
                t += rng.random_range(5.0..30.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                outliers += 1;
            }
            let across = ray_left.cross(&Vector3::y()).normalize();
            let up = ray_left.cross(&across);
            let q =
                ray_left * t + across * lateral.sample(&mut rng) + up * lateral.sample(&mut rng);
            points.push([q.x as f32, q.y as f32, q.z as f32]);
        }
    }

    let world_to_left = left_to_world.inverse();
    let both: Vec<u32> = view
        .markers_visible_left
        .iter()
        .copied()
        .filter(|id| view.markers_visible_right.contains(id))
        .collect();
    if both.len() < p.missing_markers {
        return Err(format!(
            "view {} shows {} markers to both cameras; cannot drop {}",
            p.view,
            both.len(),
            p.missing_markers
        ));
    }
    let mut kept = both.clone();
    kept.shuffle(&mut rng);
    kept.truncate(both.len() - p.missing_markers);
    let marker_noise = normal(p.marker_noise_mm);
    let mut markers: Vec<([f64; 3], Option<u32>)> = kept
        .iter()
        .map(|&id| {
            let m = &truth.markers[id as usize];
            let c = world_to_left * Point3::from(m.face_center_world_mm);
            let noisy = c.coords + Vector3::from_fn(|_, _| marker_noise.sample(&mut rng));
            (noisy.into(), Some(id))
        })
        .collect();
    let mut spurious = 0;
    let mut attempts = 0;
    while spurious < p.spurious_markers && !points.is_empty() {
        attempts += 1;
        if attempts > 10_000 {
            return Err("cannot place a spurious marker away from the real ones".into());
        }
        let candidate = Vector3::from(points[rng.random_range(0..points.len())].map(f64::from));
        let clear = truth.markers.iter().all(|m| {
            let c = world_to_left * Point3::from(m.face_center_world_mm);
            (c.coords - candidate).norm() > 20.0
        });
        if clear {
            markers.push((candidate.into(), None));
            spurious += 1;
        }
    }
    markers.shuffle(&mut rng);
    Ok(SimulatedSurface {
        points,
        outliers,
        markers: markers.iter().map(|m| m.0).collect(),
        marker_truth_ids: markers.iter().map(|m| m.1).collect(),
    })
}

/// Whether `point` (phantom frame) is seen by the right camera: in its image and
/// the first thing along the ray from its centre.
fn seen_from(
    shape: &MovedShape,
    eye: &Point3<f64>,
    point: &Point3<f64>,
    camera: &CameraModel,
    phantom_to_camera: &Isometry3<f64>,
) -> bool {
    let Some(px) = camera.project(&(phantom_to_camera * point)) else {
        return false;
    };
    if !camera.contains(&px, 0.0) {
        return false;
    }
    let to_point = point - eye;
    let distance = to_point.norm();
    shape
        .intersect(eye, &(to_point / distance), 0.0)
        .is_some_and(|h| (h.t - distance).abs() < 1e-3)
}
