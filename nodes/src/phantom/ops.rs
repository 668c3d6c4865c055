//! Node adapters: `phantom.generate`, `phantom.camera_surface`, `phantom.rig_pose`
//! and `phantom.true_disparity`.

use super::camera_surface::{SurfaceSimParams, simulate_camera_surface};
use super::generate::{PhantomConfig, PhantomSize, generate};
use super::shape::ShapeParams;
use super::true_disparity::{ViewScene, true_disparity};
use super::truth::GroundTruth;
use crate::camera::CameraModel;
use fusegraph_engine::value::{
    Disparity, Image, Markers, PathValue, Pixels, PointCloud, Rectification, StereoRig,
};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType, path_value,
};

pub(crate) struct GenerateOp(OpSpec);

impl GenerateOp {
    pub(crate) fn new() -> Self {
        let d = ShapeParams::default();
        let c = PhantomConfig::default();
        let lesions: Vec<f64> = d.lesion_centers_mm.iter().flatten().copied().collect();
        GenerateOp(
            OpSpec::new(
                "phantom.generate",
                1,
                "Synthetic breast phantom: MRI DICOM series, stereo calibration and phantom images, ground truth",
            )
            .param(ParamSpec::int("seed", c.seed as i64, "", "Seed of every random choice").at_least(0.0))
            .param(ParamSpec::choice(
                "size",
                &["full", "small"],
                "full: 0.6 x 0.6 x 1.0 mm voxels, full anti-aliasing; small: 1.5 mm voxels, for fast tests",
            ))
            .param(ParamSpec::float("width_mm", d.width_mm, "mm", "Dome width at the base").range(60.0, 200.0))
            .param(ParamSpec::float("depth_mm", d.depth_mm, "mm", "Dome depth at the base").range(60.0, 200.0))
            .param(ParamSpec::float("height_mm", d.height_mm, "mm", "Dome height").range(30.0, 100.0))
            .param(ParamSpec::float("droop_deg", d.droop_deg, "deg", "Forward droop of the dome").range(-20.0, 20.0))
            .param(ParamSpec::int("marker_count", d.marker_count as i64, "", "Number of markers").range(0.0, 30.0))
            .param(
                ParamSpec::float("marker_diameter_mm", d.marker_diameter_mm, "mm", "Marker disc diameter")
                    .range(4.0, 20.0),
            )
            .param(
                ParamSpec::float("marker_thickness_mm", d.marker_thickness_mm, "mm", "Marker height above the skin")
                    .range(2.5, 10.0),
            )
            .param(ParamSpec::float_list(
                "lesions_mm",
                &lesions,
                "mm",
                "Lesion centres in the phantom frame, flattened x, y, z triples",
            ).length_multiple_of(3))
            .param(ParamSpec::float("lesion_diameter_mm", d.lesion_diameter_mm, "mm", "Lesion diameter").range(1.0, 20.0))
            .param(ParamSpec::float("oblique_deg", c.oblique_deg, "deg", "Tilt of the MRI slices from axial").range(-45.0, 45.0))
            .param(ParamSpec::float("mri_noise", c.mri_noise_sigma, "", "MRI noise sigma (tissue signal 0.55)").range(0.0, 0.3))
            .param(
                ParamSpec::int("calibration_pairs", c.calibration_pairs as i64, "", "Usable calibration pairs (3 unusable are added)")
                    .range(3.0, 60.0),
            )
            .param(ParamSpec::int("views", c.views as i64, "", "Phantom view pairs").range(1.0, 24.0))
            .output("mri_dir", ValueType::Path, "Folder of DICOM slices (shuffled file order)")
            .output("calib_dir", ValueType::Path, "Folder of chessboard pairs left_NN.png / right_NN.png")
            .output("views_dir", ValueType::Path, "Folder of phantom pairs left_NN.png / right_NN.png")
            .output("truth", ValueType::Path, "ground_truth.json (schema fusegraph-phantom/1)"),
        )
    }
}

/// The phantom configuration a node's parameters describe.
fn config(params: &Params) -> Result<PhantomConfig, OpError> {
    let lesions = params.float_list("lesions_mm")?;
    if lesions.len() % 3 != 0 {
        return Err(OpError::invalid(format!(
            "lesions_mm holds {} numbers; it must hold x, y, z triples",
            lesions.len()
        )));
    }
    let size = params.string("size")?;
    Ok(PhantomConfig {
        seed: params.int("seed")? as u64,
        size: PhantomSize::parse(&size)
            .ok_or_else(|| OpError::invalid(format!("unknown size {size}")))?,
        shape: ShapeParams {
            width_mm: params.float("width_mm")?,
            depth_mm: params.float("depth_mm")?,
            height_mm: params.float("height_mm")?,
            droop_deg: params.float("droop_deg")?,
            marker_count: params.count("marker_count")?,
            marker_diameter_mm: params.float("marker_diameter_mm")?,
            marker_thickness_mm: params.float("marker_thickness_mm")?,
            lesion_centers_mm: lesions.chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
            lesion_diameter_mm: params.float("lesion_diameter_mm")?,
        },
        oblique_deg: params.float("oblique_deg")?,
        mri_noise_sigma: params.float("mri_noise")?,
        calibration_pairs: params.count("calibration_pairs")?,
        views: params.count("views")?,
    })
}

impl Op for GenerateOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, _: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let config = config(params)?;
        let dir = ctx.work_dir()?;
        let g = generate(&config, &dir).map_err(OpError::invalid)?;
        ctx.metric("markers", g.truth.markers.len() as f64);
        ctx.metric("lesions", g.truth.lesions.len() as f64);
        ctx.metric("mri_slices", g.truth.mri.files as f64);
        ctx.metric("calibration_pairs", g.truth.calibration.len() as f64);
        ctx.metric("views", g.truth.views.len() as f64);
        ctx.metric("mri_ms", g.stage_ms[0]);
        ctx.metric("calibration_ms", g.stage_ms[1]);
        ctx.metric("views_ms", g.stage_ms[2]);
        Ok(Outputs::new()
            .with("mri_dir", path_value(&g.mri_dir)?)
            .with("calib_dir", path_value(&g.calib_dir)?)
            .with("views_dir", path_value(&g.views_dir)?)
            .with("truth", path_value(&g.truth_file)?))
    }
}

pub(crate) struct CameraSurfaceOp(OpSpec);

impl CameraSurfaceOp {
    pub(crate) fn new() -> Self {
        CameraSurfaceOp(
            OpSpec::new(
                "phantom.camera_surface",
                1,
                "Simulated stereo reconstruction of one phantom view, from the truth: noisy visible surface and markers",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json of a phantom")
            .param(ParamSpec::int("view", 0, "", "Which view pair").at_least(0.0))
            .param(ParamSpec::int("step_px", 3, "px", "Sample every this many left-image pixels").range(1.0, 64.0))
            .param(ParamSpec::float("depth_noise_mm", 0.5, "mm", "Noise along the viewing ray").range(0.0, 10.0))
            .param(ParamSpec::float("lateral_noise_mm", 0.1, "mm", "Noise across the viewing ray").range(0.0, 10.0))
            .param(ParamSpec::float("outlier_fraction", 0.03, "", "Fraction of points 5-30 mm off").range(0.0, 0.5))
            .param(ParamSpec::float("marker_noise_mm", 0.3, "mm", "Noise of each marker centre").range(0.0, 10.0))
            .param(ParamSpec::int("missing_markers", 2, "", "Visible markers to drop").range(0.0, 30.0))
            .param(ParamSpec::int("spurious_markers", 1, "", "Spurious markers to add").range(0.0, 10.0))
            .param(ParamSpec::int("seed", 1, "", "Seed of the noise").at_least(0.0))
            .output("cloud", ValueType::PointCloud, "Visible surface, left camera frame (camera_left), mm")
            .output("markers", ValueType::Markers, "Marker face centres, left camera frame, mm (ids are arbitrary)"),
        )
    }
}

impl Op for CameraSurfaceOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let truth = truth_input(inputs)?;
        let p = SurfaceSimParams {
            view: params.count("view")?,
            step_px: params.count("step_px")?,
            depth_noise_mm: params.float("depth_noise_mm")?,
            lateral_noise_mm: params.float("lateral_noise_mm")?,
            outlier_fraction: params.float("outlier_fraction")?,
            marker_noise_mm: params.float("marker_noise_mm")?,
            missing_markers: params.count("missing_markers")?,
            spurious_markers: params.count("spurious_markers")?,
            seed: params.int("seed")? as u64,
        };
        let sim = simulate_camera_surface(&truth, &p).map_err(OpError::invalid)?;
        ctx.metric("points", sim.points.len() as f64);
        ctx.metric("outliers", sim.outliers as f64);
        ctx.metric("markers", sim.markers.len() as f64);
        let flat: Vec<f32> = sim.points.iter().flatten().copied().collect();
        let cloud =
            PointCloud::new(flat, None, None, "camera_left").map_err(|e| OpError::invalid(e.0))?;
        let positions: Vec<f64> = sim.markers.iter().flatten().copied().collect();
        let ids: Vec<u32> = (0..sim.markers.len() as u32).collect();
        let markers =
            Markers::new(positions, ids, "camera_left").map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new().with("cloud", cloud).with("markers", markers))
    }
}

pub(crate) struct RigPoseOp(OpSpec);

impl RigPoseOp {
    pub(crate) fn new() -> Self {
        RigPoseOp(
            OpSpec::new(
                "phantom.rig_pose",
                1,
                "A phantom view's left camera pose, as a robot arm would report it (with noise)",
            )
            .input(
                "truth",
                &[ValueType::Path],
                "ground_truth.json of a phantom",
            )
            .param(ParamSpec::int("view", 0, "", "Which view pair").at_least(0.0))
            .param(
                ParamSpec::float("noise_mm", 0.0, "mm", "Uniform position error, each axis")
                    .range(0.0, 1000.0),
            )
            .param(
                ParamSpec::float("noise_deg", 0.0, "deg", "Uniform rotation error, each axis")
                    .range(0.0, 180.0),
            )
            .param(ParamSpec::int("seed", 1, "", "Seed of the noise").at_least(0.0))
            .output("pose", ValueType::Transform, "camera_left -> world"),
        )
    }
}

impl Op for RigPoseOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
        use rand::{Rng, SeedableRng};
        let truth = truth_input(inputs)?;
        let view = params.count("view")?;
        let v = truth.views.get(view).ok_or_else(|| {
            OpError::invalid(format!(
                "view {view} does not exist ({} views)",
                truth.views.len()
            ))
        })?;
        let (mm, deg) = (
            params.float("noise_mm")?,
            params.float("noise_deg")?.to_radians(),
        );
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            params.int("seed")? as u64 ^ (view as u64) << 32,
        );
        let mut draw = |a: f64| {
            if a > 0.0 {
                rng.random_range(-a..a)
            } else {
                0.0
            }
        };
        let noise = nalgebra::Isometry3::new(
            nalgebra::Vector3::new(draw(mm), draw(mm), draw(mm)),
            nalgebra::Vector3::new(draw(deg), draw(deg), draw(deg)),
        );
        let pose = crate::camera::isometry_from_matrix(&v.left_camera_to_world) * noise;
        Ok(Outputs::new().with(
            "pose",
            fusegraph_engine::value::Transform {
                matrix: crate::camera::isometry_to_matrix(&pose),
                from: "camera_left".into(),
                to: "world".into(),
            },
        ))
    }
}

pub(crate) struct TrueDisparityOp(OpSpec);

impl TrueDisparityOp {
    pub(crate) fn new() -> Self {
        TrueDisparityOp(
            OpSpec::new(
                "phantom.true_disparity",
                1,
                "True disparity of a view pair as rectified with an estimated rig (calibration error included)",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json of a phantom")
            .input(
                "rig",
                &[ValueType::StereoRig],
                "The rig the images are rectified with (usually the estimated one)",
            )
            .input(
                "rectification",
                &[ValueType::Rectification],
                "calib.rectify of that rig",
            )
            .param(ParamSpec::int("view", 0, "", "Which view pair").at_least(0.0))
            .output(
                "disparity",
                ValueType::Disparity,
                "x_left - x_right on the left rectified image, px; NaN where unknown (nothing hit, outside either image, hidden from the right camera)",
            )
            .output(
                "mask",
                ValueType::Image,
                "Grey u8, left rectified: 255 where the pixel sees skin and the disparity is known",
            )
            .output(
                "labels",
                ValueType::Image,
                "Grey u8, left rectified: 0 nothing, 1 table, 2 skin, 3 marker side, 4 marker face",
            ),
        )
    }
}

impl Op for TrueDisparityOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let truth = truth_input(inputs)?;
        let rig = inputs.get::<StereoRig>("rig")?;
        let rect = crate::calib::rectification_of(&*inputs.get::<Rectification>("rectification")?);
        let scene =
            ViewScene::from_truth(&truth, params.count("view")?).map_err(OpError::invalid)?;
        let (left, right) = (
            CameraModel::from_value(&rig.left),
            CameraModel::from_value(&rig.right),
        );
        let t = true_disparity(&scene, &left, &right, &rect).map_err(OpError::invalid)?;
        let total = (t.width * t.height) as f64;
        ctx.metric("known_pct", 100.0 * t.known as f64 / total);
        ctx.metric("skin_pct", 100.0 * t.skin as f64 / total);
        ctx.metric("row_error_px", t.row_error_px);
        ctx.metric("min_px", t.min_px);
        ctx.metric("max_px", t.max_px);
        let (w, h) = (t.width, t.height);
        let grey = |data: Vec<u8>| {
            Image::new(w, h, 1, Pixels::U8(data.into())).map_err(|e| OpError::invalid(e.0))
        };
        let disparity = Disparity::new(w, h, t.disparity_px).map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new()
            .with("disparity", disparity)
            .with("mask", grey(t.mask)?)
            .with("labels", grey(t.labels)?))
    }
}

/// The ground truth on an optional `truth` input (a ground_truth.json path).
pub(crate) fn optional_truth_input(inputs: &Inputs) -> Result<Option<GroundTruth>, OpError> {
    match inputs.optional::<PathValue>("truth")? {
        Some(file) => GroundTruth::load(&file.path)
            .map(Some)
            .map_err(OpError::invalid),
        None => Ok(None),
    }
}

/// The ground truth on a required `truth` input.
pub(crate) fn truth_input(inputs: &Inputs) -> Result<GroundTruth, OpError> {
    optional_truth_input(inputs)?
        .ok_or_else(|| OpError::Input("truth".into(), "not connected".into()))
}

pub(crate) struct LesionsOp(OpSpec);

impl LesionsOp {
    pub(crate) fn new() -> Self {
        LesionsOp(
            OpSpec::new(
                "phantom.lesions",
                1,
                "The phantom's lesion centres in MRI space: the targets a radiologist would mark on the scan",
            )
            .input("truth", &[ValueType::Path], "ground_truth.json of a phantom")
            .output(
                "targets",
                ValueType::Markers,
                "Lesion centres, mm, frame mri_lps; ids the lesion numbers",
            ),
        )
    }
}

impl Op for LesionsOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }

    fn run(&self, inputs: &Inputs, _: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let truth = truth_input(inputs)?;
        let positions: Vec<f64> = truth.lesions.iter().flat_map(|l| l.center_mri_mm).collect();
        let ids: Vec<u32> = truth.lesions.iter().map(|l| l.id).collect();
        ctx.metric("targets", ids.len() as f64);
        let targets = Markers::new(positions, ids, "mri_lps").map_err(|e| OpError::invalid(e.0))?;
        Ok(Outputs::new().with("targets", targets))
    }
}
