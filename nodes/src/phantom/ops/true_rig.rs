//! `phantom.true_rig`: the stereo rig the phantom was rendered with.

use super::TruthInput;
use crate::calib::stereo_rig_value;
use crate::phantom::load_truth;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::StereoRig;

/// The stereo rig the phantom's images were rendered with (cameras and R, T):
/// in place of the calibrated one, an ablation without calibration error
#[derive(Debug, Clone, PartialEq, Op)]
// 2: the truth file's numbers read exactly as written (they were read to within
// an ulp or so).
#[op(name = "phantom.true_rig", version = 2)]
pub struct TrueRig;

/// The output of `phantom.true_rig`.
#[derive(Outputs)]
pub struct TrueRigOutputs {
    /// The true cameras (px) and R, T (left -> right camera frame, mm)
    pub rig: StereoRig,
}

impl RunOp for TrueRig {
    type Inputs = TruthInput;
    type Outputs = TrueRigOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let truth = load_truth(&inputs.truth)?;
        let rig = &truth.rig;
        ctx.metric("baseline_mm", rig.baseline_mm);
        Ok(TrueRigOutputs {
            rig: stereo_rig_value(&rig.left, &rig.right, &rig.left_to_right),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::ops::truth_file;

    #[test]
    fn the_rig_is_the_truths() {
        let (truth, file) = truth_file("true_rig");
        let mut ctx = RunCtx::new("rig", &std::env::temp_dir());
        let out = TrueRig
            .run(
                TruthInput {
                    truth: file.clone(),
                },
                &mut ctx,
            )
            .unwrap();
        // The truth as written to its file and read back: the same bits
        // (JSON keeps 17 digits, read exactly with float_roundtrip).
        let close = |a: f64, b: f64| a == b;
        let m = truth.rig.left_to_right;
        for (r, row) in m.iter().take(3).enumerate() {
            assert!(close(out.rig.translation_mm[r], row[3]), "{r}");
            for (c, &v) in row.iter().take(3).enumerate() {
                assert!(close(out.rig.rotation[r][c], v), "{r} {c}");
            }
        }
        let (k, truth_k) = (out.rig.left.k, truth.rig.left.to_value().k);
        assert!((0..3).all(|r| (0..3).all(|c| close(k[r][c], truth_k[r][c]))));
        let b = out
            .rig
            .translation_mm
            .iter()
            .map(|t| t * t)
            .sum::<f64>()
            .sqrt();
        assert!((b - ctx.metrics()["baseline_mm"]).abs() < 1e-9);
        std::fs::remove_file(&file.path).unwrap();
    }
}
