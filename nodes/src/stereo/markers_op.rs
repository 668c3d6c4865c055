//! Node adapter: `stereo.hsv_markers`.

use super::hsv_markers::{BlobParams, PairParams, stereo_markers, stereo_markers_unrectified};
use crate::camera::CameraModel;
use fusegraph_engine::value::{Image, Markers, Pixels, Rectification, StereoRig, Table};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType,
};

/// Columns of the `blobs` table.
pub const BLOB_COLUMNS: [&str; 7] = [
    "x_left_px",
    "y_left_px",
    "x_right_px",
    "y_right_px",
    "disparity_px",
    "area_left_px",
    "area_right_px",
];

pub(crate) struct HsvMarkersOp(OpSpec);

impl HsvMarkersOp {
    pub(crate) fn new() -> Self {
        let b = BlobParams::default();
        HsvMarkersOp(
            OpSpec::new(
                "stereo.hsv_markers",
                4,
                "Coloured markers found by HSV thresholds in both rectified images, paired along rows, triangulated",
            )
            .input(
                "left",
                &[ValueType::Image],
                "Left image, 8-bit RGB: rectified, or as taken when `rig` is given",
            )
            .input(
                "right",
                &[ValueType::Image],
                "Right image, 8-bit RGB: rectified, or as taken when `rig` is given",
            )
            .input(
                "rectification",
                &[ValueType::Rectification],
                "The rectification the pair is (or would be) rectified with",
            )
            .optional_input(
                "rig",
                &[ValueType::StereoRig],
                "The rig that took `left` and `right`: the blobs are then measured in the images as taken (no resampling blur) and their centroids mapped into the rectified frame",
            )
            .optional_input("min_disparity", &[ValueType::Scalar], "Smallest disparity of a pair, px")
            .optional_input("max_disparity", &[ValueType::Scalar], "Largest disparity of a pair, px")
            .param(
                ParamSpec::float_list(
                    "hue_deg",
                    &[b.hue_deg.0, b.hue_deg.1],
                    "deg",
                    "Hue range [min, max]; min > max wraps through 0 (default: the phantom's green)",
                )
                .range(0.0, 360.0)
                .length(2),
            )
            .param(
                ParamSpec::float("min_saturation", b.min_saturation, "", "Smallest saturation (0..1)")
                    .range(0.0, 1.0),
            )
            .param(
                ParamSpec::float("min_value", b.min_value, "", "Smallest value, i.e. brightness (0..1)")
                    .range(0.0, 1.0),
            )
            .param(
                ParamSpec::int(
                    "morph_radius_px",
                    b.morph_radius_px as i64,
                    "px",
                    "Disc radius of the opening then closing of the colour mask (0 = none)",
                )
                .range(0.0, 10.0),
            )
            .param(
                ParamSpec::float("min_area_px", b.min_area_px, "px", "Smallest blob area (pixels)")
                    .at_least(0.0),
            )
            .param(
                ParamSpec::float("max_area_px", b.max_area_px, "px", "Largest blob area (pixels)")
                    .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "max_aspect",
                    b.max_aspect,
                    "",
                    "Largest axis ratio of a blob's moment ellipse (a disc tilted by t: 1 / cos t)",
                )
                .at_least(1.0),
            )
            .param(
                ParamSpec::float(
                    "min_ellipse_fit",
                    b.min_ellipse_fit,
                    "",
                    "Smallest overlap (intersection over union) of a blob with its moment ellipse",
                )
                .range(0.0, 1.0),
            )
            .param(
                ParamSpec::int(
                    "border_px",
                    b.border_px as i64,
                    "px",
                    "Band around a blob whose pixels count in the centroid by their colour share",
                )
                .range(0.0, 5.0),
            )
            .param(
                ParamSpec::float(
                    "row_tolerance_px",
                    2.0,
                    "px",
                    "Largest row difference of a left-right pair",
                )
                .at_least(0.0),
            )
            .param(
                ParamSpec::float(
                    "max_area_ratio",
                    1.6,
                    "",
                    "Largest ratio of the areas of a left-right pair",
                )
                .at_least(1.0),
            )
            .output(
                "markers",
                ValueType::Markers,
                "Marker centres, mm, frame camera_left; ids 0..n in left-blob order",
            )
            .output(
                "blobs",
                ValueType::Table,
                "One row per marker: centroids in both images, disparity and areas, px",
            ),
        )
    }
}

/// The interleaved 8-bit RGB samples of input `port`.
fn rgb8<'a>(img: &'a Image, port: &str) -> Result<&'a [u8], OpError> {
    match &img.pixels {
        Pixels::U8(p) if img.channels == 3 => Ok(p),
        _ => Err(OpError::invalid(format!(
            "input `{port}`: expected an 8-bit RGB image, got {} channel(s) of {}",
            img.channels,
            if matches!(img.pixels, Pixels::U8(_)) {
                "u8"
            } else {
                "f32"
            }
        ))),
    }
}

/// `rgb` (w x h) at half size with a magenta ring and cross at each of
/// `centres` (full-size px), as PNG.
fn detections_png(
    rgb: &[u8],
    w: usize,
    h: usize,
    centres: &[(f64, f64)],
) -> Result<Vec<u8>, String> {
    let (hw, hh) = (w / 2, h / 2);
    let mut out = vec![0u8; hw * hh * 3];
    for y in 0..hh {
        for x in 0..hw {
            for c in 0..3 {
                let at = |dx: usize, dy: usize| rgb[((2 * y + dy) * w + 2 * x + dx) * 3 + c] as u16;
                out[(y * hw + x) * 3 + c] =
                    ((at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1) + 2) / 4) as u8;
            }
        }
    }
    let mut dot = |x: i64, y: i64| {
        if (0..hw as i64).contains(&x) && (0..hh as i64).contains(&y) {
            let i = (y as usize * hw + x as usize) * 3;
            out[i..i + 3].copy_from_slice(&[255, 0, 255]);
        }
    };
    for &(cx, cy) in centres {
        let (cx, cy) = (cx / 2.0, cy / 2.0);
        for t in 0..72 {
            let a = t as f64 * std::f64::consts::PI / 36.0;
            dot(
                (cx + 9.0 * a.cos()).round() as i64,
                (cy + 9.0 * a.sin()).round() as i64,
            );
        }
        for d in -3..=3 {
            dot(cx.round() as i64 + d, cy.round() as i64);
            dot(cx.round() as i64, cy.round() as i64 + d);
        }
    }
    crate::plot::png_bytes(&out, hw, hh)
}

/// The `hue_deg` parameter as (min, max).
pub(crate) fn hue_range(params: &Params) -> Result<(f64, f64), OpError> {
    let hue = params.float_list("hue_deg")?;
    let [h0, h1] = hue[..] else {
        return Err(OpError::invalid(format!(
            "parameter `hue_deg`: expected [min, max], got {} numbers",
            hue.len()
        )));
    };
    Ok((h0, h1))
}

impl Op for HsvMarkersOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (left, right) = (inputs.get::<Image>("left")?, inputs.get::<Image>("right")?);
        let rect_value = inputs.get::<Rectification>("rectification")?;
        let rig = inputs.optional::<StereoRig>("rig")?;
        if rig.is_none() && (rect_value.width, rect_value.height) != (left.width, left.height) {
            return Err(OpError::invalid(format!(
                "input `left` is {} x {} px but the rectification makes {} x {} px images",
                left.width, left.height, rect_value.width, rect_value.height
            )));
        }
        let blob = BlobParams {
            hue_deg: hue_range(params)?,
            min_saturation: params.float("min_saturation")?,
            min_value: params.float("min_value")?,
            morph_radius_px: params.count("morph_radius_px")?,
            min_area_px: params.float("min_area_px")?,
            max_area_px: params.float("max_area_px")?,
            max_aspect: params.float("max_aspect")?,
            min_ellipse_fit: params.float("min_ellipse_fit")?,
            border_px: params.count("border_px")?,
        };
        let pair = PairParams {
            row_tolerance_px: params.float("row_tolerance_px")?,
            max_area_ratio: params.float("max_area_ratio")?,
            min_disparity_px: inputs.optional::<f64>("min_disparity")?.map(|v| *v),
            max_disparity_px: inputs.optional::<f64>("max_disparity")?.map(|v| *v),
        };
        if let (Some(lo), Some(hi)) = (pair.min_disparity_px, pair.max_disparity_px)
            && (lo.is_nan() || hi.is_nan() || lo > hi)
        {
            return Err(OpError::invalid(format!(
                "empty disparity range: min_disparity {lo} px is above max_disparity {hi} px"
            )));
        }
        let rect = crate::calib::rectification_of(&rect_value);
        let left_image = left.clone();
        let left = (rgb8(&left, "left")?, left.width, left.height);
        let right = (rgb8(&right, "right")?, right.width, right.height);
        let found = match rig {
            Some(rig) => {
                let cameras = (
                    CameraModel::from_value(&rig.left),
                    CameraModel::from_value(&rig.right),
                );
                let cameras = (&cameras.0, &cameras.1);
                stereo_markers_unrectified(left, right, cameras, &rect, &blob, &pair)
            }
            None => stereo_markers(left, right, &rect, &blob, &pair),
        }
        .map_err(OpError::invalid)?;
        let positions: Vec<f64> = found
            .markers
            .iter()
            .flat_map(|m| [m.point_mm.x, m.point_mm.y, m.point_mm.z])
            .collect();
        let ids: Vec<u32> = (0..found.markers.len() as u32).collect();
        let rows: Vec<f64> = found
            .markers
            .iter()
            .flat_map(|m| {
                [
                    m.left.x_px,
                    m.left.y_px,
                    m.right.x_px,
                    m.right.y_px,
                    m.disparity_px,
                    m.left.area_px,
                    m.right.area_px,
                ]
            })
            .collect();
        let markers =
            Markers::new(positions, ids, "camera_left").map_err(|e| OpError::invalid(e.0))?;
        let table = Table::new(BLOB_COLUMNS.iter().map(|c| c.to_string()).collect(), rows)
            .map_err(|e| OpError::invalid(e.0))?;
        ctx.metric("found", found.markers.len() as f64);
        let centres: Vec<(f64, f64)> = found.markers.iter().map(|m| m.left.image_px).collect();
        if let Ok(rgb) = rgb8(&left_image, "left")
            && let Ok(png) = detections_png(rgb, left_image.width, left_image.height, &centres)
        {
            ctx.figure(
                "detections",
                "Markers found in both images, marked on the left image (half size)",
                fusegraph_engine::figure::FigureData::Png(png),
            )?;
        }
        ctx.metric("blobs_left", found.blobs_left as f64);
        ctx.metric("blobs_right", found.blobs_right as f64);
        Ok(Outputs::new().with("markers", markers).with("blobs", table))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusegraph_engine::param::ParamValue;
    use std::collections::BTreeMap;

    fn params(op: &HsvMarkersOp) -> Params {
        Params(
            op.spec()
                .params
                .iter()
                .map(|p| (p.name.clone(), p.default.clone().unwrap()))
                .collect(),
        )
    }

    fn rectification(width: usize, height: usize) -> Rectification {
        let eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let (f, b) = (1000.0, 50.0);
        Rectification {
            width,
            height,
            r1: eye,
            r2: eye,
            p1: [
                [f, 0.0, 20.0, 0.0],
                [0.0, f, 15.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
            p2: [
                [f, 0.0, 20.0, -f * b],
                [0.0, f, 15.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
            q: [
                [1.0, 0.0, 0.0, -20.0],
                [0.0, 1.0, 0.0, -15.0],
                [0.0, 0.0, 0.0, f],
                [0.0, 0.0, 1.0 / b, 0.0],
            ],
        }
    }

    /// A green disc of radius 6 px at (cx, 15) on grey.
    fn image(cx: f64) -> Image {
        let (w, h) = (60, 30);
        let px: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                if (x - cx).powi(2) + (y - 15.0).powi(2) <= 36.0 {
                    [25, 184, 51]
                } else {
                    [120, 120, 120]
                }
            })
            .collect();
        Image::new(w, h, 3, Pixels::U8(px.into())).unwrap()
    }

    fn run(inputs: Vec<(&str, fusegraph_engine::Value)>, p: &Params) -> Result<Outputs, OpError> {
        let op = HsvMarkersOp::new();
        let inputs = Inputs(
            inputs
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect::<BTreeMap<_, _>>(),
        );
        op.run(
            &inputs,
            p,
            &mut RunCtx::new("m", std::path::Path::new("/tmp")),
        )
    }

    #[test]
    fn finds_a_pair_and_reports_bad_inputs() {
        let op = HsvMarkersOp::new();
        op.spec().check().unwrap();
        let p = params(&op);
        let base = || {
            vec![
                ("left", image(40.0).into()),
                ("right", image(30.0).into()),
                ("rectification", rectification(60, 30).into()),
            ]
        };
        let out = run(base(), &p).unwrap();
        let Some(fusegraph_engine::Value::Markers(m)) = out.0.get("markers") else {
            panic!("no markers")
        };
        assert_eq!((m.len(), m.frame.as_str()), (1, "camera_left"));
        // Disparity 10 px with f = 1000 px, b = 50 mm: z = 5000 mm; x = 20 px
        // right of the principal point: 100 mm.
        let z = m.positions_mm[2];
        assert!(
            (z - 5000.0).abs() < 5.0 && (m.positions_mm[0] - 100.0).abs() < 0.2,
            "{m:?}"
        );
        let Some(fusegraph_engine::Value::Table(t)) = out.0.get("blobs") else {
            panic!("no table")
        };
        assert_eq!(t.columns, BLOB_COLUMNS);
        assert!((t.column("disparity_px").unwrap()[0] - 10.0).abs() < 0.01);

        let mut grey = base();
        grey[0].1 = Image::new(60, 30, 1, Pixels::U8(vec![0u8; 1800].into()))
            .unwrap()
            .into();
        let err = run(grey, &p).unwrap_err().to_string();
        assert!(err.contains("`left`") && err.contains("8-bit RGB"), "{err}");
        let mut sizes = base();
        sizes[2].1 = rectification(64, 30).into();
        let err = run(sizes, &p).unwrap_err().to_string();
        assert!(err.contains("60 x 30") && err.contains("64 x 30"), "{err}");
        let mut range = base();
        range.push(("min_disparity", 20.0.into()));
        range.push(("max_disparity", 5.0.into()));
        let err = run(range, &p).unwrap_err().to_string();
        assert!(err.contains("empty disparity range"), "{err}");
        let mut hue = p.clone();
        hue.0
            .insert("hue_deg".into(), ParamValue::FloatList(vec![100.0]));
        let err = run(base(), &hue).unwrap_err().to_string();
        assert!(err.contains("hue_deg"), "{err}");
    }
}
