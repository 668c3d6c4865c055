//! Features, matching and disparity range on the real Middlebury 2003 pairs
//! (`tests/data/stereo/{cones,teddy}`: im2 left, im6 right, disp2 = 4 x the
//! left disparity, 0 unknown), measured against their ground truth. Nothing
//! here is tuned to these images; the asserts are sanity floors.

use super::{
    FastParams, Features, HessianParams, MatchParams, RangeParams, detect_fast, detect_hessian,
    disparity_range, match_features,
};
use crate::io::{grey_of, load_image};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn data_dir(scene: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/stereo")
        .join(scene)
}

/// A binary PGM (P5, 8-bit): width, height, samples.
fn read_pgm(path: &Path) -> Result<(usize, usize, Vec<u8>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut fields = Vec::new();
    let mut i = 0;
    while fields.len() < 4 {
        while i < bytes.len() && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if bytes.get(i) == Some(&b'#') {
            while i < bytes.len() && bytes[i] != b'\n' {
                i += 1;
            }
            continue;
        }
        let start = i;
        while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if start == i {
            return Err(format!("{}: truncated header", path.display()));
        }
        fields.push(String::from_utf8_lossy(&bytes[start..i]).to_string());
    }
    let parse = |s: &str| {
        s.parse::<usize>()
            .map_err(|e| format!("{}: {e}", path.display()))
    };
    if fields[0] != "P5" || parse(&fields[3])? != 255 {
        return Err(format!("{}: not an 8-bit binary PGM", path.display()));
    }
    let (w, h) = (parse(&fields[1])?, parse(&fields[2])?);
    let data = bytes.get(i + 1..i + 1 + w * h).ok_or("short PGM")?.to_vec();
    Ok((w, h, data))
}

struct Figures {
    features: (usize, usize),
    matches: usize,
    within_1px: f32,
    beyond_5px: f32,
    range: (i32, i32),
    coverage: f32,
    truth_range: (f32, f32),
    ms_per_image: f64,
}

fn evaluate(scene: &str, detector: &str) -> Option<Figures> {
    let dir = data_dir(scene);
    if !dir.join("im2.png").exists() {
        eprintln!("skipped: no Middlebury pair at {}", dir.display());
        return None;
    }
    let left = load_image(&dir.join("im2.png")).unwrap();
    let right = load_image(&dir.join("im6.png")).unwrap();
    let (tw, th, truth) = read_pgm(&dir.join("disp2.pgm")).unwrap();
    assert_eq!((tw, th), (left.width, left.height));
    let (w, h) = (left.width, left.height);
    let detect = |g: &[f32]| -> Features {
        match detector {
            "fast" => detect_fast(g, w, h, &FastParams::default()).unwrap(),
            _ => detect_hessian(g, w, h, &HessianParams::default()).unwrap(),
        }
    };
    let (gl, gr) = (grey_of(&left), grey_of(&right));
    let t0 = Instant::now();
    let fl = detect(&gl);
    let fr = detect(&gr);
    let ms_per_image = t0.elapsed().as_secs_f64() * 500.0;
    let m = match_features(&fl, &fr, &MatchParams::default()).unwrap();
    let truth_at = |x: f32, y: f32| -> Option<f32> {
        let (xi, yi) = (x.round() as usize, y.round() as usize);
        let v = *truth.get(yi * w + xi)?;
        (v > 0 && xi < w && yi < h).then_some(v as f32 / 4.0)
    };
    let judged: Vec<f32> = m
        .iter()
        .filter_map(|m| truth_at(m.x_left_px, m.y_left_px).map(|t| (m.disparity_px - t).abs()))
        .collect();
    let frac = |t: f32| judged.iter().filter(|&&e| e <= t).count() as f32 / judged.len() as f32;
    let (within_1px, beyond_5px) = (frac(1.0), 1.0 - frac(5.0));
    let d: Vec<f32> = m.iter().map(|m| m.disparity_px).collect();
    let range = disparity_range(&d, &RangeParams::default()).unwrap();
    let known: Vec<f32> = truth
        .iter()
        .filter(|&&v| v > 0)
        .map(|&v| v as f32 / 4.0)
        .collect();
    let covered = known
        .iter()
        .filter(|&&t| t >= range.0 as f32 && t <= range.1 as f32)
        .count();
    let lo = known.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = known.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    Some(Figures {
        features: (fl.keypoints.len(), fr.keypoints.len()),
        matches: m.len(),
        within_1px,
        beyond_5px,
        range,
        coverage: covered as f32 / known.len() as f32,
        truth_range: (lo, hi),
        ms_per_image,
    })
}

#[test]
fn middlebury_matches_and_ranges() {
    for scene in ["cones", "teddy"] {
        for detector in ["hessian", "fast"] {
            let Some(f) = evaluate(scene, detector) else {
                return;
            };
            eprintln!(
                "{scene} {detector}: features {:?}, {} matches, {:.1} % within 1 px, {:.1} % off by > 5 px, \
                 range [{}, {}] covers {:.2} % of true disparities ({} .. {}), {:.1} ms/image",
                f.features,
                f.matches,
                100.0 * f.within_1px,
                100.0 * f.beyond_5px,
                f.range.0,
                f.range.1,
                100.0 * f.coverage,
                f.truth_range.0,
                f.truth_range.1,
                f.ms_per_image
            );
            assert!(
                f.matches >= 300,
                "{scene} {detector}: {} matches",
                f.matches
            );
            assert!(
                f.within_1px >= 0.6,
                "{scene} {detector}: {:.2}",
                f.within_1px
            );
            assert!(f.coverage >= 0.99, "{scene} {detector}: {:.3}", f.coverage);
            // No wider than the true span plus the documented margins.
            let true_span = f.truth_range.1 - f.truth_range.0;
            let width = (f.range.1 - f.range.0) as f32;
            assert!(
                width <= 1.2 * true_span + 2.0 * 8.0 + 2.0,
                "{scene} {detector}: {width} px wide"
            );
        }
    }
}

/// Time per 800 x 600 image (run with `--release --ignored`).
#[test]
#[ignore]
fn time_per_800_by_600_image() {
    use super::test_images::BlobTexture;
    let (w, h) = (800usize, 600usize);
    let tex = BlobTexture::new(-20.0, -20.0, 820.0, 620.0, 3);
    let img = tex.render(w, h, |x, y| (x, y));
    for detector in ["hessian", "fast"] {
        let run = || match detector {
            "fast" => detect_fast(&img, w, h, &FastParams::default()).unwrap(),
            _ => detect_hessian(&img, w, h, &HessianParams::default()).unwrap(),
        };
        run();
        let t0 = Instant::now();
        let n = 10;
        let mut count = 0;
        for _ in 0..n {
            count = run().keypoints.len();
        }
        let ms = t0.elapsed().as_secs_f64() * 1000.0 / n as f64;
        eprintln!("{detector}: {count} features, {ms:.1} ms per 800 x 600 image");
    }
}
