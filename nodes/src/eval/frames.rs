//! The frames a result to evaluate may come in, tied to the phantom's world.

use crate::camera::isometry_from_matrix;
use crate::phantom::GroundTruth;
use nalgebra::Isometry3;

/// The frames [`frame_to_world`] knows.
pub const EVAL_FRAMES: &str = "world, mri_lps or camera_left";

/// The rigid transform from `frame` to the phantom's world (mm): `world`,
/// `mri_lps` (the MRI patient frame), or `camera_left` (the left camera of view
/// `view`; `view` is ignored for the other frames). An unknown frame or view is
/// an error naming it.
pub fn frame_to_world(
    truth: &GroundTruth,
    frame: &str,
    view: usize,
) -> Result<Isometry3<f64>, String> {
    match frame {
        "world" => Ok(Isometry3::identity()),
        "mri_lps" => Ok(isometry_from_matrix(&truth.mri_to_world)),
        "camera_left" => truth
            .views
            .get(view)
            .map(|v| isometry_from_matrix(&v.left_camera_to_world))
            .ok_or_else(|| {
                format!(
                    "view {view} does not exist (the phantom has {} views)",
                    truth.views.len()
                )
            }),
        other => Err(format!("frame `{other}`: expected {EVAL_FRAMES}")),
    }
}

/// A small in-memory ground truth for tests: the default phantom on the table,
/// one view from above (markers 1, 2, 3 visible in both images), skin points
/// on a regular grid of the dome.
#[cfg(test)]
pub(crate) fn test_truth() -> GroundTruth {
    use crate::camera::isometry_to_matrix;
    use crate::phantom::*;
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};
    use rand::SeedableRng;

    let shape = PhantomShape::build(
        &ShapeParams::default(),
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(1),
    )
    .unwrap();
    let to_world = Isometry3::from_parts(
        Translation3::new(15.0, -10.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 20f64.to_radians()),
    );
    let to_mri = Isometry3::new(
        Vector3::new(12.0, -40.0, -30.0),
        Vector3::new(1.5, 0.1, 0.0),
    );
    let rig = Rig::paper_rig();
    let target = to_world * Point3::new(0.0, 0.0, 24.0);
    let left_to_world = rig.aim(&Point3::new(120.0, -330.0, 420.0), &target);
    let axes = Vector3::from(shape.semi_axes_mm);
    let skin: Vec<[f64; 3]> = (0..40)
        .flat_map(|i| (0..12).map(move |j| (i, j)))
        .map(|(i, j)| {
            let (az, el) = (i as f64 * 0.157, 0.1 + j as f64 * 0.12);
            let u = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            Point3::from(shape.ellipsoid_center_mm) + shape.rotation() * u.component_mul(&axes)
        })
        .filter(|p| p.z >= 0.0)
        .map(|p| (to_world * p).into())
        .collect();
    GroundTruth {
        schema: SCHEMA.into(),
        seed: 1,
        sensor_seed: None,
        size: "small".into(),
        phantom_to_mri: isometry_to_matrix(&to_mri),
        phantom_to_world: isometry_to_matrix(&to_world),
        mri_to_world: isometry_to_matrix(&(to_world * to_mri.inverse())),
        mri: MriTruth {
            dir: "mri".into(),
            files: 0,
            dims: [1, 1, 1],
            spacing_mm: [1.0; 3],
            voxel_to_patient: isometry_to_matrix(&Isometry3::identity()),
            oblique_deg: 0.0,
            series_uid: "1.2.3".into(),
            rescale_slope: 1.0,
            signal_tissue_gel_lesion: [0.55, 1.0, 0.7],
            noise_sigma: 0.0,
        },
        markers: shape
            .markers
            .iter()
            .map(|m| MarkerTruth {
                id: m.id,
                center_mri_mm: (to_mri * m.gel_center()).into(),
                center_world_mm: (to_world * m.gel_center()).into(),
                face_center_world_mm: (to_world * m.face_center()).into(),
                normal_world: (to_world * Vector3::from(m.normal)).into(),
                diameter_mm: 2.0 * m.radius_mm,
                scanned_world_mm: None,
            })
            .collect(),
        lesions: Vec::new(),
        rig: RigTruth {
            left: rig.left.clone(),
            right: rig.right.clone(),
            left_to_right: isometry_to_matrix(&rig.left_to_right),
            baseline_mm: 55.0,
            verging_deg: rig.left_to_right.rotation.angle().to_degrees(),
        },
        chessboard: ChessboardTruth {
            pattern: [9, 6],
            square_mm: 25.0,
            margin_mm: 20.0,
        },
        calibration: Vec::new(),
        views: vec![ViewTruth {
            index: 0,
            left: "views/left_00.png".into(),
            right: "views/right_00.png".into(),
            left_camera_to_world: isometry_to_matrix(&left_to_world),
            markers_visible_left: vec![0, 1, 2, 3],
            markers_visible_right: vec![1, 2, 3, 4],
        }],
        skin_world_mm: skin,
        shape,
        motion: None,
        props: Vec::new(),
        conditions: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn frames_map_known_points_to_world() {
        let truth = test_truth();
        let m = &truth.markers[0];
        let from_mri = frame_to_world(&truth, "mri_lps", 7).unwrap();
        let p = from_mri * Point3::from(m.center_mri_mm);
        assert!((p - Point3::from(m.center_world_mm)).norm() < 1e-9);
        let from_camera = frame_to_world(&truth, "camera_left", 0).unwrap();
        let camera_centre = from_camera * Point3::origin();
        let pose = isometry_from_matrix(&truth.views[0].left_camera_to_world);
        assert!((camera_centre.coords - pose.translation.vector).norm() < 1e-12);
        assert_eq!(
            frame_to_world(&truth, "world", 0).unwrap(),
            Isometry3::identity()
        );
    }

    #[test]
    fn unknown_frames_and_views_are_errors() {
        let truth = test_truth();
        let err = frame_to_world(&truth, "camera_right", 0).unwrap_err();
        assert!(err.contains("frame `camera_right`"), "{err}");
        let err = frame_to_world(&truth, "camera_left", 3).unwrap_err();
        assert!(
            err.contains("view 3 does not exist (the phantom has 1 views)"),
            "{err}"
        );
    }
}
