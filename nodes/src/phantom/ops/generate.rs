//! `phantom.generate`: a synthetic phantom and everything imaged of it.

use crate::phantom::{Conditions, PhantomConfig, PhantomSize, ShapeParams, generate};
use fusegraph_engine::path_value;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::PathValue;

/// Synthetic breast phantom: MRI DICOM series, stereo calibration and phantom
/// images, ground truth
#[derive(Debug, Clone, PartialEq, Op)]
// 6: the full phantom's views take one ray where only texture differs from
// the neighbours (edges are still supersampled): other pixels.
#[op(name = "phantom.generate", version = 6)]
pub struct Generate {
    /// Seed of every random choice
    #[param(default = 1, min = 0)]
    pub seed: u64,
    /// full: 0.6 x 0.6 x 1.0 mm voxels, full anti-aliasing; small: 1.5 mm
    /// voxels, for fast tests
    #[param(default = PhantomSize::Full)]
    pub size: PhantomSize,
    /// The dome, markers and lesions.
    #[param(flatten)]
    pub shape: ShapeParams,
    /// Tilt of the MRI slices from axial
    #[param(default = 0.0, unit = "deg", min = -45.0, max = 45.0)]
    pub oblique_deg: f64,
    /// MRI noise sigma (tissue signal 0.55)
    #[param(default = 0.02, min = 0.0, max = 0.3)]
    pub mri_noise: f64,
    /// Usable calibration pairs (3 unusable are added)
    #[param(default = 18, min = 3, max = 60)]
    pub calibration_pairs: usize,
    /// Phantom view pairs
    #[param(default = 6, min = 1, max = 24)]
    pub views: usize,
    /// The camera session's acquisition conditions.
    #[param(flatten)]
    pub conditions: Conditions,
    /// Seed of the cameras' sensor noise alone (0: from seed): the same
    /// scene, poses and textures photographed again with another noise
    /// realisation, to see how much of a figure's change is noise
    #[param(default = 0, min = 0)]
    pub sensor_seed: u64,
}

/// `phantom.generate` takes no inputs.
#[derive(Inputs)]
pub struct GenerateInputs;

/// The outputs of `phantom.generate`.
#[derive(Outputs)]
pub struct GenerateOutputs {
    /// Folder of DICOM slices (shuffled file order)
    pub mri_dir: PathValue,
    /// Folder of chessboard pairs left_NN / right_NN (.png, or .jpg with
    /// jpeg_quality)
    pub calib_dir: PathValue,
    /// Folder of phantom pairs left_NN / right_NN (.png, or .jpg with
    /// jpeg_quality)
    pub views_dir: PathValue,
    /// ground_truth.json (schema fusegraph-phantom/1)
    pub truth: PathValue,
}

impl Generate {
    /// The phantom these parameters describe.
    pub fn config(&self) -> PhantomConfig {
        PhantomConfig {
            seed: self.seed,
            size: self.size,
            shape: self.shape.clone(),
            oblique_deg: self.oblique_deg,
            mri_noise_sigma: self.mri_noise,
            calibration_pairs: self.calibration_pairs,
            views: self.views,
            conditions: self.conditions.clone(),
            sensor_seed: (self.sensor_seed != 0).then_some(self.sensor_seed),
        }
    }
}

impl RunOp for Generate {
    type Inputs = GenerateInputs;
    type Outputs = GenerateOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        self.conditions.resolved().problems()
    }

    fn run(&self, _: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let dir = ctx.work_dir()?;
        let g = generate(&self.config(), &dir).map_err(OpError::invalid)?;
        ctx.metric("markers", g.truth.markers.len() as f64);
        ctx.metric("lesions", g.truth.lesions.len() as f64);
        ctx.metric("mri_slices", g.truth.mri.files as f64);
        ctx.metric("calibration_pairs", g.truth.calibration.len() as f64);
        ctx.metric("views", g.truth.views.len() as f64);
        ctx.metric("mri_ms", g.stage_ms[0]);
        ctx.metric("calibration_ms", g.stage_ms[1]);
        ctx.metric("views_ms", g.stage_ms[2]);
        Ok(GenerateOutputs {
            mri_dir: path_value(&g.mri_dir)?,
            calib_dir: path_value(&g.calib_dir)?,
            views_dir: path_value(&g.views_dir)?,
            truth: path_value(&g.truth_file)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::typed::declared_defaults;

    #[test]
    fn the_defaults_are_the_generators_defaults() {
        let op: Generate = declared_defaults().unwrap();
        assert_eq!(op.config(), PhantomConfig::default());
    }
}
