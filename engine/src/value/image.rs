//! 2D rasters: [`Image`] and [`Disparity`].

use super::{ValueError, check_len};
use serde::Serialize;
use std::sync::Arc;

/// Pixel storage of an [`Image`]: row-major, channels interleaved.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum Pixels {
    /// 8-bit samples (0..=255).
    U8(Arc<[u8]>),
    /// Floating-point samples (usually 0..=1).
    F32(Arc<[f32]>),
}

impl Pixels {
    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            Pixels::U8(p) => p.len(),
            Pixels::F32(p) => p.len(),
        }
    }

    /// Whether there is no sample.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// An image of `width x height` pixels with 1 (grey) or 3 (RGB) channels.
/// Pixel (x, y) has its top-left corner at (x, y) and its centre at (x + 0.5, y + 0.5)
/// in the OpenCV convention used for pixel coordinates elsewhere, i.e. integer
/// coordinates are pixel centres.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Image {
    /// Width in px.
    pub width: usize,
    /// Height in px.
    pub height: usize,
    /// 1 (grey) or 3 (RGB).
    pub channels: usize,
    /// `width * height * channels` samples.
    pub pixels: Pixels,
}

impl Image {
    /// Checks the channel count and the buffer length.
    pub fn new(
        width: usize,
        height: usize,
        channels: usize,
        pixels: Pixels,
    ) -> Result<Self, ValueError> {
        if channels != 1 && channels != 3 {
            return Err(ValueError(format!(
                "Image: {channels} channels (1 or 3 expected)"
            )));
        }
        check_len("Image", pixels.len(), width * height * channels)?;
        Ok(Image {
            width,
            height,
            channels,
            pixels,
        })
    }
}

/// A dense disparity map (px) on the left rectified image: `x_left - x_right`;
/// NaN where there is no match.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Disparity {
    /// Width in px.
    pub width: usize,
    /// Height in px.
    pub height: usize,
    /// Row-major disparities in px.
    pub data: Arc<[f32]>,
}

impl Disparity {
    /// Checks the buffer length.
    pub fn new(
        width: usize,
        height: usize,
        data: impl Into<Arc<[f32]>>,
    ) -> Result<Self, ValueError> {
        let data = data.into();
        check_len("Disparity", data.len(), width * height)?;
        Ok(Disparity {
            width,
            height,
            data,
        })
    }
}
