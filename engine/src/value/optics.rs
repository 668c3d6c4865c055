//! Cameras and transforms: [`Camera`], [`StereoRig`], [`Rectification`], [`Transform`].
//! Conventions follow OpenCV (pixel centres at integer coordinates, x right, y down,
//! camera z forward) so parameters can be exchanged with it directly.

use serde::Serialize;

/// A pinhole camera with Brown-Conrady lens distortion.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Camera {
    /// Image width in px.
    pub width: usize,
    /// Image height in px.
    pub height: usize,
    /// Intrinsic matrix K (fx, fy, cx, cy in px), row-major.
    pub k: [[f64; 3]; 3],
    /// Distortion coefficients k1, k2, p1, p2, k3 (OpenCV order, dimensionless).
    pub distortion: [f64; 5],
}

/// Two cameras and the rig extrinsics: a point X in the left camera's frame (mm)
/// is at `rotation * X + translation_mm` in the right camera's frame.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StereoRig {
    /// The left (reference) camera.
    pub left: Camera,
    /// The right camera.
    pub right: Camera,
    /// Rotation from the left to the right camera frame, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Translation from the left to the right camera frame, mm.
    pub translation_mm: [f64; 3],
}

/// Stereo rectification (Bouguet), as OpenCV's `stereoRectify` returns it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Rectification {
    /// Rectified image width in px.
    pub width: usize,
    /// Rectified image height in px.
    pub height: usize,
    /// Rotation of the left camera into the rectified frame.
    pub r1: [[f64; 3]; 3],
    /// Rotation of the right camera into the rectified frame.
    pub r2: [[f64; 3]; 3],
    /// Left rectified projection (px; translation in mm).
    pub p1: [[f64; 4]; 3],
    /// Right rectified projection (px; translation in mm).
    pub p2: [[f64; 4]; 3],
    /// Disparity-to-depth matrix: (x, y, d, 1) -> homogeneous (X, Y, Z, W), mm.
    pub q: [[f64; 4]; 4],
}

/// A 4x4 homogeneous transform (rotation, translation in mm, optionally a uniform
/// scale) mapping points from frame `from` to frame `to`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Transform {
    /// Row-major 4x4 matrix; `p_to = matrix * p_from`.
    pub matrix: [[f64; 4]; 4],
    /// Frame the transform maps from (e.g. `"mri_lps"`).
    pub from: String,
    /// Frame the transform maps to (e.g. `"camera_left"`).
    pub to: String,
}

impl Transform {
    /// The identity between two frames.
    pub fn identity(from: impl Into<String>, to: impl Into<String>) -> Self {
        let mut matrix = [[0.0; 4]; 4];
        (0..4).for_each(|i| matrix[i][i] = 1.0);
        Transform {
            matrix,
            from: from.into(),
            to: to.into(),
        }
    }
}
