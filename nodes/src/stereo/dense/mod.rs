//! Dense matching of a rectified grey pair: matching costs (census,
//! Birchfield-Tomasi), semi-global aggregation or local block matching, the
//! selection of one disparity per pixel, and the filters after it (speckles,
//! texture, intensity refinement, confidence-aware filling and smoothing).
//!
//! Layers, each importing only those below it: [`simd`] (the kernels, run
//! with the CPU's best instruction set), `pair` (the checked pair and
//! disparity range), `volume` (the cost layout), `cost` and `select`,
//! `sgm` and `block_match`, and `sgm_disparity` (the whole SGM pipeline).

mod block_match;
mod cost;
mod figure;
mod fill;
mod filter;
mod pair;
mod refine;
mod select;
mod sgm;
mod sgm_disparity;
mod simd;
mod slanted;
mod texture;
mod volume;
mod window_sums;

pub use block_match::{BlockCost, block_match};
pub use cost::{CensusCosts, bt_costs, census_costs, census_transform, check_census_window};
pub(crate) use figure::disparity_figure_png;
pub use fill::{FillParams, fill_disparity};
pub use filter::filter_speckles;
pub use pair::{DisparityRange, GreyImage, check_pair};
pub use refine::{MAX_SIDE, RefineParams, refine_disparity};
pub use select::{SelectParams, select};
pub use sgm::{Aggregated, Paths, SgmParams, aggregate, check_penalties};
pub use sgm_disparity::{MatchCost, SgmConfig, check_bt_window, sgm_disparity, speckle_size_px};
pub use simd::Isa;
pub use slanted::{SlantedParams, WindowShape, refine_slanted};
pub use texture::{flat_windows, noise_sigma, pair_noise_dn};
pub use volume::{CostRows, CostVolume};
