//! `stereo.hsv_markers`' algorithm on the phantom's renders: blob centroids in
//! the original images against the projected true face centres, and markers
//! found in rectified pairs, triangulated, against the true faces in 3D.

use fusegraph_nodes::calib::{rectify, remap};
use fusegraph_nodes::camera::isometry_from_matrix;
use fusegraph_nodes::phantom::{GroundTruth, PhantomSize};
use fusegraph_nodes::stereo::{BlobParams, PairParams, find_blobs, stereo_markers};
use nalgebra::{Point3, Vector3};
use std::path::Path;

/// The phantom the binary's tests share, and whether it is the full one.
fn phantom() -> (&'static Path, &'static GroundTruth, bool) {
    let (dir, truth) = super::shared_phantom();
    (dir, truth, super::phantom_size() == PhantomSize::Full)
}

fn rgb(path: &Path) -> (Vec<u8>, usize, usize) {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8();
    let (w, h) = img.dimensions();
    (img.into_raw(), w as usize, h as usize)
}

#[test]
fn phantom_markers_in_the_original_and_rectified_images() {
    let (dir, truth, full) = phantom();
    // The small phantom's light anti-aliasing leaves stair steps on edges.
    let (tol_px, tol_mm) = if full { (0.2, 0.3) } else { (0.25, 0.6) };
    let left_to_right = isometry_from_matrix(&truth.rig.left_to_right);
    let (cam_l, cam_r) = (&truth.rig.left, &truth.rig.right);
    let rect = rectify(cam_l, cam_r, &left_to_right, 0.0);
    let params = BlobParams::default();
    let (mut errors_2d, mut errors_3d) = (Vec::new(), Vec::new());
    let (mut expected, mut spurious) = (0, 0);
    for view in &truth.views {
        let left_pose = isometry_from_matrix(&view.left_camera_to_world);
        let right_pose = left_pose * left_to_right.inverse();
        // Faces seen within 60 deg of head-on in a camera: not hidden in part
        // by their own rim.
        let facing = |id: u32, pose: &nalgebra::Isometry3<f64>| {
            let m = &truth.markers[id as usize];
            let eye = Point3::from(pose.translation.vector);
            let face = Point3::from(m.face_center_world_mm);
            (eye - face).normalize().dot(&Vector3::from(m.normal_world)) >= 0.5
        };
        let mut images = Vec::new();
        for (file, camera, pose, visible) in [
            (&view.left, cam_l, left_pose, &view.markers_visible_left),
            (&view.right, cam_r, right_pose, &view.markers_visible_right),
        ] {
            let (img, w, h) = rgb(&dir.join(file));
            let (blobs, _) = find_blobs(&img, w, h, &params).unwrap();
            for &id in visible.iter().filter(|&&id| facing(id, &pose)) {
                let p = face_outline_centroid(truth, id, camera, &pose);
                let err = blobs
                    .iter()
                    .map(|b| ((b.x_px - p.0).powi(2) + (b.y_px - p.1).powi(2)).sqrt())
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    err < tol_px,
                    "{file}: marker {id}: nearest blob {err} px away"
                );
                errors_2d.push(err);
            }
            images.push(remap(
                &img,
                3,
                camera,
                &rect_rot(&rect, images.len()),
                &rect_proj(&rect, images.len()),
                rect.size,
            ));
        }
        let (w, h) = rect.size;
        let found = stereo_markers(
            (&images[0], w, h),
            (&images[1], w, h),
            &rect,
            &params,
            &PairParams::default(),
        )
        .unwrap();
        let both: Vec<u32> = view
            .markers_visible_left
            .iter()
            .copied()
            .filter(|id| view.markers_visible_right.contains(id))
            .filter(|&id| facing(id, &left_pose) && facing(id, &right_pose))
            .collect();
        expected += both.len();
        let found_world: Vec<Point3<f64>> = found
            .markers
            .iter()
            .map(|m| left_pose * m.point_mm)
            .collect();
        for &id in &both {
            let face = Point3::from(truth.markers[id as usize].face_center_world_mm);
            let err = found_world
                .iter()
                .map(|p| (p - face).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(
                err < tol_mm,
                "view {}: marker {id}: nearest found {err} mm away",
                view.index
            );
            errors_3d.push(err);
        }
        // Every found marker is one of the true faces (possibly one seen
        // obliquely, whose centroid the rim biases).
        spurious += found_world
            .iter()
            .filter(|p| {
                truth
                    .markers
                    .iter()
                    .all(|m| (*p - Point3::from(m.face_center_world_mm)).norm() > 2.0)
            })
            .count();
    }
    let stats = |v: &[f64]| {
        (
            v.iter().sum::<f64>() / v.len() as f64,
            v.iter().copied().fold(0.0, f64::max),
        )
    };
    let ((m2, x2), (m3, x3)) = (stats(&errors_2d), stats(&errors_3d));
    eprintln!(
        "{} faces in original images: centroid error mean {m2:.3} px, max {x2:.3} px; \
         {} markers in both rectified images: 3D error mean {m3:.3} mm, max {x3:.3} mm; {spurious} spurious",
        errors_2d.len(),
        errors_3d.len()
    );
    assert!(
        errors_2d.len() >= 30 && expected >= 15,
        "{} {expected}",
        errors_2d.len()
    );
    assert_eq!(spurious, 0);
}

fn rect_rot(
    rect: &fusegraph_nodes::calib::StereoRectification,
    side: usize,
) -> nalgebra::Matrix3<f64> {
    if side == 0 { rect.r1 } else { rect.r2 }
}

fn rect_proj(
    rect: &fusegraph_nodes::calib::StereoRectification,
    side: usize,
) -> nalgebra::Matrix3x4<f64> {
    if side == 0 { rect.p1 } else { rect.p2 }
}

/// Centroid (px) of the image of marker `id`'s coloured face: the area
/// centroid of its projected outline (perspective moves it off the projected
/// face centre by up to about 0.1 px at the phantom's tilts).
fn face_outline_centroid(
    truth: &GroundTruth,
    id: u32,
    camera: &fusegraph_nodes::camera::CameraModel,
    camera_to_world: &nalgebra::Isometry3<f64>,
) -> (f64, f64) {
    let m = &truth.markers[id as usize];
    let n = Vector3::from(m.normal_world);
    let u = n
        .cross(&Vector3::z())
        .try_normalize(1e-9)
        .unwrap_or(Vector3::x());
    let v = n.cross(&u);
    let c = Point3::from(m.face_center_world_mm);
    let r = 0.5 * m.diameter_mm;
    let outline: Vec<(f64, f64)> = (0..720)
        .map(|k| {
            let a = k as f64 / 720.0 * std::f64::consts::TAU;
            let p = c + r * (a.cos() * u + a.sin() * v);
            let q = camera.project(&(camera_to_world.inverse() * p)).unwrap();
            (q.x, q.y)
        })
        .collect();
    let (mut area, mut cx, mut cy) = (0.0, 0.0, 0.0);
    for k in 0..outline.len() {
        let ((x0, y0), (x1, y1)) = (outline[k], outline[(k + 1) % outline.len()]);
        let cross = x0 * y1 - x1 * y0;
        area += cross;
        cx += (x0 + x1) * cross;
        cy += (y0 + y1) * cross;
    }
    (cx / (3.0 * area), cy / (3.0 * area))
}
