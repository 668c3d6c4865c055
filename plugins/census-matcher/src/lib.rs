//! An example fusegraph plugin: `census.match`, a stereo matcher (census
//! transform, box-aggregated Hamming costs, winner-takes-all, left-right
//! check, sub-pixel parabola). It takes the ports of the built-in matchers,
//! so a graph swaps it in by config alone:
//!
//! ```sh
//! cargo build --release -p census-matcher
//! fusegraph run graphs/stereo.toml --plugin target/release/libcensus_matcher.so \
//!     --set match.op=census.match
//! ```

pub mod census;

use census::{CensusParams, census_match};
use fusegraph_plugin_api::derive::{Inputs, Op, Outputs};
use fusegraph_plugin_api::{
    DisparityMap, ImageView, Outputs, PixelsView, Typed, TypedPluginOp, export_plugin,
};

/// Census transform + box-aggregated Hamming costs, winner-takes-all, left-right check -> Disparity
#[derive(Op)]
#[op(name = "census.match", version = 1)]
pub struct CensusMatch {
    /// Census window width, height (odd; area <= 64)
    #[param(default = [9, 7], unit = "px")]
    pub census_window_px: [i64; 2],
    /// Side of the window costs are summed over (odd)
    #[param(default = 7, unit = "px", min = 1, max = 51)]
    pub aggregate_px: i64,
    /// Lowest disparity when no input gives it
    #[param(default = 0, unit = "px")]
    pub min_disparity_px: i64,
    /// Highest disparity when no input gives it
    #[param(default = 64, unit = "px")]
    pub max_disparity_px: i64,
    /// Largest left-right disagreement kept (negative: no check)
    #[param(default = 1.0, unit = "px")]
    pub lr_max_diff_px: f64,
    /// The best cost must be this much below the second best
    #[param(default = 5.0, unit = "%", min = 0.0, max = 100.0)]
    pub uniqueness_pct: f64,
}

/// The ports of the built-in matchers.
#[derive(Inputs)]
pub struct CensusInputs<'a> {
    /// Left rectified image
    pub left: ImageView<'a>,
    /// Right rectified image, same size
    pub right: ImageView<'a>,
    /// Lowest disparity, px (overrides min_disparity_px)
    pub min_disparity: Option<f64>,
    /// Highest disparity, px (overrides max_disparity_px)
    pub max_disparity: Option<f64>,
}

/// The disparity map.
#[derive(Outputs)]
pub struct CensusOutputs {
    /// Disparity on the left rectified image, px (NaN: no match)
    pub disparity: DisparityMap,
}

/// Grey levels of an image (luma of RGB; floats taken as 0..=1).
pub fn grey(im: &ImageView) -> Vec<u8> {
    let level = |v: f32| (v * 255.0).round().clamp(0.0, 255.0) as u8;
    match (im.pixels, im.channels) {
        (PixelsView::U8(p), 1) => p.to_vec(),
        (PixelsView::U8(p), _) => p
            .chunks_exact(3)
            .map(|c| ((77 * c[0] as u32 + 150 * c[1] as u32 + 29 * c[2] as u32 + 128) >> 8) as u8)
            .collect(),
        (PixelsView::F32(p), 1) => p.iter().map(|&v| level(v)).collect(),
        (PixelsView::F32(p), _) => p
            .chunks_exact(3)
            .map(|c| level(0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]))
            .collect(),
    }
}

/// An odd window side in `1..=max`, or why not.
fn odd(name: &str, v: i64, max: i64) -> Result<usize, String> {
    if v < 1 || v > max || v % 2 == 0 {
        return Err(format!("{name} = {v}: must be odd, 1 to {max}"));
    }
    Ok(v as usize)
}

/// One end of the disparity range: the port's value, else the parameter's.
fn bound(port: &str, given: Option<f64>, param: i64, round: fn(f64) -> f64) -> Result<i32, String> {
    let v = given.unwrap_or(param as f64);
    if !v.is_finite() || v.abs() > 1e5 {
        return Err(format!("{port} = {v}: not a disparity"));
    }
    Ok(round(v) as i32)
}

impl TypedPluginOp for CensusMatch {
    type Inputs<'a> = CensusInputs<'a>;
    type Outputs = CensusOutputs;

    fn run(&self, inputs: CensusInputs<'_>, out: &mut Outputs) -> Result<CensusOutputs, String> {
        let (l, r) = (inputs.left, inputs.right);
        if (l.width, l.height) != (r.width, r.height) {
            return Err(format!(
                "left is {} x {} px, right {} x {} px: a rectified pair has one size",
                l.width, l.height, r.width, r.height
            ));
        }
        let window = self.census_window_px;
        let census = [
            odd("census width", window[0], 15)?,
            odd("census height", window[1], 15)?,
        ];
        if census[0] * census[1] > 64 {
            return Err(format!(
                "census window {} x {}: more than 64 bits",
                census[0], census[1]
            ));
        }
        let range = [
            bound(
                "min_disparity",
                inputs.min_disparity,
                self.min_disparity_px,
                f64::floor,
            )?,
            bound(
                "max_disparity",
                inputs.max_disparity,
                self.max_disparity_px,
                f64::ceil,
            )?,
        ];
        if range[0] > range[1] || range[1] - range[0] >= l.width as i32 {
            return Err(format!(
                "disparity range {}..={} px does not fit an image {} px wide",
                range[0], range[1], l.width
            ));
        }
        let p = CensusParams {
            census,
            aggregate: odd("aggregate_px", self.aggregate_px, 51)?,
            range,
            lr_max_diff_px: self.lr_max_diff_px as f32,
            uniqueness_pct: self.uniqueness_pct as f32,
        };
        let d = census_match(&grey(&l), &grey(&r), l.width, l.height, &p);
        let valid = d.iter().filter(|v| !v.is_nan()).count();
        out.metric("coverage_pct", 100.0 * valid as f64 / d.len().max(1) as f64);
        out.metric("min_disparity_px", range[0] as f64);
        out.metric("max_disparity_px", range[1] as f64);
        Ok(CensusOutputs {
            disparity: DisparityMap {
                width: l.width,
                height: l.height,
                data: d,
            },
        })
    }
}

export_plugin!(Typed::<CensusMatch>::new());

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_plugin_api::{OpDecl, Param, PluginOp};

    /// The declaration as it was written with the builder before the typed
    /// form: the host must read the same TOML from the derive.
    fn builder_declaration() -> OpDecl {
        OpDecl::new(
            "census.match",
            1,
            "Census transform + box-aggregated Hamming costs, winner-takes-all, left-right check -> Disparity",
        )
        .input("left", &["Image"], "Left rectified image")
        .input("right", &["Image"], "Right rectified image, same size")
        .optional_input("min_disparity", &["Scalar"], "Lowest disparity, px (overrides min_disparity_px)")
        .optional_input("max_disparity", &["Scalar"], "Highest disparity, px (overrides max_disparity_px)")
        .output("disparity", "Disparity", "Disparity on the left rectified image, px (NaN: no match)")
        .param(Param::int_list("census_window_px", &[9, 7], "px", "Census window width, height (odd; area <= 64)").lengths(&[2]))
        .param(Param::int("aggregate_px", 7, "px", "Side of the window costs are summed over (odd)").range(1.0, 51.0))
        .param(Param::int("min_disparity_px", 0, "px", "Lowest disparity when no input gives it"))
        .param(Param::int("max_disparity_px", 64, "px", "Highest disparity when no input gives it"))
        .param(Param::float("lr_max_diff_px", 1.0, "px", "Largest left-right disagreement kept (negative: no check)"))
        .param(Param::float("uniqueness_pct", 5.0, "%", "The best cost must be this much below the second best").range(0.0, 100.0))
    }

    #[test]
    fn the_derived_declaration_is_the_builders() {
        let derived = Typed::<CensusMatch>::new().declare();
        assert_eq!(derived.to_toml(), builder_declaration().to_toml());
    }
}
