//! A stereo rig as an OpenCV FileStorage YAML file, as `io.write_rig` writes
//! it (`cv2.FileStorage(path, cv2.FILE_STORAGE_READ)` reads K1, D1, K2, D2, R,
//! T, image_width, image_height).

use fusegraph_engine::value::StereoRig;

fn matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    let values: Vec<String> = data.iter().map(|v| format!("{v:.17e}")).collect();
    format!(
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
        values.join(", ")
    )
}

/// The rig in OpenCV's FileStorage YAML: K1, D1 (1 x 5), K2, D2, R, T (3 x 1, mm).
pub fn rig_yaml(rig: &StereoRig) -> String {
    let mut s = String::from("%YAML:1.0\n---\n");
    s += &format!(
        "image_width: {}\nimage_height: {}\n",
        rig.left.width, rig.left.height
    );
    s += &matrix("K1", 3, 3, rig.left.k.as_flattened());
    s += &matrix("D1", 1, 5, &rig.left.distortion);
    s += &matrix("K2", 3, 3, rig.right.k.as_flattened());
    s += &matrix("D2", 1, 5, &rig.right.distortion);
    s += &matrix("R", 3, 3, rig.rotation.as_flattened());
    s += &matrix("T", 3, 1, &rig.translation_mm);
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::value::Camera;

    #[test]
    fn yaml_has_opencv_matrix_nodes() {
        let cam = Camera {
            width: 800,
            height: 600,
            k: [[1333.0, 0.0, 400.0], [0.0, 1334.0, 300.0], [0.0, 0.0, 1.0]],
            distortion: [-0.1, 0.15, 0.001, -0.001, 0.0],
        };
        let rig = StereoRig {
            left: cam.clone(),
            right: cam,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation_mm: [-55.0, 0.0, 0.0],
        };
        let y = rig_yaml(&rig);
        assert!(
            y.starts_with("%YAML:1.0\n---\nimage_width: 800\nimage_height: 600\n"),
            "{y}"
        );
        assert!(y.contains("D1: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"));
        let t_line = y
            .lines()
            .skip_while(|l| !l.starts_with("T:"))
            .nth(4)
            .unwrap();
        assert_eq!(t_line.matches(',').count(), 2, "{t_line}");
        assert!(t_line.contains("-5.5"), "{t_line}");
    }
}
