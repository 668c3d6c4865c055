//! The simulated sensor: what turns the lens's image (linear RGB, 0..1 =
//! saturation) into the 8-bit file a camera writes. Vignetting, exposure,
//! shot and read noise, clipping at saturation, an optional Bayer mosaic
//! demosaiced bilinearly (as cheap cameras do), and PNG or JPEG output.
//! Rows are processed in parallel with per-row random streams, so the output
//! is the same for any thread count. Written here: each step is a line or two
//! of arithmetic on our own image layout.

use crate::camera::CameraModel;
use crate::numeric::floor_small_u64;
use crate::simd::{Isa, kernels};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// How the sensor turns light into 8-bit values.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorParams {
    /// Read noise standard deviation, in units of the full scale (1.0 = 255).
    pub read_noise: f64,
    /// Electrons at saturation; shot noise has variance `signal / full_well`
    /// (full-scale units). 0 = no shot noise.
    pub full_well_e: f64,
    /// Exposure gain on the linear signal (1 = as lit; 2 = one stop over).
    pub exposure_gain: f64,
    /// Strength of the natural cos^4 falloff: the fade is (1 + r^2)^(-2 s)
    /// with r the normalised image radius (0 = none, 1 = natural).
    pub vignetting: f64,
    /// Record one colour per pixel through an RGGB Bayer mosaic and demosaic
    /// bilinearly.
    pub bayer: bool,
    /// Seed of the noise.
    pub seed: u64,
}

impl SensorParams {
    /// The ideal phantom's sensor: read noise only, natural vignetting.
    pub fn ideal(read_noise: f64, seed: u64) -> Self {
        SensorParams {
            read_noise,
            full_well_e: 0.0,
            exposure_gain: 1.0,
            vignetting: 1.0,
            bayer: false,
            seed,
        }
    }
}

/// The fade of the light at squared normalised image radius `r2` from
/// vignetting of strength `s`.
fn fade_at_radius(r2: f64, s: f64) -> f64 {
    if s == 0.0 {
        1.0
    } else if s == 1.0 {
        // The natural falloff, computed as it always was (same bits).
        1.0 / (1.0 + r2).powi(2)
    } else {
        (1.0 + r2).powf(-2.0 * s)
    }
}

/// The sensor's gain and noise, the same for every sample.
#[derive(Clone, Copy)]
pub(crate) struct SampleNoise {
    /// Read noise standard deviation, full-scale units.
    read: f64,
    /// [`SensorParams::exposure_gain`].
    exposure_gain: f64,
    /// [`SensorParams::full_well_e`] (0: no shot noise).
    full_well_e: f64,
}

kernels! {
    /// Each sample's 8-bit value: its light `values[i]` (linear, 0..1 =
    /// saturation) faded by `fades[i]`, gained, plus Gaussian noise drawn
    /// from the random word `words[i]`, clipped and rounded. Branch-free
    /// within a loop, so it vectorises; AVX2 gives the same bits.
    fn expose_samples(values: &[f32], fades: &[f64], words: &[u64], noise: SampleNoise, out: &mut [u8]) {
        let n = out.len();
        let (values, fades, words) = (&values[..n], &fades[..n], &words[..n]);
        let SampleNoise { read, exposure_gain, full_well_e } = noise;
        // Without shot noise the loop has no square root or division.
        if full_well_e > 0.0 {
            for i in 0..n {
                let signal = values[i] as f64 * fades[i] * exposure_gain;
                let sigma = (read * read + signal.max(0.0) / full_well_e).sqrt();
                out[i] = exposed_sample(signal, sigma, words[i]);
            }
        } else {
            for i in 0..n {
                // Times a gain of exactly 1 is the same bits as no product.
                let signal = values[i] as f64 * fades[i] * exposure_gain;
                out[i] = exposed_sample(signal, read, words[i]);
            }
        }
    }
}

/// The 8-bit value of a sample of `signal` (full-scale units) with
/// Gaussian noise of standard deviation `sigma` drawn from the random word
/// `r`, clipped and rounded.
#[inline(always)]
fn exposed_sample(signal: f64, sigma: f64, r: u64) -> u8 {
    // Sensor noise: the sum of four 16-bit uniforms (Irwin-Hall),
    // scaled to unit variance, is Gaussian to within 2 % in density
    // for |z| < 3 and takes one random word per sample instead of a
    // ziggurat draw. The sum is under 2^18, so its f64 is the bits
    // 2^52 + sum, less 2^52 (exact; a conversion that vectorises).
    let sum = (r & 0xFFFF) + ((r >> 16) & 0xFFFF) + ((r >> 32) & 0xFFFF) + (r >> 48);
    let uniforms =
        (f64::from_bits(0x4330_0000_0000_0000 | sum) - 4_503_599_627_370_496.0) / 65536.0;
    let v = signal + (uniforms - 2.0) * 3.0f64.sqrt() * sigma;
    // The floor after +0.5 rounds (in 0.5..=255.5 after the clamp; NaN
    // gives 0, as the cast of old did).
    floor_small_u64((v * 255.0).clamp(0.0, 255.0) + 0.5) as u8
}

/// Which colour an RGGB mosaic records at (x, y).
fn bayer_channel(x: usize, y: usize) -> usize {
    match (y % 2, x % 2) {
        (0, 0) => 0,
        (1, 1) => 2,
        _ => 1,
    }
}

/// Exposes `image` (linear RGB, row-major, `camera`'s size): interleaved
/// 8-bit RGB, row-major.
pub fn expose(image: &[[f32; 3]], camera: &CameraModel, p: &SensorParams) -> Vec<u8> {
    let (w, h) = (camera.width, camera.height);
    let read = p.read_noise.max(0.0);
    let mut out = vec![0u8; w * h * 3];
    // The squared radius splits into a column's and a row's part.
    let column_r2: Vec<f64> = (0..w)
        .map(|x| ((x as f64 - camera.cx) / camera.fx).powi(2))
        .collect();
    let samples_per_pixel = if p.bayer { 1 } else { 3 };
    let isa = Isa::detect();
    let noise = SampleNoise {
        read,
        exposure_gain: p.exposure_gain,
        full_well_e: p.full_well_e,
    };
    out.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        let mut rng =
            ChaCha8Rng::seed_from_u64(p.seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ y as u64);
        // One random word per sample, drawn in sample order (filled as
        // bytes: the words `next_u64` would give, without a call each).
        let mut words = vec![0u64; w * samples_per_pixel];
        rng.fill(&mut words[..]);
        let row_r2 = ((y as f64 - camera.cy) / camera.fy).powi(2);
        let fade = |c: f64| fade_at_radius(c + row_r2, p.vignetting);
        let pixels = &image[y * w..(y + 1) * w];
        if p.bayer {
            let channel = |x: usize| bayer_channel(x, y);
            let values: Vec<f32> = (0..w).map(|x| pixels[x][channel(x)]).collect();
            let fades: Vec<f64> = column_r2.iter().map(|&c| fade(c)).collect();
            let mut recorded = vec![0u8; w];
            isa.expose_samples(&values, &fades, &words, noise, &mut recorded);
            for (x, v) in recorded.into_iter().enumerate() {
                row[x * 3 + channel(x)] = v;
            }
        } else {
            let mut fades = Vec::with_capacity(3 * w);
            for &c in &column_r2 {
                let f = fade(c);
                fades.extend_from_slice(&[f, f, f]);
            }
            isa.expose_samples(pixels.as_flattened(), &fades, &words, noise, row);
        }
    });
    if p.bayer {
        demosaic_bilinear(&mut out, w, h);
    }
    out
}

/// Fills the two colours each pixel of an RGGB mosaic did not record (held
/// in `rgb`'s own channel of each pixel) by bilinear interpolation: the
/// weighted mean of the 3 x 3 neighbours that recorded it (weights 4 at the
/// centre, 2 beside, 1 diagonal), which is bilinear on every site.
pub fn demosaic_bilinear(rgb: &mut [u8], w: usize, h: usize) {
    let raw: Vec<u8> = (0..w * h)
        .map(|i| rgb[i * 3 + bayer_channel(i % w, i / w)])
        .collect();
    rgb.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let own = bayer_channel(x, y);
            let mut sum = [0u32; 3];
            let mut weight = [0u32; 3];
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    let c = bayer_channel(xx, yy);
                    let k = 4 >> (yy.abs_diff(y) + xx.abs_diff(x));
                    sum[c] += k * raw[xx + yy * w] as u32;
                    weight[c] += k;
                }
            }
            for c in 0..3 {
                if c != own && weight[c] > 0 {
                    row[x * 3 + c] = ((sum[c] + weight[c] / 2) / weight[c]) as u8;
                }
            }
        }
    });
}

/// Writes interleaved 8-bit RGB: PNG (fast compression) when `jpeg_quality`
/// is 0, else baseline JPEG at that quality (1-100, libjpeg's scale).
pub fn write_image(
    path: &std::path::Path,
    rgb: &[u8],
    width: usize,
    height: usize,
    jpeg_quality: u8,
) -> std::io::Result<()> {
    use image::ImageEncoder;
    use image::codecs::jpeg::JpegEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let (w, h, colour) = (width as u32, height as u32, image::ExtendedColorType::Rgb8);
    if jpeg_quality == 0 {
        PngEncoder::new_with_quality(file, CompressionType::Fast, FilterType::Adaptive)
            .write_image(rgb, w, h, colour)
    } else {
        JpegEncoder::new_with_quality(file, jpeg_quality.min(100)).write_image(rgb, w, h, colour)
    }
    .map_err(std::io::Error::other)
}

/// The file extension [`write_image`] writes for `jpeg_quality`.
pub fn image_extension(jpeg_quality: u8) -> &'static str {
    if jpeg_quality == 0 { "png" } else { "jpg" }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngCore;

    fn camera(w: usize, h: usize) -> CameraModel {
        CameraModel {
            width: w,
            height: h,
            fx: 100.0,
            fy: 100.0,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            distortion: [0.0; 5],
        }
    }

    #[test]
    fn words_filled_as_bytes_are_the_drawn_words() {
        for n in [1, 7, 64, 65, 2400] {
            let (mut a, mut b) = (ChaCha8Rng::seed_from_u64(9), ChaCha8Rng::seed_from_u64(9));
            // Start off a block's edge too: the words straddle blocks.
            a.next_u32();
            b.next_u32();
            let drawn: Vec<u64> = (0..n).map(|_| a.next_u64()).collect();
            let mut filled = vec![0u64; n];
            b.fill(&mut filled[..]);
            assert_eq!(drawn, filled, "{n} words");
            assert_eq!(a.next_u32(), b.next_u32());
        }
    }

    #[test]
    fn demosaicing_a_smooth_image_gives_it_back() {
        // A linear ramp in each channel: bilinear interpolation is exact on it
        // away from the border (up to rounding).
        let (w, h) = (16, 12);
        let truth: Vec<u8> = (0..w * h)
            .flat_map(|i| {
                let (x, y) = ((i % w) as u32, (i / w) as u32);
                [
                    (10 + 8 * x) as u8,
                    (20 + 6 * y) as u8,
                    (30 + 4 * x + 3 * y) as u8,
                ]
            })
            .collect();
        let mut mosaic = truth.clone();
        demosaic_bilinear(&mut mosaic, w, h);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                for c in 0..3 {
                    let (a, b) = (mosaic[(x + y * w) * 3 + c], truth[(x + y * w) * 3 + c]);
                    assert!(a.abs_diff(b) <= 1, "({x}, {y}) channel {c}: {a} vs {b}");
                }
            }
        }
    }

    /// Corner errors (rms, px) of a neutral chessboard corner seen through an
    /// RGGB mosaic and demosaiced, over sub-pixel positions and angles, its
    /// grey taken with the channel weights `weights` (no mosaic: `mosaic`
    /// false).
    fn demosaiced_corner_rms_px(weights: [f32; 3], mosaic: bool) -> f64 {
        let (w, h) = (40, 40);
        let mut sum = 0.0;
        let mut n = 0;
        for k in 0..24 {
            let (x0, y0) = (19.0 + 0.37 * k as f64 % 1.0, 19.5 + 0.61 * k as f64 % 1.0);
            let angle = 0.13 * k as f64;
            let (sin, cos) = angle.sin_cos();
            // 8 x 8 samples per pixel, then a 1 px lens blur in two box passes.
            let sharp: Vec<[f32; 3]> = (0..w * h)
                .map(|i| {
                    let mut acc = 0.0;
                    for s in 0..64 {
                        let px = (i % w) as f64 + ((s % 8) as f64 + 0.5) / 8.0 - 0.5 - x0;
                        let py = (i / w) as f64 + ((s / 8) as f64 + 0.5) / 8.0 - 0.5 - y0;
                        let (u, v) = (cos * px + sin * py, -sin * px + cos * py);
                        acc += if (u > 0.0) == (v > 0.0) { 0.1 } else { 0.85 };
                    }
                    [acc / 64.0; 3]
                })
                .collect();
            let blurred = super::super::defocus::gaussian_blur(&sharp, w, h, 1.0);
            let mut rgb: Vec<u8> = blurred
                .iter()
                .flat_map(|v| v.map(|c| (c * 255.0).round() as u8))
                .collect();
            if mosaic {
                demosaic_bilinear(&mut rgb, w, h);
            }
            let grey: Vec<f32> = rgb
                .chunks(3)
                .map(|c| (0..3).map(|i| weights[i] * c[i] as f32).sum::<f32>() / 255.0)
                .collect();
            let (x, y) = crate::calib::refine_corner(&grey, w, h, (x0 + 0.3, y0 - 0.3), 5)
                .expect("a corner");
            sum += (x - x0).powi(2) + (y - y0).powi(2);
            n += 1;
        }
        (sum / n as f64).sqrt()
    }

    #[test]
    fn equal_channel_weights_cancel_what_demosaicing_moves_and_luma_does_not() {
        // What 8 x 8 samples and 8 bits leave without a mosaic.
        let floor = demosaiced_corner_rms_px([1.0 / 3.0; 3], false);
        let mean = demosaiced_corner_rms_px([1.0 / 3.0; 3], true);
        let luma = demosaiced_corner_rms_px([0.299, 0.587, 0.114], true);
        // Equal weights keep the mosaic-free accuracy (0.025 px here); luma
        // adds about 0.02 px in quadrature.
        assert!(
            mean < 1.05 * floor && luma > 1.15 * floor,
            "corner rms: no mosaic {floor:.4} px, equal weights {mean:.4} px, luma {luma:.4} px"
        );
    }

    #[test]
    fn saturation_clips_and_shot_noise_grows_with_the_signal() {
        let cam = camera(64, 64);
        let grey = |v: f32| vec![[v; 3]; 64 * 64];
        let mut p = SensorParams::ideal(0.0, 3);
        p.vignetting = 0.0;
        p.exposure_gain = 4.0;
        assert!(expose(&grey(0.5), &cam, &p).iter().all(|&v| v == 255));
        p.exposure_gain = 1.0;
        p.full_well_e = 2000.0;
        let spread = |v: f32| {
            let img = expose(&grey(v), &cam, &p);
            let mean = img.iter().map(|&x| x as f64).sum::<f64>() / img.len() as f64;
            let var =
                img.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / img.len() as f64;
            var.sqrt() / 255.0
        };
        // sigma = sqrt(signal / full_well): 0.0071 at 0.1, 0.0158 at 0.5.
        let (low, high) = (spread(0.1), spread(0.5));
        assert!((low - (0.1f64 / 2000.0).sqrt()).abs() < 0.0015, "{low}");
        assert!((high - (0.5f64 / 2000.0).sqrt()).abs() < 0.0015, "{high}");
    }

    #[test]
    fn vignetting_strength_scales_the_falloff() {
        // At r^2 = 1 (100 px from the centre at f = 100 px): 1/4 at the
        // natural strength, 1/16 at twice it, none at 0.
        assert_eq!(fade_at_radius(1.0, 1.0), 0.25);
        assert!((fade_at_radius(1.0, 2.0) - 1.0 / 16.0).abs() < 1e-12);
        assert_eq!(fade_at_radius(1.0, 0.0), 1.0);
    }

    /// The libjpeg quality whose luminance table (the standard one of the
    /// JPEG spec's Annex K, scaled as libjpeg scales it) holds the values of
    /// the file's first quantisation table; compared as sorted values, which
    /// needs no zigzag order.
    fn jpeg_quality_of(bytes: &[u8]) -> Option<u8> {
        const ANNEX_K_LUMA: [u32; 64] = [
            16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57,
            69, 56, 14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55,
            64, 81, 104, 113, 92, 49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100,
            103, 99,
        ];
        let at = bytes.windows(2).position(|m| m == [0xFF, 0xDB])?;
        // Marker, 2-byte length, precision/table id, 64 8-bit values.
        let mut table: Vec<u32> = bytes
            .get(at + 5..at + 69)?
            .iter()
            .map(|&v| v as u32)
            .collect();
        table.sort_unstable();
        (1..=100u32).find_map(|q| {
            let scale = if q < 50 { 5000 / q } else { 200 - 2 * q };
            let mut expected: Vec<u32> = ANNEX_K_LUMA
                .iter()
                .map(|&v| ((v * scale + 50) / 100).clamp(1, 255))
                .collect();
            expected.sort_unstable();
            (expected == table).then_some(q as u8)
        })
    }

    #[test]
    fn jpeg_is_written_at_the_quality_asked() {
        let d = tempfile::tempdir().unwrap();
        let (w, h) = (64, 48);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        for q in [30u8, 75, 90] {
            let path = d.path().join(format!("q{q}.{}", image_extension(q)));
            write_image(&path, &rgb, w, h, q).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            assert_eq!(&bytes[..2], &[0xFF, 0xD8], "a JPEG file");
            assert_eq!(jpeg_quality_of(&bytes), Some(q));
        }
        let png = d.path().join("lossless.png");
        write_image(&png, &rgb, w, h, 0).unwrap();
        assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
    }
}
