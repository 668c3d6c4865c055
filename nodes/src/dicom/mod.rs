//! Reading DICOM series into volumes: `dicom.load_series`.
//!
//! Files are read with dicom-object and decoded with dicom-pixeldata (every
//! uncompressed transfer syntax, deflate, RLE, JPEG baseline/lossless, JPEG 2000
//! via the pure-Rust openjp2 port). JPEG-LS is reported as unsupported, naming
//! the file and syntax: dicom-pixeldata decodes it only through CharLS, whose
//! `charls` feature builds the C++ library with CMake (not on a clean machine).
//! 8-, 16- and 32-bit integer samples are read (32-bit: RT Dose, with
//! DoseGridScaling applied and frames placed by GridFrameOffsetVector).
//! Geometry comes from ImagePositionPatient, ImageOrientationPatient and
//! PixelSpacing; slices are ordered by their position along the slice normal,
//! never by file name or InstanceNumber. Headers are checked before decoding
//! (declared lengths against the file size, the pixel module, the pixel data
//! size, numbers that must parse and be finite), and the slices of a series
//! must share one pixel format. Non-image objects in a folder (DICOMDIR,
//! structured reports, RT plans, ...) are skipped with a warning per file.

mod frames;
mod header;
mod layout;
pub mod ops;
mod series;

pub use frames::{Encoding, FileContent, Frame, dicom_encoding, read_file, read_frames};
pub use header::{
    MAX_DECODE_BYTES, MAX_SPACING_MM, MAX_VOXELS, ORIENTATION_TOLERANCE, PixelFormat,
    check_orientation, check_pixel_size, check_pixel_spacing, expected_pixel_bytes, finite_numbers,
    number_of_frames, pixel_format,
};
pub use layout::{Layout, LengthError, looks_like_bare_dataset, scan_layout, tag_name};
pub use series::{
    LoadOptions, LoadedSeries, MAX_NAMED_SKIPS, SeriesError, assemble, load_series,
    load_series_with,
};

use fusegraph_engine::Registry;
use fusegraph_engine::registry::RegisterError;

/// Registers the `dicom.*` ops.
pub fn register(registry: &mut Registry) -> Result<(), RegisterError> {
    registry.add::<ops::LoadSeries>()
}
