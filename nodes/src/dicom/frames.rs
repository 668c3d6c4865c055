//! One DICOM file -> its image frames with their geometry, rescaled to f32.

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, InMemDicomObject};
use dicom_pixeldata::PixelDecoder;
use dicom_transfer_syntax_registry::TransferSyntaxIndex;
use std::path::{Path, PathBuf};

/// One 2D image with its place in patient space (LPS, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The file it came from.
    pub file: PathBuf,
    /// Frame number within the file (0 for single-frame files).
    pub frame: u32,
    /// SeriesInstanceUID (empty if absent).
    pub series_uid: String,
    /// SeriesDescription (empty if absent).
    pub series_description: String,
    /// Rows (j).
    pub rows: usize,
    /// Columns (i).
    pub cols: usize,
    /// ImagePositionPatient: centre of the first pixel, mm.
    pub position: [f64; 3],
    /// ImageOrientationPatient: row direction (increasing column index), then
    /// column direction (increasing row index), unit vectors.
    pub orientation: [f64; 6],
    /// PixelSpacing: between rows, between columns, mm.
    pub pixel_spacing: [f64; 2],
    /// SliceThickness or SpacingBetweenSlices, mm, if given.
    pub slice_thickness: Option<f64>,
    /// Pixel values with the modality rescale applied, row-major.
    pub pixels: Vec<f32>,
}

/// Whether a file starts like a DICOM Part 10 file ("DICM" after a 128-byte
/// preamble). Other files in a series folder (notes, DICOMDIR viewers' files) are
/// skipped rather than failing the load.
pub fn looks_like_dicom(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 132];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| &head[128..132] == b"DICM")
}

fn text(obj: &InMemDicomObject, tag: Tag) -> String {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

fn numbers(obj: &InMemDicomObject, tag: Tag) -> Option<Vec<f64>> {
    obj.element_opt(tag).ok().flatten()?.to_multi_float64().ok()
}

/// The first item of sequence `seq` in `obj`.
fn item(obj: &InMemDicomObject, seq: Tag) -> Option<&InMemDicomObject> {
    obj.element_opt(seq).ok().flatten()?.items()?.first()
}

/// A geometry attribute: at the top level, or in the functional groups of an
/// enhanced multi-frame object (per-frame first, then shared).
fn geometry(
    obj: &InMemDicomObject,
    per_frame: Option<&InMemDicomObject>,
    macro_seq: Tag,
    tag: Tag,
) -> Option<Vec<f64>> {
    let shared = item(obj, tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE);
    per_frame
        .and_then(|f| item(f, macro_seq))
        .and_then(|m| numbers(m, tag))
        .or_else(|| {
            shared
                .and_then(|s| item(s, macro_seq))
                .and_then(|m| numbers(m, tag))
        })
        .or_else(|| numbers(obj, tag))
}

fn fixed<const N: usize>(v: Option<Vec<f64>>, path: &Path, name: &str) -> Result<[f64; N], String> {
    let v = v.ok_or_else(|| {
        format!(
            "{}: missing {name}, cannot place the image in space",
            path.display()
        )
    })?;
    v.get(..N)
        .filter(|s| s.iter().all(|x| x.is_finite()))
        .map(|s| std::array::from_fn(|i| s[i]))
        .ok_or_else(|| {
            format!(
                "{}: {name} has {} values, expected {N}",
                path.display(),
                v.len()
            )
        })
}

/// Reads every frame of one file. Errors name the file and what is wrong:
/// truncated or corrupt data, missing geometry, an unsupported transfer syntax.
pub fn read_frames(path: &Path) -> Result<Vec<Frame>, String> {
    let obj: DefaultDicomObject = dicom_object::open_file(path)
        .map_err(|e| format!("{}: unreadable DICOM file: {e}", path.display()))?;
    let syntax = obj
        .meta()
        .transfer_syntax()
        .trim_end_matches('\0')
        .to_string();
    let decoded = obj.decode_pixel_data().map_err(|e| {
        let name = dicom_transfer_syntax_registry::TransferSyntaxRegistry
            .get(&syntax)
            .map(|ts| ts.name().to_string())
            .unwrap_or_else(|| "unknown".into());
        format!(
            "{}: cannot decode pixel data (transfer syntax {syntax}, {name}): {e}",
            path.display()
        )
    })?;
    let (rows, cols) = (decoded.rows() as usize, decoded.columns() as usize);
    if decoded.samples_per_pixel() != 1 {
        return Err(format!(
            "{}: {} samples per pixel; only greyscale images form a volume",
            path.display(),
            decoded.samples_per_pixel()
        ));
    }
    let frames = decoded.number_of_frames().max(1);
    let per_frame_items = obj
        .element_opt(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE)
        .ok()
        .flatten()
        .and_then(|e| e.items());
    let thickness = numbers(&obj, tags::SPACING_BETWEEN_SLICES)
        .or_else(|| numbers(&obj, tags::SLICE_THICKNESS))
        .and_then(|v| v.first().copied())
        .filter(|t| *t > 0.0);
    let mut out = Vec::with_capacity(frames as usize);
    for f in 0..frames {
        let per_frame = per_frame_items.and_then(|items| items.get(f as usize));
        let position = geometry(
            &obj,
            per_frame,
            tags::PLANE_POSITION_SEQUENCE,
            tags::IMAGE_POSITION_PATIENT,
        );
        let orientation = geometry(
            &obj,
            per_frame,
            tags::PLANE_ORIENTATION_SEQUENCE,
            tags::IMAGE_ORIENTATION_PATIENT,
        );
        let spacing = geometry(
            &obj,
            per_frame,
            tags::PIXEL_MEASURES_SEQUENCE,
            tags::PIXEL_SPACING,
        );
        let pixels: Vec<f32> = decoded.to_vec_frame(f).map_err(|e| {
            format!(
                "{}: frame {f}: cannot convert pixel data: {e}",
                path.display()
            )
        })?;
        if pixels.len() != rows * cols {
            return Err(format!(
                "{}: frame {f} has {} pixels, expected {rows} x {cols} (truncated?)",
                path.display(),
                pixels.len()
            ));
        }
        let orientation: [f64; 6] = fixed(orientation, path, "ImageOrientationPatient")?;
        let pixel_spacing: [f64; 2] = fixed(spacing, path, "PixelSpacing")?;
        if pixel_spacing.iter().any(|&s| s <= 0.0) {
            return Err(format!(
                "{}: PixelSpacing {pixel_spacing:?} must be positive",
                path.display()
            ));
        }
        out.push(Frame {
            file: path.to_path_buf(),
            frame: f,
            series_uid: text(&obj, tags::SERIES_INSTANCE_UID),
            series_description: text(&obj, tags::SERIES_DESCRIPTION),
            rows,
            cols,
            position: fixed(position, path, "ImagePositionPatient")?,
            orientation,
            pixel_spacing,
            slice_thickness: thickness,
            pixels,
        });
    }
    Ok(out)
}
