//! `stereo.fill_disparity`: confidence-aware, edge-aware filling and
//! smoothing of any matcher's disparity map.

use super::shape_error;
use crate::stereo::dense::disparity_figure_png;
use crate::stereo::{FillParams, GreyImage, fill_disparity};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Disparity, Image};

/// Holes filled and noise smoothed from valid neighbours on the same
/// surface (normalised convolution, edge-aware along the left image and the
/// disparities' own steps) -> Disparity
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.fill_disparity", version = 2)]
pub struct FillDisparity {
    /// Reach of the filter (its standard deviation on an edge-free image)
    #[param(default = 16.0, unit = "px", min = 0.001, max = 1000.0)]
    pub sigma_px: f64,
    /// A grey-level step of the left image this large stops the filter as
    /// much as sigma_px of distance
    #[param(default = 32.0, unit = "grey levels", min = 0.001)]
    pub sigma_grey: f64,
    /// A disparity step between valid neighbours this large stops the
    /// filter as much as sigma_px of distance
    #[param(default = 2.0, unit = "px", min = 0.001)]
    pub sigma_disparity_px: f64,
    /// A hole is filled where valid pixels carry at least this share of the
    /// filter's weight (1: no hole is filled, only smoothing)
    #[param(default = 0.5, min = 0.0, max = 1.0)]
    pub min_support: f64,
    /// Valid disparities take the filtered value too (smoothing), unless it
    /// would move them by more than sigma_disparity_px
    #[param(default = true)]
    pub smooth: bool,
}

#[derive(Inputs)]
pub struct FillDisparityInputs {
    /// Disparity of the left rectified image, px (NaN = invalid)
    pub disparity: Arc<Disparity>,
    /// The left rectified image it belongs to (its edges guide the filter)
    pub image: Arc<Image>,
}

#[derive(Outputs)]
pub struct FillDisparityOutputs {
    /// The filled and smoothed disparity, px (NaN = still invalid)
    pub disparity: Disparity,
}

impl FillDisparity {
    /// The filter's settings.
    pub fn params(&self) -> FillParams {
        FillParams {
            sigma_px: self.sigma_px as f32,
            sigma_grey: self.sigma_grey as f32,
            sigma_disparity_px: self.sigma_disparity_px as f32,
            min_support: self.min_support as f32,
            smooth: self.smooth,
        }
    }
}

impl RunOp for FillDisparity {
    type Inputs = FillDisparityInputs;
    type Outputs = FillDisparityOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (d, img) = (&inputs.disparity, &inputs.image);
        if (d.width, d.height) != (img.width, img.height) {
            return Err(OpError::invalid(format!(
                "the disparity is {} x {} px and the image {} x {} px: give the left image the \
                 disparity was matched on",
                d.width, d.height, img.width, img.height
            )));
        }
        let guide = GreyImage::from_image(img);
        let mut data = d.data.to_vec();
        let before = data.iter().filter(|v| !v.is_nan()).count();
        let filled = fill_disparity(&mut data, &guide, &self.params());
        let n = data.len().max(1) as f64;
        ctx.metric("filled_pct", 100.0 * filled as f64 / n);
        ctx.metric("coverage_pct", 100.0 * (before + filled) as f64 / n);
        let disparity = Disparity::new(d.width, d.height, data).map_err(shape_error)?;
        if let Some(png) = disparity_figure_png(&disparity) {
            ctx.figure(
                "disparity",
                "Disparity after filling and smoothing, px (black: invalid)",
                FigureData::Png(png),
            )?;
        }
        Ok(FillDisparityOutputs { disparity })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{ctx, defaults};
    use super::*;
    use fusegraph_engine::value::Pixels;

    fn grey(w: usize, h: usize) -> Arc<Image> {
        Arc::new(Image::new(w, h, 1, Pixels::U8(vec![120u8; w * h].into())).unwrap())
    }

    #[test]
    fn fills_a_hole_and_reports_it() {
        let (w, h) = (40, 30);
        let mut data = vec![7.5f32; w * h];
        data[15 * w + 20] = f32::NAN;
        let inputs = FillDisparityInputs {
            disparity: Arc::new(Disparity::new(w, h, data).unwrap()),
            image: grey(w, h),
        };
        let op: FillDisparity = defaults();
        let mut c = ctx();
        let out = op.run(inputs, &mut c).unwrap();
        assert!((out.disparity.data[15 * w + 20] - 7.5).abs() < 1e-4);
        let m = c.into_metrics();
        assert_eq!(m["filled_pct"], 100.0 / (w * h) as f64);
        assert_eq!(m["coverage_pct"], 100.0);
    }

    #[test]
    fn a_disparity_of_another_image_is_refused() {
        let inputs = FillDisparityInputs {
            disparity: Arc::new(Disparity::new(40, 30, vec![1.0; 1200]).unwrap()),
            image: grey(41, 30),
        };
        let op: FillDisparity = defaults();
        let e = op.run(inputs, &mut ctx()).err().unwrap().to_string();
        assert!(e.contains("40 x 30 px and the image 41 x 30 px"), "{e}");
    }
}
