//! What `stereo.sgm` and `stereo.block_match` share: the pair and the optional
//! disparity range they take, the selection and filter parameters (a group
//! flattened into both), and the disparity map they give.

use super::shape_error;
use crate::stereo::dense::disparity_figure_png;
use crate::stereo::{DisparityRange, GreyImage, RefineParams, SelectParams, check_pair};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Disparity, Image};

/// The parameters of both dense matchers (declared first in each).
#[derive(Debug, Clone, PartialEq, Params)]
pub struct MatcherParams {
    /// Smallest disparity searched when the input is not connected
    #[param(default = 0, unit = "px")]
    pub min_disparity_px: i64,
    /// Largest disparity searched when the input is not connected
    #[param(default = 63, unit = "px")]
    pub max_disparity_px: i64,
    /// Invalid when another disparity (beyond +-1) costs less than best x
    /// (1 + this/100); 0 = off
    #[param(default = 10.0, unit = "%", min = 0.0, max = 100.0)]
    pub uniqueness_pct: f64,
    /// Left-right check: largest difference from the right image's
    /// disparity; negative = off
    #[param(default = 1.0, unit = "px")]
    pub lr_max_diff_px: f64,
    /// Fit a parabola to the costs around the best disparity
    #[param(default = true)]
    pub subpixel: bool,
    /// intensity: then align the intensities along the row (Lucas-Kanade,
    /// +-1 px) for sub-pixel accuracy; none: keep the parabola
    #[param(default = Refine::Intensity)]
    pub refine: Refine,
    /// Window of the intensity refinement (odd)
    #[param(default = 9, unit = "px", min = 3, max = 31)]
    pub refine_window_px: usize,
    /// Remove regions of similar disparity up to this share of the image
    /// area (0 = off)
    #[param(default = 0.08, unit = "%", min = 0.0, max = 100.0)]
    pub speckle_area_pct: f64,
    /// Largest step between neighbours inside one speckle region
    #[param(default = 2.0, unit = "px", min = 0.0)]
    pub speckle_range_px: f64,
}

/// Sub-pixel refinement after selection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum Refine {
    /// Align the intensities along the row (Lucas-Kanade, +-1 px).
    Intensity,
    /// Keep the cost parabola's sub-pixel values.
    None,
}

impl MatcherParams {
    /// The disparity range: the `min` and `max` inputs (px) where connected,
    /// else the parameters; for images `width` px wide.
    pub(crate) fn range(
        &self,
        min: Option<f64>,
        max: Option<f64>,
        width: usize,
    ) -> Result<DisparityRange, OpError> {
        let bound =
            |input: Option<f64>, port: &str, param: (&str, i64), round: fn(f64) -> f64| match input
            {
                Some(v) if v.is_finite() && v.abs() < 1e6 => Ok(round(v) as i32),
                Some(v) => Err(OpError::invalid(format!(
                    "input `{port}` is {v}, not a disparity"
                ))),
                None => i32::try_from(param.1).map_err(|_| {
                    OpError::invalid(format!("parameter `{}` is out of range", param.0))
                }),
            };
        let min = bound(
            min,
            "min_disparity",
            ("min_disparity_px", self.min_disparity_px),
            f64::floor,
        )?;
        let max = bound(
            max,
            "max_disparity",
            ("max_disparity_px", self.max_disparity_px),
            f64::ceil,
        )?;
        DisparityRange::new(min, max, width).map_err(OpError::invalid)
    }

    /// How disparities are chosen from the costs.
    pub(crate) fn select(&self) -> SelectParams {
        let lr = self.lr_max_diff_px;
        SelectParams {
            uniqueness_pct: self.uniqueness_pct,
            lr_max_diff_px: (lr >= 0.0).then_some(lr),
            subpixel: self.subpixel,
        }
    }

    /// What [`MatcherParams::refine`] would refuse, at validation.
    pub(crate) fn check(&self) -> Vec<(&'static str, String)> {
        self.even_refine_window()
            .map(|m| ("refine_window_px", m))
            .into_iter()
            .collect()
    }

    fn even_refine_window(&self) -> Option<String> {
        let window = self.refine_window_px;
        (self.refine != Refine::None && window.is_multiple_of(2))
            .then(|| format!("refine_window_px = {window}: must be odd"))
    }

    /// The intensity refinement, `None` when off; an even window is an error.
    pub(crate) fn refine(&self) -> Result<Option<RefineParams>, OpError> {
        if self.refine == Refine::None {
            return Ok(None);
        }
        if let Some(m) = self.even_refine_window() {
            return Err(OpError::invalid(m));
        }
        let window = self.refine_window_px;
        Ok(Some(RefineParams {
            half_window: window / 2,
            iterations: 2,
            max_change_px: 1.0,
        }))
    }
}

/// The inputs of both dense matchers.
#[derive(Inputs)]
pub struct MatcherInputs {
    /// Left rectified image
    pub left: Arc<Image>,
    /// Right rectified image (same size)
    pub right: Arc<Image>,
    /// Smallest disparity, px (e.g. from stereo.disparity_range; else the
    /// parameter)
    pub min_disparity: Option<f64>,
    /// Largest disparity, px (else the parameter)
    pub max_disparity: Option<f64>,
}

impl MatcherInputs {
    /// The pair as grey images, checked.
    pub(crate) fn grey_pair(&self) -> Result<(GreyImage, GreyImage), OpError> {
        let (l, r) = (
            GreyImage::from_image(&self.left),
            GreyImage::from_image(&self.right),
        );
        check_pair(&l, &r).map_err(OpError::invalid)?;
        Ok((l, r))
    }
}

/// The output of both dense matchers.
#[derive(Outputs)]
pub struct DisparityOutputs {
    /// x_left - x_right on the left image, px (NaN = invalid)
    pub disparity: Disparity,
}

impl DisparityOutputs {
    /// The disparity map `data` (`width x height` px) with its coverage and
    /// range as metrics and its picture as a figure.
    pub(crate) fn new(
        data: Vec<f32>,
        width: usize,
        height: usize,
        range: DisparityRange,
        ctx: &mut RunCtx,
    ) -> Result<Self, OpError> {
        let valid = data.iter().filter(|d| !d.is_nan()).count();
        ctx.metric(
            "coverage_pct",
            100.0 * valid as f64 / data.len().max(1) as f64,
        );
        ctx.metric("min_disparity_px", range.min_px as f64);
        ctx.metric("max_disparity_px", range.max_px() as f64);
        let disparity = Disparity::new(width, height, data).map_err(shape_error)?;
        if let Some(png) = disparity_figure_png(&disparity) {
            ctx.figure(
                "disparity",
                "Disparity on the left rectified image, px (black: invalid)",
                FigureData::Png(png),
            )?;
        }
        Ok(DisparityOutputs { disparity })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::defaults;
    use super::*;
    use crate::stereo::SgmConfig;

    #[test]
    fn the_defaults_are_sgm_config_defaults() {
        let p: MatcherParams = defaults();
        let d = SgmConfig::default();
        assert_eq!(p.select(), d.select);
        assert_eq!(p.refine().unwrap(), d.refine);
        assert_eq!(p.speckle_area_pct, d.speckle_area_pct);
        assert_eq!(p.speckle_range_px as f32, d.speckle_range_px);
    }

    #[test]
    fn inputs_override_the_range_parameters() {
        let p: MatcherParams = defaults();
        let r = p.range(Some(-3.5), Some(20.2), 100).unwrap();
        assert_eq!((r.min_px, r.max_px()), (-4, 21));
        let r = p.range(None, None, 100).unwrap();
        assert_eq!((r.min_px, r.max_px()), (0, 63));
        let e = p.range(Some(f64::NAN), None, 100).unwrap_err();
        assert!(
            e.to_string().contains("input `min_disparity` is NaN"),
            "{e}"
        );
        let far = MatcherParams {
            max_disparity_px: 1 << 40,
            ..p.clone()
        };
        let e = far.range(None, None, 100).unwrap_err();
        assert!(
            e.to_string().contains("`max_disparity_px` is out of range"),
            "{e}"
        );
        let even = MatcherParams {
            refine_window_px: 8,
            ..p
        };
        assert!(
            even.refine()
                .unwrap_err()
                .to_string()
                .contains("must be odd")
        );
    }
}
