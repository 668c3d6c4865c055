//! `io.write_transform` (4x4 JSON and an ITK transform file) and
//! `io.write_cloud` (one or two point clouds as coloured PLY).

use super::write_mesh::write_ply;
use fusegraph_engine::value::{PointCloud, Transform};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType, path_value,
};
use std::sync::Arc;

/// An ITK text transform holding the *inverse* of `matrix` (row-major 4x4,
/// mapping the moving data's frame `from` onto the fixed frame `to`), because
/// ITK stores resampling transforms, which map points of the fixed space to the
/// moving space: MRI -> camera is written as camera -> MRI, and 3D Slicer then
/// moves the MRI into camera space as intended. Coordinates are taken as LPS, as
/// ITK's are.
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

pub(crate) struct WriteTransformOp(OpSpec);

impl WriteTransformOp {
    pub(crate) fn new() -> Self {
        WriteTransformOp(
            OpSpec::new(
                "io.write_transform",
                1,
                "Write a transform as 4x4 JSON and as an ITK .tfm (for 3D Slicer)",
            )
            .input(
                "transform",
                &[ValueType::Transform],
                "The transform (from -> to)",
            )
            .param(ParamSpec::string(
                "file",
                "transform",
                "Base name: writes NAME.json and NAME.tfm",
            ))
            .param(ParamSpec::bool(
                "invert",
                false,
                "Write the inverse (to -> from), e.g. MRI -> camera from an ICP that ran camera -> MRI",
            ))
            .output("json", ValueType::Path, "The JSON file")
            .output(
                "itk",
                ValueType::Path,
                "The ITK file (inverse matrix: fixed -> moving)",
            )
            .writes_output(),
        )
    }
}

impl Op for WriteTransformOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let given = inputs.get::<Transform>("transform")?;
        let t = if params.bool("invert")? {
            let m = nalgebra::Matrix4::from_fn(|r, c| given.matrix[r][c])
                .try_inverse()
                .ok_or_else(|| OpError::invalid("the transform is singular"))?;
            Arc::new(Transform {
                matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])),
                from: given.to.clone(),
                to: given.from.clone(),
            })
        } else {
            given
        };
        let name = params.string("file")?;
        let json = ctx.output_path(&format!("{name}.json"))?;
        std::fs::write(
            &json,
            serde_json::to_string_pretty(&*t).expect("plain data") + "\n",
        )
        .map_err(|e| OpError::io(&json, e))?;
        let itk = ctx.output_path(&format!("{name}.tfm"))?;
        let text = itk_transform_text(&t.matrix)
            .ok_or_else(|| OpError::invalid("the transform is singular"))?;
        std::fs::write(&itk, text).map_err(|e| OpError::io(&itk, e))?;
        Ok(Outputs::new()
            .with("json", path_value(&json)?)
            .with("itk", path_value(&itk)?))
    }
}

pub(crate) struct WriteCloudOp(OpSpec);

impl WriteCloudOp {
    pub(crate) fn new() -> Self {
        WriteCloudOp(
            OpSpec::new(
                "io.write_cloud",
                1,
                "Write one or two point clouds (same frame) as one coloured binary PLY",
            )
            .input("cloud", &[ValueType::PointCloud], "First cloud")
            .optional_input(
                "other",
                &[ValueType::PointCloud],
                "Second cloud, coloured apart",
            )
            .param(
                ParamSpec::int_list(
                    "color",
                    &[230, 120, 60],
                    "",
                    "RGB of the first cloud (if it has no colours)",
                )
                .range(0.0, 255.0)
                .length(3),
            )
            .param(
                ParamSpec::int_list(
                    "other_color",
                    &[60, 140, 230],
                    "",
                    "RGB of the second cloud",
                )
                .range(0.0, 255.0)
                .length(3),
            )
            .param(ParamSpec::string(
                "file",
                "cloud.ply",
                "PLY file, relative to the output folder",
            ))
            .output("file", ValueType::Path, "The PLY")
            .writes_output(),
        )
    }
}

impl Op for WriteCloudOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let a = inputs.get::<PointCloud>("cloud")?;
        let b: Option<Arc<PointCloud>> = inputs.optional("other")?;
        if let Some(b) = &b
            && b.frame != a.frame
        {
            return Err(OpError::invalid(format!(
                "the clouds are in different frames: `{}` and `{}`",
                a.frame, b.frame
            )));
        }
        let rgb = |name: &str| -> Result<[u8; 3], OpError> {
            let v = params.int_list(name)?;
            let &[r, g, bl] = v.as_slice() else {
                return Err(OpError::invalid(format!("{name} takes r, g, b")));
            };
            Ok([r as u8, g as u8, bl as u8])
        };
        let mut points: Vec<f32> = a.points.to_vec();
        let mut colors: Vec<u8> = match &a.colors {
            Some(c) => c.to_vec(),
            None => rgb("color")?.repeat(a.len()),
        };
        if let Some(b) = &b {
            points.extend_from_slice(&b.points);
            colors.extend(match &b.colors {
                Some(c) => c.to_vec(),
                None => rgb("other_color")?.repeat(b.len()),
            });
        }
        let path = ctx.output_path(&params.string("file")?)?;
        write_ply(
            &path,
            &points,
            None,
            Some(&colors),
            &[],
            &format!("fusegraph cloud, mm, frame {}", a.frame),
        )
        .map_err(|e| OpError::io(&path, e))?;
        Ok(Outputs::new().with("file", path_value(&path)?))
    }
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
