//! Reading DICOM series into volumes: `dicom.load_series`.
//!
//! Files are read with dicom-object and decoded with dicom-pixeldata (every
//! uncompressed transfer syntax, deflate, RLE, JPEG baseline/lossless, JPEG 2000
//! via the pure-Rust openjp2 port; JPEG-LS needs a C library and is reported as
//! unsupported, naming the syntax). Geometry comes from ImagePositionPatient,
//! ImageOrientationPatient and PixelSpacing; slices are ordered by their position
//! along the slice normal, never by file name or InstanceNumber.

mod frames;
mod ops;
mod series;

pub use frames::{Frame, read_frames};
pub use series::{LoadedSeries, SeriesError, assemble, load_series};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;
use std::sync::Arc;

/// Registers the `dicom.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.register(Arc::new(ops::LoadSeriesOp::new()))
}
