//! One DICOM file -> its image frames with their geometry, rescaled to f32.

use super::header::{
    MAX_SPACING_MM, PixelFormat, check_orientation, check_pixel_size, check_pixel_spacing,
    finite_numbers, number_of_frames, pixel_format,
};
use super::layout::{looks_like_bare_dataset, scan_layout, tag_name};
use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, InMemDicomObject};
use dicom_pixeldata::PixelDecoder;
use dicom_transfer_syntax_registry::TransferSyntaxIndex;
use fusegraph_engine::panics::catch_quietly;
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
    /// The file's pixel format (what every slice of a series must share).
    pub format: PixelFormat,
    /// Pixel values with the modality rescale applied, row-major.
    pub pixels: Vec<f32>,
    /// Whether the file carries overlay planes (OverlayData, 60xx,3000),
    /// which are not loaded.
    pub has_overlay: bool,
}

/// How a file holds a DICOM data set, from its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// A Part 10 file: 128-byte preamble, "DICM", file meta group.
    Part10,
    /// A data set alone, implicit VR little endian (see
    /// [`looks_like_bare_dataset`]).
    Bare,
}

/// Whether a file starts like a DICOM Part 10 file ("DICM" after a 128-byte
/// preamble) or a bare implicit VR little endian data set, and which. Other
/// files in a series folder (notes, DICOMDIR viewers' files) are skipped
/// rather than failing the load.
pub fn dicom_encoding(path: &Path) -> Option<Encoding> {
    use std::io::Read;
    let mut file = std::fs::File::open(path).ok()?;
    let file_len = file.metadata().ok()?.len();
    let mut head = Vec::with_capacity(132);
    (&mut file).take(132).read_to_end(&mut head).ok()?;
    if head.len() == 132 && &head[128..132] == b"DICM" {
        Some(Encoding::Part10)
    } else if looks_like_bare_dataset(&head, file_len) {
        Some(Encoding::Bare)
    } else {
        None
    }
}

/// Opens a data set written without the Part 10 header as implicit VR little
/// endian, with a file meta group made from its SOP class and instance.
fn open_bare(path: &Path) -> Result<DefaultDicomObject, String> {
    let syntax = dicom_transfer_syntax_registry::TransferSyntaxRegistry
        .get(IMPLICIT_LE)
        .ok_or("implicit VR little endian is not registered")?;
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let obj = InMemDicomObject::read_dataset_with_ts(std::io::BufReader::new(file), syntax)
        .map_err(|e| error_chain(&e))?;
    obj.with_meta(dicom_object::meta::FileMetaTableBuilder::new().transfer_syntax(IMPLICIT_LE))
        .map_err(|e| {
            format!(
                "no SOP class or instance UID to read it by ({})",
                error_chain(&e)
            )
        })
}

const IMPLICIT_LE: &str = "1.2.840.10008.1.2";

fn text(obj: &InMemDicomObject, tag: Tag) -> String {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// A numeric attribute, `None` when absent; malformed or non-finite values are
/// errors naming the file and the tag.
fn numbers(obj: &InMemDicomObject, tag: Tag, path: &Path) -> Result<Option<Vec<f64>>, String> {
    finite_numbers(obj, tag).map_err(|e| format!("{}: {e}", path.display()))
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
    path: &Path,
) -> Result<Option<Vec<f64>>, String> {
    let shared = item(obj, tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE);
    for group in [per_frame, shared] {
        if let Some(m) = group.and_then(|g| item(g, macro_seq))
            && let Some(v) = numbers(m, tag, path)?
        {
            return Ok(Some(v));
        }
    }
    numbers(obj, tag, path)
}

/// Checks RescaleSlope and RescaleIntercept wherever they are (top level, or
/// the functional groups' PixelValueTransformationSequence): numbers, finite,
/// a slope other than 0. dicom-pixeldata takes a value it cannot parse as
/// slope 1 or intercept 0, which gives values silently off.
fn check_rescale(obj: &InMemDicomObject, path: &Path) -> Result<(), String> {
    let mut places = vec![obj];
    for seq in [
        tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
        tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
    ] {
        if let Some(items) = obj.element_opt(seq).ok().flatten().and_then(|e| e.items()) {
            places.extend(
                items
                    .iter()
                    .filter_map(|i| item(i, tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE)),
            );
        }
    }
    for place in places {
        numbers(place, tags::RESCALE_INTERCEPT, path)?;
        if let Some(slope) = numbers(place, tags::RESCALE_SLOPE, path)?
            && slope.contains(&0.0)
        {
            return Err(format!(
                "{}: {} is 0 (every voxel would be the intercept)",
                path.display(),
                tag_name(tags::RESCALE_SLOPE)
            ));
        }
    }
    Ok(())
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
///
/// Before anything is decoded: element lengths are checked against the file
/// size ([`scan_layout`], so memory stays bounded by the file), the Image Pixel
/// module ([`pixel_format`]), the PixelData size against the dimensions and a
/// memory cap ([`check_pixel_size`]), and rescale and geometry numbers (they
/// must parse and be finite; spacing positive and sane; orientation
/// orthonormal). A caught panic around the parser and the decoder stays as
/// the last defence.
pub fn read_file(path: &Path) -> Result<FileContent, String> {
    check_lengths(path)?;
    let bare = dicom_encoding(path) == Some(Encoding::Bare);
    let what = if bare {
        "unreadable DICOM data set (no Part 10 header; read as implicit VR little endian)"
    } else {
        "unreadable DICOM file"
    };
    let obj: DefaultDicomObject = catch_quietly(|| {
        if bare {
            open_bare(path)
        } else {
            dicom_object::open_file(path).map_err(|e| e.to_string())
        }
    })
    .map_err(|panic| {
        format!(
            "{}: {what}: the parser failed on it: {panic}",
            path.display()
        )
    })?
    .map_err(|e| format!("{}: {what}: {e}", path.display()))?;
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
    let format = pixel_format(&obj).map_err(|e| format!("{}: {e}", path.display()))?;
    let frames = number_of_frames(&obj).map_err(|e| format!("{}: {e}", path.display()))?;
    let native_len = match ts {
        Some(ts) if !ts.is_encapsulated_pixel_data() => obj
            .element(tags::PIXEL_DATA)
            .ok()
            .map(|e| e.value().to_bytes().map_or(0, |b| b.len() as u64)),
        _ => None,
    };
    check_pixel_size(&format, frames, native_len).map_err(|e| {
        format!(
            "{}: {e} [transfer syntax {syntax}, {syntax_name}]",
            path.display()
        )
    })?;
    check_rescale(&obj, path)?;
    let decoded = catch_quietly(|| decode_frames(&obj, path, &syntax, &syntax_name, &format))
        .unwrap_or_else(|panic| {
            Err(format!(
                "{}: pixel data could not be decoded ({syntax_name}): the decoder failed on it (truncated or corrupt data?): {panic} [transfer syntax {syntax}]",
                path.display()
            ))
        })?;
    Ok(FileContent::Frames(decoded))
}

/// Refuses a file whose element headers declare more bytes than the file
/// holds, before dicom-object allocates them (see [`scan_layout`]).
fn check_lengths(path: &Path) -> Result<(), String> {
    let Ok(file) = std::fs::File::open(path) else {
        return Ok(()); // the parser names the error
    };
    let len = file.metadata().map(|m| m.len()).unwrap_or(u64::MAX);
    match scan_layout(file, len) {
        Ok(_) => Ok(()),
        // A fragment of encapsulated pixel data (an item inside PixelData).
        Err(e) if e.in_pixel_data && e.tag.group() == 0xFFFE => {
            let name = dicom_transfer_syntax_registry::TransferSyntaxRegistry
                .get(&e.transfer_syntax)
                .map(|ts| ts.name().to_string())
                .unwrap_or_else(|| "unknown".into());
            Err(format!(
                "{}: pixel data could not be decoded ({name}): {e}; the file is {len} bytes",
                path.display()
            ))
        }
        Err(e) => Err(format!(
            "{}: unreadable DICOM file: {e}; the file is {len} bytes",
            path.display()
        )),
    }
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
    let Some(offsets) = numbers(obj, tags::GRID_FRAME_OFFSET_VECTOR, path)? else {
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
        numbers(obj, tags::IMAGE_POSITION_PATIENT, path)?,
        path,
        "ImagePositionPatient",
    )?;
    let iop: [f64; 6] = fixed(
        numbers(obj, tags::IMAGE_ORIENTATION_PATIENT, path)?,
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
    super::header::fmt_numbers(v)
}

/// One frame's place in space, read and checked before any pixel is decoded.
struct Placement {
    position: [f64; 3],
    orientation: [f64; 6],
    pixel_spacing: [f64; 2],
}

fn decode_frames(
    obj: &DefaultDicomObject,
    path: &Path,
    syntax: &str,
    syntax_name: &str,
    format: &PixelFormat,
) -> Result<Vec<Frame>, String> {
    let file = path.display();
    if format.samples_per_pixel != 1 {
        return Err(format!(
            "{file}: {} samples per pixel; only greyscale images form a volume",
            format.samples_per_pixel
        ));
    }
    let frames = number_of_frames(obj).map_err(|e| format!("{file}: {e}"))?;
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
    let dose_scaling = match numbers(obj, tags::DOSE_GRID_SCALING, path)? {
        None => None,
        Some(v) => match v.first() {
            Some(&s) if s > 0.0 => Some(s),
            _ => {
                return Err(format!(
                    "{file}: {} [{}] must be one positive number",
                    tag_name(tags::DOSE_GRID_SCALING),
                    fmt_list(&v)
                ));
            }
        },
    };
    let mut thickness = None;
    for tag in [tags::SPACING_BETWEEN_SLICES, tags::SLICE_THICKNESS] {
        let value = numbers(obj, tag, path)?.and_then(|v| v.first().copied());
        if let Some(t) = value.filter(|t| t.abs() > MAX_SPACING_MM) {
            return Err(format!(
                "{file}: {} {} mm is absurd (more than {MAX_SPACING_MM} mm)",
                tag_name(tag),
                super::header::fmt_number(t)
            ));
        }
        thickness = thickness.or(value.filter(|t| *t > 0.0));
    }
    let mut placements = Vec::with_capacity(frames as usize);
    for f in 0..frames {
        let per_frame = per_frame_items.and_then(|items| items.get(f as usize));
        let position = match &grid_positions {
            Some(p) => Some(p[f as usize].to_vec()),
            None => geometry(
                obj,
                per_frame,
                tags::PLANE_POSITION_SEQUENCE,
                tags::IMAGE_POSITION_PATIENT,
                path,
            )?,
        };
        let orientation = geometry(
            obj,
            per_frame,
            tags::PLANE_ORIENTATION_SEQUENCE,
            tags::IMAGE_ORIENTATION_PATIENT,
            path,
        )?;
        let spacing = geometry(
            obj,
            per_frame,
            tags::PIXEL_MEASURES_SEQUENCE,
            tags::PIXEL_SPACING,
            path,
        )?;
        let orientation: [f64; 6] = fixed(orientation, path, "ImageOrientationPatient")?;
        check_orientation(orientation).map_err(|e| format!("{file}: {e}"))?;
        let pixel_spacing: [f64; 2] = fixed(spacing, path, "PixelSpacing")?;
        check_pixel_spacing(pixel_spacing).map_err(|e| format!("{file}: {e}"))?;
        placements.push(Placement {
            position: fixed(position, path, "ImagePositionPatient")?,
            orientation,
            pixel_spacing,
        });
    }
    let decoded = obj.decode_pixel_data().map_err(|e| {
        format!(
            "{file}: pixel data could not be decoded ({syntax_name}): {} [transfer syntax {syntax}]",
            error_chain(&e)
        )
    })?;
    let (rows, cols) = (format.rows as usize, format.cols as usize);
    let has_overlay = obj.tags().any(|t| {
        (0x6000..=0x601E).contains(&t.group()) && t.group() % 2 == 0 && t.element() == 0x3000
    });
    let mut out = Vec::with_capacity(frames as usize);
    for (f, place) in (0..frames).zip(placements) {
        let mut pixels = frame_values(&decoded, f, path)?;
        if pixels.len() != rows * cols {
            return Err(format!(
                "{file}: frame {f} has {} pixels, expected {rows} x {cols} (truncated?)",
                pixels.len()
            ));
        }
        if let Some(s) = dose_scaling {
            for p in &mut pixels {
                *p = (*p as f64 * s) as f32;
            }
        }
        out.push(Frame {
            has_overlay,
            file: path.to_path_buf(),
            frame: f,
            series_uid: text(obj, tags::SERIES_INSTANCE_UID),
            series_description: text(obj, tags::SERIES_DESCRIPTION),
            rows,
            cols,
            position: place.position,
            orientation: place.orientation,
            pixel_spacing: place.pixel_spacing,
            slice_thickness: thickness,
            format: format.clone(),
            pixels,
        });
    }
    Ok(out)
}
