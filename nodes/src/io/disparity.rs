//! Disparity map files: reading PFM, or 8/16-bit PGM or PNG holding
//! disparity times a scale (as Middlebury and KITTI store them), and writing
//! PFM and a colour-mapped PNG with a legend in px.

use fusegraph_engine::value::Disparity;
use std::path::Path;

/// The first `n` whitespace-separated header tokens of a PNM-style file
/// (`#` comments skipped) and the offset of the data, which starts after the
/// single whitespace byte that ends the last token.
fn header_tokens(bytes: &[u8], n: usize) -> Result<(Vec<String>, usize), String> {
    let mut tokens = Vec::new();
    let mut i = 0;
    while tokens.len() < n {
        while i < bytes.len() && (bytes[i].is_ascii_whitespace() || bytes[i] == b'#') {
            if bytes[i] == b'#' {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
            } else {
                i += 1;
            }
        }
        let start = i;
        while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if start == i || i >= bytes.len() {
            return Err(format!(
                "header ends after {} of its {n} fields",
                tokens.len()
            ));
        }
        tokens.push(String::from_utf8_lossy(&bytes[start..i]).into_owned());
    }
    Ok((tokens, i + 1))
}

fn dimensions(w: &str, h: &str) -> Result<(usize, usize), String> {
    match (w.parse::<usize>(), h.parse::<usize>()) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 && w.checked_mul(h).is_some() => Ok((w, h)),
        _ => Err(format!("bad size `{w} {h}` in the header")),
    }
}

fn check_data_len(got: usize, need: usize, w: usize, h: usize) -> Result<(), String> {
    if got < need {
        Err(format!(
            "truncated: {got} bytes of pixel data, {w} x {h} needs {need}"
        ))
    } else if got > need {
        Err(format!(
            "size mismatch: {got} bytes of pixel data, {w} x {h} needs {need}"
        ))
    } else {
        Ok(())
    }
}

/// Decodes a grey PFM (`Pf`; little endian when the scale is negative, rows
/// stored bottom to top) into row-major rows top to bottom; infinities (the
/// Middlebury mark of unknown) become NaN.
pub fn decode_pfm(bytes: &[u8]) -> Result<(usize, usize, Vec<f32>), String> {
    let (t, start) = header_tokens(bytes, 4)?;
    match t[0].as_str() {
        "Pf" => {}
        "PF" => return Err("colour PFM (PF): a disparity map is a grey PFM (Pf)".into()),
        other => return Err(format!("not a PFM file (starts with `{other}`)")),
    }
    let (w, h) = dimensions(&t[1], &t[2])?;
    let scale: f64 = t[3]
        .parse()
        .ok()
        .filter(|s: &f64| s.is_finite() && *s != 0.0)
        .ok_or_else(|| format!("bad scale `{}` in the header", t[3]))?;
    let data = &bytes[start.min(bytes.len())..];
    check_data_len(data.len(), w * h * 4, w, h)?;
    let mut out = vec![0f32; w * h];
    for (r, row) in data.chunks_exact(w * 4).enumerate() {
        let dst = &mut out[(h - 1 - r) * w..(h - r) * w];
        for (d, b) in dst.iter_mut().zip(row.chunks_exact(4)) {
            let b = [b[0], b[1], b[2], b[3]];
            let v = if scale < 0.0 {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
            *d = if v.is_infinite() { f32::NAN } else { v };
        }
    }
    Ok((w, h, out))
}

/// Encodes a little-endian grey PFM (scale -1, rows bottom to top), NaN
/// written as +inf so Middlebury's tools read it as unknown.
pub fn encode_pfm(width: usize, height: usize, data: &[f32]) -> Vec<u8> {
    let mut out = format!("Pf\n{width} {height}\n-1\n").into_bytes();
    out.reserve(width * height * 4);
    for r in (0..height).rev() {
        for &v in &data[r * width..(r + 1) * width] {
            let v = if v.is_nan() { f32::INFINITY } else { v };
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Decodes a binary (`P5`) or text (`P2`) PGM of 8 or 16 bits (big endian,
/// as the format says) into its grey levels.
pub fn decode_pgm(bytes: &[u8]) -> Result<(usize, usize, Vec<u16>), String> {
    let (t, start) = header_tokens(bytes, 4)?;
    if t[0] != "P5" && t[0] != "P2" {
        return Err(format!("not a grey PGM file (starts with `{}`)", t[0]));
    }
    let (w, h) = dimensions(&t[1], &t[2])?;
    let maxval: u32 = t[3]
        .parse()
        .ok()
        .filter(|m| (1..=65535).contains(m))
        .ok_or_else(|| format!("bad maximum value `{}` in the header", t[3]))?;
    let data = &bytes[start.min(bytes.len())..];
    if t[0] == "P2" {
        let values: Vec<u16> = std::str::from_utf8(data)
            .map_err(|_| "text PGM with non-text data".to_string())?
            .split_ascii_whitespace()
            .map(|s| {
                s.parse::<u16>()
                    .map_err(|_| format!("bad grey level `{s}`"))
            })
            .collect::<Result<_, _>>()?;
        if values.len() != w * h {
            return Err(format!(
                "size mismatch: {} grey levels, {w} x {h} needs {}",
                values.len(),
                w * h
            ));
        }
        return Ok((w, h, values));
    }
    if maxval < 256 {
        check_data_len(data.len(), w * h, w, h)?;
        Ok((w, h, data.iter().map(|&v| v as u16).collect()))
    } else {
        check_data_len(data.len(), w * h * 2, w, h)?;
        Ok((
            w,
            h,
            data.chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]]))
                .collect(),
        ))
    }
}

/// Reads a disparity map: a PFM, a PGM or a PNG (8 or 16-bit grey), told
/// apart by their first bytes. Every value is divided by `scale`; in PGM and
/// PNG files a stored 0 means unknown (NaN) when `zero_is_unknown`; in PFM
/// files infinities mean unknown. Errors name the file.
pub fn read_disparity(path: &Path, scale: f64, zero_is_unknown: bool) -> Result<Disparity, String> {
    let named = |e: String| format!("{}: {e}", path.display());
    let bytes = std::fs::read(path).map_err(|e| named(e.to_string()))?;
    if !(scale.is_finite() && scale > 0.0) {
        return Err(named(format!("scale {scale} must be positive")));
    }
    let integers = |w: usize, h: usize, v: Vec<u16>| {
        let data: Vec<f32> = v
            .into_iter()
            .map(|x| {
                if x == 0 && zero_is_unknown {
                    f32::NAN
                } else {
                    (x as f64 / scale) as f32
                }
            })
            .collect();
        (w, h, data)
    };
    let (w, h, data) = if bytes.starts_with(b"Pf") || bytes.starts_with(b"PF") {
        let (w, h, mut d) = decode_pfm(&bytes).map_err(named)?;
        if scale != 1.0 {
            d.iter_mut().for_each(|v| *v = (*v as f64 / scale) as f32);
        }
        (w, h, d)
    } else if bytes.starts_with(b"P5") || bytes.starts_with(b"P2") {
        let (w, h, v) = decode_pgm(&bytes).map_err(named)?;
        integers(w, h, v)
    } else if bytes.starts_with(b"\x89PNG") {
        let img = image::load_from_memory(&bytes).map_err(|e| named(e.to_string()))?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        let v: Vec<u16> = match img {
            image::DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(u16::from).collect(),
            image::DynamicImage::ImageLuma16(b) => b.into_raw(),
            other => {
                return Err(named(format!(
                    "a disparity PNG is 8 or 16-bit grey, this one is {:?}",
                    other.color()
                )));
            }
        };
        integers(w, h, v)
    } else {
        return Err(named("not a PFM, PGM or PNG file".into()));
    };
    Disparity::new(w, h, data).map_err(|e| named(e.0))
}

/// Viridis (perceptually uniform, readable in grey and by colour-blind
/// readers) at `t` in 0..1, as 8-bit RGB; a degree-6 polynomial fit of the
/// matplotlib table, within about 3/255.
pub fn viridis(t: f64) -> [u8; 3] {
    const C: [[f64; 3]; 7] = [
        [0.277_727_327_2, 0.005_407_344_5, 0.334_099_805_3],
        [0.105_093_043_1, 1.404_613_529_9, 1.384_590_162_6],
        [-0.330_861_828_7, 0.214_847_559_5, 0.095_095_163_0],
        [-4.634_230_499_0, -5.799_100_973_4, -19.332_440_956_3],
        [6.228_269_936_3, 14.179_933_366_8, 56.690_552_600_7],
        [4.776_384_997_7, -13.745_145_377_7, -65.353_032_633_4],
        [-5.435_455_855_9, 4.645_852_612_2, 26.312_435_249_6],
    ];
    let t = t.clamp(0.0, 1.0);
    std::array::from_fn(|c| {
        let v = C.iter().rev().fold(0.0, |acc, k| acc * t + k[c]);
        (v * 255.0).round().clamp(0.0, 255.0) as u8
    })
}

/// The `lo`..`hi` percentiles of the finite values of `data` (nearest rank);
/// `None` when there is none.
pub fn finite_percentiles(data: &[f32], lo: f64, hi: f64) -> Option<(f64, f64)> {
    let mut v: Vec<f32> = data.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    // The two ranks a sort would put there, found by selection (linear, not
    // a sort of the whole map: each figure of a disparity map asks).
    let rank = |q: f64| ((q / 100.0) * (v.len() - 1) as f64).round() as usize;
    let (a, b) = (rank(lo), rank(hi));
    let (first, second) = (a.min(b), a.max(b));
    let (_, &mut low, rest) = v.select_nth_unstable_by(first, f32::total_cmp);
    let high = if second == first {
        low
    } else {
        *rest
            .select_nth_unstable_by(second - first - 1, f32::total_cmp)
            .1
    };
    let (at_a, at_b) = if a <= b { (low, high) } else { (high, low) };
    Some((at_a as f64, at_b as f64))
}

/// Width of the legend strip right of the map, px.
const LEGEND_W: usize = 110;
/// Smallest image height, so the legend is readable under small maps, px.
const MIN_H: usize = 220;

/// The colour-mapped map (viridis over `range_px`, values outside clamped,
/// unknown = black) with a legend right of it: a colour bar with tick labels
/// in px. Returns 8-bit RGB and its size (width + 110, at least 220 high).
pub fn disparity_png(
    d: &Disparity,
    range_px: (f64, f64),
) -> Result<(Vec<u8>, usize, usize), String> {
    let (lo, hi) = range_px;
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Err(format!("colour range {lo}..{hi} px is empty"));
    }
    let (w, h) = (d.width + LEGEND_W, d.height.max(MIN_H));
    let mut rgb = vec![255u8; w * h * 3];
    for y in 0..d.height {
        for x in 0..d.width {
            let v = d.data[y * d.width + x];
            let c = if v.is_finite() {
                viridis((v as f64 - lo) / (hi - lo))
            } else {
                [0, 0, 0]
            };
            rgb[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&c);
        }
    }
    // The bar: high values at the top.
    let (bx0, bx1, by0, by1) = (d.width + 12, d.width + 36, 14usize, h - 14);
    for y in by0..=by1 {
        let c = viridis((by1 - y) as f64 / (by1 - by0) as f64);
        for x in bx0..=bx1 {
            rgb[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&c);
        }
    }
    crate::plot::register_font();
    {
        use plotters::prelude::*;
        let root = BitMapBackend::with_buffer(&mut rgb, (w as u32, h as u32)).into_drawing_area();
        let ticks = 5;
        let step = (hi - lo) / ticks as f64;
        let decimals = if step >= 10.0 {
            0
        } else if step >= 1.0 {
            1
        } else {
            2
        };
        let style = ("sans-serif", 13).into_font().color(&BLACK);
        for k in 0..=ticks {
            let value = lo + step * k as f64;
            let y = by1 as i32 - ((by1 - by0) as f64 * k as f64 / ticks as f64).round() as i32;
            root.draw(&PathElement::new(
                vec![(bx1 as i32 + 1, y), (bx1 as i32 + 6, y)],
                BLACK,
            ))
            .map_err(|e| e.to_string())?;
            root.draw(&Text::new(
                format!("{value:.decimals$}"),
                (bx1 as i32 + 9, y - 7),
                style.clone(),
            ))
            .map_err(|e| e.to_string())?;
        }
        root.draw(&Text::new("px", (bx0 as i32, 0), style))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok((rgb, w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_the_sorted_finite_values_ranks() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let mut next = || rng.random::<u32>();
        for n in [1usize, 2, 3, 10, 101, 5000] {
            let data: Vec<f32> = (0..n)
                .map(|_| match next() % 9 {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => (next() % 7) as f32, // ties
                    _ => (next() % 100_000) as f32 / 37.0 - 900.0,
                })
                .collect();
            let mut sorted: Vec<f32> = data.iter().copied().filter(|x| x.is_finite()).collect();
            sorted.sort_by(f32::total_cmp);
            for (lo, hi) in [(1.0, 99.0), (0.0, 100.0), (50.0, 50.0), (90.0, 10.0)] {
                let expected = (!sorted.is_empty()).then(|| {
                    let at = |q: f64| {
                        sorted[((q / 100.0) * (sorted.len() - 1) as f64).round() as usize] as f64
                    };
                    (at(lo), at(hi))
                });
                assert_eq!(
                    finite_percentiles(&data, lo, hi),
                    expected,
                    "n {n}, {lo}..{hi}"
                );
            }
        }
        assert_eq!(
            finite_percentiles(&[f32::NAN, f32::NEG_INFINITY], 1.0, 99.0),
            None
        );
    }

    fn temp_file(dir: &tempfile::TempDir, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    #[test]
    fn pfm_round_trip_is_bit_exact_with_nan_as_inf() {
        let data = vec![
            1.5f32,
            -0.0,
            f32::NAN,
            63.75,
            1e-30,
            f32::MAX,
            -2.25,
            std::f32::consts::PI,
        ];
        let bytes = encode_pfm(4, 2, &data);
        assert!(bytes.starts_with(b"Pf\n4 2\n-1\n"));
        // The bottom row comes first: NaN (row 0, col 2) is the 7th value.
        let inf_at = 10 + 4 * 6;
        assert_eq!(&bytes[inf_at..inf_at + 4], &f32::INFINITY.to_le_bytes());
        let (w, h, back) = decode_pfm(&bytes).unwrap();
        assert_eq!((w, h), (4, 2));
        for (a, b) in data.iter().zip(&back) {
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "{a} {b}"
            );
        }
    }

    #[test]
    fn big_endian_pfm_by_hand() {
        let mut bytes = b"Pf\n2 2\n1.0\n".to_vec();
        // Bottom row (3, inf), then top row (1, 2).
        for v in [3.0f32, f32::INFINITY, 1.0, 2.0] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        let (w, h, d) = decode_pfm(&bytes).unwrap();
        assert_eq!((w, h), (2, 2));
        assert_eq!(&d[..3], &[1.0, 2.0, 3.0]);
        assert!(d[3].is_nan());
    }

    #[test]
    fn pgm_and_png_with_scale() {
        let t = tempfile::tempdir().unwrap();
        let mut pgm = b"P5\n# Middlebury\n3 2\n255\n".to_vec();
        pgm.extend_from_slice(&[0, 4, 8, 255, 12, 1]);
        let p = temp_file(&t, "disp2.pgm", &pgm);
        let d = read_disparity(&p, 4.0, true).unwrap();
        assert_eq!((d.width, d.height), (3, 2));
        assert!(d.data[0].is_nan());
        assert_eq!(&d.data[1..], &[1.0, 2.0, 63.75, 3.0, 0.25]);
        assert_eq!(read_disparity(&p, 4.0, false).unwrap().data[0], 0.0);
        // 16-bit PGM is big endian.
        let mut pgm16 = b"P5 2 1 65535\n".to_vec();
        pgm16.extend_from_slice(&[0x01, 0x00, 0xff, 0xff]);
        let d = read_disparity(&temp_file(&t, "d16.pgm", &pgm16), 256.0, true).unwrap();
        assert_eq!(&d.data[..], &[1.0, 65535.0 / 256.0]);
        // 16-bit PNG, KITTI style.
        let png = t.path().join("kitti.png");
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(2, 1, vec![0u16, 512])
            .unwrap()
            .save(&png)
            .unwrap();
        let d = read_disparity(&png, 256.0, true).unwrap();
        assert!(d.data[0].is_nan() && d.data[1] == 2.0);
    }

    #[test]
    fn bad_files_name_the_file() {
        let t = tempfile::tempdir().unwrap();
        let mut truncated = b"Pf\n3 2\n-1\n".to_vec();
        truncated.extend_from_slice(&[0u8; 20]);
        let p = temp_file(&t, "short.pfm", &truncated);
        let err = read_disparity(&p, 1.0, true).unwrap_err();
        assert!(
            err.contains("short.pfm") && err.contains("truncated"),
            "{err}"
        );
        let p = temp_file(&t, "colour.pfm", b"PF\n1 1\n-1\n\0\0\0\0\0\0\0\0\0\0\0\0");
        let err = read_disparity(&p, 1.0, true).unwrap_err();
        assert!(
            err.contains("colour.pfm") && err.contains("grey PFM"),
            "{err}"
        );
        let p = temp_file(&t, "header.pfm", b"Pf\n2 x\n-1\n");
        let err = read_disparity(&p, 1.0, true).unwrap_err();
        assert!(
            err.contains("header.pfm") && err.contains("bad size"),
            "{err}"
        );
        let p = temp_file(&t, "long.pgm", b"P5\n2 2\n255\n\x01\x02\x03\x04\x05");
        let err = read_disparity(&p, 1.0, true).unwrap_err();
        assert!(
            err.contains("long.pgm") && err.contains("size mismatch"),
            "{err}"
        );
        let p = temp_file(&t, "what.bin", b"GIF89a");
        let err = read_disparity(&p, 1.0, true).unwrap_err();
        assert!(
            err.contains("what.bin") && err.contains("not a PFM"),
            "{err}"
        );
        let err = read_disparity(&t.path().join("missing.pfm"), 1.0, true).unwrap_err();
        assert!(err.contains("missing.pfm"), "{err}");
    }

    #[test]
    fn viridis_ends_and_the_png_decodes_with_its_size() {
        // matplotlib's table: viridis(0) = (68, 1, 84), viridis(0.5) =
        // (33, 145, 140), viridis(1) = (253, 231, 37).
        for (t, want) in [
            (0.0, [68, 1, 84]),
            (0.5, [33, 145, 140]),
            (1.0, [253, 231, 37]),
        ] {
            let got = viridis(t);
            assert!(
                (0..3).all(|c| (got[c] as i32 - want[c]).abs() <= 4),
                "{t}: {got:?}"
            );
        }
        let d = Disparity::new(
            40,
            30,
            (0..1200)
                .map(|i| {
                    if i % 7 == 0 {
                        f32::NAN
                    } else {
                        (i % 40) as f32
                    }
                })
                .collect::<Vec<f32>>(),
        )
        .unwrap();
        let (lo, hi) = finite_percentiles(&d.data, 1.0, 99.0).unwrap();
        assert_eq!((lo, hi), (0.0, 39.0));
        let (rgb, w, h) = disparity_png(&d, (lo, hi)).unwrap();
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("d.png");
        image::save_buffer(
            &path,
            &rgb,
            w as u32,
            h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(back.dimensions(), (40 + 110, 220));
        assert_eq!(back.get_pixel(0, 0).0, [0, 0, 0], "NaN is black");
        assert_eq!(back.get_pixel(39, 1).0, viridis(1.0));
        assert_eq!(back.get_pixel(0, 25).0, viridis(0.0));
        // Tick labels drew dark text beside the bar.
        let dark = (40 + 40..150)
            .flat_map(|x| (0..220).map(move |y| (x, y)))
            .filter(|&(x, y)| back.get_pixel(x, y).0.iter().all(|&c| c < 100))
            .count();
        assert!(dark > 30, "{dark} dark legend pixels");
        assert!(disparity_png(&d, (3.0, 3.0)).is_err());
    }
}
