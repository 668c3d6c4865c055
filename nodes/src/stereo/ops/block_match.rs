//! `stereo.block_match`: local block matching of a rectified pair.

use super::matcher::{DisparityOutputs, MatcherInputs, MatcherParams};
use crate::stereo::{BlockCost, block_match, filter_speckles, refine_disparity, speckle_size_px};
use fusegraph_engine::typed::prelude::*;

/// Local block matching (SAD, ZNCC or census over a window) -> Disparity
#[derive(Debug, Clone, PartialEq, Op)]
#[op(name = "stereo.block_match", version = 4)]
pub struct BlockMatch {
    /// Range, selection and filters, as `stereo.sgm`.
    #[param(flatten)]
    pub matcher: MatcherParams,
    /// zncc: 1 - zero-mean normalised cross-correlation; sad: absolute
    /// differences; census: summed 5 x 5 census Hamming distances
    #[param(default = BlockCost::Zncc)]
    pub cost: BlockCost,
    /// Window side (odd)
    #[param(default = 9, unit = "px", min = 1, max = 51)]
    pub window: usize,
}

impl BlockMatch {
    fn even_window(&self) -> Option<String> {
        let window = self.window;
        window
            .is_multiple_of(2)
            .then(|| format!("window = {window}: must be odd"))
    }
}

impl RunOp for BlockMatch {
    type Inputs = MatcherInputs;
    type Outputs = DisparityOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        let mut problems = self.matcher.check();
        problems.extend(self.even_window().map(|m| ("window", m)));
        problems
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (left, right) = inputs.grey_pair()?;
        let m = &self.matcher;
        let range = m.range(inputs.min_disparity, inputs.max_disparity, left.width)?;
        if let Some(m) = self.even_window() {
            return Err(OpError::invalid(m));
        }
        let window = self.window;
        let refine = m.refine()?;
        let (w, h) = (left.width, left.height);
        let mut data = block_match(&left, &right, range, self.cost, window, &m.select());
        filter_speckles(
            &mut data,
            w,
            h,
            speckle_size_px(m.speckle_area_pct, w, h),
            m.speckle_range_px as f32,
        );
        if let Some(refine) = refine {
            refine_disparity(&left, &right, &mut data, &refine);
        }
        DisparityOutputs::new(data, w, h, range, ctx)
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{ctx, defaults};
    use super::*;
    use fusegraph_engine::value::{Image, Pixels};

    /// A random texture and the same texture moved left by `shift` px (a
    /// disparity of `shift` px), with the range 0..=15 px on the inputs.
    fn pair(w: usize, h: usize, shift: usize) -> MatcherInputs {
        let texture = |x: usize, y: usize| {
            // splitmix64 of the position: no structure to match but the shift.
            let mut z =
                (x as u64 * 7919 + y as u64 * 1_000_003).wrapping_add(0x9E37_79B9_7F4A_7C15);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 56) as u8
        };
        let image = |shift: usize| {
            let data: Vec<u8> = (0..w * h).map(|i| texture(i % w + shift, i / w)).collect();
            Arc::new(Image::new(w, h, 1, Pixels::U8(data.into())).unwrap())
        };
        MatcherInputs {
            left: image(0),
            right: image(shift),
            min_disparity: Some(0.0),
            max_disparity: Some(15.0),
        }
    }

    #[test]
    fn finds_a_uniform_shift_with_every_cost() {
        for cost in [BlockCost::Zncc, BlockCost::Sad, BlockCost::Census] {
            let op = BlockMatch { cost, ..defaults() };
            let out = op.run(pair(60, 24, 5), &mut ctx()).unwrap();
            let d = &out.disparity.data;
            let right = d.iter().filter(|v| (**v - 5.0).abs() < 0.25).count();
            assert!(right * 2 > d.len(), "{cost:?}: {right} of {}", d.len());
        }
        let even = BlockMatch {
            window: 8,
            ..defaults()
        };
        let e = even.run(pair(60, 24, 5), &mut ctx()).err().unwrap();
        assert!(e.to_string().contains("window = 8: must be odd"), "{e}");
    }
}
