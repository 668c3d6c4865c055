//! `stereo.triangulate`: a disparity map to a metric point cloud.

use super::shape_error;
use crate::calib::rectification_of;
use crate::stereo::triangulate_disparity;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Disparity, Image, Pixels, PointCloud, Rectification};

/// Disparity + rectification -> point cloud (mm) in the original left camera
/// frame
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.triangulate", version = 1)]
pub struct Triangulate {
    /// Nearest depth kept (z in the left camera frame)
    #[param(default = 400.0, unit = "mm", min = 0.0)]
    pub min_depth_mm: f64,
    /// Farthest depth kept
    #[param(default = 700.0, unit = "mm", min = 0.0)]
    pub max_depth_mm: f64,
}

#[derive(Inputs)]
pub struct TriangulateInputs {
    /// Disparity on the left rectified image, px
    pub disparity: Arc<Disparity>,
    /// The rectification the disparity was measured in
    pub rectification: Arc<Rectification>,
    /// Left rectified image: colours of the points
    pub image: Option<Arc<Image>>,
}

#[derive(Outputs)]
pub struct TriangulateOutputs {
    /// Points in mm, frame camera_left, with colours if given
    pub cloud: PointCloud,
}

impl RunOp for Triangulate {
    type Inputs = TriangulateInputs;
    type Outputs = TriangulateOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let disparity = inputs.disparity;
        let rect = rectification_of(&inputs.rectification);
        let (w, h) = (disparity.width, disparity.height);
        if (w, h) != rect.size {
            return Err(OpError::invalid(format!(
                "disparity is {w} x {h} px but the rectification is {} x {} px",
                rect.size.0, rect.size.1
            )));
        }
        let (near, far) = (self.min_depth_mm, self.max_depth_mm);
        if near >= far {
            return Err(OpError::invalid(format!(
                "min_depth_mm ({near}) must be below max_depth_mm ({far})"
            )));
        }
        let image = inputs.image;
        if let Some(img) = &image
            && (img.width, img.height) != (w, h)
        {
            return Err(OpError::invalid(format!(
                "image is {} x {} px but the disparity is {w} x {h} px",
                img.width, img.height
            )));
        }
        let points = triangulate_disparity(&disparity.data, w, &rect, near, far);
        let xyz: Vec<f32> = points
            .iter()
            .flat_map(|(_, p)| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let colors = image.map(|img| {
            let rgb = |i: usize, c: usize| -> u8 {
                let k = if img.channels == 3 { 3 * i + c } else { i };
                match &img.pixels {
                    Pixels::U8(p) => p[k],
                    Pixels::F32(p) => (p[k] * 255.0).round().clamp(0.0, 255.0) as u8,
                }
            };
            points
                .iter()
                .flat_map(|&(i, _)| [rgb(i, 0), rgb(i, 1), rgb(i, 2)])
                .collect::<Vec<u8>>()
                .into()
        });
        let valid = disparity.data.iter().filter(|d| !d.is_nan()).count();
        ctx.metric("points", points.len() as f64);
        ctx.metric(
            "in_range_pct",
            100.0 * points.len() as f64 / valid.max(1) as f64,
        );
        let cloud = PointCloud::new(xyz, colors, None, "camera_left").map_err(shape_error)?;
        Ok(TriangulateOutputs { cloud })
    }
}
