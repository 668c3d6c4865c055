//! `register.procrustes`: the similarity between corresponding markers.

use crate::register::convert::{marker_points, similarity_value};
use crate::register::umeyama;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Markers, Transform};

/// Least-squares similarity (Umeyama) between corresponding markers
#[derive(Op)]
#[op(name = "register.procrustes", version = 1)]
pub struct Procrustes {
    /// Estimate a uniform scale (false: exactly 1)
    #[param(default = false)]
    pub scale: bool,
}

#[derive(Inputs)]
pub struct ProcrustesInputs {
    /// Source markers
    pub source: Arc<Markers>,
    /// Target markers, same order
    pub target: Arc<Markers>,
}

#[derive(Outputs)]
pub struct ProcrustesOutputs {
    /// Source frame -> target frame
    pub transform: Transform,
}

impl RunOp for Procrustes {
    type Inputs = ProcrustesInputs;
    type Outputs = ProcrustesOutputs;

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (s, t) = (inputs.source, inputs.target);
        let (sp, tp) = (marker_points(&s), marker_points(&t));
        if sp.len() != tp.len() {
            return Err(OpError::invalid(format!(
                "{} source vs {} target markers: they must correspond one to one",
                sp.len(),
                tp.len()
            )));
        }
        let sim = umeyama(&sp, &tp, None, self.scale)
            .ok_or_else(|| OpError::invalid("fewer than 3 markers, or all on one line"))?;
        ctx.metric("rmse_mm", sim.rmse(&sp, &tp));
        ctx.metric("scale", sim.scale);
        Ok(ProcrustesOutputs {
            transform: similarity_value(&sim, &s.frame, &t.frame),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn markers(positions: &[[f64; 3]], frame: &str) -> Arc<Markers> {
        let ids: Vec<u32> = (0..positions.len() as u32).collect();
        Arc::new(Markers::new(positions.concat(), ids, frame).unwrap())
    }

    #[test]
    fn the_transform_maps_the_source_frame_onto_the_target_frame() {
        let src = [
            [0.0, 0.0, 0.0],
            [30.0, 0.0, 0.0],
            [0.0, 20.0, 0.0],
            [0.0, 0.0, 10.0],
        ];
        let dst: Vec<[f64; 3]> = src.iter().map(|p| [p[0] + 5.0, p[1], p[2] - 2.0]).collect();
        let mut ctx = RunCtx::new("fit", &std::env::temp_dir());
        let inputs = ProcrustesInputs {
            source: markers(&src, "camera_left"),
            target: markers(&dst, "mri_lps"),
        };
        let t = Procrustes { scale: false }
            .run(inputs, &mut ctx)
            .unwrap()
            .transform;
        assert_eq!((t.from.as_str(), t.to.as_str()), ("camera_left", "mri_lps"));
        assert!((t.matrix[0][3] - 5.0).abs() < 1e-9 && (t.matrix[2][3] + 2.0).abs() < 1e-9);
        assert!(ctx.metrics()["rmse_mm"] < 1e-9);
        assert_eq!(ctx.metrics()["scale"], 1.0);
        let inputs = ProcrustesInputs {
            source: markers(&src, "camera_left"),
            target: markers(&dst[..3], "mri_lps"),
        };
        let e = Procrustes { scale: false }
            .run(inputs, &mut ctx)
            .map(|_| ())
            .unwrap_err();
        assert!(
            e.to_string().contains("4 source vs 3 target markers"),
            "{e}"
        );
    }
}
