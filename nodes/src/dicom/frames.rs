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

/// What one DICOM file holds.
#[derive(Debug, Clone, PartialEq)]
pub enum FileContent {
    /// Image frames, each placed in patient space.
    Frames(Vec<Frame>),
    /// A DICOM object that is not an image (a DICOMDIR, a structured report, an
    /// RT structure set or plan, a presentation state, anything without
    /// PixelData); the text says what it is, for the skip note.
    NotImage(String),
}

/// The SOP class's name without its " Storage" suffix ("Basic Text SR"), or
/// its UID when the dictionary does not know it.
fn sop_class_name(uid: &str) -> String {
    use dicom_core::dictionary::UidDictionary;
    let uid = uid.trim_end_matches('\0').trim();
    match dicom_dictionary_std::StandardSopClassDictionary.by_uid(uid) {
        Some(entry) => entry
            .name
            .strip_suffix(" Storage")
            .unwrap_or(entry.name)
            .to_string(),
        None if uid.is_empty() => "an object with no SOP class".into(),
        None => format!("SOP class {uid}"),
    }
}

/// Why `obj` is not an image, or `None` when it holds pixel data.
fn not_an_image(obj: &DefaultDicomObject) -> Option<String> {
    let media_class = obj
        .meta()
        .media_storage_sop_class_uid()
        .trim_end_matches('\0');
    if media_class == dicom_dictionary_std::uids::MEDIA_STORAGE_DIRECTORY_STORAGE {
        return Some("a media directory (DICOMDIR), not an image".into());
    }
    let has = |tag| obj.element_opt(tag).ok().flatten().is_some();
    if has(tags::PIXEL_DATA) || has(tags::FLOAT_PIXEL_DATA) || has(tags::DOUBLE_FLOAT_PIXEL_DATA) {
        return None;
    }
    let class = text(obj, tags::SOP_CLASS_UID);
    let class = if class.is_empty() {
        media_class.to_string()
    } else {
        class
    };
    Some(format!("{} (no pixel data)", sop_class_name(&class)))
}

/// The text of a caught panic's payload.
fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "the decoder panicked".into())
}

/// An error and its sources, "outer: inner: innermost".
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let t = s.to_string();
        if !text.contains(&t) {
            text = format!("{text}: {t}");
        }
        source = s.source();
    }
    text
}

/// Transfer syntaxes of JPEG-LS, which this build cannot decode.
const JPEG_LS: [&str; 2] = ["1.2.840.10008.1.2.4.80", "1.2.840.10008.1.2.4.81"];

/// Reads every frame of one file. Errors name the file and what is wrong:
/// truncated or corrupt data (a decoder that panics on it included), missing
/// geometry, an unsupported transfer syntax or sample format. Objects without
/// pixel data come back as [`FileContent::NotImage`].
pub fn read_file(path: &Path) -> Result<FileContent, String> {
    let obj: DefaultDicomObject = std::panic::catch_unwind(|| dicom_object::open_file(path))
        .map_err(|payload| {
            format!(
                "{}: unreadable DICOM file: the parser failed on it: {}",
                path.display(),
                panic_text(payload.as_ref())
            )
        })?
        .map_err(|e| format!("{}: unreadable DICOM file: {e}", path.display()))?;
    if let Some(why) = not_an_image(&obj) {
        return Ok(FileContent::NotImage(why));
    }
    if obj.element_opt(tags::PIXEL_DATA).ok().flatten().is_none() {
        return Err(format!(
            "{}: float pixel data (FloatPixelData or DoubleFloatPixelData, as in parametric maps) is not supported; only integer PixelData is",
            path.display()
        ));
    }
    let syntax = obj
        .meta()
        .transfer_syntax()
        .trim_end_matches('\0')
        .to_string();
    let ts = dicom_transfer_syntax_registry::TransferSyntaxRegistry.get(&syntax);
    let syntax_name = ts
        .map(|ts| ts.name().to_string())
        .unwrap_or_else(|| "unknown".into());
    if JPEG_LS.contains(&syntax.as_str()) && !ts.is_some_and(|ts| ts.can_decode_all()) {
        return Err(format!(
            "{}: JPEG-LS is not supported by this build (transfer syntax {syntax}, {syntax_name}): \
             dicom-pixeldata decodes JPEG-LS only through CharLS, a C++ library that its `charls` \
             feature builds with CMake, which a clean machine does not have; convert the file, \
             e.g. `gdcmconv --raw` or `dcmdjpls`",
            path.display()
        ));
    }
    let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        decode_frames(&obj, path, &syntax, &syntax_name)
    }))
    .unwrap_or_else(|payload| {
        Err(format!(
            "{}: pixel data could not be decoded ({syntax_name}): the decoder failed on it (truncated or corrupt data?): {} [transfer syntax {syntax}]",
            path.display(),
            panic_text(payload.as_ref())
        ))
    })?;
    Ok(FileContent::Frames(decoded))
}

/// Reads every frame of one image file; an object without pixel data is an
/// error here (use [`read_file`] to tell them apart).
pub fn read_frames(path: &Path) -> Result<Vec<Frame>, String> {
    match read_file(path)? {
        FileContent::Frames(frames) => Ok(frames),
        FileContent::NotImage(why) => Err(format!("{}: not an image: {why}", path.display())),
    }
}

/// One frame's stored values as f32 with the modality rescale applied. 8- and
/// 16-bit samples go through dicom-pixeldata; 32-bit samples (RT Dose) are
/// read here, since dicom-pixeldata 0.10 converts only 8 and 16 bits.
fn frame_values(
    decoded: &dicom_pixeldata::DecodedPixelData<'_>,
    f: u32,
    path: &Path,
) -> Result<Vec<f32>, String> {
    let bits = decoded.bits_allocated();
    let unsupported = || {
        format!(
            "{}: unsupported sample format: BitsAllocated {bits}, BitsStored {}, PixelRepresentation {} (8, 16 and 32 bits are read)",
            path.display(),
            decoded.bits_stored(),
            decoded.pixel_representation() as u16,
        )
    };
    match bits {
        8 | 16 => decoded.to_vec_frame(f).map_err(|e| {
            format!(
                "{}: frame {f}: cannot convert pixel data: {e}",
                path.display()
            )
        }),
        32 => {
            let stored = decoded.bits_stored();
            if stored == 0 || stored > 32 {
                return Err(unsupported());
            }
            let bytes = decoded
                .frame_data(f)
                .map_err(|e| format!("{}: frame {f}: {e} (truncated?)", path.display()))?;
            let rescale = decoded
                .rescale()
                .map_err(|e| format!("{}: {e}", path.display()))?;
            let r = rescale.get(f as usize).unwrap_or(&rescale[0]);
            let signed =
                decoded.pixel_representation() == dicom_pixeldata::PixelRepresentation::Signed;
            let shift = 32 - stored as u32;
            Ok(bytes
                .chunks_exact(4)
                .map(|b| {
                    let raw = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]) << shift;
                    let v = if signed {
                        ((raw as i32) >> shift) as f64
                    } else {
                        (raw >> shift) as f64
                    };
                    (v * r.slope + r.intercept) as f32
                })
                .collect())
        }
        _ => Err(unsupported()),
    }
}

/// The frames' positions from GridFrameOffsetVector (RT Dose): offsets along
/// the normal from ImagePositionPatient when the first is 0, else (axial
/// grids only) the frames' z coordinates.
fn grid_frame_positions(
    obj: &InMemDicomObject,
    frames: u32,
    path: &Path,
) -> Result<Option<Vec<[f64; 3]>>, String> {
    let Some(offsets) = numbers(obj, tags::GRID_FRAME_OFFSET_VECTOR) else {
        return Ok(None);
    };
    let list = || fmt_list(&offsets);
    if offsets.len() != frames as usize || offsets.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "{}: GridFrameOffsetVector has {} values [{}], NumberOfFrames is {frames}",
            path.display(),
            offsets.len(),
            list()
        ));
    }
    let ipp: [f64; 3] = fixed(
        numbers(obj, tags::IMAGE_POSITION_PATIENT),
        path,
        "ImagePositionPatient",
    )?;
    let iop: [f64; 6] = fixed(
        numbers(obj, tags::IMAGE_ORIENTATION_PATIENT),
        path,
        "ImageOrientationPatient",
    )?;
    let normal = [
        iop[1] * iop[5] - iop[2] * iop[4],
        iop[2] * iop[3] - iop[0] * iop[5],
        iop[0] * iop[4] - iop[1] * iop[3],
    ];
    if offsets[0] == 0.0 {
        return Ok(Some(
            offsets
                .iter()
                .map(|&d| std::array::from_fn(|a| ipp[a] + d * normal[a]))
                .collect(),
        ));
    }
    let axial = iop
        .iter()
        .zip([1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
        .all(|(a, b)| (a - b).abs() < 1e-6);
    if !axial {
        return Err(format!(
            "{}: GridFrameOffsetVector [{}] starts at {} (absolute z), which DICOM allows only for axial grids, but ImageOrientationPatient is [{}]",
            path.display(),
            list(),
            offsets[0],
            fmt_list(&iop)
        ));
    }
    Ok(Some(offsets.iter().map(|&z| [ipp[0], ipp[1], z]).collect()))
}

fn fmt_list(v: &[f64]) -> String {
    v.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

fn decode_frames(
    obj: &DefaultDicomObject,
    path: &Path,
    syntax: &str,
    syntax_name: &str,
) -> Result<Vec<Frame>, String> {
    let decoded = obj.decode_pixel_data().map_err(|e| {
        format!(
            "{}: pixel data could not be decoded ({syntax_name}): {} [transfer syntax {syntax}]",
            path.display(),
            error_chain(&e)
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
    let grid_positions = match per_frame_items {
        Some(_) => None,
        None if frames > 1 => grid_frame_positions(obj, frames, path)?,
        None => None,
    };
    // RT Dose: stored values times DoseGridScaling are the dose in Gy.
    let dose_scaling = match numbers(obj, tags::DOSE_GRID_SCALING) {
        None => None,
        Some(v) => match v.first() {
            Some(&s) if s.is_finite() && s > 0.0 => Some(s),
            _ => {
                return Err(format!(
                    "{}: DoseGridScaling [{}] must be one positive number",
                    path.display(),
                    fmt_list(&v)
                ));
            }
        },
    };
    let thickness = numbers(obj, tags::SPACING_BETWEEN_SLICES)
        .or_else(|| numbers(obj, tags::SLICE_THICKNESS))
        .and_then(|v| v.first().copied())
        .filter(|t| *t > 0.0);
    let mut out = Vec::with_capacity(frames as usize);
    for f in 0..frames {
        let per_frame = per_frame_items.and_then(|items| items.get(f as usize));
        let position = match &grid_positions {
            Some(p) => Some(p[f as usize].to_vec()),
            None => geometry(
                obj,
                per_frame,
                tags::PLANE_POSITION_SEQUENCE,
                tags::IMAGE_POSITION_PATIENT,
            ),
        };
        let orientation = geometry(
            obj,
            per_frame,
            tags::PLANE_ORIENTATION_SEQUENCE,
            tags::IMAGE_ORIENTATION_PATIENT,
        );
        let spacing = geometry(
            obj,
            per_frame,
            tags::PIXEL_MEASURES_SEQUENCE,
            tags::PIXEL_SPACING,
        );
        let mut pixels = frame_values(&decoded, f, path)?;
        if pixels.len() != rows * cols {
            return Err(format!(
                "{}: frame {f} has {} pixels, expected {rows} x {cols} (truncated?)",
                path.display(),
                pixels.len()
            ));
        }
        if let Some(s) = dose_scaling {
            for p in &mut pixels {
                *p = (*p as f64 * s) as f32;
            }
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
            series_uid: text(obj, tags::SERIES_INSTANCE_UID),
            series_description: text(obj, tags::SERIES_DESCRIPTION),
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
