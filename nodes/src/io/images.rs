//! Images in and out: decoding PNG and JPEG files (as RGB, or straight to grey
//! levels) within a size limit, and a rectified pair side by side with
//! horizontal lines, to check rectification by eye.

use fusegraph_engine::OpError;
use fusegraph_engine::param::ParamSpec;
use fusegraph_engine::value::{Image, Pixels};
use fusegraph_plugin_api::derive::Params;
use fusegraph_plugin_api::typed::ParamSet;

/// The largest image read by default, in pixels (100 Mpixel: well above any
/// camera; a header declaring more is refused before anything is allocated).
pub const DEFAULT_MAX_PIXELS: u64 = 100_000_000;

/// The `max_megapixels` parameter of the ops that read images (flattened into
/// them with `#[param(flatten)]`).
#[derive(Debug, Clone, Copy, PartialEq, Params)]
pub struct ImageSizeLimit {
    /// Largest image to decode: a file whose header declares more is refused before decoding
    #[param(default = DEFAULT_MAX_PIXELS as f64 / 1e6, unit = "Mpixel", min = 0.01, max = 10_000.0)]
    pub max_megapixels: f64,
}

impl ImageSizeLimit {
    /// The limit in pixels.
    pub fn max_pixels(&self) -> u64 {
        (self.max_megapixels * 1e6) as u64
    }
}

/// The `max_megapixels` parameter as the engine declares it, for ops still
/// declared with [`ParamSpec`] builders (the typed form flattens
/// [`ImageSizeLimit`] instead).
pub fn max_megapixels_param() -> ParamSpec {
    let decl = ImageSizeLimit::param_decls().remove(0);
    fusegraph_engine::typed::param_spec(decl)
}

/// Pixels allowed by a `max_megapixels` parameter (for ops still declared with
/// [`ParamSpec`] builders; the typed form uses [`ImageSizeLimit::max_pixels`]).
pub fn max_pixels(params: &fusegraph_engine::Params) -> Result<u64, OpError> {
    let limit = ImageSizeLimit::from_params(params).map_err(|p| {
        OpError::Param(fusegraph_engine::param::ParamError {
            name: p.name,
            problem: p.problem,
        })
    })?;
    Ok(limit.max_pixels())
}

/// Refuses an image whose declared size exceeds `max_pixels`, naming the file,
/// the size and the memory decoding it would take.
fn check_size(path: &std::path::Path, (w, h): (u64, u64), max_pixels: u64) -> Result<(), OpError> {
    if w.saturating_mul(h) <= max_pixels {
        return Ok(());
    }
    Err(OpError::invalid(format!(
        "{}: declares {w} x {h} px ({:.0} Mpixel, about {:.1} GB decoded), above the limit of {:.0} Mpixel (max_megapixels)",
        path.display(),
        (w * h) as f64 / 1e6,
        (w * h * 3) as f64 / 1e9,
        max_pixels as f64 / 1e6
    )))
}

/// Reads a PNG or JPEG file as 8-bit RGB (at most [`DEFAULT_MAX_PIXELS`]).
pub fn load_image(path: &std::path::Path) -> Result<Image, OpError> {
    load_image_within(path, DEFAULT_MAX_PIXELS)
}

/// Reads a PNG or JPEG file as 8-bit RGB; a header declaring more than
/// `max_pixels` is refused before decoding, and the decoder may allocate no
/// more than the image needs.
pub fn load_image_within(path: &std::path::Path, max_pixels: u64) -> Result<Image, OpError> {
    let bytes = std::fs::read(path).map_err(|e| OpError::io(path, e))?;
    decode_rgb(path, &bytes, max_pixels)
}

/// Decodes the bytes of image file `path` (named in errors) as 8-bit RGB:
/// the header's size is checked first, then the decoder runs with its
/// allocations bounded by that size.
fn decode_rgb(path: &std::path::Path, bytes: &[u8], max_pixels: u64) -> Result<Image, OpError> {
    if is_jpeg(bytes) {
        let (rgb, width, height) = decode_jpeg(path, bytes, max_pixels)?;
        return Image::new(width, height, 3, Pixels::U8(rgb.into()))
            .map_err(|e| OpError::invalid(e.0));
    }
    let named = |e: image::ImageError| OpError::invalid(format!("{}: {e}", path.display()));
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| OpError::io(path, e))
    };
    let (w, h) = reader()?.into_dimensions().map_err(named)?;
    check_size(path, (w as u64, h as u64), max_pixels)?;
    let mut limits = image::Limits::default();
    // RGBA at 16 bits is the widest output, plus a copy while converting.
    limits.max_alloc = Some((w as u64 * h as u64 * 8).saturating_mul(2).max(1 << 20));
    let mut r = reader()?;
    r.limits(limits);
    let img = r.decode().map_err(named)?.to_rgb8();
    let (w, h) = img.dimensions();
    Image::new(w as usize, h as usize, 3, Pixels::U8(img.into_raw().into()))
        .map_err(|e| OpError::invalid(e.0))
}

fn is_jpeg(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0xFF, 0xD8])
}

/// Decodes a JPEG with zune-jpeg in strict mode: a truncated file ("premature
/// end"), a corrupt entropy-coded segment or a marker out of place is an
/// error naming the file, not an image whose lower part is filler. The
/// header's size is checked against `max_pixels` before decoding. Returns
/// the RGB samples, width and height, px.
fn decode_jpeg(
    path: &std::path::Path,
    bytes: &[u8],
    max_pixels: u64,
) -> Result<(Vec<u8>, usize, usize), OpError> {
    use zune_core::bytestream::ZCursor;
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    let channels = 3;
    let failed = |e: zune_jpeg::errors::DecodeErrors| {
        OpError::invalid(format!(
            "{}: the JPEG does not decode cleanly ({e}): a truncated or corrupt file?",
            path.display()
        ))
    };
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(ColorSpace::RGB)
        .set_strict_mode(true);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    decoder.decode_headers().map_err(failed)?;
    if let Some((w, h)) = decoder.dimensions() {
        check_size(path, (w as u64, h as u64), max_pixels)?;
    }
    let samples = decoder.decode().map_err(failed)?;
    let (width, height) = decoder
        .dimensions()
        .ok_or_else(|| OpError::invalid(format!("{}: no image size", path.display())))?;
    if samples.len() != width * height * channels {
        return Err(OpError::invalid(format!(
            "{}: decoded {} samples for {width} x {height} px",
            path.display(),
            samples.len()
        )));
    }
    Ok((samples, width, height))
}

/// A grey image: levels 0..1, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// `width * height` levels, 0..1.
    pub levels: Vec<f32>,
}

/// Reads an image file as grey levels (0..1) for detectors: the mean of R,
/// G and B ([`grey_of`]), whatever the format. Not a JPEG's luma plane,
/// though decoding it alone is faster: a chessboard is neutral, so equal
/// weights give the best signal to noise, and behind a Bayer mosaic they
/// cancel the demosaicing errors of the red and blue sites (which lie on
/// opposite diagonals), which luma's 0.299 / 0.114 leave in. Phantom
/// calibration under Bayer and JPEG 90: corners 0.072 -> 0.049 px RMS.
/// Same bytes, same levels, in every binary and on any thread count.
pub fn load_grey(path: &std::path::Path) -> Result<GreyImage, OpError> {
    load_grey_within(path, DEFAULT_MAX_PIXELS)
}

/// [`load_grey`], refusing an image whose header declares more than
/// `max_pixels` before decoding it.
pub fn load_grey_within(path: &std::path::Path, max_pixels: u64) -> Result<GreyImage, OpError> {
    let bytes = std::fs::read(path).map_err(|e| OpError::io(path, e))?;
    let img = decode_rgb(path, &bytes, max_pixels)?;
    Ok(GreyImage {
        width: img.width,
        height: img.height,
        levels: grey_of(&img),
    })
}

/// Grey levels (0..1) of an RGB or grey image, row-major.
pub fn grey_of(img: &Image) -> Vec<f32> {
    let n = img.width * img.height;
    match &img.pixels {
        Pixels::U8(p) if img.channels == 3 => (0..n)
            .map(|i| (p[3 * i] as f32 + p[3 * i + 1] as f32 + p[3 * i + 2] as f32) / 765.0)
            .collect(),
        Pixels::U8(p) => p.iter().map(|&v| v as f32 / 255.0).collect(),
        Pixels::F32(p) if img.channels == 3 => (0..n)
            .map(|i| (p[3 * i] + p[3 * i + 1] + p[3 * i + 2]) / 3.0)
            .collect(),
        Pixels::F32(p) => p.to_vec(),
    }
}

/// 8-bit RGB samples of an image (grey repeated, floats scaled from 0..1).
fn rgb8(img: &Image) -> Vec<u8> {
    let n = img.width * img.height;
    let sample = |i: usize, c: usize| -> u8 {
        let k = if img.channels == 3 { 3 * i + c } else { i };
        match &img.pixels {
            Pixels::U8(p) => p[k],
            Pixels::F32(p) => (p[k] * 255.0).round().clamp(0.0, 255.0) as u8,
        }
    };
    (0..n)
        .flat_map(|i| [sample(i, 0), sample(i, 1), sample(i, 2)])
        .collect()
}

/// The two images side by side with a red horizontal line every `every_px`
/// rows (0: none): 8-bit RGB rows, and the width and height in px. The images
/// must be equally high.
pub fn side_by_side(
    left: &Image,
    right: &Image,
    every_px: usize,
) -> Result<(Vec<u8>, usize, usize), String> {
    if left.height != right.height {
        return Err(format!(
            "heights differ: {} and {} px",
            left.height, right.height
        ));
    }
    let (w, h) = (left.width + right.width, left.height);
    let (l, r) = (rgb8(left), rgb8(right));
    let mut out = vec![0u8; w * h * 3];
    for y in 0..h {
        out[y * w * 3..(y * w + left.width) * 3]
            .copy_from_slice(&l[y * left.width * 3..(y + 1) * left.width * 3]);
        out[(y * w + left.width) * 3..(y + 1) * w * 3]
            .copy_from_slice(&r[y * right.width * 3..(y + 1) * right.width * 3]);
        if every_px > 0 && y % every_px == every_px / 2 {
            for x in 0..w {
                out[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&[255, 40, 40]);
            }
        }
    }
    Ok((out, w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG file of a few dozen bytes whose header declares `w x h` pixels.
    fn png_declaring(w: u32, h: u32) -> Vec<u8> {
        let mut ihdr = b"IHDR".to_vec();
        ihdr.extend(w.to_be_bytes());
        ihdr.extend(h.to_be_bytes());
        ihdr.extend([8, 0, 0, 0, 0]); // 8-bit grey, no interlace
        let chunk = |body: &[u8]| {
            let mut crc = flate2::Crc::new();
            crc.update(body);
            let mut c = ((body.len() - 4) as u32).to_be_bytes().to_vec();
            c.extend(body);
            c.extend(crc.sum().to_be_bytes());
            c
        };
        // The first scanlines only (a few zero bytes compressed): the rest of
        // the declared image is missing, as in a crafted file.
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        std::io::Write::write_all(&mut z, &[0u8; 64]).unwrap();
        let mut idat = b"IDAT".to_vec();
        idat.extend(z.finish().unwrap());
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend(chunk(&ihdr));
        png.extend(chunk(&idat));
        png.extend(chunk(b"IEND"));
        png
    }

    #[test]
    fn a_header_declaring_a_huge_image_is_refused_before_decoding() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("bomb.png");
        std::fs::write(&path, png_declaring(20_000, 20_000)).unwrap();
        for result in [load_image(&path).map(|_| ()), load_grey(&path).map(|_| ())] {
            let e = result.unwrap_err().to_string();
            assert!(
                e.contains("bomb.png: declares 20000 x 20000 px (400 Mpixel"),
                "{e}"
            );
            assert!(e.contains("above the limit of 100 Mpixel"), "{e}");
        }
        // A real photo within a smaller limit is refused the same way.
        let photo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/data/chessboard/calibration03.jpg");
        let e = load_grey_within(&photo, 100_000).unwrap_err().to_string();
        assert!(e.contains("declares 1280 x 720 px"), "{e}");
        assert!(load_grey_within(&photo, 1_000_000).is_ok());
    }

    #[test]
    fn a_truncated_jpeg_is_an_error_naming_the_file() {
        let photo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/data/chessboard/calibration03.jpg");
        let bytes = std::fs::read(&photo).unwrap();
        let t = tempfile::tempdir().unwrap();
        let cut = t.path().join("cut.jpg");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        for e in [
            load_image(&cut).unwrap_err().to_string(),
            load_grey(&cut).unwrap_err().to_string(),
        ] {
            assert!(
                e.contains("cut.jpg") && e.contains("does not decode cleanly"),
                "{e}"
            );
        }
        // The whole file decodes, in colour and grey, to the same size.
        let rgb = load_image(&photo).unwrap();
        let grey = load_grey(&photo).unwrap();
        assert_eq!((rgb.width, rgb.height, rgb.channels), (1280, 720, 3));
        assert_eq!((grey.width, grey.height), (1280, 720));
    }
}
