//! `ground_truth.json`: everything the phantom generator knows, for measuring
//! every stage against. The schema is documented field by field here and in the
//! README. Frames: `phantom` (the phantom's own, base on z = 0), `mri` (DICOM
//! patient LPS), `world` (the table/robot frame, z up; the phantom base lies on
//! z = 0), `left_camera` (OpenCV camera frame). All lengths in mm; matrices are
//! row-major 4x4 `a_to_b` mapping points in frame a to frame b.

use super::motion::MotionField;
use super::props::Prop;
use super::shape::PhantomShape;
use crate::camera::CameraModel;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The current schema name.
pub const SCHEMA: &str = "fusegraph-phantom/1";

/// A row-major 4x4 matrix.
pub type Mat4 = [[f64; 4]; 4];

/// The whole ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    /// Always [`SCHEMA`].
    pub schema: String,
    /// Generator seed.
    pub seed: u64,
    /// Seed of the cameras' sensor noise, where one was given apart from
    /// [`GroundTruth::seed`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor_seed: Option<u64>,
    /// `small` or `full`.
    pub size: String,
    /// The phantom's geometry in its own frame.
    pub shape: PhantomShape,
    /// Phantom frame -> MRI patient LPS.
    pub phantom_to_mri: Mat4,
    /// Phantom frame -> world.
    pub phantom_to_world: Mat4,
    /// MRI patient LPS -> world: the transform registration must recover.
    pub mri_to_world: Mat4,
    /// The MRI series.
    pub mri: MriTruth,
    /// Marker centres.
    pub markers: Vec<MarkerTruth>,
    /// Lesion (target) centres.
    pub lesions: Vec<LesionTruth>,
    /// The stereo rig.
    pub rig: RigTruth,
    /// The calibration target.
    pub chessboard: ChessboardTruth,
    /// Calibration image pairs (world = left camera frame).
    pub calibration: Vec<CalibrationPairTruth>,
    /// Phantom image pairs.
    pub views: Vec<ViewTruth>,
    /// Points sampled uniformly over the skin (dome surface), world frame, mm,
    /// where the cameras see them (after any motion).
    pub skin_world_mm: Vec<[f64; 3]>,
    /// How the tissue moved between the MRI and the camera session (phantom
    /// frame); absent when it did not. World positions above are where the
    /// cameras see things; `scanned_world_mm` fields are where they were
    /// when scanned (`mri_to_world` applied to the MRI positions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<MotionField>,
    /// Things beside the phantom in the camera session (distractors, a
    /// tool), world frame.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub props: Vec<Prop>,
    /// The acquisition conditions in force (light, lens, sensor, texture,
    /// motion, scene), by `phantom.generate`'s parameter names; absent for
    /// the ideal phantom.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub conditions: Option<std::collections::BTreeMap<String, serde_json::Value>>,
}

/// The MRI series geometry and contrast.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MriTruth {
    /// Folder, relative to the truth file.
    pub dir: String,
    /// Number of files (one per slice).
    pub files: usize,
    /// Columns, rows, slices.
    pub dims: [usize; 3],
    /// Voxel spacing along columns, rows, slices, mm.
    pub spacing_mm: [f64; 3],
    /// Voxel index (i, j, k) -> patient LPS mm.
    pub voxel_to_patient: Mat4,
    /// Tilt of the slice plane from axial, deg.
    pub oblique_deg: f64,
    /// SeriesInstanceUID.
    pub series_uid: String,
    /// Stored value * slope = signal.
    pub rescale_slope: f64,
    /// Noise-free signal of tissue, gel, lesion.
    pub signal_tissue_gel_lesion: [f32; 3],
    /// Complex Gaussian noise sigma (Rician magnitude noise), signal units.
    pub noise_sigma: f64,
}

/// One marker's true centres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkerTruth {
    /// Marker number.
    pub id: u32,
    /// Gel core centre in MRI patient LPS, mm (what MRI localisation finds).
    pub center_mri_mm: [f64; 3],
    /// Gel core centre in world, mm, in the camera session.
    pub center_world_mm: [f64; 3],
    /// Centre of the coloured outer face in world, mm (what cameras see).
    pub face_center_world_mm: [f64; 3],
    /// Outward axis of the marker, world.
    pub normal_world: [f64; 3],
    /// Disc diameter, mm.
    pub diameter_mm: f64,
    /// Gel core centre in world as scanned, mm, when the tissue moved since.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scanned_world_mm: Option<[f64; 3]>,
}

/// One lesion's true centre (the targets of target registration error).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LesionTruth {
    /// Lesion number.
    pub id: u32,
    /// Centre in MRI patient LPS, mm.
    pub center_mri_mm: [f64; 3],
    /// Centre in world, mm, in the camera session (where a needle must go).
    pub center_world_mm: [f64; 3],
    /// Diameter, mm.
    pub diameter_mm: f64,
    /// Centre in world as scanned, mm, when the tissue moved since.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scanned_world_mm: Option<[f64; 3]>,
}

/// Both cameras and the rig extrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigTruth {
    /// Left camera intrinsics and distortion.
    pub left: CameraModel,
    /// Right camera intrinsics and distortion.
    pub right: CameraModel,
    /// Left camera frame -> right camera frame (OpenCV's R, T).
    pub left_to_right: Mat4,
    /// Distance between the camera centres, mm.
    pub baseline_mm: f64,
    /// Angle between the optical axes, deg.
    pub verging_deg: f64,
}

/// The chessboard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChessboardTruth {
    /// Inner corners per row and per column (OpenCV's pattern size), e.g. [9, 6].
    pub pattern: [usize; 2],
    /// Square size, mm.
    pub square_mm: f64,
    /// White border beyond the outer squares, mm.
    pub margin_mm: f64,
}

/// One calibration pair.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationPairTruth {
    /// Pair number.
    pub index: usize,
    /// Left image, relative to the truth file.
    pub left: String,
    /// Right image, relative to the truth file.
    pub right: String,
    /// Board frame (origin at the first inner corner, x along a row of corners,
    /// y down the columns, z into the board) -> left camera frame.
    pub board_to_left_camera: Mat4,
    /// Whether the whole board is visible and resolvable in both images.
    pub detectable: bool,
    /// Why not, when not.
    pub note: String,
}

/// One phantom view pair.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewTruth {
    /// View number.
    pub index: usize,
    /// Left image, relative to the truth file.
    pub left: String,
    /// Right image, relative to the truth file.
    pub right: String,
    /// Left camera frame -> world (the rig pose).
    pub left_camera_to_world: Mat4,
    /// Markers whose coloured face is visible (facing, unoccluded, in frame) in
    /// the left image.
    pub markers_visible_left: Vec<u32>,
    /// The same for the right image.
    pub markers_visible_right: Vec<u32>,
}

impl GroundTruth {
    /// The motion between scan and camera session (a still field when none).
    pub fn motion_field(&self) -> MotionField {
        self.motion.clone().unwrap_or_else(MotionField::still)
    }

    /// Reads and checks a truth file.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let truth: GroundTruth = serde_json::from_str(&text)
            .map_err(|e| format!("{}: not a phantom truth file: {e}", path.display()))?;
        if truth.schema != SCHEMA {
            return Err(format!(
                "{}: schema {:?}, expected {SCHEMA:?}",
                path.display(),
                truth.schema
            ));
        }
        Ok(truth)
    }

    /// Writes the truth as JSON.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string(self).map_err(std::io::Error::other)?;
        std::fs::write(path, text)
    }
}
