//! The header values the loader relies on, checked before any pixel is decoded:
//! the Image Pixel module (dicom-pixeldata panics on BitsStored 0 and the like),
//! the declared pixel data size against the element's length and a memory cap,
//! and numbers (rescale, geometry) that must parse and be finite.

use super::layout::tag_name;
use dicom_core::Tag;
use dicom_core::header::HasLength;
use dicom_dictionary_std::tags;
use dicom_object::InMemDicomObject;

/// At most this many voxels (rows x columns x frames) in one file.
pub const MAX_VOXELS: u64 = 1 << 31;
/// At most this much memory for decoding one file (stored samples plus the
/// f32 values), bytes: 4 GiB.
pub const MAX_DECODE_BYTES: u64 = 4 << 30;
/// Pixel spacing and slice thickness above this (mm) are taken as corrupt.
pub const MAX_SPACING_MM: f64 = 1e4;
/// How far from unit length, and from orthogonal (dot product), the two
/// ImageOrientationPatient vectors may be.
pub const ORIENTATION_TOLERANCE: f64 = 1e-3;

/// The pixel format of one file: what every slice of a series must share.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct PixelFormat {
    /// Rows.
    pub rows: u16,
    /// Columns.
    pub cols: u16,
    /// SamplesPerPixel.
    pub samples_per_pixel: u16,
    /// BitsAllocated (8, 16 or 32).
    pub bits_allocated: u16,
    /// BitsStored (1 ..= BitsAllocated).
    pub bits_stored: u16,
    /// PixelRepresentation: 0 unsigned, 1 signed.
    pub pixel_representation: u16,
    /// PhotometricInterpretation.
    pub photometric: String,
}

impl PixelFormat {
    /// The values that differ between `self` and `other`, as
    /// ("BitsAllocated 8", "BitsAllocated 16") pairs joined by ", ".
    pub fn differences(&self, other: &PixelFormat) -> (String, String) {
        let mine = self.fields();
        let theirs = other.fields();
        let (a, b): (Vec<_>, Vec<_>) = mine
            .iter()
            .zip(&theirs)
            .filter(|(a, b)| a.1 != b.1)
            .map(|(a, b)| (format!("{} {}", a.0, a.1), format!("{} {}", b.0, b.1)))
            .unzip();
        (a.join(", "), b.join(", "))
    }

    fn fields(&self) -> [(&'static str, String); 7] {
        [
            ("BitsAllocated", self.bits_allocated.to_string()),
            ("BitsStored", self.bits_stored.to_string()),
            ("PixelRepresentation", self.pixel_representation.to_string()),
            ("SamplesPerPixel", self.samples_per_pixel.to_string()),
            ("PhotometricInterpretation", self.photometric.clone()),
            ("Rows", self.rows.to_string()),
            ("Columns", self.cols.to_string()),
        ]
    }
}

/// An unsigned integer attribute (US or IS), `None` if absent or empty.
fn uint(obj: &InMemDicomObject, tag: Tag) -> Result<Option<u32>, String> {
    let Some(e) = obj.element_opt(tag).ok().flatten() else {
        return Ok(None);
    };
    if e.is_empty() {
        return Ok(None);
    }
    let shown = e.to_str().map(|s| s.trim().to_string()).unwrap_or_default();
    e.to_int::<i64>()
        .ok()
        .and_then(|v| u32::try_from(v).ok())
        .map(Some)
        .ok_or_else(|| format!("{} is not a non-negative integer: {shown:?}", tag_name(tag)))
}

fn required(obj: &InMemDicomObject, tag: Tag) -> Result<u32, String> {
    uint(obj, tag)?.ok_or_else(|| format!("missing {}", tag_name(tag)))
}

/// Reads and checks the Image Pixel module of `obj`: Rows, Columns,
/// SamplesPerPixel at least 1; BitsAllocated 8, 16 or 32; BitsStored 1 ..=
/// BitsAllocated; HighBit = BitsStored - 1; PixelRepresentation 0 or 1.
/// Errors name the tags and their values (not the file: the caller adds it).
pub fn pixel_format(obj: &InMemDicomObject) -> Result<PixelFormat, String> {
    let get = |tag| required(obj, tag);
    let rows = get(tags::ROWS)?;
    let cols = get(tags::COLUMNS)?;
    let samples = get(tags::SAMPLES_PER_PIXEL)?;
    let allocated = get(tags::BITS_ALLOCATED)?;
    let stored = get(tags::BITS_STORED)?;
    let high = get(tags::HIGH_BIT)?;
    let representation = get(tags::PIXEL_REPRESENTATION)?;
    let photometric = obj
        .element_opt(tags::PHOTOMETRIC_INTERPRETATION)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim_end_matches(['\0', ' ']).trim().to_string())
        .unwrap_or_default();
    let bits = format!("BitsAllocated {allocated}, BitsStored {stored}, HighBit {high}");
    if rows == 0 || cols == 0 || rows > u16::MAX as u32 || cols > u16::MAX as u32 {
        return Err(format!(
            "Rows {rows}, Columns {cols}: an image needs 1 to 65535 of each"
        ));
    }
    if samples == 0 || samples > 4 {
        return Err(format!("SamplesPerPixel {samples} (1 to 4 are defined)"));
    }
    if ![8, 16, 32].contains(&allocated) {
        return Err(format!("{bits}: BitsAllocated must be 8, 16 or 32"));
    }
    if stored == 0 || stored > allocated {
        return Err(format!("{bits}: BitsStored must be 1 to BitsAllocated"));
    }
    if high + 1 != stored {
        return Err(format!("{bits}: HighBit must be BitsStored - 1"));
    }
    if representation > 1 {
        return Err(format!(
            "PixelRepresentation {representation} (0 unsigned or 1 signed)"
        ));
    }
    if photometric.is_empty() {
        return Err(format!(
            "missing {}",
            tag_name(tags::PHOTOMETRIC_INTERPRETATION)
        ));
    }
    Ok(PixelFormat {
        rows: rows as u16,
        cols: cols as u16,
        samples_per_pixel: samples as u16,
        bits_allocated: allocated as u16,
        bits_stored: stored as u16,
        pixel_representation: representation as u16,
        photometric,
    })
}

/// NumberOfFrames (1 when absent); 0 or a malformed value is an error.
pub fn number_of_frames(obj: &InMemDicomObject) -> Result<u32, String> {
    match uint(obj, tags::NUMBER_OF_FRAMES)? {
        None => Ok(1),
        Some(0) => Err(format!("{} is 0", tag_name(tags::NUMBER_OF_FRAMES))),
        Some(n) => Ok(n),
    }
}

/// The stored pixel data size that `format` and `frames` declare, bytes.
pub fn expected_pixel_bytes(format: &PixelFormat, frames: u32) -> u64 {
    format.rows as u64
        * format.cols as u64
        * frames as u64
        * format.samples_per_pixel as u64
        * (format.bits_allocated as u64 / 8)
}

/// Refuses dimensions whose decoding would take more than [`MAX_VOXELS`]
/// voxels or [`MAX_DECODE_BYTES`] of memory, and (for a native, uncompressed
/// syntax, `native_len` = the PixelData element's length) a PixelData length
/// other than the declared size (plus one byte of padding to an even length).
pub fn check_pixel_size(
    format: &PixelFormat,
    frames: u32,
    native_len: Option<u64>,
) -> Result<(), String> {
    let voxels = format.rows as u64 * format.cols as u64 * frames as u64;
    let expected = expected_pixel_bytes(format, frames);
    let dims = format!(
        "Rows {} x Columns {} x NumberOfFrames {frames} x SamplesPerPixel {} x BitsAllocated {}",
        format.rows, format.cols, format.samples_per_pixel, format.bits_allocated
    );
    let memory = expected + voxels * format.samples_per_pixel as u64 * 4;
    if voxels > MAX_VOXELS || memory > MAX_DECODE_BYTES {
        return Err(format!(
            "{dims} = {voxels} voxels would take about {:.1} GB to decode (limits: {MAX_VOXELS} voxels, {:.1} GB): a corrupt header?",
            memory as f64 / 1e9,
            MAX_DECODE_BYTES as f64 / 1e9
        ));
    }
    if let Some(len) = native_len
        && len != expected
        && len != expected + expected % 2
    {
        let why = if len < expected {
            "the pixel data is truncated, or the header is corrupt"
        } else {
            "the header is corrupt"
        };
        return Err(format!(
            "{} is {len} bytes, but {dims} / 8 = {expected} bytes ({why})",
            tag_name(tags::PIXEL_DATA)
        ));
    }
    Ok(())
}

/// A numeric attribute (DS, IS, FD, ...) as numbers; `None` when absent or
/// empty. A value that does not parse, or is NaN or infinite, is an error
/// naming the tag and the text.
pub fn finite_numbers(obj: &InMemDicomObject, tag: Tag) -> Result<Option<Vec<f64>>, String> {
    let Some(e) = obj.element_opt(tag).ok().flatten() else {
        return Ok(None);
    };
    if e.is_empty() {
        return Ok(None);
    }
    let text = || {
        e.to_str()
            .map(|s| s.trim_end_matches('\0').trim().to_string())
            .unwrap_or_default()
    };
    if text().is_empty() {
        return Ok(None);
    }
    match e.to_multi_float64() {
        Ok(v) if v.iter().all(|x| x.is_finite()) => Ok(Some(v)),
        Ok(_) => Err(format!("{} is not finite: {:?}", tag_name(tag), text())),
        Err(_) => Err(format!("{} is not a number: {:?}", tag_name(tag), text())),
    }
}

/// A number as short text: plain ("0.5", "-99.48"), or with an exponent
/// when very large or small ("1e308").
pub(crate) fn fmt_number(x: f64) -> String {
    if x != 0.0 && !(1e-4..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}

/// Numbers as "a, b, c".
pub(crate) fn fmt_numbers(v: &[f64]) -> String {
    v.iter()
        .map(|&x| fmt_number(x))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Checks PixelSpacing (between rows, between columns): finite, positive and
/// at most [`MAX_SPACING_MM`].
pub fn check_pixel_spacing(spacing: [f64; 2]) -> Result<(), String> {
    if spacing.iter().all(|&s| s > 0.0 && s <= MAX_SPACING_MM) {
        return Ok(());
    }
    Err(format!(
        "{} [{}] must be positive and at most {MAX_SPACING_MM} mm",
        tag_name(tags::PIXEL_SPACING),
        fmt_numbers(&spacing)
    ))
}

/// Checks ImageOrientationPatient: two unit vectors (row, then column
/// direction), orthogonal, within [`ORIENTATION_TOLERANCE`].
pub fn check_orientation(iop: [f64; 6]) -> Result<(), String> {
    let (r, c) = (&iop[..3], &iop[3..]);
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let (nr, nc, rc) = (dot(r, r).sqrt(), dot(c, c).sqrt(), dot(r, c));
    let tol = ORIENTATION_TOLERANCE;
    if (nr - 1.0).abs() <= tol && (nc - 1.0).abs() <= tol && rc.abs() <= tol {
        return Ok(());
    }
    Err(format!(
        "{} [{}] is not two orthogonal unit vectors (lengths {nr:.4} and {nc:.4}, dot product {rc:.4})",
        tag_name(tags::IMAGE_ORIENTATION_PATIENT),
        fmt_numbers(&iop)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dicom_core::value::PrimitiveValue;
    use dicom_core::{DataElement, VR};

    fn object(values: &[(Tag, u16)]) -> InMemDicomObject {
        let mut obj = InMemDicomObject::from_element_iter(
            values
                .iter()
                .map(|&(t, v)| DataElement::new(t, VR::US, PrimitiveValue::from(v))),
        );
        obj.put(DataElement::new(
            tags::PHOTOMETRIC_INTERPRETATION,
            VR::CS,
            PrimitiveValue::from("MONOCHROME2"),
        ));
        obj
    }

    fn module(allocated: u16, stored: u16, high: u16) -> InMemDicomObject {
        object(&[
            (tags::ROWS, 4),
            (tags::COLUMNS, 3),
            (tags::SAMPLES_PER_PIXEL, 1),
            (tags::BITS_ALLOCATED, allocated),
            (tags::BITS_STORED, stored),
            (tags::HIGH_BIT, high),
            (tags::PIXEL_REPRESENTATION, 0),
        ])
    }

    #[test]
    fn the_pixel_module_is_checked() {
        let f = pixel_format(&module(16, 12, 11)).unwrap();
        assert_eq!((f.rows, f.cols, f.bits_stored), (4, 3, 12));
        assert_eq!(expected_pixel_bytes(&f, 2), 48);
        for (a, s, h, text) in [
            (16, 0, 0, "BitsStored must be 1 to BitsAllocated"),
            (16, 17, 16, "BitsStored must be 1 to BitsAllocated"),
            (12, 12, 11, "BitsAllocated must be 8, 16 or 32"),
            (16, 12, 15, "HighBit must be BitsStored - 1"),
        ] {
            let err = pixel_format(&module(a, s, h)).unwrap_err();
            assert!(
                err.contains(text) && err.contains(&format!("BitsStored {s}")),
                "{err}"
            );
        }
        let mut obj = module(16, 16, 15);
        obj.put(DataElement::new(
            tags::ROWS,
            VR::US,
            PrimitiveValue::from(0u16),
        ));
        assert!(pixel_format(&obj).unwrap_err().contains("Rows 0"));
        obj.remove_element(tags::ROWS);
        assert!(pixel_format(&obj).unwrap_err().contains("missing Rows"));
    }

    #[test]
    fn pixel_sizes_are_checked_against_the_length_and_the_cap() {
        let f = pixel_format(&module(16, 16, 15)).unwrap();
        assert!(check_pixel_size(&f, 1, Some(24)).is_ok());
        let err = check_pixel_size(&f, 1, Some(26)).unwrap_err();
        assert!(
            err.contains("PixelData (7FE0,0010) is 26 bytes") && err.contains("= 24 bytes"),
            "{err}"
        );
        let big = PixelFormat {
            rows: 65535,
            cols: 65535,
            ..f
        };
        let err = check_pixel_size(&big, 1, None).unwrap_err();
        assert!(
            err.contains("4294836225 voxels") && err.contains("GB to decode"),
            "{err}"
        );
        // An odd size may be padded by one byte.
        let odd = PixelFormat {
            rows: 3,
            cols: 3,
            bits_allocated: 8,
            ..pixel_format(&module(8, 8, 7)).unwrap()
        };
        assert!(check_pixel_size(&odd, 1, Some(10)).is_ok());
        assert!(check_pixel_size(&odd, 1, Some(9)).is_ok());
    }

    #[test]
    fn numbers_must_parse_and_be_finite() {
        let ds = |s: &str| {
            InMemDicomObject::from_element_iter([DataElement::new(
                tags::RESCALE_SLOPE,
                VR::DS,
                PrimitiveValue::from(s),
            )])
        };
        assert_eq!(
            finite_numbers(&ds("2.5"), tags::RESCALE_SLOPE).unwrap(),
            Some(vec![2.5])
        );
        assert_eq!(finite_numbers(&ds(""), tags::RESCALE_SLOPE).unwrap(), None);
        for bad in ["abc", "nan", "inf", "1e999"] {
            let err = finite_numbers(&ds(bad), tags::RESCALE_SLOPE).unwrap_err();
            assert!(
                err.starts_with("RescaleSlope (0028,1053) is not"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn spacing_and_orientation_are_checked() {
        assert!(check_pixel_spacing([0.5, 0.5]).is_ok());
        for bad in [[0.0, 1.0], [-1.0, 1.0], [1e308, 1.0], [1.0, 2e4]] {
            assert!(
                check_pixel_spacing(bad)
                    .unwrap_err()
                    .contains("PixelSpacing")
            );
        }
        assert!(check_orientation([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]).is_ok());
        let err = check_orientation([1.0, 0.0, 0.0, 0.0, 2.0, 0.0]).unwrap_err();
        assert!(err.contains("lengths 1.0000 and 2.0000"), "{err}");
        let err = check_orientation([1.0, 0.0, 0.0, 0.6, 0.8, 0.0]).unwrap_err();
        assert!(err.contains("dot product 0.6000"), "{err}");
    }
}
