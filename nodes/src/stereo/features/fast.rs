//! FAST-9 corners (Rosten and Drummond 2006) ranked by the Harris measure, with
//! a 256-bit BRIEF descriptor on a Gaussian-smoothed image, steered by the
//! intensity-centroid orientation (ORB, Rublee et al. 2011). Patent-free.

use super::{Descriptors, Features, Keypoint, check_image, keep_spread_by};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::sync::OnceLock;

/// Settings of the FAST detector.
#[derive(Debug, Clone, PartialEq)]
pub struct FastParams {
    /// Segment-test threshold on grey levels 0..1: a corner has 9 contiguous
    /// circle pixels all brighter or all darker than the centre by this much.
    pub threshold: f32,
    /// Pyramid levels (1 = the image only; each further level halves the size).
    pub octaves: usize,
    /// No orientation (angle 0): right for rectified pairs, and faster.
    pub upright: bool,
    /// At most this many keypoints, strongest first, spread over the image.
    pub max_features: usize,
}

impl Default for FastParams {
    fn default() -> Self {
        FastParams {
            threshold: 0.04,
            octaves: 3,
            upright: true,
            max_features: 4000,
        }
    }
}

/// The 16 pixels of the Bresenham circle of radius 3, clockwise from the top.
const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Radius of the descriptor patch and of the orientation disc, px of the level.
const PATCH_RADIUS: i32 = 15;
/// Keypoints closer than this to a level's border are dropped (patch + rounding).
const BORDER: i32 = PATCH_RADIUS + 2;

/// One pyramid level: a grey image, its size and its Sobel gradients (zero on
/// the outermost pixels).
struct Level {
    grey: Vec<f32>,
    width: usize,
    height: usize,
    gx: Vec<f32>,
    gy: Vec<f32>,
}

impl Level {
    fn new(grey: Vec<f32>, width: usize, height: usize) -> Level {
        let mut gx = vec![0.0f32; width * height];
        let mut gy = vec![0.0f32; width * height];
        if width >= 3 && height >= 3 {
            gx.par_chunks_mut(width)
                .zip(gy.par_chunks_mut(width))
                .enumerate()
                .filter(|(y, _)| *y >= 1 && *y + 1 < height)
                .for_each(|(y, (rx, ry))| {
                    let p = |u: usize, v: usize| grey[v * width + u];
                    for u in 1..width - 1 {
                        rx[u] = (p(u + 1, y - 1) + 2.0 * p(u + 1, y) + p(u + 1, y + 1))
                            - (p(u - 1, y - 1) + 2.0 * p(u - 1, y) + p(u - 1, y + 1));
                        ry[u] = (p(u - 1, y + 1) + 2.0 * p(u, y + 1) + p(u + 1, y + 1))
                            - (p(u - 1, y - 1) + 2.0 * p(u, y - 1) + p(u + 1, y - 1));
                    }
                });
        }
        Level {
            grey,
            width,
            height,
            gx,
            gy,
        }
    }

    #[inline]
    fn at(&self, x: i32, y: i32) -> f32 {
        self.grey[y as usize * self.width + x as usize]
    }

    /// The next level: 2 x 2 averages.
    fn half(&self) -> Level {
        let (w, h) = (self.width / 2, self.height / 2);
        let grey = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (2 * (i % w), 2 * (i / w));
                let s = self.width;
                0.25 * (self.grey[y * s + x]
                    + self.grey[y * s + x + 1]
                    + self.grey[(y + 1) * s + x]
                    + self.grey[(y + 1) * s + x + 1])
            })
            .collect();
        Level::new(grey, w, h)
    }
}

/// Whether the 16-bit circular mask holds a run of 9 set bits.
#[inline]
fn has_run_of_9(mask: u32) -> bool {
    let m = mask | (mask << 16);
    let mut run = m;
    for k in 1..9 {
        run &= m >> k;
    }
    run != 0
}

/// FAST-9 segment test at (x, y); the caller keeps (x, y) 3 px inside.
fn is_corner(level: &Level, x: i32, y: i32, t: f32) -> bool {
    let p = level.at(x, y);
    let (hi, lo) = (p + t, p - t);
    // Nine contiguous pixels include at least two of the four compass points.
    let compass = [0usize, 4, 8, 12].map(|k| level.at(x + CIRCLE[k].0, y + CIRCLE[k].1));
    let brighter = compass.iter().filter(|&&v| v > hi).count();
    let darker = compass.iter().filter(|&&v| v < lo).count();
    if brighter < 2 && darker < 2 {
        return false;
    }
    let (mut b, mut d) = (0u32, 0u32);
    for (k, &(dx, dy)) in CIRCLE.iter().enumerate() {
        let v = level.at(x + dx, y + dy);
        if v > hi {
            b |= 1 << k;
        } else if v < lo {
            d |= 1 << k;
        }
    }
    has_run_of_9(b) || has_run_of_9(d)
}

/// Harris measure det(M) - 0.04 tr(M)^2 of Sobel gradients over the 7 x 7
/// window at (x, y), Gaussian-weighted (sigma 1.5 px: a flat window would put
/// the peak of a right-angle corner two pixels inside it); the caller keeps
/// (x, y) 4 px inside.
fn harris(level: &Level, x: i32, y: i32) -> f32 {
    static WEIGHTS: OnceLock<[f32; 49]> = OnceLock::new();
    let weights = WEIGHTS.get_or_init(|| {
        std::array::from_fn(|k| {
            let (du, dv) = ((k % 7) as f32 - 3.0, (k / 7) as f32 - 3.0);
            (-(du * du + dv * dv) / (2.0 * 1.5 * 1.5)).exp()
        })
    });
    let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
    for v in y - 3..=y + 3 {
        for u in x - 3..=x + 3 {
            let wt = weights[((v - y + 3) * 7 + (u - x + 3)) as usize];
            let k = v as usize * level.width + u as usize;
            let (gx, gy) = (level.gx[k], level.gy[k]);
            a += wt * gx * gx;
            b += wt * gx * gy;
            c += wt * gy * gy;
        }
    }
    a * c - b * b - 0.04 * (a + c) * (a + c)
}

/// Sub-pixel peak offset (each within -0.5..0.5) of the quadratic fitted to
/// the 3 x 3 Harris values around a local maximum at (x, y); zero when the fit
/// is not a maximum.
fn quadratic_peak(level: &Level, x: i32, y: i32, centre: f32) -> (f32, f32) {
    let v = |dx: i32, dy: i32| {
        if (dx, dy) == (0, 0) {
            centre
        } else {
            harris(level, x + dx, y + dy)
        }
    };
    let gx = 0.5 * (v(1, 0) - v(-1, 0));
    let gy = 0.5 * (v(0, 1) - v(0, -1));
    let hxx = v(1, 0) - 2.0 * centre + v(-1, 0);
    let hyy = v(0, 1) - 2.0 * centre + v(0, -1);
    let hxy = 0.25 * (v(1, 1) - v(-1, 1) - v(1, -1) + v(-1, -1));
    let det = hxx * hyy - hxy * hxy;
    if !(hxx < 0.0 && det > 0.0) {
        return (0.0, 0.0);
    }
    let ox = -(hyy * gx - hxy * gy) / det;
    let oy = -(hxx * gy - hxy * gx) / det;
    (ox.clamp(-0.5, 0.5), oy.clamp(-0.5, 0.5))
}

/// Corners of one level: FAST, Harris score, 3 x 3 non-maximum suppression
/// among corners, sub-pixel peak of the Harris measure. Returns level pixel,
/// offset and score.
fn level_corners(level: &Level, t: f32) -> Vec<(i32, i32, f32, f32, f32)> {
    let (w, h) = (level.width as i32, level.height as i32);
    if w <= 2 * BORDER || h <= 2 * BORDER {
        return Vec::new();
    }
    // Scores of corners (NEG_INFINITY elsewhere) on the rows that matter.
    let mut score = vec![f32::NEG_INFINITY; (w * h) as usize];
    score
        .par_chunks_mut(w as usize)
        .enumerate()
        .filter(|(y, _)| *y as i32 >= BORDER - 1 && (*y as i32) < h - BORDER + 1)
        .for_each(|(y, row)| {
            let y = y as i32;
            for x in BORDER - 1..w - BORDER + 1 {
                if is_corner(level, x, y, t) {
                    row[x as usize] = harris(level, x, y);
                }
            }
        });
    let at = |x: i32, y: i32| score[(y * w + x) as usize];
    (BORDER..h - BORDER)
        .into_par_iter()
        .flat_map_iter(|y| {
            let at = &at;
            (BORDER..w - BORDER).filter_map(move |x| {
                let s = at(x, y);
                if s == f32::NEG_INFINITY || s <= 0.0 {
                    return None;
                }
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        if (dx, dy) != (0, 0) && at(x + dx, y + dy) >= s {
                            return None;
                        }
                    }
                }
                let (ox, oy) = quadratic_peak(level, x, y, s);
                Some((x, y, ox, oy, s))
            })
        })
        .collect()
}

/// Separable Gaussian blur (sigma 2 px, radius 6 px), borders clamped.
fn smooth(level: &Level) -> Vec<f32> {
    let sigma = 2.0f32;
    let kernel: Vec<f32> = (-6..=6)
        .map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let (w, h) = (level.width, level.height);
    let mut tmp = vec![0.0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let mut s = 0.0;
            for (k, kv) in kernel.iter().enumerate() {
                let xx = (x as i64 + k as i64 - 6).clamp(0, w as i64 - 1) as usize;
                s += kv * level.grey[y * w + xx];
            }
            *out = s;
        }
    });
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut s = 0.0;
            for (k, kv) in kernel.iter().enumerate() {
                let yy = (y as i64 + k as i64 - 6).clamp(0, h as i64 - 1) as usize;
                s += kv * tmp[yy * w + x];
            }
            *o = s;
        }
    });
    out
}

/// The 256 point pairs of the binary test, fixed (a seeded isotropic Gaussian
/// of sigma 31/5 px, as in Calonder et al.'s BRIEF, kept inside the patch disc).
fn pattern() -> &'static [[(f32, f32); 2]; 256] {
    static PATTERN: OnceLock<[[(f32, f32); 2]; 256]> = OnceLock::new();
    PATTERN.get_or_init(|| {
        let mut rng = ChaCha8Rng::seed_from_u64(0x0b1e_f00d);
        let normal = rand_distr::Normal::new(0.0f32, 31.0 / 5.0).expect("valid sigma");
        let r2 = (PATCH_RADIUS * PATCH_RADIUS) as f32;
        let mut point = || loop {
            let (x, y) = (rng.sample(normal), rng.sample(normal));
            if x * x + y * y <= r2 {
                return (x, y);
            }
        };
        let mut pairs = [[(0.0, 0.0); 2]; 256];
        for p in pairs.iter_mut() {
            *p = [point(), point()];
        }
        pairs
    })
}

/// Orientation (rad) from the intensity centroid over the patch disc.
fn centroid_angle(level: &Level, x: i32, y: i32) -> f32 {
    let (mut m10, mut m01) = (0.0f32, 0.0f32);
    let r = PATCH_RADIUS;
    for v in -r..=r {
        for u in -r..=r {
            if u * u + v * v <= r * r {
                let i = level.at(x + u, y + v);
                m10 += u as f32 * i;
                m01 += v as f32 * i;
            }
        }
    }
    m01.atan2(m10)
}

/// The 256 tests `I(p) < I(q)` on the smoothed level, pattern turned by `angle`.
fn brief(smoothed: &[f32], width: usize, x: i32, y: i32, angle: f32) -> [u64; 4] {
    let (sin, cos) = angle.sin_cos();
    let at = |(px, py): (f32, f32)| {
        let u = (px * cos - py * sin).round() as i32;
        let v = (px * sin + py * cos).round() as i32;
        smoothed[(y + v) as usize * width + (x + u) as usize]
    };
    let mut bits = [0u64; 4];
    for (i, [p, q]) in pattern().iter().enumerate() {
        if at(*p) < at(*q) {
            bits[i / 64] |= 1 << (i % 64);
        }
    }
    bits
}

/// FAST keypoints with BRIEF descriptors of a grey image (0..1, row-major,
/// `width * height`); positions in px of that image. Keypoints of pyramid level
/// `l` have `size_px = 31 * 2^l`.
pub fn detect_fast(
    grey: &[f32],
    width: usize,
    height: usize,
    params: &FastParams,
) -> Result<Features, String> {
    check_image(grey, width, height)?;
    if params.octaves == 0 || params.octaves > 6 {
        return Err(format!("octaves {} must be 1..6", params.octaves));
    }
    if !(params.threshold.is_finite() && params.threshold > 0.0) {
        return Err(format!("fast threshold {} must be > 0", params.threshold));
    }
    let mut levels = vec![Level::new(grey.to_vec(), width, height)];
    while levels.len() < params.octaves {
        let next = levels[levels.len() - 1].half();
        if next.width <= 2 * BORDER as usize || next.height <= 2 * BORDER as usize {
            break;
        }
        levels.push(next);
    }
    // (keypoint, level, integer level pixel)
    let mut candidates: Vec<(Keypoint, usize, i32, i32)> = Vec::new();
    for (l, level) in levels.iter().enumerate() {
        let scale = (1usize << l) as f32;
        for (x, y, ox, oy, s) in level_corners(level, params.threshold) {
            // Level pixel centre x maps to (x + 0.5) * scale - 0.5 in the image.
            let kp = Keypoint {
                x_px: (x as f32 + ox + 0.5) * scale - 0.5,
                y_px: (y as f32 + oy + 0.5) * scale - 0.5,
                size_px: 31.0 * scale,
                angle_rad: 0.0,
                response: s,
                laplacian_positive: false,
            };
            candidates.push((kp, l, x, y));
        }
    }
    let kept = keep_spread_by(candidates, |c| &c.0, width, height, params.max_features);
    let smoothed: Vec<Vec<f32>> = levels.iter().map(smooth).collect();
    let (keypoints, descriptors): (Vec<Keypoint>, Vec<[u64; 4]>) = kept
        .into_par_iter()
        .map(|(mut kp, l, x, y)| {
            if !params.upright {
                kp.angle_rad = centroid_angle(&levels[l], x, y);
            }
            let d = brief(&smoothed[l], levels[l].width, x, y, kp.angle_rad);
            (kp, d)
        })
        .unzip();
    Ok(Features {
        keypoints,
        descriptors: Descriptors::Binary(descriptors),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_circle_has_radius_3() {
        for &(dx, dy) in &CIRCLE {
            let r = ((dx * dx + dy * dy) as f32).sqrt();
            assert!((2.8..=3.2).contains(&r), "({dx}, {dy})");
        }
        // Neighbours on the circle are adjacent pixels.
        for k in 0..16 {
            let (a, b) = (CIRCLE[k], CIRCLE[(k + 1) % 16]);
            assert!((a.0 - b.0).abs() <= 1 && (a.1 - b.1).abs() <= 1);
        }
    }

    #[test]
    fn runs_of_nine_wrap_around() {
        assert!(has_run_of_9(0b1_1111_1111));
        assert!(!has_run_of_9(0b1111_1111));
        // Bits 12..15 and 0..4: nine across the wrap.
        assert!(has_run_of_9(0xF01F));
        assert!(!has_run_of_9(0xF00F));
    }

    #[test]
    fn finds_the_corner_of_a_square() {
        // A bright square [30, 60) x [25, 55) on dark: corners at the four
        // pixel corners, i.e. between pixels: (29.5, 24.5) etc. FAST fires on
        // the pixel inside; Harris peaks at the corner to within a pixel.
        let (w, h) = (90usize, 80usize);
        let img: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if (30..60).contains(&x) && (25..55).contains(&y) {
                    0.8
                } else {
                    0.2
                }
            })
            .collect();
        let p = FastParams {
            octaves: 1,
            ..FastParams::default()
        };
        let f = detect_fast(&img, w, h, &p).unwrap();
        for (cx, cy) in [(29.5, 24.5), (59.5, 24.5), (29.5, 54.5), (59.5, 54.5)] {
            assert!(
                f.keypoints
                    .iter()
                    .any(|k| (k.x_px - cx).abs() <= 1.0 && (k.y_px - cy).abs() <= 1.0),
                "no keypoint near ({cx}, {cy}): {:?}",
                f.keypoints
            );
        }
        // No keypoint on the straight edges or in the flat parts.
        for k in &f.keypoints {
            let near_corner = [29.5, 59.5].iter().any(|c| (k.x_px - c).abs() <= 2.0)
                && [24.5, 54.5].iter().any(|c| (k.y_px - c).abs() <= 2.0);
            assert!(near_corner, "spurious keypoint {k:?}");
        }
    }

    #[test]
    fn centroid_angle_points_to_the_bright_side() {
        // Brightness rising to the lower right: centroid angle 45 degrees.
        let (w, h) = (40usize, 40usize);
        let img: Vec<f32> = (0..w * h)
            .map(|i| 0.01 * ((i % w) + (i / w)) as f32)
            .collect();
        let level = Level::new(img, w, h);
        let a = centroid_angle(&level, 20, 20);
        assert!((a - std::f32::consts::FRAC_PI_4).abs() < 1e-3, "{a}");
    }

    #[test]
    fn bad_parameters_are_errors() {
        let img = vec![0.5f32; 64 * 64];
        let p = FastParams {
            threshold: 0.0,
            ..FastParams::default()
        };
        assert!(detect_fast(&img, 64, 64, &p).is_err());
        let p = FastParams {
            octaves: 0,
            ..FastParams::default()
        };
        assert!(detect_fast(&img, 64, 64, &p).is_err());
        let flat = detect_fast(&img, 64, 64, &FastParams::default()).unwrap();
        assert!(flat.keypoints.is_empty());
    }
}
