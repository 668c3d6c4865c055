//! `stereo.sgm`: semi-global matching of a rectified pair.

use super::matcher::{DisparityOutputs, MatcherInputs, MatcherParams};
use crate::stereo::{
    MatchCost, Paths, SgmConfig, SgmParams, check_bt_window, check_census_window, check_penalties,
    sgm_disparity,
};
use fusegraph_engine::typed::prelude::*;

/// Semi-global matching (census or Birchfield-Tomasi costs, 5 paths in one
/// pass, or 4 or 8 in two) -> Disparity
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.sgm", version = 7)]
pub struct Sgm {
    /// Range, selection and filters, as `stereo.block_match`.
    #[param(flatten)]
    pub matcher: MatcherParams,
    /// census: Hamming distance of census codes (robust to exposure, JPEG);
    /// bt: Birchfield-Tomasi grey difference
    #[param(default = SgmCost::Census)]
    pub cost: SgmCost,
    /// Census window width, height (odd; area <= 65)
    #[param(default = [9, 7], unit = "px", min = 1, max = 65)]
    pub census_window: [usize; 2],
    /// Window the BT cost is averaged over (odd)
    #[param(default = 5, unit = "px", min = 1, max = 31)]
    pub bt_window: usize,
    /// Aggregation paths: 5 = one top-down pass (both horizontals, down, the
    /// two downward diagonals; fastest, no stored volume); 4 or 8 = two
    /// passes (8 adds the upward paths and diagonals)
    #[param(default = 5, min = 4, max = 8)]
    pub paths: i64,
    /// Penalty for a 1 px disparity step between neighbours
    #[param(default = 8, unit = "cost", min = 1, max = 3999)]
    pub p1: u16,
    /// Penalty for a larger disparity jump (> p1)
    #[param(default = 80, unit = "cost", min = 2, max = 4000)]
    pub p2: u16,
    /// P2 falls to P2 gamma / (gamma + |dI|) across an intensity step dI
    /// (0 = constant P2)
    #[param(default = 8.0, unit = "grey levels", min = 0.0)]
    pub p2_gamma: f64,
    /// Invalid where the cost window's grey-level spread is below this
    /// multiple of the image noise (estimated from the image; 0 = off)
    #[param(default = 0.0, min = 0.0)]
    pub min_texture_snr: f64,
    /// Census on a noisy pair: measure its noise from the residual at the
    /// first matches and, above about 2.5 grey levels, match again with both
    /// images smoothed by the Gaussian that brings it to 1 grey level (at
    /// most 2 px); clean pairs are matched once, as they are
    #[param(default = true)]
    pub denoise: bool,
    /// Refuse when the cost volumes would need more memory than this
    #[param(default = 4096, unit = "MB", min = 1)]
    pub max_memory_mb: usize,
}

/// The pixel matching cost of `stereo.sgm`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Choice)]
pub enum SgmCost {
    /// Census transform over `census_window`, Hamming distance.
    Census,
    /// Birchfield-Tomasi grey difference averaged over `bt_window`.
    Bt,
}

impl Sgm {
    /// The matcher's settings.
    pub fn config(&self) -> Result<SgmConfig, OpError> {
        let cost = match self.cost {
            SgmCost::Census => MatchCost::Census {
                width: self.census_window[0],
                height: self.census_window[1],
            },
            SgmCost::Bt => MatchCost::BirchfieldTomasi {
                window: self.bt_window,
            },
        };
        let paths = Paths::from_count(self.paths).map_err(OpError::invalid)?;
        let m = &self.matcher;
        Ok(SgmConfig {
            cost,
            sgm: SgmParams {
                p1: self.p1,
                p2: self.p2,
                paths,
                p2_gamma: self.p2_gamma as f32,
            },
            select: m.select(),
            speckle_area_pct: m.speckle_area_pct,
            speckle_range_px: m.speckle_range_px as f32,
            max_memory_mb: self.max_memory_mb,
            refine: m.refine()?,
            min_texture_snr: self.min_texture_snr,
            denoise: self.denoise,
        })
    }
}

impl RunOp for Sgm {
    type Inputs = MatcherInputs;
    type Outputs = DisparityOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        let mut problems = self.matcher.check();
        let window = match self.cost {
            SgmCost::Census => {
                let [w, h] = self.census_window;
                check_census_window(w, h).map_err(|e| ("census_window", e))
            }
            SgmCost::Bt => check_bt_window(self.bt_window).map_err(|e| ("bt_window", e)),
        };
        problems.extend(window.err());
        problems.extend(Paths::from_count(self.paths).err().map(|e| ("paths", e)));
        problems.extend(check_penalties(self.p1, self.p2).err().map(|e| ("p2", e)));
        problems
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (left, right) = inputs.grey_pair()?;
        let range = self
            .matcher
            .range(inputs.min_disparity, inputs.max_disparity, left.width)?;
        let config = self.config()?;
        let data = sgm_disparity(&left, &right, range, &config).map_err(OpError::invalid)?;
        DisparityOutputs::new(data, left.width, left.height, range, ctx)
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{ctx, defaults};
    use super::*;
    use fusegraph_engine::value::{Image, Pixels};

    fn grey(w: usize, h: usize) -> Arc<Image> {
        let data: Vec<u8> = (0..w * h).map(|i| (i * 37 % 251) as u8).collect();
        Arc::new(Image::new(w, h, 1, Pixels::U8(data.into())).unwrap())
    }

    fn run_sgm(
        left: Arc<Image>,
        right: Arc<Image>,
        min_disparity_px: i64,
        max_disparity_px: i64,
    ) -> Result<DisparityOutputs, OpError> {
        let mut op: Sgm = defaults();
        op.matcher.min_disparity_px = min_disparity_px;
        op.matcher.max_disparity_px = max_disparity_px;
        let inputs = MatcherInputs {
            left,
            right,
            min_disparity: None,
            max_disparity: None,
        };
        op.run(inputs, &mut ctx())
    }

    #[test]
    fn the_defaults_are_sgm_config_defaults() {
        let op: Sgm = defaults();
        assert_eq!(op.config().unwrap(), SgmConfig::default());
    }

    #[test]
    fn bad_input_gets_a_clear_error() {
        let e = run_sgm(grey(40, 30), grey(40, 31), 0, 63)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("differ in size"), "{e}");
        let e = run_sgm(grey(40, 30), grey(40, 30), 20, 10)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("empty disparity range"), "{e}");
        let e = run_sgm(grey(40, 30), grey(40, 30), 0, 63)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("wider than the image"), "{e}");
        let out = run_sgm(grey(40, 30), grey(40, 30), 0, 15).unwrap();
        assert_eq!((out.disparity.width, out.disparity.height), (40, 30));
    }
}
