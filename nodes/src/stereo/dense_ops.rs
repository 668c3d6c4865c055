//! Node adapters of the dense matchers and triangulation: `stereo.sgm`,
//! `stereo.block_match`, `stereo.triangulate`.

use super::block_match::{BlockCost, block_match};
use super::dense::{MatchCost, SgmConfig, sgm_disparity, speckle_size_px};
use super::filter::filter_speckles;
use super::pair::{DisparityRange, GreyImage, check_pair};
use super::refine::{RefineParams, refine_disparity};
use super::select::SelectParams;
use super::sgm::{Paths, SgmParams};
use super::triangulate::point_from_disparity;
use crate::calib::rectification_of;
use fusegraph_engine::value::{Disparity, Image, Pixels, PointCloud, Rectification};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};
use rayon::prelude::*;

/// The ports and parameters every dense matcher shares.
fn matcher_spec(name: &str, version: u32, doc: &str) -> OpSpec {
    let d = SgmConfig::default();
    let refine_window = d.refine.map_or(9, |r| 2 * r.half_window as i64 + 1);
    OpSpec::new(name, version, doc)
        .input("left", &[ValueType::Image], "Left rectified image")
        .input("right", &[ValueType::Image], "Right rectified image (same size)")
        .optional_input(
            "min_disparity",
            &[ValueType::Scalar],
            "Smallest disparity, px (e.g. from stereo.disparity_range; else the parameter)",
        )
        .optional_input(
            "max_disparity",
            &[ValueType::Scalar],
            "Largest disparity, px (else the parameter)",
        )
        .param(ParamSpec::int(
            "min_disparity_px",
            0,
            "px",
            "Smallest disparity searched when the input is not connected",
        ))
        .param(ParamSpec::int(
            "max_disparity_px",
            63,
            "px",
            "Largest disparity searched when the input is not connected",
        ))
        .param(
            ParamSpec::float(
                "uniqueness_pct",
                d.select.uniqueness_pct,
                "%",
                "Invalid when another disparity (beyond +-1) costs less than best x (1 + this/100); 0 = off",
            )
            .range(0.0, 100.0),
        )
        .param(ParamSpec::float(
            "lr_max_diff_px",
            d.select.lr_max_diff_px.unwrap_or(-1.0),
            "px",
            "Left-right check: largest difference from the right image's disparity; negative = off",
        ))
        .param(ParamSpec::bool(
            "subpixel",
            d.select.subpixel,
            "Fit a parabola to the costs around the best disparity",
        ))
        .param(ParamSpec::choice(
            "refine",
            &["intensity", "none"],
            "intensity: then align the intensities along the row (Lucas-Kanade, +-1 px) for sub-pixel accuracy; none: keep the parabola",
        ))
        .param(
            ParamSpec::int("refine_window_px", refine_window, "px", "Window of the intensity refinement (odd)")
                .range(3.0, 31.0),
        )
        .param(
            ParamSpec::float(
                "speckle_area_pct",
                d.speckle_area_pct,
                "%",
                "Remove regions of similar disparity up to this share of the image area (0 = off)",
            )
            .range(0.0, 100.0),
        )
        .param(
            ParamSpec::float(
                "speckle_range_px",
                d.speckle_range_px as f64,
                "px",
                "Largest step between neighbours inside one speckle region",
            )
            .at_least(0.0),
        )
        .output(
            "disparity",
            ValueType::Disparity,
            "x_left - x_right on the left image, px (NaN = invalid)",
        )
}

/// The pair as grey images, checked.
fn grey_pair(inputs: &Inputs) -> Result<(GreyImage, GreyImage), OpError> {
    let (l, r) = (inputs.get::<Image>("left")?, inputs.get::<Image>("right")?);
    let (l, r) = (GreyImage::from_image(&l), GreyImage::from_image(&r));
    check_pair(&l, &r).map_err(OpError::invalid)?;
    Ok((l, r))
}

/// The disparity range from the optional inputs, else the parameters.
fn disparity_range(
    inputs: &Inputs,
    params: &Params,
    width: usize,
) -> Result<DisparityRange, OpError> {
    let bound = |port: &str, param: &str, round: fn(f64) -> f64| -> Result<i32, OpError> {
        match inputs.optional::<f64>(port)? {
            Some(v) if v.is_finite() && v.abs() < 1e6 => Ok(round(*v) as i32),
            Some(v) => Err(OpError::invalid(format!(
                "input `{port}` is {v}, not a disparity"
            ))),
            None => i32::try_from(params.int(param)?)
                .map_err(|_| OpError::invalid(format!("parameter `{param}` is out of range"))),
        }
    };
    let min = bound("min_disparity", "min_disparity_px", f64::floor)?;
    let max = bound("max_disparity", "max_disparity_px", f64::ceil)?;
    DisparityRange::new(min, max, width).map_err(OpError::invalid)
}

fn refine_params(params: &Params) -> Result<Option<RefineParams>, OpError> {
    if params.string("refine")? == "none" {
        return Ok(None);
    }
    let window = params.count("refine_window_px")?;
    if window.is_multiple_of(2) {
        return Err(OpError::invalid(format!(
            "refine_window_px = {window}: must be odd"
        )));
    }
    Ok(Some(RefineParams {
        half_window: window / 2,
        iterations: 2,
        max_change_px: 1.0,
    }))
}

fn select_params(params: &Params) -> Result<SelectParams, OpError> {
    let lr = params.float("lr_max_diff_px")?;
    Ok(SelectParams {
        uniqueness_pct: params.float("uniqueness_pct")?,
        lr_max_diff_px: (lr >= 0.0).then_some(lr),
        subpixel: params.bool("subpixel")?,
    })
}

/// The disparity value, with its coverage and range as metrics.
fn disparity_output(
    data: Vec<f32>,
    width: usize,
    height: usize,
    range: DisparityRange,
    ctx: &mut RunCtx,
) -> Result<Outputs, OpError> {
    let valid = data.iter().filter(|d| !d.is_nan()).count();
    ctx.metric(
        "coverage_pct",
        100.0 * valid as f64 / data.len().max(1) as f64,
    );
    ctx.metric("min_disparity_px", range.min_px as f64);
    ctx.metric("max_disparity_px", range.max_px() as f64);
    let value = Disparity::new(width, height, data).map_err(|e| OpError::invalid(e.0))?;
    // The map for the report, coloured over its 1st to 99th percentiles.
    if let Some(range) = crate::io::finite_percentiles(&value.data, 1.0, 99.0)
        && let Ok((rgb, w, h)) = crate::io::disparity_png(&value, range)
        && let Ok(png) = crate::plot::png_bytes(&rgb, w, h)
    {
        ctx.figure(
            "disparity",
            "Disparity on the left rectified image, px (black: invalid)",
            fusegraph_engine::figure::FigureData::Png(png),
        )?;
    }
    Ok(Outputs::new().with("disparity", value))
}

pub(crate) struct SgmOp(OpSpec);

impl SgmOp {
    pub(crate) fn new() -> Self {
        let d = SgmConfig::default();
        let (width, height) = match d.cost {
            MatchCost::Census { width, height } => (width, height),
            MatchCost::BirchfieldTomasi { .. } => (9, 7),
        };
        let paths = d.sgm.paths.count();
        SgmOp(
            matcher_spec(
                "stereo.sgm",
                6,
                "Semi-global matching (census or Birchfield-Tomasi costs, 5 paths in one pass, or 4 or 8 in two) -> Disparity",
            )
            .param(ParamSpec::choice(
                "cost",
                &["census", "bt"],
                "census: Hamming distance of census codes (robust to exposure, JPEG); bt: Birchfield-Tomasi grey difference",
            ))
            .param(
                ParamSpec::int_list("census_window", &[width as i64, height as i64], "px", "Census window width, height (odd; area <= 65)")
                    .range(1.0, 65.0)
                    .length(2),
            )
            .param(
                ParamSpec::int("bt_window", 5, "px", "Window the BT cost is averaged over (odd)")
                    .range(1.0, 31.0),
            )
            .param(ParamSpec::int(
                "paths",
                paths as i64,
                "",
                "Aggregation paths: 5 = one top-down pass (both horizontals, down, the two downward diagonals; fastest, no stored volume); 4 or 8 = two passes (8 adds the upward paths and diagonals)",
            ).range(4.0, 8.0))
            .param(
                ParamSpec::int("p1", d.sgm.p1 as i64, "cost", "Penalty for a 1 px disparity step between neighbours")
                    .range(1.0, 3999.0),
            )
            .param(
                ParamSpec::int("p2", d.sgm.p2 as i64, "cost", "Penalty for a larger disparity jump (> p1)")
                    .range(2.0, 4000.0),
            )
            .param(
                ParamSpec::float(
                    "p2_gamma",
                    d.sgm.p2_gamma as f64,
                    "grey levels",
                    "P2 falls to P2 gamma / (gamma + |dI|) across an intensity step dI (0 = constant P2)",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "min_texture_snr",
                    d.min_texture_snr,
                    "",
                    "Invalid where the cost window's grey-level spread is below this multiple of the image noise (estimated from the image; 0 = off)",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::int(
                    "max_memory_mb",
                    d.max_memory_mb as i64,
                    "MB",
                    "Refuse when the cost volumes would need more memory than this",
                )
                .at_least(1.0),
            ),
        )
    }
}

impl Op for SgmOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (left, right) = grey_pair(inputs)?;
        let range = disparity_range(inputs, params, left.width)?;
        let cost = match params.string("cost")?.as_str() {
            "census" => {
                let &[width, height] = params.int_list("census_window")?.as_slice() else {
                    return Err(OpError::invalid(
                        "census_window takes two numbers: width, height",
                    ));
                };
                MatchCost::Census {
                    width: width as usize,
                    height: height as usize,
                }
            }
            _ => MatchCost::BirchfieldTomasi {
                window: params.count("bt_window")?,
            },
        };
        let paths = Paths::from_count(params.int("paths")?).map_err(OpError::invalid)?;
        let config = SgmConfig {
            cost,
            sgm: SgmParams {
                p1: params.int("p1")? as u16,
                p2: params.int("p2")? as u16,
                paths,
                p2_gamma: params.float("p2_gamma")? as f32,
            },
            select: select_params(params)?,
            speckle_area_pct: params.float("speckle_area_pct")?,
            speckle_range_px: params.float("speckle_range_px")? as f32,
            max_memory_mb: params.count("max_memory_mb")?,
            refine: refine_params(params)?,
            min_texture_snr: params.float("min_texture_snr")?,
        };
        let data = sgm_disparity(&left, &right, range, &config).map_err(OpError::invalid)?;
        disparity_output(data, left.width, left.height, range, ctx)
    }
}

pub(crate) struct BlockMatchOp(OpSpec);

impl BlockMatchOp {
    pub(crate) fn new() -> Self {
        BlockMatchOp(
            matcher_spec(
                "stereo.block_match",
                4,
                "Local block matching (SAD, ZNCC or census over a window) -> Disparity",
            )
            .param(ParamSpec::choice(
                "cost",
                &["zncc", "sad", "census"],
                "zncc: 1 - zero-mean normalised cross-correlation; sad: absolute differences; census: summed 5 x 5 census Hamming distances",
            ))
            .param(ParamSpec::int("window", 9, "px", "Window side (odd)").range(1.0, 51.0)),
        )
    }
}

impl Op for BlockMatchOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (left, right) = grey_pair(inputs)?;
        let range = disparity_range(inputs, params, left.width)?;
        let window = params.count("window")?;
        if window % 2 == 0 {
            return Err(OpError::invalid(format!("window = {window}: must be odd")));
        }
        let cost = match params.string("cost")?.as_str() {
            "sad" => BlockCost::Sad,
            "census" => BlockCost::Census,
            _ => BlockCost::Zncc,
        };
        let mut data = block_match(&left, &right, range, cost, window, &select_params(params)?);
        filter_speckles(
            &mut data,
            left.width,
            left.height,
            speckle_size_px(params.float("speckle_area_pct")?, left.width, left.height),
            params.float("speckle_range_px")? as f32,
        );
        if let Some(refine) = refine_params(params)? {
            refine_disparity(&left, &right, &mut data, &refine);
        }
        disparity_output(data, left.width, left.height, range, ctx)
    }
}

pub(crate) struct TriangulateOp(OpSpec);

impl TriangulateOp {
    pub(crate) fn new() -> Self {
        TriangulateOp(
            OpSpec::new(
                "stereo.triangulate",
                1,
                "Disparity + rectification -> point cloud (mm) in the original left camera frame",
            )
            .input(
                "disparity",
                &[ValueType::Disparity],
                "Disparity on the left rectified image, px",
            )
            .input(
                "rectification",
                &[ValueType::Rectification],
                "The rectification the disparity was measured in",
            )
            .optional_input(
                "image",
                &[ValueType::Image],
                "Left rectified image: colours of the points",
            )
            .param(
                ParamSpec::float(
                    "min_depth_mm",
                    400.0,
                    "mm",
                    "Nearest depth kept (z in the left camera frame)",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float("max_depth_mm", 700.0, "mm", "Farthest depth kept").at_least(0.0),
            )
            .output(
                "cloud",
                ValueType::PointCloud,
                "Points in mm, frame camera_left, with colours if given",
            ),
        )
    }
}

/// The points (mm, original left camera frame) of every valid disparity whose
/// depth lies in `min_depth_mm..=max_depth_mm`, with the pixel each came from.
pub fn triangulate_disparity(
    disparity: &[f32],
    width: usize,
    rect: &crate::calib::StereoRectification,
    min_depth_mm: f64,
    max_depth_mm: f64,
) -> Vec<(usize, nalgebra::Point3<f64>)> {
    disparity
        .par_iter()
        .enumerate()
        .filter_map(|(i, &d)| {
            if d.is_nan() {
                return None;
            }
            let p = point_from_disparity(rect, (i % width) as f64, (i / width) as f64, d as f64)?;
            (min_depth_mm..=max_depth_mm)
                .contains(&p.z)
                .then_some((i, p))
        })
        .collect()
}

impl Op for TriangulateOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let disparity = inputs.get::<Disparity>("disparity")?;
        let rect = rectification_of(&*inputs.get::<Rectification>("rectification")?);
        let (w, h) = (disparity.width, disparity.height);
        if (w, h) != rect.size {
            return Err(OpError::invalid(format!(
                "disparity is {w} x {h} px but the rectification is {} x {} px",
                rect.size.0, rect.size.1
            )));
        }
        let (near, far) = (params.float("min_depth_mm")?, params.float("max_depth_mm")?);
        if near >= far {
            return Err(OpError::invalid(format!(
                "min_depth_mm ({near}) must be below max_depth_mm ({far})"
            )));
        }
        let image = inputs.optional::<Image>("image")?;
        if let Some(img) = &image
            && (img.width, img.height) != (w, h)
        {
            return Err(OpError::invalid(format!(
                "image is {} x {} px but the disparity is {w} x {h} px",
                img.width, img.height
            )));
        }
        let points = triangulate_disparity(&disparity.data, w, &rect, near, far);
        let xyz: Vec<f32> = points
            .iter()
            .flat_map(|(_, p)| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let colors = image.map(|img| {
            let rgb = |i: usize, c: usize| -> u8 {
                let k = if img.channels == 3 { 3 * i + c } else { i };
                match &img.pixels {
                    Pixels::U8(p) => p[k],
                    Pixels::F32(p) => (p[k] * 255.0).round().clamp(0.0, 255.0) as u8,
                }
            };
            points
                .iter()
                .flat_map(|&(i, _)| [rgb(i, 0), rgb(i, 1), rgb(i, 2)])
                .collect::<Vec<u8>>()
                .into()
        });
        let valid = disparity.data.iter().filter(|d| !d.is_nan()).count();
        ctx.metric("points", points.len() as f64);
        ctx.metric(
            "in_range_pct",
            100.0 * points.len() as f64 / valid.max(1) as f64,
        );
        let cloud =
            PointCloud::new(xyz, colors, None, "camera_left").map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new().with("cloud", cloud))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::{ParamValue, Value};

    fn grey(w: usize, h: usize) -> Value {
        let data: Vec<u8> = (0..w * h).map(|i| (i * 37 % 251) as u8).collect();
        Image::new(w, h, 1, Pixels::U8(data.into())).unwrap().into()
    }

    fn run_sgm(left: Value, right: Value, set: &[(&str, i64)]) -> Result<Outputs, OpError> {
        let op = SgmOp::new();
        let mut params = Params::default();
        for p in &op.spec().params {
            params.0.insert(p.name.clone(), p.default.clone().unwrap());
        }
        for (k, v) in set {
            params.0.insert(k.to_string(), ParamValue::Int(*v));
        }
        let mut inputs = Inputs::default();
        inputs.0.insert("left".into(), left);
        inputs.0.insert("right".into(), right);
        op.run(
            &inputs,
            &params,
            &mut RunCtx::new("match", std::path::Path::new(".")),
        )
    }

    #[test]
    fn specs_are_valid() {
        for op in [
            SgmOp::new().0,
            BlockMatchOp::new().0,
            TriangulateOp::new().0,
        ] {
            op.check().unwrap();
        }
    }

    #[test]
    fn bad_input_gets_a_clear_error() {
        let e = run_sgm(grey(40, 30), grey(40, 31), &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("differ in size"), "{e}");
        let empty = [("min_disparity_px", 20), ("max_disparity_px", 10)];
        let e = run_sgm(grey(40, 30), grey(40, 30), &empty)
            .unwrap_err()
            .to_string();
        assert!(e.contains("empty disparity range"), "{e}");
        let wide = [("max_disparity_px", 63)];
        let e = run_sgm(grey(40, 30), grey(40, 30), &wide)
            .unwrap_err()
            .to_string();
        assert!(e.contains("wider than the image"), "{e}");
        let fits = [("max_disparity_px", 15)];
        assert!(run_sgm(grey(40, 30), grey(40, 30), &fits).is_ok());
    }
}
