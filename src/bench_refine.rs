//! `fusegraph bench refine`: `stereo.refine_slanted` timed, and measured
//! against the truth, on the maps the main job gives it: each pair matched
//! by `stereo.sgm`'s defaults and filled and smoothed by
//! `stereo.fill_disparity` with graphs/fusion.toml's `min_support = 1`.

use crate::bench_sgm::SgmCase;
use fusegraph_engine::typed::declared_defaults;
use fusegraph_nodes::eval::disparity_errors;
use fusegraph_nodes::stereo::ops::{FillDisparity, RefineSlanted};
use fusegraph_nodes::stereo::{SgmConfig, fill_disparity, refine_slanted, sgm_disparity};
use std::time::Instant;

/// Parameters of the refinement that differ from its declared defaults.
#[derive(Debug, Default, Clone, Copy)]
pub struct Overrides {
    /// `iterations`.
    pub iterations: Option<usize>,
    /// `max_window_px`.
    pub max_window_px: Option<usize>,
}

/// Times the refinement on every case (best of `repeat`) and prints one
/// line each: time, share of values refined, and bad-1 / bad-2 / MAE before
/// and after it (against the truth, where the case has one).
pub fn run(cases: &[SgmCase], repeat: usize, overrides: Overrides) -> anyhow::Result<()> {
    let mut refine: RefineSlanted =
        declared_defaults().ok_or_else(|| anyhow::anyhow!("refine_slanted has no defaults"))?;
    if let Some(n) = overrides.iterations {
        refine.iterations = n;
    }
    if let Some(px) = overrides.max_window_px {
        refine.max_window_px = px;
    }
    let params = refine.params().map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut fill: FillDisparity =
        declared_defaults().ok_or_else(|| anyhow::anyhow!("fill_disparity has no defaults"))?;
    fill.min_support = 1.0;
    println!(
        "bench refine: stereo.refine_slanted ({params:?}) on stereo.sgm + \
         stereo.fill_disparity maps, best of {repeat}, {} threads",
        rayon::current_num_threads()
    );
    for case in cases {
        let (l, r, range) = case.grey_pair()?;
        let mut smoothed =
            sgm_disparity(&l, &r, range, &SgmConfig::default()).map_err(anyhow::Error::msg)?;
        fill_disparity(&mut smoothed, &l, &fill.params());
        let mut best = f64::MAX;
        let (mut refined, mut changed) = (Vec::new(), 0);
        for _ in 0..repeat.max(1) {
            let t = Instant::now();
            (refined, changed) = refine_slanted(&l, &r, &smoothed, &params);
            best = best.min(t.elapsed().as_secs_f64());
        }
        let valid = refined.iter().filter(|d| !d.is_nan()).count().max(1);
        let mut line = format!(
            "  {}: {:.1} ms, {:.1} % refined",
            case.name,
            best * 1e3,
            100.0 * changed as f64 / valid as f64
        );
        if let Some(truth) = &case.truth {
            for (name, map) in [("before", &smoothed), ("after", &refined)] {
                let e =
                    disparity_errors(map, truth, None, &[1.0, 2.0]).map_err(anyhow::Error::msg)?;
                line += &format!(
                    "; {name}: bad1.0 {:.3}%, bad2.0 {:.3}%, MAE {:.4} px",
                    e.bad_pct[0], e.bad_pct[1], e.mae_px
                );
            }
        }
        println!("{line}");
    }
    Ok(())
}
