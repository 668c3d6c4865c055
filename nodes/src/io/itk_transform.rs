//! ITK text transform files (`.tfm`, as 3D Slicer reads them), written by
//! `io.write_transform`.

/// An ITK text transform holding the *inverse* of `matrix` (row-major 4x4,
/// mapping the moving data's frame `from` onto the fixed frame `to`), because
/// ITK stores resampling transforms, which map points of the fixed space to the
/// moving space: MRI -> camera is written as camera -> MRI, and 3D Slicer then
/// moves the MRI into camera space as intended. Coordinates are taken as LPS, as
/// ITK's are. `None` when `matrix` is singular.
pub fn itk_transform_text(matrix: &[[f64; 4]; 4]) -> Option<String> {
    let m = nalgebra::Matrix4::from_fn(|r, c| matrix[r][c]).try_inverse()?;
    let mut params: Vec<String> = Vec::new();
    for r in 0..3 {
        for c in 0..3 {
            params.push(format!("{:.17e}", m[(r, c)]));
        }
    }
    for r in 0..3 {
        params.push(format!("{:.17e}", m[(r, 3)]));
    }
    Some(format!(
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\nParameters: {}\nFixedParameters: 0 0 0\n",
        params.join(" ")
    ))
}

/// Reads back the 4x4 of an ITK affine text transform (the resampling,
/// fixed -> moving, matrix).
pub fn read_itk_transform(text: &str) -> Option<[[f64; 4]; 4]> {
    let line = text.lines().find(|l| l.starts_with("Parameters:"))?;
    let p: Vec<f64> = line["Parameters:".len()..]
        .split_whitespace()
        .map(|v| v.parse().ok())
        .collect::<Option<_>>()?;
    if p.len() != 12 {
        return None;
    }
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        m[r][..3].copy_from_slice(&p[3 * r..3 * r + 3]);
        m[r][3] = p[9 + r];
    }
    m[3][3] = 1.0;
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn itk_file_reads_back_as_the_inverse() {
        let iso = nalgebra::Isometry3::new(
            nalgebra::Vector3::new(12.0, -40.0, 300.0),
            nalgebra::Vector3::new(0.3, -1.2, 2.0),
        );
        let m = iso.to_homogeneous();
        let matrix: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
        let text = itk_transform_text(&matrix).unwrap();
        assert!(text.starts_with("#Insight Transform File V1.0\n"));
        assert!(text.contains("Transform: AffineTransform_double_3_3\n"));
        let back = read_itk_transform(&text).unwrap();
        let inv = iso.inverse().to_homogeneous();
        for r in 0..4 {
            for c in 0..4 {
                assert!((back[r][c] - inv[(r, c)]).abs() < 1e-9, "[{r}][{c}]");
            }
        }
    }
}
