//! Node adapters: `stereo.features`, `stereo.match_features` and
//! `stereo.disparity_range`, and the feature table they exchange.

use super::features::{
    Descriptors, FastParams, Features, HessianParams, Keypoint, detect_fast, detect_hessian,
};
use super::matching::{MatchParams, match_features};
use super::range::{RangeParams, disparity_range};
use crate::io::grey_of;
use fusegraph_engine::value::{Image, Matches, Table};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};

/// Keypoint columns of a feature table, before the descriptor columns.
const KEYPOINT_COLUMNS: [&str; 6] = [
    "x_px",
    "y_px",
    "size_px",
    "angle_deg",
    "response",
    "laplacian_sign",
];

/// A feature table: one row per keypoint, `KEYPOINT_COLUMNS` then `d00..d63`
/// (float descriptors; `laplacian_sign` +1 or -1) or `w0..w7` (the 256 bits as
/// eight 32-bit words, bit k of the descriptor in word k / 32; `laplacian_sign` 0).
pub fn features_to_table(f: &Features) -> Table {
    let binary = matches!(f.descriptors, Descriptors::Binary(_));
    let mut columns: Vec<String> = KEYPOINT_COLUMNS.iter().map(|c| c.to_string()).collect();
    if binary {
        columns.extend((0..8).map(|k| format!("w{k}")));
    } else {
        columns.extend((0..64).map(|k| format!("d{k:02}")));
    }
    let mut data = Vec::with_capacity(columns.len() * f.keypoints.len());
    for (i, kp) in f.keypoints.iter().enumerate() {
        let sign = match (binary, kp.laplacian_positive) {
            (true, _) => 0.0,
            (false, true) => 1.0,
            (false, false) => -1.0,
        };
        data.extend([
            kp.x_px as f64,
            kp.y_px as f64,
            kp.size_px as f64,
            (kp.angle_rad as f64).to_degrees(),
            kp.response as f64,
            sign,
        ]);
        match &f.descriptors {
            Descriptors::Float(d) => data.extend(d[i].iter().map(|&v| v as f64)),
            Descriptors::Binary(d) => {
                for word in d[i] {
                    data.extend([(word & 0xFFFF_FFFF) as f64, (word >> 32) as f64]);
                }
            }
        }
    }
    Table::new(columns, data).expect("rows are filled column by column")
}

/// Keypoints and descriptors back from a feature table; `what` names the input
/// in errors.
pub fn features_from_table(t: &Table, what: &str) -> Result<Features, String> {
    let n_kp = KEYPOINT_COLUMNS.len();
    if t.columns.len() < n_kp || t.columns[..n_kp].iter().ne(KEYPOINT_COLUMNS.iter()) {
        return Err(format!(
            "{what}: not a feature table from stereo.features (columns start {:?})",
            &t.columns[..t.columns.len().min(n_kp)]
        ));
    }
    let desc_cols = &t.columns[n_kp..];
    let float_names: Vec<String> = (0..64).map(|k| format!("d{k:02}")).collect();
    let binary_names: Vec<String> = (0..8).map(|k| format!("w{k}")).collect();
    let binary = if desc_cols == binary_names.as_slice() {
        true
    } else if desc_cols == float_names.as_slice() {
        false
    } else {
        return Err(format!(
            "{what}: descriptor columns are neither d00..d63 nor w0..w7"
        ));
    };
    let mut keypoints = Vec::with_capacity(t.row_count());
    let mut float = Vec::new();
    let mut bits = Vec::new();
    for r in 0..t.row_count() {
        let row = t.row(r);
        if let Some(c) = row.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "{what}: row {r}, column {} is not finite",
                t.columns[c]
            ));
        }
        keypoints.push(Keypoint {
            x_px: row[0] as f32,
            y_px: row[1] as f32,
            size_px: row[2] as f32,
            angle_rad: row[3].to_radians() as f32,
            response: row[4] as f32,
            laplacian_positive: row[5] > 0.0,
        });
        let d = &row[n_kp..];
        if binary {
            let mut words = [0u64; 4];
            for (k, &v) in d.iter().enumerate() {
                if v < 0.0 || v > u32::MAX as f64 || v.fract() != 0.0 {
                    return Err(format!("{what}: row {r}, w{k} = {v} is not a 32-bit word"));
                }
                words[k / 2] |= (v as u64) << (32 * (k % 2));
            }
            bits.push(words);
        } else {
            float.push(std::array::from_fn(|k| d[k] as f32));
        }
    }
    let descriptors = if binary {
        Descriptors::Binary(bits)
    } else {
        Descriptors::Float(float)
    };
    Ok(Features {
        keypoints,
        descriptors,
    })
}

pub(crate) struct FeaturesOp(OpSpec);

impl FeaturesOp {
    pub(crate) fn new() -> Self {
        FeaturesOp(
            OpSpec::new(
                "stereo.features",
                1,
                "Keypoints with descriptors of a (rectified) image: SURF-style Hessian or FAST + BRIEF",
            )
            .input("image", &[ValueType::Image], "Rectified image (grey or RGB)")
            .param(ParamSpec::choice(
                "detector",
                &["hessian", "fast"],
                "hessian: SURF-style blobs, 64-float descriptors; fast: FAST-9 corners, 256-bit BRIEF",
            ))
            .param(
                ParamSpec::int(
                    "max_features",
                    4000,
                    "",
                    "Keep at most this many, strongest first, spread over an up to 8 x 8 grid",
                )
                .at_least(1.0),
            )
            .param(
                ParamSpec::float(
                    "hessian_threshold",
                    HessianParams::default().threshold as f64,
                    "",
                    "hessian: smallest scale-normalised Hessian determinant (grey 0..1)",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "fast_threshold",
                    FastParams::default().threshold as f64,
                    "",
                    "fast: segment-test contrast on grey 0..1",
                )
                .range(1e-4, 1.0),
            )
            .param(ParamSpec::bool(
                "upright",
                true,
                "No orientation (angle 0): right for rectified pairs, and faster",
            ))
            .param(
                ParamSpec::int(
                    "octaves",
                    4,
                    "",
                    "hessian: filter-size octaves (9-27 px, doubling); fast: pyramid levels (halving)",
                )
                .range(1.0, 6.0),
            )
            .output(
                "features",
                ValueType::Table,
                "x_px, y_px, size_px, angle_deg, response, laplacian_sign, then d00..d63 or w0..w7",
            ),
        )
    }
}

impl Op for FeaturesOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let image = inputs.get::<Image>("image")?;
        let grey = grey_of(&image);
        let max_features = params.count("max_features")?;
        let upright = params.bool("upright")?;
        let octaves = params.count("octaves")?;
        let features = match params.string("detector")?.as_str() {
            "fast" => detect_fast(
                &grey,
                image.width,
                image.height,
                &FastParams {
                    threshold: params.float("fast_threshold")? as f32,
                    octaves,
                    upright,
                    max_features,
                },
            ),
            _ => detect_hessian(
                &grey,
                image.width,
                image.height,
                &HessianParams {
                    threshold: params.float("hessian_threshold")? as f32,
                    octaves,
                    upright,
                    max_features,
                },
            ),
        }
        .map_err(|e| OpError::invalid(format!("input `image`: {e}")))?;
        ctx.metric("count", features.keypoints.len() as f64);
        Ok(Outputs::new().with("features", features_to_table(&features)))
    }
}

pub(crate) struct MatchFeaturesOp(OpSpec);

impl MatchFeaturesOp {
    pub(crate) fn new() -> Self {
        MatchFeaturesOp(
            OpSpec::new(
                "stereo.match_features",
                1,
                "Nearest-neighbour descriptor matches (ratio test, mutual check, same rows if rectified)",
            )
            .input("left", &[ValueType::Table], "Features of the left image (stereo.features)")
            .input("right", &[ValueType::Table], "Features of the right image, same detector")
            .param(
                ParamSpec::float(
                    "ratio",
                    0.8,
                    "",
                    "Lowe's ratio: nearest distance below this times the second nearest (1 = off)",
                )
                .range(0.01, 1.0),
            )
            .param(ParamSpec::bool(
                "mutual",
                true,
                "Keep only matches that are each other's nearest",
            ))
            .param(ParamSpec::bool(
                "rectified",
                true,
                "Rectified pair: candidates only within row_tolerance_px rows",
            ))
            .param(
                ParamSpec::float(
                    "row_tolerance_px",
                    2.0,
                    "px",
                    "Largest |y_left - y_right| of a match when rectified",
                )
                .at_least(0.0),
            )
            .param(ParamSpec::float_list(
                "disparity_bounds_px",
                &[],
                "px",
                "[min, max] allowed x_left - x_right; empty: no bound",
            ).lengths(&[0, 2]))
            .output("matches", ValueType::Matches, "Matched positions (px) and descriptor distances")
            .output(
                "table",
                ValueType::Table,
                "x_left_px, y_left_px, x_right_px, y_right_px, disparity_px, score",
            ),
        )
    }
}

impl Op for MatchFeaturesOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let left = features_from_table(&*inputs.get::<Table>("left")?, "input `left`")
            .map_err(OpError::invalid)?;
        let right = features_from_table(&*inputs.get::<Table>("right")?, "input `right`")
            .map_err(OpError::invalid)?;
        let bounds = params.float_list("disparity_bounds_px")?;
        let disparity_bounds_px = match bounds.as_slice() {
            [] => None,
            [lo, hi] => Some((*lo as f32, *hi as f32)),
            _ => {
                return Err(OpError::invalid(format!(
                    "disparity_bounds_px: {} numbers; give none or [min, max]",
                    bounds.len()
                )));
            }
        };
        let p = MatchParams {
            ratio: params.float("ratio")? as f32,
            mutual: params.bool("mutual")?,
            rectified: params.bool("rectified")?,
            row_tolerance_px: params.float("row_tolerance_px")? as f32,
            disparity_bounds_px,
        };
        let found = match_features(&left, &right, &p).map_err(OpError::invalid)?;
        let mut left_px = Vec::with_capacity(2 * found.len());
        let mut right_px = Vec::with_capacity(2 * found.len());
        let mut rows = Vec::with_capacity(6 * found.len());
        for m in &found {
            left_px.extend([m.x_left_px, m.y_left_px]);
            right_px.extend([m.x_right_px, m.y_right_px]);
            rows.extend(
                [
                    m.x_left_px,
                    m.y_left_px,
                    m.x_right_px,
                    m.y_right_px,
                    m.disparity_px,
                    m.score,
                ]
                .map(f64::from),
            );
        }
        let scores: Vec<f32> = found.iter().map(|m| m.score).collect();
        let matches = Matches::new(left_px, right_px, scores).map_err(|e| OpError::invalid(e.0))?;
        let columns = [
            "x_left_px",
            "y_left_px",
            "x_right_px",
            "y_right_px",
            "disparity_px",
            "score",
        ];
        let table = Table::new(columns.iter().map(|c| c.to_string()).collect(), rows)
            .map_err(|e| OpError::invalid(e.0))?;
        ctx.metric("matches", found.len() as f64);
        Ok(Outputs::new().with("matches", matches).with("table", table))
    }
}

pub(crate) struct DisparityRangeOp(OpSpec);

impl DisparityRangeOp {
    pub(crate) fn new() -> Self {
        let d = RangeParams::default();
        DisparityRangeOp(
            OpSpec::new(
                "stereo.disparity_range",
                1,
                "Disparity search range from matches: percentiles widened by a margin",
            )
            .input(
                "matches",
                &[ValueType::Matches],
                "Matches of a rectified pair",
            )
            .param(
                ParamSpec::float(
                    "low_percentile",
                    d.low_percentile,
                    "%",
                    "Lower percentile of matched disparities",
                )
                .range(0.0, 100.0),
            )
            .param(
                ParamSpec::float(
                    "high_percentile",
                    d.high_percentile,
                    "%",
                    "Upper percentile of matched disparities",
                )
                .range(0.0, 100.0),
            )
            .param(
                ParamSpec::float(
                    "margin_px",
                    d.margin_px,
                    "px",
                    "Fixed margin added on both sides",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "margin_fraction",
                    d.margin_fraction,
                    "",
                    "Margin added on both sides, as a fraction of the percentile spread",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::int(
                    "min_matches",
                    d.min_matches as i64,
                    "",
                    "Fewer matches is an error",
                )
                .at_least(1.0),
            )
            .output(
                "min_disparity",
                ValueType::Scalar,
                "Smallest disparity to search, px",
            )
            .output(
                "max_disparity",
                ValueType::Scalar,
                "Largest disparity to search, px",
            ),
        )
    }
}

impl Op for DisparityRangeOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let matches = inputs.get::<Matches>("matches")?;
        let disparities: Vec<f32> = matches
            .left_px
            .chunks(2)
            .zip(matches.right_px.chunks(2))
            .map(|(l, r)| l[0] - r[0])
            .collect();
        let p = RangeParams {
            low_percentile: params.float("low_percentile")?,
            high_percentile: params.float("high_percentile")?,
            margin_px: params.float("margin_px")?,
            margin_fraction: params.float("margin_fraction")?,
            min_matches: params.count("min_matches")?,
        };
        let (min, max) = disparity_range(&disparities, &p)
            .map_err(|e| OpError::invalid(format!("input `matches`: {e}")))?;
        ctx.metric("min_px", min as f64);
        ctx.metric("max_px", max as f64);
        ctx.metric("matches", disparities.len() as f64);
        Ok(Outputs::new()
            .with("min_disparity", min as f64)
            .with("max_disparity", max as f64))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::features::test_images::blob_texture;
    use fusegraph_engine::value::Pixels;
    use std::sync::Arc;

    fn run(
        op: &dyn Op,
        inputs: Inputs,
        set: &[(&str, fusegraph_engine::ParamValue)],
    ) -> Result<(Outputs, RunCtx<'static>), OpError> {
        let mut params = Params::default();
        for p in &op.spec().params {
            params.0.insert(p.name.clone(), p.default.clone().unwrap());
        }
        for (k, v) in set {
            params.0.insert(k.to_string(), v.clone());
        }
        let mut ctx = RunCtx::new("test", std::path::Path::new("/nonexistent"));
        let out = op.run(&inputs, &params, &mut ctx)?;
        Ok((out, ctx))
    }

    fn image(grey: &[f32], w: usize, h: usize) -> Image {
        Image::new(w, h, 1, Pixels::F32(grey.to_vec().into())).unwrap()
    }

    #[test]
    fn specs_are_valid() {
        FeaturesOp::new().spec().check().unwrap();
        MatchFeaturesOp::new().spec().check().unwrap();
        DisparityRangeOp::new().spec().check().unwrap();
    }

    #[test]
    fn tables_round_trip() {
        let kp = Keypoint {
            x_px: 1.5,
            y_px: 2.25,
            size_px: 15.0,
            angle_rad: 0.5,
            response: 0.01,
            laplacian_positive: true,
        };
        let f = Features {
            keypoints: vec![kp],
            descriptors: Descriptors::Binary(vec![[u64::MAX, 1, 1 << 63, 0xDEAD_BEEF_0000_0001]]),
        };
        let t = features_to_table(&f);
        assert_eq!(t.columns.len(), 14);
        assert_eq!(t.row(0)[5], 0.0, "FAST has no Laplacian sign");
        let back = features_from_table(&t, "t").unwrap();
        assert_eq!(back.descriptors, f.descriptors);
        assert!((back.keypoints[0].angle_rad - 0.5).abs() < 1e-6);
        let mut d = [0.0f32; 64];
        d[7] = 0.25;
        let f = Features {
            keypoints: vec![kp],
            descriptors: Descriptors::Float(vec![d]),
        };
        let t = features_to_table(&f);
        assert_eq!(t.columns[6], "d00");
        assert_eq!(t.row(0)[5], 1.0);
        assert_eq!(features_from_table(&t, "t").unwrap(), f);
        let other = Table::new(vec!["x_px".into()], vec![1.0]).unwrap();
        assert!(
            features_from_table(&other, "input `left`")
                .unwrap_err()
                .contains("input `left`")
        );
    }

    #[test]
    fn the_three_ops_chain() {
        let (w, h) = (160, 120);
        let left = image(&blob_texture(w, h, 0.0, 0.0, 5), w, h);
        let right = image(&blob_texture(w, h, -17.0, 0.0, 5), w, h);
        let feat = FeaturesOp::new();
        let mut tables = Vec::new();
        for img in [left, right] {
            let mut i = Inputs::default();
            i.0.insert("image".into(), img.into());
            let (out, ctx) = run(&feat, i, &[]).unwrap();
            assert!(ctx.metrics()["count"] > 50.0);
            tables.push(out.0["features"].clone());
        }
        let mut i = Inputs::default();
        i.0.insert("left".into(), tables[0].clone());
        i.0.insert("right".into(), tables[1].clone());
        let (out, ctx) = run(&MatchFeaturesOp::new(), i, &[]).unwrap();
        assert!(ctx.metrics()["matches"] > 30.0);
        let matches = out.0["matches"].clone();
        let mut i = Inputs::default();
        i.0.insert("matches".into(), matches);
        let (out, ctx) = run(&DisparityRangeOp::new(), i, &[]).unwrap();
        let min = ctx.metrics()["min_px"];
        let max = ctx.metrics()["max_px"];
        // Every true disparity is 17 px: p2 = p98 = 17, margin 16.
        assert!(min <= 17.0 && max >= 17.0, "[{min}, {max}]");
        assert!(min >= 17.0 - 17.0 && max <= 17.0 + 17.0, "[{min}, {max}]");
        assert_eq!(out.0.len(), 2);
        // A FAST table against a Hessian table is refused.
        let mut i = Inputs::default();
        i.0.insert(
            "image".into(),
            image(&blob_texture(w, h, 0.0, 0.0, 5), w, h).into(),
        );
        let fast = fusegraph_engine::ParamValue::String("fast".into());
        let (out, _) = run(&feat, i, &[("detector", fast)]).unwrap();
        let mut i = Inputs::default();
        i.0.insert("left".into(), tables[0].clone());
        i.0.insert("right".into(), out.0["features"].clone());
        let err = run(&MatchFeaturesOp::new(), i, &[]).err().unwrap();
        assert!(err.to_string().contains("different detectors"), "{err}");
    }

    #[test]
    fn too_few_matches_name_the_remedy() {
        let m = Matches::new(vec![10.0f32, 5.0], vec![2.0f32, 5.0], vec![0.1f32]).unwrap();
        let mut i = Inputs::default();
        i.0.insert("matches".into(), Arc::new(m).into());
        let err = run(&DisparityRangeOp::new(), i, &[])
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("only 1 matches") && err.contains("parameters"),
            "{err}"
        );
    }
}
