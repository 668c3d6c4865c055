//! Semi-global matching from a grey pair to a disparity map: costs, path
//! aggregation, selection, speckle removal.

use super::cost::{CensusCosts, bt_costs, check_census_window};
use super::filter::filter_speckles;
use super::pair::{DisparityRange, GreyImage, check_pair};
use super::refine::{RefineParams, refine_disparity};
use super::select::SelectParams;
use super::sgm::{SgmParams, aggregate_and_select};
use super::texture::{
    census_prefilter_sigma_px, flat_windows, noise_sigma, pair_noise_dn, smoothed,
};

/// The pixel matching cost semi-global matching aggregates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatchCost {
    /// Census transform over a `width x height` window (odd sides, area <= 65),
    /// Hamming distance; costs 0 ..= area - 1.
    Census {
        /// Window width, px.
        width: usize,
        /// Window height, px.
        height: usize,
    },
    /// Birchfield-Tomasi grey-level difference averaged over a square window;
    /// costs 0 ..= 255.
    BirchfieldTomasi {
        /// Window side, px (odd).
        window: usize,
    },
}

/// Everything semi-global matching needs besides the images and the range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgmConfig {
    /// Matching cost.
    pub cost: MatchCost,
    /// Penalties and paths.
    pub sgm: SgmParams,
    /// Winner selection.
    pub select: SelectParams,
    /// Largest speckle removed, as a share of the image area, % (0 = none):
    /// speckles scale with the resolution, so a pixel count would not carry
    /// from one camera to another.
    pub speckle_area_pct: f64,
    /// Largest disparity step inside one speckle region, px.
    pub speckle_range_px: f32,
    /// Refuse to run when the cost volumes would need more memory than this, MB.
    pub max_memory_mb: usize,
    /// Sub-pixel refinement on the intensities after selection (`None` keeps
    /// the cost parabola's sub-pixel values).
    pub refine: Option<RefineParams>,
    /// Invalidate pixels whose census window's grey-level spread is below this
    /// multiple of the image's own noise level (no texture to match; 0 = off).
    pub min_texture_snr: f64,
    /// Census costs on a noisy pair: measure its noise from the first
    /// matches ([`pair_noise_dn`]) and, where it calls for smoothing
    /// ([`census_prefilter_sigma_px`]), match again on the smoothed pair.
    pub denoise: bool,
}

impl Default for SgmConfig {
    /// The defaults of `stereo.sgm`: census 9 x 7 (costs 0..62 bits), 5 paths
    /// in one pass (as accurate as 8 on Middlebury's pairs, 0.5 points more
    /// bad-1 on the phantom, in 55-70 % of the time),
    /// P1 = 8 and P2 = 80 bits (P2 about a wrong match's cost, so a jump needs
    /// evidence from several pixels) falling at intensity edges (gamma 8 grey
    /// levels), OpenCV's uniqueness (10 %), left-right (1 px) and speckle
    /// (2 px) settings with speckles up to 0.08 % of the image (OpenCV's
    /// usual 100-400 px at 640 x 480 to 800 x 600), and intensity refinement
    /// over 9 x 9 windows. The texture test is off: the noise estimate counts
    /// fine texture as noise, and at twice it the test removed a third of the
    /// correct pixels of Middlebury's cones, where propagation matches
    /// low-texture surfaces well.
    fn default() -> Self {
        SgmConfig {
            cost: MatchCost::Census {
                width: 9,
                height: 7,
            },
            sgm: SgmParams {
                p1: 8,
                p2: 80,
                paths: super::sgm::Paths::Five,
                p2_gamma: 8.0,
            },
            select: SelectParams {
                uniqueness_pct: 10.0,
                lr_max_diff_px: Some(1.0),
                subpixel: true,
            },
            speckle_area_pct: 0.08,
            speckle_range_px: 2.0,
            max_memory_mb: 4096,
            refine: Some(RefineParams {
                half_window: 4,
                iterations: 2,
                max_change_px: 1.0,
            }),
            min_texture_snr: 0.0,
            denoise: true,
        }
    }
}

/// The largest speckle, px, for `area_pct` % of a `w x h` image (at least one
/// pixel when not 0).
pub fn speckle_size_px(area_pct: f64, w: usize, h: usize) -> usize {
    if area_pct <= 0.0 {
        return 0;
    }
    ((area_pct / 100.0 * (w * h) as f64).round() as usize).max(1)
}

/// Bytes `config` holds for `cells` (pixels x disparities) at its peak: a
/// Birchfield-Tomasi volume with its window sums (4 bytes a cell; census
/// costs are computed row by row), and for two passes the 16-bit sums the
/// first pass hands over for half the rows (1 byte a cell).
fn memory_bytes(config: &SgmConfig, cells: usize) -> usize {
    let costs = match config.cost {
        MatchCost::Census { .. } => 0,
        MatchCost::BirchfieldTomasi { .. } => 4,
    };
    let sums = match config.sgm.paths {
        super::sgm::Paths::Five => 0,
        _ => 1,
    };
    cells * (costs + sums)
}

/// The Birchfield-Tomasi cost's averaging window, px: odd and at most 31.
pub fn check_bt_window(window: usize) -> Result<(), String> {
    if window.is_multiple_of(2) || window > 31 {
        return Err(format!(
            "Birchfield-Tomasi window {window} px: must be odd and at most 31"
        ));
    }
    Ok(())
}

/// Disparities (px, NaN = invalid) of the left image of a rectified pair.
///
/// # Examples
///
/// A random texture that the right image sees 6 px further left: the
/// disparity is 6 px (to half a pixel; pixel noise leaves no better
/// sub-pixel fit) wherever the match is valid.
///
/// ```
/// use fusegraph_nodes::stereo::{DisparityRange, GreyImage, SgmConfig, sgm_disparity};
///
/// let (w, h) = (64, 32);
/// // Grey levels hashed from the position (splitmix64): nothing repeats.
/// let texture = |x: usize, y: usize| {
///     let mut z = ((y * 1000 + x) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
///     z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
///     z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
///     ((z ^ (z >> 31)) >> 56) as u8
/// };
/// let image = |shift: usize| GreyImage {
///     width: w,
///     height: h,
///     data: (0..w * h).map(|i| texture(i % w + shift, i / w)).collect(),
/// };
/// let (left, right) = (image(0), image(6));
/// let range = DisparityRange::new(0, 15, w).unwrap();
/// let d = sgm_disparity(&left, &right, range, &SgmConfig::default()).unwrap();
/// let valid: Vec<f32> = d.into_iter().filter(|d| !d.is_nan()).collect();
/// assert!(valid.len() > w * h / 2, "{} valid", valid.len());
/// let six = valid.iter().filter(|d| (*d - 6.0).abs() < 0.5).count();
/// assert!(six * 100 >= valid.len() * 98, "{six} of {}", valid.len());
/// ```
pub fn sgm_disparity(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
    config: &SgmConfig,
) -> Result<Vec<f32>, String> {
    check_pair(left, right)?;
    config.sgm.check()?;
    let (w, h) = (left.width, left.height);
    let mb = memory_bytes(config, w * h * range.count) >> 20;
    if mb > config.max_memory_mb {
        return Err(format!(
            "{w} x {h} px with {} disparities needs about {mb} MB for its costs and sums, more \
             than max_memory_mb = {}: narrow the disparity range or raise the limit",
            range.count, config.max_memory_mb
        ));
    }
    let t0 = std::time::Instant::now();
    // Census costs are computed row by row as the aggregation needs them (a
    // noisy pair is matched twice, the second time smoothed);
    // Birchfield-Tomasi's window means need the whole volume first.
    let (mut disparity, t1) = match config.cost {
        MatchCost::Census { width, height } => {
            check_census_window(width, height)?;
            let census = |l: &GreyImage, r: &GreyImage| {
                let costs = CensusCosts::new(l, r, range, width, height);
                aggregate_and_select(&costs, &config.sgm, Some(l), &config.select)
            };
            let d = census(left, right);
            let sigma = config
                .denoise
                .then(|| pair_noise_dn(left, right, &d))
                .flatten()
                .map_or(0.0, census_prefilter_sigma_px);
            let d = if sigma > 0.0 {
                let (l, r) = rayon::join(|| smoothed(left, sigma), || smoothed(right, sigma));
                tracing::debug!("sgm: a noisy pair, matched again smoothed by {sigma:.2} px");
                census(&l, &r)
            } else {
                d
            };
            // The census costs are computed inside the aggregation.
            (d, t0)
        }
        MatchCost::BirchfieldTomasi { window } => {
            check_bt_window(window)?;
            let costs = bt_costs(left, right, range, window);
            let t1 = std::time::Instant::now();
            let d = aggregate_and_select(&costs, &config.sgm, Some(left), &config.select);
            (d, t1)
        }
    };
    let t2 = std::time::Instant::now();
    if config.min_texture_snr > 0.0 {
        let (ww, wh) = match config.cost {
            MatchCost::Census { width, height } => (width, height),
            MatchCost::BirchfieldTomasi { window } => (window, window),
        };
        let flat = flat_windows(left, ww, wh, config.min_texture_snr * noise_sigma(left));
        for (d, f) in disparity.iter_mut().zip(flat) {
            if f {
                *d = f32::NAN;
            }
        }
    }
    let t3 = std::time::Instant::now();
    let speckles = |d: &mut Vec<f32>| {
        let t = std::time::Instant::now();
        let max_size = speckle_size_px(config.speckle_area_pct, w, h);
        filter_speckles(d, w, h, max_size, config.speckle_range_px);
        t.elapsed()
    };
    let speckle_time = match &config.refine {
        // Refinement moves each pixel by its own window alone, and speckle
        // removal only turns pixels invalid: the two can run side by side
        // (the serial flood fill beside the parallel refinement) and give
        // what one after the other gives.
        Some(refine) => {
            let mut refined = disparity.clone();
            let (time, _) = rayon::join(
                || speckles(&mut disparity),
                || refine_disparity(left, right, &mut refined, refine),
            );
            for (d, r) in disparity.iter_mut().zip(refined) {
                if !d.is_nan() {
                    *d = r;
                }
            }
            time
        }
        None => speckles(&mut disparity),
    };
    let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64() * 1e3;
    tracing::debug!(
        "sgm {w} x {h} x {}: costs {:.1} ms, aggregation and selection {:.1} ms, filters {:.1} ms, speckles and refinement {:.1} ms (speckles alone {:.1} ms)",
        range.count,
        ms(t0, t1),
        ms(t1, t2),
        ms(t2, t3),
        t3.elapsed().as_secs_f64() * 1e3,
        speckle_time.as_secs_f64() * 1e3
    );
    Ok(disparity)
}

#[cfg(test)]
mod tests {
    use super::super::sgm::Paths;
    use super::*;

    /// A random-dot pair: the left image is the right one shifted by a known
    /// disparity per region (a background plane and a raised square).
    fn random_dot_pair(w: usize, h: usize) -> (GreyImage, GreyImage, Vec<f32>) {
        let mut s = 12345u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 56) as u8
        };
        // Dots of 1 px on a wide canvas.
        let cw = w + 64;
        let canvas: Vec<u8> = (0..cw * h).map(|_| next()).collect();
        let truth: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if (w / 3..2 * w / 3).contains(&x) && (h / 3..2 * h / 3).contains(&y) {
                    20.0
                } else {
                    8.0
                }
            })
            .collect();
        // right(x) = canvas(x); left(x) = right(x - d).
        let right = GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| canvas[(i / w) * cw + i % w + 32])
                .collect(),
        };
        let left = GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| {
                    let (x, y) = (i % w, i / w);
                    canvas[y * cw + x + 32 - truth[i] as usize]
                })
                .collect(),
        };
        (left, right, truth)
    }

    fn config(cost: MatchCost, paths: Paths, subpixel: bool) -> SgmConfig {
        SgmConfig {
            cost,
            sgm: SgmParams {
                p1: 8,
                p2: 100,
                paths,
                p2_gamma: 0.0,
            },
            select: SelectParams {
                uniqueness_pct: 5.0,
                lr_max_diff_px: Some(1.0),
                subpixel,
            },
            speckle_area_pct: 0.35,
            speckle_range_px: 1.0,
            max_memory_mb: 1024,
            refine: None,
            min_texture_snr: 0.0,
            denoise: true,
        }
    }

    /// A fronto-parallel plane at `disparity` px with a weak smooth random
    /// texture (features of about 4 px, 40 grey levels peak to peak) and
    /// white noise of `noise` grey levels on each image.
    fn noisy_plane(w: usize, h: usize, disparity: usize, noise: f64) -> (GreyImage, GreyImage) {
        let mut s = 99u64;
        let mut uniform = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let (gw, gh) = ((w + disparity) / 4 + 2, h / 4 + 2);
        let grid: Vec<f64> = (0..gw * gh).map(|_| 108.0 + 40.0 * uniform()).collect();
        let texture = |x: usize, y: usize| {
            let (gx, gy) = (x as f64 / 4.0, y as f64 / 4.0);
            let (i, j) = (gx as usize, gy as usize);
            let (tx, ty) = (gx - i as f64, gy - j as f64);
            let g = |i: usize, j: usize| grid[i + j * gw];
            (g(i, j) * (1.0 - tx) + g(i + 1, j) * tx) * (1.0 - ty)
                + (g(i, j + 1) * (1.0 - tx) + g(i + 1, j + 1) * tx) * ty
        };
        let mut image = |shift: usize| GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| {
                    let n = (0..12).map(|_| uniform()).sum::<f64>() - 6.0;
                    (texture(i % w + shift, i / w) + noise * n)
                        .round()
                        .clamp(0.0, 255.0) as u8
                })
                .collect(),
        };
        // left(x) = right(x - d): the right image sees the texture d px on.
        let right = image(disparity);
        let left = image(0);
        (left, right)
    }

    #[test]
    fn a_noisy_pair_is_matched_again_smoothed() {
        let (w, h, d) = (160, 120, 12);
        let (left, right) = noisy_plane(w, h, d, 12.0);
        let range = DisparityRange::new(0, 31, w).unwrap();
        let census = MatchCost::Census {
            width: 9,
            height: 7,
        };
        let run = |denoise: bool| {
            let c = SgmConfig {
                denoise,
                ..config(census, Paths::Five, true)
            };
            let disparity = sgm_disparity(&left, &right, range, &c).unwrap();
            let valid: Vec<f32> = disparity[..]
                .chunks(w)
                .flat_map(|row| row[40..w - 8].to_vec())
                .filter(|v| v.is_finite())
                .collect();
            let right_px = valid
                .iter()
                .filter(|v| (**v - d as f32).abs() < 1.0)
                .count();
            (valid.len(), right_px)
        };
        let (raw, raw_right) = run(false);
        let (smooth, smooth_right) = run(true);
        let area = h * (w - 48);
        assert!(
            smooth as f64 > 0.95 * area as f64 && smooth as f64 > 1.3 * raw as f64,
            "{raw} -> {smooth} of {area} px"
        );
        assert!(
            smooth_right as f64 > 0.8 * smooth as f64
                && smooth_right as f64 > 1.5 * raw_right as f64,
            "right within 1 px: {raw_right} of {raw} -> {smooth_right} of {smooth}"
        );
    }

    #[test]
    fn exact_on_a_random_dot_pair() {
        let census = MatchCost::Census {
            width: 9,
            height: 7,
        };
        // 300 rows: the one-pass paths run in two stripes.
        for (w, h, cost, paths) in [
            (96, 64, census, Paths::Five),
            (96, 300, census, Paths::Five),
        ] {
            assert_exact_on_random_dots(w, h, cost, paths);
        }
        for (cost, paths) in [
            (
                MatchCost::Census {
                    width: 9,
                    height: 7,
                },
                Paths::Eight,
            ),
            (
                MatchCost::Census {
                    width: 5,
                    height: 5,
                },
                Paths::Four,
            ),
            (MatchCost::BirchfieldTomasi { window: 3 }, Paths::Eight),
        ] {
            assert_exact_on_random_dots(96, 64, cost, paths);
        }
    }

    fn assert_exact_on_random_dots(w: usize, h: usize, cost: MatchCost, paths: Paths) {
        let (left, right, truth) = random_dot_pair(w, h);
        let range = DisparityRange::new(0, 31, w).unwrap();
        {
            let d = sgm_disparity(&left, &right, range, &config(cost, paths, false)).unwrap();
            // Every pixel that the right image also sees, away from the
            // occluded band beside the square and with its matching window
            // inside the image, has the exact (integer) disparity.
            let (mut checked, mut exact) = (0, 0);
            for y in 0..h {
                for x in 24..w - 4 {
                    let near_edge = (w / 3).abs_diff(x) < 14 || (2 * w / 3).abs_diff(x) < 4;
                    if near_edge || (h / 3).abs_diff(y) < 4 || (2 * h / 3).abs_diff(y) < 4 {
                        continue;
                    }
                    checked += 1;
                    if (d[y * w + x] - truth[y * w + x]).abs() < 0.25 {
                        exact += 1;
                    }
                }
            }
            assert!(checked > 1900, "{checked} pixels checked");
            assert_eq!(exact, checked, "{cost:?} {paths:?}");
        }
    }

    #[test]
    fn same_bits_on_any_number_of_threads() {
        // Tall enough for the default paths to run in stripes.
        let (w, h) = (96, 300);
        let (left, right, _) = random_dot_pair(w, h);
        let range = DisparityRange::new(0, 31, w).unwrap();
        let config = SgmConfig::default();
        let run = |threads: usize| {
            let d = crate::on_threads(threads, || {
                sgm_disparity(&left, &right, range, &config).unwrap()
            });
            d.iter().map(|v| v.to_bits()).collect::<Vec<u32>>()
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn refuses_bad_input() {
        let (left, right, _) = random_dot_pair(40, 20);
        let range = DisparityRange::new(0, 15, 40).unwrap();
        let small = GreyImage {
            width: 30,
            height: 20,
            data: vec![0; 600],
        };
        let cfg = config(
            MatchCost::Census {
                width: 9,
                height: 7,
            },
            Paths::Eight,
            true,
        );
        assert!(
            sgm_disparity(&left, &small, range, &cfg)
                .unwrap_err()
                .contains("differ in size")
        );
        let bad_window = config(
            MatchCost::Census {
                width: 8,
                height: 9,
            },
            Paths::Eight,
            true,
        );
        assert!(
            sgm_disparity(&left, &right, range, &bad_window)
                .unwrap_err()
                .contains("census window")
        );
        let mut tiny_memory = cfg;
        tiny_memory.max_memory_mb = 0;
        let grey = GreyImage {
            width: 400,
            height: 400,
            data: vec![0; 160_000],
        };
        let wide = DisparityRange::new(0, 300, 400).unwrap();
        let e = sgm_disparity(&grey, &grey, wide, &tiny_memory).unwrap_err();
        assert!(e.contains("max_memory_mb"), "{e}");
    }
}
