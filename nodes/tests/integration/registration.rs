//! Registration end to end on the phantom's truth: markers with 2 missing and 1
//! spurious, Procrustes, point-to-plane ICP; from many initial rotations.

use fusegraph_nodes::camera::isometry_from_matrix;
use fusegraph_nodes::cloud::{Nearest, estimate_normals};
use fusegraph_nodes::phantom::{
    GroundTruth, PhantomConfig, PhantomSize, SurfaceSimParams, generate, simulate_camera_surface,
};
use fusegraph_nodes::register::{IcpMethod, IcpParams, Kernel, icp, match_markers, umeyama};
use nalgebra::{Isometry3, Point3, Vector3};
use std::path::Path;

fn truth() -> GroundTruth {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("registration-phantom");
    let _ = std::fs::remove_dir_all(&dir);
    let config = PhantomConfig {
        size: PhantomSize::Small,
        calibration_pairs: 3,
        views: 3,
        ..PhantomConfig::default()
    };
    generate(&config, &dir).unwrap().truth
}

#[test]
fn registration_recovers_any_initial_rotation() {
    let truth = truth();
    let view = 1;
    let sim = simulate_camera_surface(
        &truth,
        &SurfaceSimParams {
            view,
            step_px: 4,
            depth_noise_mm: 0.5,
            lateral_noise_mm: 0.1,
            outlier_fraction: 0.03,
            marker_noise_mm: 0.3,
            missing_markers: 2,
            spurious_markers: 1,
            seed: 9,
        },
    )
    .unwrap();
    let mri_to_world = isometry_from_matrix(&truth.mri_to_world);
    let world_to_mri = mri_to_world.inverse();
    let camera_to_world = isometry_from_matrix(&truth.views[view].left_camera_to_world);
    let true_camera_to_mri = world_to_mri * camera_to_world;
    // MRI side from the truth: gel centres and the skin, in MRI coordinates.
    let mri_markers: Vec<Point3<f64>> = truth
        .markers
        .iter()
        .map(|m| Point3::from(m.center_mri_mm))
        .collect();
    let mri_skin: Vec<Point3<f64>> = truth
        .skin_world_mm
        .iter()
        .map(|p| world_to_mri * Point3::from(*p))
        .collect();
    let normals = estimate_normals(&mri_skin, 12, None);
    let tree = Nearest::new(&mri_skin).unwrap();
    let params = IcpParams {
        method: IcpMethod::PointToPlane,
        max_distance_mm: 6.0,
        trim_ratio: 0.85,
        kernel: Kernel::Huber(1.0),
        max_iterations: 60,
        tolerance: 1e-7,
        voxel_sizes_mm: vec![4.0, 2.0, 0.0],
    };
    for (k, axis_angle) in [
        Vector3::zeros(),
        Vector3::new(0.0, 0.0, 2.5),
        Vector3::new(1.7, 0.0, 0.0),
        Vector3::new(-0.9, 2.2, 0.4),
        Vector3::new(0.0, -3.0, 0.0),
    ]
    .iter()
    .enumerate()
    {
        // Turn the whole camera side (the phantom as the cameras saw it).
        let turn = Isometry3::new(Vector3::new(40.0, -25.0, 10.0), *axis_angle);
        let cam_markers: Vec<Point3<f64>> = sim
            .markers
            .iter()
            .map(|m| turn * Point3::from(*m))
            .collect();
        let cam_cloud: Vec<Point3<f64>> = sim
            .points
            .iter()
            .map(|p| turn * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let truth_now = true_camera_to_mri * turn.inverse();
        let m = match_markers(&cam_markers, &mri_markers, 4.0, false)
            .unwrap_or_else(|| panic!("case {k}: no match"));
        // Every pair is a true correspondence: the spurious marker is left out.
        for &(i, j) in &m.pairs {
            assert_eq!(
                sim.marker_truth_ids[i],
                Some(j as u32),
                "case {k}: camera marker {i} matched to MRI marker {j}"
            );
        }
        assert_eq!(m.pairs.len(), sim.markers.len() - 1);
        let (s, t): (Vec<_>, Vec<_>) = m
            .pairs
            .iter()
            .map(|&(i, j)| (cam_markers[i], mri_markers[j]))
            .unzip();
        let start = umeyama(&s, &t, None, false).unwrap().isometry();
        let r = icp(
            &cam_cloud,
            &mri_skin,
            Some(&normals),
            &tree,
            &start,
            &params,
        )
        .unwrap();
        let tre: f64 = truth
            .lesions
            .iter()
            .map(|l| {
                let p = Point3::from(l.center_mri_mm);
                (r.transform.inverse() * p - truth_now.inverse() * p).norm()
            })
            .fold(0.0, f64::max);
        assert!(tre <= 1.5, "case {k}: TRE {tre} mm");
        assert!(r.rmse_mm <= 1.0, "case {k}: RMSE {} mm", r.rmse_mm);
    }
}

/// Six simulated views of the phantom (depth noise `depth_noise_mm`) merged
/// from rough poses a robot would report, anchored by the markers the views
/// share or not: how far off (mm) the worst view sees the phantom's centre,
/// and the largest view RMSE.
fn merge_six_views(depth_noise_mm: f64, anchored: bool) -> (f64, f64) {
    use fusegraph_nodes::register::{MarkerAnchoring, View, register_views};
    use rand::{Rng, SeedableRng};
    let truth = truth_with_views(6);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut views = Vec::new();
    let mut markers = Vec::new();
    let (mut rough, mut exact) = (Vec::new(), Vec::new());
    for v in 0..6 {
        let sim = simulate_camera_surface(
            &truth,
            &SurfaceSimParams {
                view: v,
                step_px: 5,
                depth_noise_mm,
                lateral_noise_mm: 0.1,
                outlier_fraction: 0.03,
                marker_noise_mm: 0.3,
                missing_markers: 0,
                spurious_markers: 0,
                seed: v as u64,
            },
        )
        .unwrap();
        let points: Vec<Point3<f64>> = sim
            .points
            .iter()
            .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let normals = estimate_normals(&points, 12, Some(Point3::origin()));
        views.push(View { points, normals });
        markers.push(
            sim.markers
                .iter()
                .map(|m| Point3::from(*m))
                .collect::<Vec<_>>(),
        );
        let pose = isometry_from_matrix(&truth.views[v].left_camera_to_world);
        exact.push(pose);
        // A robot arm's pose, a couple of degrees and millimetres off.
        let noise = Isometry3::new(
            Vector3::new(
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
            ),
            Vector3::new(
                rng.random_range(-0.03..0.03),
                rng.random_range(-0.03..0.03),
                rng.random_range(-0.03..0.03),
            ),
        );
        rough.push(if v == 0 { pose } else { pose * noise });
    }
    let params = IcpParams {
        method: IcpMethod::PointToPlane,
        max_distance_mm: 8.0,
        trim_ratio: 0.8,
        kernel: Kernel::Huber(1.0),
        max_iterations: 40,
        tolerance: 1e-7,
        voxel_sizes_mm: vec![4.0, 0.0],
    };
    let anchoring = MarkerAnchoring {
        markers,
        tolerance_mm: 4.0,
        weight: 1.0,
        outlier_mm: 2.5,
        covariances: Vec::new(),
    };
    let m = register_views(&views, &rough, &params, 2, anchored.then_some(&anchoring)).unwrap();
    // Every view lands where the truth has it (view 0 is the anchor): compare
    // where each camera sees the phantom's centre.
    let centre = isometry_from_matrix(&truth.phantom_to_world) * Point3::new(0.0, 0.0, 25.0);
    let worst = (1..6)
        .map(|v| {
            let seen_rough = (rough[v].inverse() * centre - exact[v].inverse() * centre).norm();
            let seen = (m.poses[v].inverse() * centre - exact[v].inverse() * centre).norm();
            eprintln!(
                "noise {depth_noise_mm} mm, anchored {anchored}: view {v}: rough pose \
                 {seen_rough:.2} mm off, registered {seen:.3} mm"
            );
            seen
        })
        .fold(0.0, f64::max);
    (worst, m.view_rmse_mm.iter().copied().fold(0.0, f64::max))
}

#[test]
fn six_views_merge_into_one_consistent_cloud() {
    let (worst, rmse) = merge_six_views(0.5, false);
    assert!(worst < 1.0, "surfaces alone: {worst} mm off");
    assert!(rmse < 1.0, "{rmse}");
    // The markers the views share hold them where noisy surfaces slide.
    let (worst, _) = merge_six_views(0.5, true);
    assert!(worst < 1.0, "anchored: {worst} mm off");
    let (worst, _) = merge_six_views(2.0, true);
    assert!(worst < 1.0, "anchored, 2 mm depth noise: {worst} mm off");
}

fn truth_with_views(views: usize) -> GroundTruth {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("registration-phantom-{views}"));
    let _ = std::fs::remove_dir_all(&dir);
    let config = PhantomConfig {
        size: PhantomSize::Small,
        calibration_pairs: 3,
        views,
        ..PhantomConfig::default()
    };
    generate(&config, &dir).unwrap().truth
}
