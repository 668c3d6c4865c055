//! Images in and out: `io.read_image` and `io.write_stereo_pair` (a rectified
//! pair side by side with horizontal lines, to check rectification by eye).

use fusegraph_engine::value::{Image, PathValue, Pixels};
use fusegraph_engine::{
    Inputs, Op, OpError, OpSpec, Outputs, ParamSpec, Params, RunCtx, ValueType, path_value,
};
use std::sync::Arc;

/// Reads a PNG, JPEG or TIFF file as 8-bit RGB.
pub fn load_image(path: &std::path::Path) -> Result<Image, OpError> {
    let img = image::open(path)
        .map_err(|e| OpError::invalid(format!("{}: {e}", path.display())))?
        .to_rgb8();
    let (w, h) = img.dimensions();
    Image::new(w as usize, h as usize, 3, Pixels::U8(img.into_raw().into()))
        .map_err(|e| OpError::invalid(e.0))
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

/// Reads an image file as grey levels (0..1) for detectors. A JPEG is decoded
/// straight to its luma plane (Y of its YCbCr, what the camera encoded as
/// brightness), skipping the colour planes, their upsampling and the RGB
/// conversion; other formats go through [`load_image`] and [`grey_of`].
/// Same bytes, same levels, in every binary and on any thread count.
pub fn load_grey(path: &std::path::Path) -> Result<GreyImage, OpError> {
    let bytes = std::fs::read(path).map_err(|e| OpError::io(path, e))?;
    if bytes.starts_with(&[0xFF, 0xD8]) {
        use zune_core::bytestream::ZCursor;
        use zune_core::colorspace::ColorSpace;
        use zune_core::options::DecoderOptions;
        let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::Luma);
        let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(&bytes), options);
        let luma = decoder
            .decode()
            .map_err(|e| OpError::invalid(format!("{}: {e:?}", path.display())))?;
        let (width, height) = decoder
            .dimensions()
            .ok_or_else(|| OpError::invalid(format!("{}: no image size", path.display())))?;
        if luma.len() != width * height {
            return Err(OpError::invalid(format!(
                "{}: decoded {} samples for {width} x {height} px",
                path.display(),
                luma.len()
            )));
        }
        let levels = luma.iter().map(|&v| v as f32 / 255.0).collect();
        return Ok(GreyImage {
            width,
            height,
            levels,
        });
    }
    let img = load_image(path)?;
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

/// The two images side by side with a horizontal line every `every_px` rows.
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

/// The ports and parameters that say which file a reader op reads: a `dir`
/// input with a `file` name, or a `path`; [`source_file`] resolves them.
pub(crate) trait SourceFileSpec {
    /// Adds the `dir` input and the `file` and `path` parameters.
    fn with_source_file(self) -> Self;
}

impl SourceFileSpec for OpSpec {
    fn with_source_file(self) -> Self {
        self.optional_input(
            "dir",
            &[ValueType::Path],
            "Folder the file is in (else relative to the graph)",
        )
        .param(ParamSpec::string(
            "file",
            "",
            "File name (inside `dir` when connected)",
        ))
        .param(ParamSpec::optional_path(
            "path",
            "File, relative to the graph (instead of dir + file)",
        ))
    }
}

/// The file a reader op reads: its `path` parameter, or its `dir` input joined
/// with its `file` parameter (exactly one of the two).
pub(crate) fn source_file(inputs: &Inputs, params: &Params) -> Result<std::path::PathBuf, OpError> {
    let dir: Option<Arc<PathValue>> = inputs.optional("dir")?;
    match (params.optional_path("path")?, dir) {
        (Some(p), None) => Ok(p),
        (None, Some(d)) => Ok(d.path.join(params.string("file")?)),
        _ => Err(OpError::invalid(
            "give the `path` parameter, or the `dir` input and the `file` parameter",
        )),
    }
}

pub(crate) struct ReadImageOp(OpSpec);

impl ReadImageOp {
    pub(crate) fn new() -> Self {
        ReadImageOp(
            OpSpec::new(
                "io.read_image",
                1,
                "Read an image file (PNG, JPEG, TIFF) as 8-bit RGB",
            )
            .with_source_file()
            .output("image", ValueType::Image, "The image"),
        )
    }
}

impl Op for ReadImageOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, _: &mut RunCtx) -> Result<Outputs, OpError> {
        let path = source_file(inputs, params)?;
        Ok(Outputs::new().with("image", load_image(&path)?))
    }
}

pub(crate) struct WriteStereoPairOp(OpSpec);

impl WriteStereoPairOp {
    pub(crate) fn new() -> Self {
        WriteStereoPairOp(
            OpSpec::new(
                "io.write_stereo_pair",
                1,
                "Write two images side by side as PNG, with horizontal lines",
            )
            .input("left", &[ValueType::Image], "Left image")
            .input("right", &[ValueType::Image], "Right image")
            .param(
                ParamSpec::int("lines_every_px", 40, "px", "Line spacing (0 = none)").at_least(0.0),
            )
            .param(ParamSpec::string(
                "file",
                "pair.png",
                "PNG file, relative to the output folder",
            ))
            .output("file", ValueType::Path, "The PNG")
            .writes_output(),
        )
    }
}

impl Op for WriteStereoPairOp {
    fn spec(&self) -> &OpSpec {
        &self.0
    }
    fn run(&self, inputs: &Inputs, params: &Params, ctx: &mut RunCtx) -> Result<Outputs, OpError> {
        let (l, r) = (inputs.get::<Image>("left")?, inputs.get::<Image>("right")?);
        let (rgb, w, h) =
            side_by_side(&l, &r, params.count("lines_every_px")?).map_err(OpError::invalid)?;
        let path = ctx.output_path(&params.string("file")?)?;
        image::save_buffer(
            &path,
            &rgb,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| OpError::invalid(format!("{}: {e}", path.display())))?;
        Ok(Outputs::new().with("file", path_value(&path)?))
    }
}
