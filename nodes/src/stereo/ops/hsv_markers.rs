//! `stereo.hsv_markers`: coloured markers found in both images, paired and
//! triangulated.

use super::shape_error;
use crate::calib::rectification_of;
use crate::calib::{RigModel, perturbed_rigs_from_table, triangulated_covariance};
use crate::calib::{columns_with_covariance, covariance_entries};
use crate::camera::CameraModel;
use crate::stereo::markers::MIN_PAIRS_FOR_NOISE;
use crate::stereo::markers::detections_png;
use crate::stereo::{
    BlobParams, GREY_CHROMA_LEVELS, PairParams, StereoMarker, localisation_noise_px, max_chroma,
    stereo_markers, stereo_markers_unrectified,
};
use fusegraph_engine::figure::FigureData;
use fusegraph_engine::typed::prelude::*;
use fusegraph_engine::value::{Image, Markers, Pixels, Rectification, StereoRig, Table};

/// Coloured markers found by HSV thresholds in both rectified images, paired
/// along rows, triangulated
#[derive(Debug, Clone, PartialEq, Op)]
// 6: each marker's covariance. 7: and its localisation part alone.
#[op(name = "stereo.hsv_markers", version = 7)]
pub struct HsvMarkers {
    /// Hue range [min, max]; min > max wraps through 0 (default: the
    /// phantom's green)
    #[param(default = [90.0, 170.0], unit = "deg", min = 0.0, max = 360.0)]
    pub hue_deg: [f64; 2],
    /// Smallest saturation (0..1)
    #[param(default = 0.45, min = 0.0, max = 1.0)]
    pub min_saturation: f64,
    /// Smallest value, i.e. brightness (0..1)
    #[param(default = 0.12, min = 0.0, max = 1.0)]
    pub min_value: f64,
    /// Disc radius of the opening then closing of the colour mask (0 = none)
    #[param(default = 1, unit = "px", min = 0, max = 10)]
    pub morph_radius_px: usize,
    /// Smallest blob area (pixels)
    #[param(default = 20.0, unit = "px", min = 0.0)]
    pub min_area_px: f64,
    /// Largest blob area (pixels)
    #[param(default = 20000.0, unit = "px", min = 0.0)]
    pub max_area_px: f64,
    /// Largest axis ratio of a blob's moment ellipse (a disc tilted by t:
    /// 1 / cos t)
    #[param(default = 6.0, min = 1.0)]
    pub max_aspect: f64,
    /// Smallest overlap (intersection over union) of a blob with its moment
    /// ellipse
    #[param(default = 0.8, min = 0.0, max = 1.0)]
    pub min_ellipse_fit: f64,
    /// Band around a blob whose pixels count in the centroid by their colour
    /// share
    #[param(default = 2, unit = "px", min = 0, max = 5)]
    pub border_px: usize,
    /// Largest row difference of a left-right pair
    #[param(default = 2.0, unit = "px", min = 0.0)]
    pub row_tolerance_px: f64,
    /// Largest ratio of the areas of a left-right pair
    #[param(default = 1.6, min = 1.0)]
    pub max_area_ratio: f64,
}

/// The inputs of `stereo.hsv_markers`.
#[derive(Inputs)]
pub struct HsvMarkersInputs {
    /// Left image, 8-bit RGB: rectified, or as taken when `rig` is given
    pub left: Arc<Image>,
    /// Right image, 8-bit RGB: rectified, or as taken when `rig` is given
    pub right: Arc<Image>,
    /// The rectification the pair is (or would be) rectified with
    pub rectification: Arc<Rectification>,
    /// The rig that took `left` and `right`: the blobs are then measured in
    /// the images as taken (no resampling blur) and their centroids mapped
    /// into the rectified frame
    pub rig: Option<Arc<StereoRig>>,
    /// The rig's parameter covariance (calib.stereo_calibrate's
    /// `covariance`): its spread joins each marker's covariance
    pub rig_covariance: Option<Arc<Table>>,
    /// Smallest disparity of a pair, px
    pub min_disparity: Option<f64>,
    /// Largest disparity of a pair, px
    pub max_disparity: Option<f64>,
}

/// The outputs of `stereo.hsv_markers`.
#[derive(Outputs)]
pub struct HsvMarkersOutputs {
    /// Marker centres, mm, frame camera_left; ids 0..n in left-blob order
    pub markers: Markers,
    /// One row per marker: centroids in both images, disparity and areas, px
    pub blobs: Table,
    /// Each marker's covariance (camera_left, mm^2) from its centroids'
    /// noise (measured from the pairs' rows) and, given, the calibration's
    /// spread, to first order: `id`, `cov_{xx,xy,xz,yy,yz,zz}_mm2`; needs
    /// `rig` and three or more pairs (otherwise no rows)
    pub covariance: Table,
    /// The part of `covariance` from the centroids' noise alone (the same
    /// columns and rows): what differs from view to view of one rig (the
    /// calibration's error moves every view's markers alike in its own
    /// frame). register.multiview takes it as the sightings' noise and adds
    /// the calibration's spread to their weights itself.
    pub localisation_covariance: Table,
}

/// The covariance rows of [`HsvMarkersOutputs`]: with the calibration's
/// spread, and from the centroids' noise alone.
#[derive(Debug, Default)]
struct CovarianceRows {
    total: Vec<Vec<f64>>,
    localisation: Vec<Vec<f64>>,
}

/// Each marker's covariance rows (see [`HsvMarkersOutputs::covariance`]),
/// and the noise of a centroid; none without a rig or enough pairs.
fn marker_covariances(
    ctx: &mut RunCtx,
    found: &[StereoMarker],
    rig: Option<&StereoRig>,
    rig_covariance: Option<&Table>,
) -> Result<CovarianceRows, OpError> {
    let Some(rig) = rig else {
        if rig_covariance.is_some() {
            return Err(OpError::invalid(
                "rig_covariance needs the rig: connect `rig` too",
            ));
        }
        return Ok(CovarianceRows::default());
    };
    let Some(sigma_px) = localisation_noise_px(found) else {
        ctx.note(format!(
            "no marker covariances: {} pairs, and the centroids' noise is measured from {MIN_PAIRS_FOR_NOISE} or more",
            found.len()
        ));
        return Ok(CovarianceRows::default());
    };
    ctx.metric("localisation_sd_px", sigma_px);
    let model = RigModel::from_value(rig);
    let perturbed = match rig_covariance.filter(|t| t.row_count() > 0) {
        Some(t) => perturbed_rigs_from_table(&model, t)
            .map_err(|e| OpError::invalid(format!("rig_covariance: {e}")))?,
        None => Vec::new(),
    };
    let row = |id: usize, c: &nalgebra::Matrix3<f64>| -> Vec<f64> {
        [id as f64]
            .into_iter()
            .chain(covariance_entries(c))
            .collect()
    };
    let mut rows = CovarianceRows::default();
    for (id, m) in found.iter().enumerate() {
        let both = triangulated_covariance(&model, &perturbed, &m.point_mm, sigma_px)
            .zip(triangulated_covariance(&model, &[], &m.point_mm, sigma_px));
        if let Some((total, localisation)) = both {
            rows.total.push(row(id, &total));
            rows.localisation.push(row(id, &localisation));
        }
    }
    let mean_sd = |rows: &[Vec<f64>]| {
        (rows.iter().map(|r| r[1] + r[4] + r[6]).sum::<f64>() / rows.len() as f64).sqrt()
    };
    if !rows.total.is_empty() {
        ctx.metric("marker_sd_mm", mean_sd(&rows.total));
        ctx.metric("marker_localisation_sd_mm", mean_sd(&rows.localisation));
    }
    Ok(rows)
}

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

impl HsvMarkers {
    /// What a marker looks like in one image.
    pub fn blob_params(&self) -> BlobParams {
        BlobParams {
            hue_deg: (self.hue_deg[0], self.hue_deg[1]),
            min_saturation: self.min_saturation,
            min_value: self.min_value,
            morph_radius_px: self.morph_radius_px,
            min_area_px: self.min_area_px,
            max_area_px: self.max_area_px,
            max_aspect: self.max_aspect,
            min_ellipse_fit: self.min_ellipse_fit,
            border_px: self.border_px,
        }
    }

    /// How blobs pair, within the disparities `min` and `max` (px) where
    /// given.
    pub fn pair_params(&self, min: Option<f64>, max: Option<f64>) -> PairParams {
        PairParams {
            row_tolerance_px: self.row_tolerance_px,
            max_area_ratio: self.max_area_ratio,
            min_disparity_px: min,
            max_disparity_px: max,
        }
    }
}

/// The 8-bit RGB pixels of `img`; an error naming `port` for another kind of
/// image, or for one that is grey throughout (no hue to find markers by).
fn rgb8<'a>(img: &'a Image, port: &str) -> Result<&'a [u8], OpError> {
    match &img.pixels {
        Pixels::U8(p) if img.channels == 3 => {
            let chroma = max_chroma(p);
            if chroma <= GREY_CHROMA_LEVELS {
                return Err(OpError::invalid(format!(
                    "input `{port}` is grey (R, G and B within {chroma} levels in every pixel): \
                     markers are found by their hue, which needs colour photos \
                     (a greyscale camera, or a grey conversion upstream?)"
                )));
            }
            Ok(p)
        }
        Pixels::U8(_) if img.channels == 1 => Err(OpError::invalid(format!(
            "input `{port}` is a one-channel (grey) image: markers are found by their hue, which needs colour (RGB) photos"
        ))),
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

impl RunOp for HsvMarkers {
    type Inputs = HsvMarkersInputs;
    type Outputs = HsvMarkersOutputs;

    fn check(&self, _: Wired) -> Vec<(&'static str, String)> {
        self.blob_params().problems()
    }

    fn run(&self, inputs: Self::Inputs, ctx: &mut RunCtx) -> Result<Self::Outputs, OpError> {
        let (left, right) = (inputs.left, inputs.right);
        let rect_value = inputs.rectification;
        let rig = inputs.rig;
        if rig.is_none() && (rect_value.width, rect_value.height) != (left.width, left.height) {
            return Err(OpError::invalid(format!(
                "input `left` is {} x {} px but the rectification makes {} x {} px images",
                left.width, left.height, rect_value.width, rect_value.height
            )));
        }
        let blob = self.blob_params();
        let pair = self.pair_params(inputs.min_disparity, inputs.max_disparity);
        if let (Some(lo), Some(hi)) = (pair.min_disparity_px, pair.max_disparity_px)
            && (lo.is_nan() || hi.is_nan() || lo > hi)
        {
            return Err(OpError::invalid(format!(
                "empty disparity range: min_disparity {lo} px is above max_disparity {hi} px"
            )));
        }
        let rect = rectification_of(&rect_value);
        let left_rgb = (rgb8(&left, "left")?, left.width, left.height);
        let right_rgb = (rgb8(&right, "right")?, right.width, right.height);
        let found = match &rig {
            Some(rig) => {
                let cameras = (
                    CameraModel::from_value(&rig.left),
                    CameraModel::from_value(&rig.right),
                );
                let cameras = (&cameras.0, &cameras.1);
                stereo_markers_unrectified(left_rgb, right_rgb, cameras, &rect, &blob, &pair)
            }
            None => stereo_markers(left_rgb, right_rgb, &rect, &blob, &pair),
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
        let markers = Markers::new(positions, ids, "camera_left").map_err(shape_error)?;
        let columns = BLOB_COLUMNS.iter().map(|c| c.to_string()).collect();
        let blobs = Table::new(columns, rows).map_err(shape_error)?;
        ctx.metric("found", found.markers.len() as f64);
        let centres: Vec<(f64, f64)> = found.markers.iter().map(|m| m.left.image_px).collect();
        if let Ok(png) = detections_png(left_rgb.0, left.width, left.height, &centres) {
            ctx.figure(
                "detections",
                "Markers found in both images, marked on the left image (half size)",
                FigureData::Png(png),
            )?;
        }
        ctx.metric("blobs_left", found.blobs_left as f64);
        ctx.metric("blobs_right", found.blobs_right as f64);
        let rows = marker_covariances(
            ctx,
            &found.markers,
            rig.as_deref(),
            inputs.rig_covariance.as_deref(),
        )?;
        let table = |rows: Vec<Vec<f64>>| {
            Table::new(columns_with_covariance(&["id"]), rows.concat()).map_err(shape_error)
        };
        Ok(HsvMarkersOutputs {
            markers,
            blobs,
            covariance: table(rows.total)?,
            localisation_covariance: table(rows.localisation)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{ctx, default_params, defaults};
    use super::*;
    use fusegraph_engine::param::ParamValue;
    use fusegraph_engine::typed::Typed;
    use fusegraph_engine::{Inputs, Op};

    #[test]
    fn the_defaults_are_the_blob_and_pair_defaults() {
        let op: HsvMarkers = defaults();
        assert_eq!(op.blob_params(), BlobParams::default());
        assert_eq!(op.pair_params(None, None), PairParams::default());
    }

    fn rectification(width: usize, height: usize) -> Arc<Rectification> {
        let eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let (f, b) = (1000.0, 50.0);
        Arc::new(Rectification {
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
        })
    }

    /// A green disc of radius 6 px at (cx, 15) on grey.
    fn image(cx: f64) -> Arc<Image> {
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
        Arc::new(Image::new(w, h, 3, Pixels::U8(px.into())).unwrap())
    }

    fn base() -> HsvMarkersInputs {
        HsvMarkersInputs {
            left: image(40.0),
            right: image(30.0),
            rectification: rectification(60, 30),
            rig: None,
            rig_covariance: None,
            min_disparity: None,
            max_disparity: None,
        }
    }

    #[test]
    fn finds_a_pair_and_reports_bad_inputs() {
        let op: HsvMarkers = defaults();
        let out = op.run(base(), &mut ctx()).unwrap();
        let m = &out.markers;
        assert_eq!((m.len(), m.frame.as_str()), (1, "camera_left"));
        // Disparity 10 px with f = 1000 px, b = 50 mm: z = 5000 mm; x = 20 px
        // right of the principal point: 100 mm.
        let z = m.positions_mm[2];
        assert!(
            (z - 5000.0).abs() < 5.0 && (m.positions_mm[0] - 100.0).abs() < 0.2,
            "{m:?}"
        );
        assert_eq!(out.blobs.columns, BLOB_COLUMNS);
        assert!((out.blobs.column("disparity_px").unwrap()[0] - 10.0).abs() < 0.01);

        let grey = HsvMarkersInputs {
            left: Arc::new(Image::new(60, 30, 1, Pixels::U8(vec![0u8; 1800].into())).unwrap()),
            ..base()
        };
        let err = op.run(grey, &mut ctx()).err().unwrap().to_string();
        assert!(
            err.contains("`left`") && err.contains("one-channel"),
            "{err}"
        );
        // Grey photos stored as RGB (R = G = B, give or take JPEG rounding).
        let grey_rgb: Vec<u8> = (0..1800)
            .flat_map(|i| {
                let v = (i % 200) as u8;
                [v, v + 1, v]
            })
            .collect();
        let grey_rgb = HsvMarkersInputs {
            right: Arc::new(Image::new(60, 30, 3, Pixels::U8(grey_rgb.into())).unwrap()),
            ..base()
        };
        let err = op.run(grey_rgb, &mut ctx()).err().unwrap().to_string();
        assert!(
            err.contains("input `right` is grey") && err.contains("hue"),
            "{err}"
        );
        let sizes = HsvMarkersInputs {
            rectification: rectification(64, 30),
            ..base()
        };
        let err = op.run(sizes, &mut ctx()).err().unwrap().to_string();
        assert!(err.contains("60 x 30") && err.contains("64 x 30"), "{err}");
        let range = HsvMarkersInputs {
            min_disparity: Some(20.0),
            max_disparity: Some(5.0),
            ..base()
        };
        let err = op.run(range, &mut ctx()).err().unwrap().to_string();
        assert!(err.contains("empty disparity range"), "{err}");
    }

    #[test]
    fn a_hue_range_of_one_number_is_refused_by_name() {
        // Validation refuses it before a run; the adapter names it too.
        let mut params = default_params::<HsvMarkers>();
        params
            .0
            .insert("hue_deg".into(), ParamValue::FloatList(vec![100.0]));
        let mut inputs = Inputs::default();
        let b = base();
        inputs.0.insert("left".into(), b.left.into());
        inputs.0.insert("right".into(), b.right.into());
        inputs
            .0
            .insert("rectification".into(), b.rectification.into());
        let op = Typed::<HsvMarkers>::new().unwrap();
        let err = op.run(&inputs, &params, &mut ctx()).err().unwrap();
        assert!(err.to_string().contains("hue_deg"), "{err}");
    }

    #[test]
    fn the_localisation_part_leaves_out_the_calibrations_spread() {
        let rig = crate::calib::parallel_test_rig();
        // Three markers at 500 mm, their centroids' rows 0.1 px apart.
        let blob = |x: f64, y: f64| crate::stereo::Blob {
            x_px: x,
            y_px: y,
            area_px: 50.0,
            aspect: 1.0,
            fit: 1.0,
            image_px: (x, y),
        };
        let found: Vec<StereoMarker> = [(-30.0, 0.0), (20.0, 10.0), (15.0, -25.0)]
            .iter()
            .map(|&(x, y)| {
                let (u, v) = (400.0 + 1300.0 * x / 500.0, 300.0 + 1300.0 * y / 500.0);
                StereoMarker {
                    left: blob(u, v),
                    right: blob(u - 208.0, v + 0.1),
                    disparity_px: 208.0,
                    point_mm: nalgebra::Point3::new(x, y, 500.0),
                }
            })
            .collect();
        let alone = marker_covariances(&mut ctx(), &found, Some(&rig), None).unwrap();
        assert_eq!(alone.total, alone.localisation);
        // The left focal length known to 2 px: the total grows (every
        // marker is off the optical axis in x, where fx moves it), the
        // localisation part does not.
        let fx = Table::new(vec!["left_fx_px".into()], vec![4.0]).unwrap();
        let rows = marker_covariances(&mut ctx(), &found, Some(&rig), Some(&fx)).unwrap();
        assert_eq!(rows.localisation, alone.localisation);
        for (total, own) in rows.total.iter().zip(&rows.localisation) {
            let trace = |r: &[f64]| r[1] + r[4] + r[6];
            assert!(trace(total) > trace(own) + 1e-6, "{total:?} vs {own:?}");
        }
    }
}
