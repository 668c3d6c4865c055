//! `stereo.features`: keypoints and descriptors of one image.

use crate::io::grey_of;
use crate::stereo::features::{FastParams, HessianParams, detect_fast, detect_hessian};
use crate::stereo::features_to_table;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Image, Table};

/// Keypoints with descriptors of a (rectified) image: SURF-style Hessian or
/// FAST + BRIEF
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.features", version = 1)]
pub struct Features {
    /// hessian: SURF-style blobs, 64-float descriptors; fast: FAST-9
    /// corners, 256-bit BRIEF
    #[param(default = Detector::Hessian)]
    pub detector: Detector,
    /// Keep at most this many, strongest first, spread over an up to 8 x 8
    /// grid
    #[param(default = 4000, min = 1)]
    pub max_features: usize,
    /// hessian: smallest scale-normalised Hessian determinant (grey 0..1)
    // The detector's threshold is an f32: its default as an f32.
    #[param(default = 1e-4_f32 as f64, min = 0.0)]
    pub hessian_threshold: f64,
    /// fast: segment-test contrast on grey 0..1
    #[param(default = 0.04_f32 as f64, min = 1e-4, max = 1.0)]
    pub fast_threshold: f64,
    /// No orientation (angle 0): right for rectified pairs, and faster
    #[param(default = true)]
    pub upright: bool,
    /// hessian: filter-size octaves (9-27 px, doubling); fast: pyramid
    /// levels (halving)
    #[param(default = 4, min = 1, max = 6)]
    pub octaves: usize,
}

/// The keypoint detector of `stereo.features`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum Detector {
    /// SURF-style Fast-Hessian blobs with 64-float descriptors.
    Hessian,
    /// FAST-9 corners with 256-bit steered BRIEF descriptors.
    Fast,
}

/// The input of `stereo.features`.
#[derive(Inputs)]
pub struct FeaturesInputs {
    /// Rectified image (grey or RGB)
    pub image: Arc<Image>,
}

/// The output of `stereo.features`.
#[derive(Outputs)]
pub struct FeaturesOutputs {
    /// x_px, y_px, size_px, angle_deg, response, laplacian_sign, then
    /// d00..d63 or w0..w7
    pub features: Table,
}

impl Features {
    /// The Hessian detector's settings.
    pub fn hessian(&self) -> HessianParams {
        HessianParams {
            threshold: self.hessian_threshold as f32,
            octaves: self.octaves,
            upright: self.upright,
            max_features: self.max_features,
        }
    }

    /// The FAST detector's settings.
    pub fn fast(&self) -> FastParams {
        FastParams {
            threshold: self.fast_threshold as f32,
            octaves: self.octaves,
            upright: self.upright,
            max_features: self.max_features,
        }
    }
}

impl RunOp for Features {
    type Inputs = FeaturesInputs;
    type Outputs = FeaturesOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let image = inputs.image;
        let grey = grey_of(&image);
        let (w, h) = (image.width, image.height);
        let features = match self.detector {
            Detector::Fast => detect_fast(&grey, w, h, &self.fast()),
            Detector::Hessian => detect_hessian(&grey, w, h, &self.hessian()),
        }
        .map_err(|e| OpError::invalid(format!("input `image`: {e}")))?;
        ctx.metric("count", features.keypoints.len() as f64);
        Ok(FeaturesOutputs {
            features: features_to_table(&features),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::defaults;
    use super::*;

    #[test]
    fn the_thresholds_are_the_detectors_defaults() {
        let op: Features = defaults();
        assert_eq!(op.hessian().threshold, HessianParams::default().threshold);
        assert_eq!(op.fast().threshold, FastParams::default().threshold);
    }
}
