//! Coloured markers in a rectified stereo pair: HSV thresholds, morphological
//! opening and closing, blobs filtered by area and ellipse shape, sub-pixel
//! centroids, pairing along epipolar rows, triangulation.
//!
//! Pixel coordinates are in the rectified images (px, integer values at pixel
//! centres); 3D points are in mm in the original left camera frame.

use super::blobs::{MomentEllipse, components, ellipse_fit, open_close, soft_centroid};
use crate::calib::StereoRectification;
use crate::camera::CameraModel;
use crate::stereo::point_from_disparity;
use nalgebra::{Point2, Point3};

/// Hue (deg, 0..360), saturation (0..1) and value (0..1) of an RGB colour
/// with channels in 0..1 (hexcone model; hue 0 for greys).
pub fn hsv(r: f64, g: f64, b: f64) -> (f64, f64, f64) {
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let c = max - min;
    let s = if max > 0.0 { c / max } else { 0.0 };
    let h = if c <= 0.0 {
        0.0
    } else if max == r {
        60.0 * ((g - b) / c).rem_euclid(6.0)
    } else if max == g {
        60.0 * ((b - r) / c + 2.0)
    } else {
        60.0 * ((r - g) / c + 4.0)
    };
    (h, s, max)
}

/// What a marker looks like in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct BlobParams {
    /// Accepted hue range [min, max], deg; min > max wraps through 0 (reds).
    pub hue_deg: (f64, f64),
    /// Smallest saturation (0..1).
    pub min_saturation: f64,
    /// Smallest value (brightness, 0..1).
    pub min_value: f64,
    /// Radius of the disc used for opening then closing the colour mask, px
    /// (0 = none).
    pub morph_radius_px: usize,
    /// Smallest blob area, px (pixels after opening and closing).
    pub min_area_px: f64,
    /// Largest blob area, px.
    pub max_area_px: f64,
    /// Largest ratio of the moment ellipse's axes (a disc tilted by t shows
    /// 1 / cos t: 2 at 60 deg, 6 at 80 deg: markers near the silhouette are
    /// still markers).
    pub max_aspect: f64,
    /// Smallest [`ellipse_fit`] (intersection over union of the blob and its
    /// moment ellipse).
    pub min_ellipse_fit: f64,
    /// Band around a blob whose pixels count by their colour share in the
    /// centroid, px.
    pub border_px: usize,
}

impl Default for BlobParams {
    /// Suits the phantom's green faces (linear RGB about (0.10, 0.72, 0.20):
    /// hue 130 deg, saturation 0.86) under shading from 0.35 to 1.
    fn default() -> Self {
        BlobParams {
            hue_deg: (90.0, 170.0),
            min_saturation: 0.45,
            min_value: 0.12,
            morph_radius_px: 1,
            min_area_px: 20.0,
            max_area_px: 20000.0,
            max_aspect: 6.0,
            min_ellipse_fit: 0.8,
            border_px: 2,
        }
    }
}

impl BlobParams {
    /// Checks ranges; the error names the parameter.
    pub fn check(&self) -> Result<(), String> {
        match self.problems().into_iter().next() {
            Some((_, problem)) => Err(problem),
            None => Ok(()),
        }
    }

    /// Every range problem, as `(parameter, problem)` pairs.
    pub fn problems(&self) -> Vec<(&'static str, String)> {
        let mut problems = Vec::new();
        let (h0, h1) = self.hue_deg;
        if !(0.0..=360.0).contains(&h0) || !(0.0..=360.0).contains(&h1) {
            problems.push((
                "hue_deg",
                format!("hue_deg [{h0}, {h1}]: both must be in 0..360 deg"),
            ));
        }
        if self.min_area_px > self.max_area_px {
            problems.push((
                "min_area_px",
                format!(
                    "min_area_px {} is above max_area_px {}",
                    self.min_area_px, self.max_area_px
                ),
            ));
        }
        problems
    }

    fn hue_ok(&self, h: f64) -> bool {
        let (h0, h1) = self.hue_deg;
        if h0 <= h1 {
            (h0..=h1).contains(&h)
        } else {
            h >= h0 || h <= h1
        }
    }

    /// The middle of the hue range, deg.
    fn hue_centre_deg(&self) -> f64 {
        let (h0, h1) = self.hue_deg;
        let span = (h1 - h0).rem_euclid(360.0);
        (h0 + 0.5 * span).rem_euclid(360.0)
    }
}

/// One accepted blob.
#[derive(Debug, Clone, PartialEq)]
pub struct Blob {
    /// Sub-pixel centroid, px.
    pub x_px: f64,
    /// Sub-pixel centroid, px.
    pub y_px: f64,
    /// Area with edge pixels counted by their colour share, px.
    pub area_px: f64,
    /// Major over minor axis of the moment ellipse.
    pub aspect: f64,
    /// [`ellipse_fit`] of the blob.
    pub fit: f64,
    /// The centroid in the image the blob was found in, px (the same as
    /// `x_px`, `y_px` unless they were mapped into the rectified frame).
    pub image_px: (f64, f64),
}

/// Checks an interleaved 8-bit RGB buffer's length.
fn check_rgb(rgb: &[u8], width: usize, height: usize, what: &str) -> Result<(), String> {
    if rgb.len() != width * height * 3 || width == 0 || height == 0 {
        return Err(format!(
            "{what}: {} samples for {width} x {height} RGB",
            rgb.len()
        ));
    }
    Ok(())
}

/// The largest chroma (max - min of R, G, B, in 8-bit levels) of any pixel:
/// 0 for an image that is grey however it is stored (a greyscale camera's
/// frames saved as RGB, a grey conversion upstream), where no hue exists to
/// find markers by. JPEG rounding leaves a grey image within 1 or 2 levels.
///
/// # Examples
///
/// ```
/// use fusegraph_nodes::stereo::max_chroma;
///
/// assert_eq!(max_chroma(&[10, 10, 10, 200, 200, 200]), 0);
/// assert_eq!(max_chroma(&[10, 10, 10, 40, 200, 60]), 160);
/// ```
pub fn max_chroma(rgb: &[u8]) -> u8 {
    rgb.chunks_exact(3)
        .map(|p| p.iter().max().unwrap() - p.iter().min().unwrap())
        .max()
        .unwrap_or(0)
}

/// Chroma at or below this many levels is grey stored as colour.
pub const GREY_CHROMA_LEVELS: u8 = 2;

/// Pixels of `rgb` (interleaved 8-bit) inside the HSV thresholds.
pub fn colour_mask(rgb: &[u8], p: &BlobParams) -> Vec<bool> {
    rgb.chunks_exact(3)
        .map(|c| {
            let (h, s, v) = hsv(
                c[0] as f64 / 255.0,
                c[1] as f64 / 255.0,
                c[2] as f64 / 255.0,
            );
            s >= p.min_saturation && v >= p.min_value && p.hue_ok(h)
        })
        .collect()
}

/// How strongly each pixel shows hue `hue_deg`: its chroma vector
/// (R - (G + B) / 2, sqrt(3) / 2 (G - B)) projected on that hue's direction.
/// Linear in RGB (so a mixed pixel scores the mix of its parts) and 0 for
/// every grey, whatever its brightness.
pub fn hue_score(rgb: &[u8], hue_deg: f64) -> Vec<f64> {
    let (s, c) = hue_deg.to_radians().sin_cos();
    let k = 3f64.sqrt() / 2.0;
    rgb.chunks_exact(3)
        .map(|px| {
            let [r, g, b] = [px[0], px[1], px[2]].map(|v| v as f64 / 255.0);
            c * (r - 0.5 * (g + b)) + s * k * (g - b)
        })
        .collect()
}

/// The marker blobs of one image (interleaved 8-bit RGB), in raster order of
/// their first pixel, and how many colour blobs there were before the area and
/// shape filters.
pub fn find_blobs(
    rgb: &[u8],
    width: usize,
    height: usize,
    p: &BlobParams,
) -> Result<(Vec<Blob>, usize), String> {
    check_rgb(rgb, width, height, "image")?;
    p.check()?;
    let mask = open_close(&colour_mask(rgb, p), width, height, p.morph_radius_px);
    let (labels, pixels) = components(&mask, width, height);
    let score = hue_score(rgb, p.hue_centre_deg());
    let blobs = pixels
        .iter()
        .enumerate()
        .filter_map(|(k, px)| {
            let area = px.len() as f64;
            if area < p.min_area_px || area > p.max_area_px {
                return None;
            }
            let aspect = MomentEllipse::of(px, width)?.aspect();
            if aspect.is_nan() || aspect > p.max_aspect {
                return None;
            }
            let fit = ellipse_fit(px, width, height);
            if fit < p.min_ellipse_fit {
                return None;
            }
            let ((x, y), soft_area) = soft_centroid(
                &labels,
                width,
                height,
                k as u32 + 1,
                px,
                &score,
                p.border_px,
            );
            Some(Blob {
                x_px: x,
                y_px: y,
                area_px: soft_area,
                aspect,
                fit,
                image_px: (x, y),
            })
        })
        .collect();
    Ok((blobs, pixels.len()))
}

/// How blobs of the left and right images may pair.
#[derive(Debug, Clone, PartialEq)]
pub struct PairParams {
    /// Largest |y_left - y_right|, px.
    pub row_tolerance_px: f64,
    /// Largest ratio of the larger to the smaller area (>= 1).
    pub max_area_ratio: f64,
    /// Smallest disparity x_left - x_right, px (it must be positive anyway).
    pub min_disparity_px: Option<f64>,
    /// Largest disparity, px.
    pub max_disparity_px: Option<f64>,
}

impl Default for PairParams {
    fn default() -> Self {
        PairParams {
            row_tolerance_px: 2.0,
            max_area_ratio: 1.6,
            min_disparity_px: None,
            max_disparity_px: None,
        }
    }
}

/// Cost of pairing `l` with `r`, or `None` when they may not pair: the squared
/// row offset and log area ratio, each relative to its limit (so 0..2).
fn pair_cost(l: &Blob, r: &Blob, p: &PairParams) -> Option<f64> {
    let d = l.x_px - r.x_px;
    let dy = (l.y_px - r.y_px).abs();
    let ratio = l.area_px.max(r.area_px) / l.area_px.min(r.area_px);
    let ok = d > 0.0
        && p.min_disparity_px.is_none_or(|m| d >= m)
        && p.max_disparity_px.is_none_or(|m| d <= m)
        && dy <= p.row_tolerance_px
        && ratio <= p.max_area_ratio;
    ok.then(|| {
        let row = dy / p.row_tolerance_px.max(1e-9);
        let size = ratio.ln() / p.max_area_ratio.ln().max(1e-9);
        row * row + size * size
    })
}

/// Most blobs per image the pairing takes (it is cubic in the count).
pub const MAX_BLOBS: usize = 1000;

/// One-to-one pairs (left index, right index), in left order: of all the
/// pairings allowed by `p` (same row within the tolerance, positive disparity
/// inside the optional range, similar area), the one with the most pairs and,
/// among those, the least total `pair_cost` (Hungarian algorithm). Unlike a
/// greedy choice, two markers on one row cannot steal each other's partner.
pub fn pair_blobs(
    left: &[Blob],
    right: &[Blob],
    p: &PairParams,
) -> Result<Vec<(usize, usize)>, String> {
    if left.len() > MAX_BLOBS || right.len() > MAX_BLOBS {
        return Err(format!(
            "{} left and {} right blobs (at most {MAX_BLOBS}): tighten the colour thresholds or the area range",
            left.len(),
            right.len()
        ));
    }
    if left.is_empty() || right.is_empty() {
        return Ok(Vec::new());
    }
    // Columns: right blobs, then one "unpaired" column per left blob. Leaving a
    // blob unpaired costs more than any path of re-pairings can save.
    const UNPAIRED: f64 = 1e4;
    const FORBIDDEN: f64 = 1e9;
    let (n, m) = (left.len(), right.len() + left.len());
    let cost: Vec<Vec<f64>> = left
        .iter()
        .map(|l| {
            let mut row: Vec<f64> = right
                .iter()
                .map(|r| pair_cost(l, r, p).unwrap_or(FORBIDDEN))
                .collect();
            row.resize(m, UNPAIRED);
            row
        })
        .collect();
    let assigned = hungarian(&cost, n, m);
    Ok(assigned
        .into_iter()
        .enumerate()
        .filter(|&(i, j)| j < right.len() && cost[i][j] < FORBIDDEN)
        .collect())
}

/// Minimum-cost assignment of each of `n` rows to a distinct one of `m >= n`
/// columns (the O(n^2 m) shortest augmenting path form of the Hungarian
/// algorithm); returns the column of each row.
fn hungarian(cost: &[Vec<f64>], n: usize, m: usize) -> Vec<usize> {
    let inf = f64::INFINITY;
    let (mut u, mut v) = (vec![0.0; n + 1], vec![0.0; m + 1]);
    let (mut p, mut way) = (vec![0usize; m + 1], vec![0usize; m + 1]);
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0;
        let mut minv = vec![inf; m + 1];
        let mut used = vec![false; m + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let (mut delta, mut j1) = (inf, 0);
            for j in 1..=m {
                if !used[j] {
                    let cur = cost[i0 - 1][j - 1] - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut out = vec![0; n];
    for j in 1..=m {
        if p[j] != 0 {
            out[p[j] - 1] = j - 1;
        }
    }
    out
}

/// A paired and triangulated marker.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoMarker {
    /// The left blob.
    pub left: Blob,
    /// The right blob.
    pub right: Blob,
    /// `x_left - x_right`, px.
    pub disparity_px: f64,
    /// Centre in mm in the original left camera frame.
    pub point_mm: Point3<f64>,
}

/// Fewest pairs [`localisation_noise_px`] estimates the noise from.
pub const MIN_PAIRS_FOR_NOISE: usize = 3;

/// The noise of a blob centroid's coordinates (px, each coordinate alike),
/// measured from the pairs' rectified rows: a pair's two centroids lie on one
/// epipolar line, so their row difference is the noise of two centroids
/// (RMS about zero, so a rectification's own misalignment counts too).
/// `None` with fewer than [`MIN_PAIRS_FOR_NOISE`] pairs.
pub fn localisation_noise_px(markers: &[StereoMarker]) -> Option<f64> {
    if markers.len() < MIN_PAIRS_FOR_NOISE {
        return None;
    }
    let sum: f64 = markers
        .iter()
        .map(|m| (m.left.y_px - m.right.y_px).powi(2))
        .sum();
    Some((sum / markers.len() as f64 / 2.0).sqrt())
}

/// Everything [`stereo_markers`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoMarkers {
    /// Paired markers in left-blob order.
    pub markers: Vec<StereoMarker>,
    /// Accepted blobs in the left image.
    pub blobs_left: usize,
    /// Accepted blobs in the right image.
    pub blobs_right: usize,
}

/// Finds the markers of a rectified pair (interleaved 8-bit RGB, same size),
/// pairs them and triangulates each at the left centroid with the measured
/// disparity, on the mean of the two rows (the best estimate of their common
/// epipolar line).
pub fn stereo_markers(
    left: (&[u8], usize, usize),
    right: (&[u8], usize, usize),
    rect: &StereoRectification,
    blob: &BlobParams,
    pair: &PairParams,
) -> Result<StereoMarkers, String> {
    let ((l, w, h), (r, rw, rh)) = (left, right);
    if (w, h) != (rw, rh) {
        return Err(format!("left is {w} x {h} px but right is {rw} x {rh} px"));
    }
    check_rgb(l, w, h, "left")?;
    check_rgb(r, w, h, "right")?;
    let (bl, br) = rayon::join(|| find_blobs(l, w, h, blob), || find_blobs(r, w, h, blob));
    let ((bl, _), (br, _)) = (bl?, br?);
    pair_and_triangulate(bl, br, rect, pair)
}

/// [`stereo_markers`] on the images as the cameras took them (before
/// undistortion and rectification): the blobs are measured there and only
/// their centroids are mapped into the rectified frame. Resampling an image
/// blurs a small blob's edges, and with them its sub-pixel centroid (about
/// 0.1 px on the phantom's thinnest ellipses, 0.3 mm in depth); a point maps
/// exactly. `cameras` are the rig's left and right cameras.
pub fn stereo_markers_unrectified(
    left: (&[u8], usize, usize),
    right: (&[u8], usize, usize),
    cameras: (&CameraModel, &CameraModel),
    rect: &StereoRectification,
    blob: &BlobParams,
    pair: &PairParams,
) -> Result<StereoMarkers, String> {
    let sides = [(left, cameras.0, "left"), (right, cameras.1, "right")];
    for ((rgb, w, h), camera, side) in sides {
        check_rgb(rgb, w, h, side)?;
        if (w, h) != (camera.width, camera.height) {
            return Err(format!(
                "{side} image is {w} x {h} px but its camera is {} x {}",
                camera.width, camera.height
            ));
        }
    }
    let find = |((rgb, w, h), camera, side): ((&[u8], usize, usize), &CameraModel, &str)| {
        let (r, p) = if side == "left" {
            (&rect.r1, &rect.p1)
        } else {
            (&rect.r2, &rect.p2)
        };
        let (blobs, _) = find_blobs(rgb, w, h, blob)?;
        Ok::<_, String>(
            blobs
                .into_iter()
                .map(|b| {
                    let at = Point2::new(b.x_px, b.y_px);
                    let q = StereoRectification::rectify_point(camera, r, p, &at);
                    Blob {
                        x_px: q.x,
                        y_px: q.y,
                        ..b
                    }
                })
                .collect::<Vec<_>>(),
        )
    };
    let (bl, br) = rayon::join(|| find(sides[0]), || find(sides[1]));
    pair_and_triangulate(bl?, br?, rect, pair)
}

/// Pairs blobs given in rectified coordinates and triangulates each pair.
fn pair_and_triangulate(
    bl: Vec<Blob>,
    br: Vec<Blob>,
    rect: &StereoRectification,
    pair: &PairParams,
) -> Result<StereoMarkers, String> {
    let markers = pair_blobs(&bl, &br, pair)?
        .into_iter()
        .filter_map(|(i, j)| {
            let (a, b) = (&bl[i], &br[j]);
            let d = a.x_px - b.x_px;
            let point = point_from_disparity(rect, a.x_px, 0.5 * (a.y_px + b.y_px), d)?;
            Some(StereoMarker {
                left: a.clone(),
                right: b.clone(),
                disparity_px: d,
                point_mm: point,
            })
        })
        .collect();
    Ok(StereoMarkers {
        markers,
        blobs_left: bl.len(),
        blobs_right: br.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    const GREEN: [f64; 3] = [0.10, 0.72, 0.20];

    /// A shape: colour (linear RGB) and whether a point lies inside.
    type Shape = ([f64; 3], Box<dyn Fn(f64, f64) -> bool>);

    fn ellipse(cx: f64, cy: f64, a: f64, b: f64, angle_deg: f64) -> Box<dyn Fn(f64, f64) -> bool> {
        let (s, c) = angle_deg.to_radians().sin_cos();
        Box::new(move |x, y| {
            let (dx, dy) = (x - cx, y - cy);
            let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
            (u / a).powi(2) + (v / b).powi(2) <= 1.0
        })
    }

    /// Renders shapes over a textured skin-coloured background: 8 x 8 samples
    /// per pixel (anti-aliasing), shading falling 10 % across each shape from
    /// left to right, Gaussian noise of 1.5 / 255, 8-bit.
    fn render(w: usize, h: usize, shapes: &[Shape], seed: u64) -> Vec<u8> {
        let skin = [0.92, 0.72, 0.62];
        let texture = |x: f64, y: f64| {
            0.85 + 0.10 * (0.9 * x + 0.4 * y).sin() * (0.7 * y - 0.2 * x).cos()
                + 0.06 * (2.1 * x - 1.3 * y + 0.5).sin()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, 1.5 / 255.0).unwrap();
        let n = 8;
        let mut out = vec![0u8; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0.0; 3];
                for sy in 0..n {
                    for sx in 0..n {
                        let px = x as f64 + (sx as f64 + 0.5) / n as f64 - 0.5;
                        let py = y as f64 + (sy as f64 + 0.5) / n as f64 - 0.5;
                        let c = match shapes.iter().find(|s| (s.1)(px, py)) {
                            Some((colour, _)) => colour.map(|v| v * (0.85 - 0.0006 * px)),
                            None => skin.map(|v| v * texture(px, py)),
                        };
                        (0..3).for_each(|k| acc[k] += c[k]);
                    }
                }
                for k in 0..3 {
                    let v = acc[k] / (n * n) as f64 + noise.sample(&mut rng);
                    out[(y * w + x) * 3 + k] = (v * 255.0).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        out
    }

    #[test]
    fn hsv_of_primaries_and_the_phantom_green() {
        assert_eq!(hsv(1.0, 0.0, 0.0), (0.0, 1.0, 1.0));
        assert_eq!(hsv(0.0, 0.5, 0.0), (120.0, 1.0, 0.5));
        assert_eq!(hsv(0.0, 0.0, 1.0).0, 240.0);
        assert_eq!(hsv(0.4, 0.4, 0.4), (0.0, 0.0, 0.4));
        let (h, s, v) = hsv(GREEN[0], GREEN[1], GREEN[2]);
        // 120 + 60 * (0.20 - 0.10) / 0.62
        assert!((h - (120.0 + 60.0 * 0.1 / 0.62)).abs() < 1e-12);
        assert!((s - 0.62 / 0.72).abs() < 1e-12 && v == 0.72);
        let p = BlobParams::default();
        assert!(p.hue_ok(h) && s >= p.min_saturation && 0.35 * v >= p.min_value);
        let red = BlobParams {
            hue_deg: (340.0, 20.0),
            ..p
        };
        assert!(red.hue_ok(350.0) && red.hue_ok(5.0) && !red.hue_ok(100.0));
        assert!((red.hue_centre_deg() - 0.0).abs() < 1e-12);
    }

    #[test]
    fn hue_score_is_linear_and_zero_on_grey() {
        let s = hue_score(&[128, 128, 128, 0, 255, 0, 0, 128, 0], 120.0);
        assert!(s[0].abs() < 1e-12);
        // Pure green: chroma (-1/2, sqrt(3)/2) on the 120 deg direction = 1.
        assert!((s[1] - 1.0).abs() < 1e-12);
        assert!((s[2] - 128.0 / 255.0).abs() < 1e-12);
    }

    #[test]
    fn centroids_of_anti_aliased_discs_and_ellipses_within_0_05_px() {
        let (w, h) = (300, 200);
        let truth = [
            (40.3, 35.7),
            (110.65, 40.2),
            (190.4, 45.9),
            (60.2, 110.35),
            (250.75, 60.15),
        ];
        let shapes: Vec<Shape> = vec![
            (GREEN, ellipse(truth[0].0, truth[0].1, 9.0, 9.0, 0.0)),
            (GREEN, ellipse(truth[1].0, truth[1].1, 6.0, 6.0, 0.0)),
            // Discs tilted by 54 and 57 deg: ellipses.
            (GREEN, ellipse(truth[2].0, truth[2].1, 12.0, 7.0, 25.0)),
            (GREEN, ellipse(truth[3].0, truth[3].1, 10.0, 5.5, -60.0)),
            (GREEN, ellipse(truth[4].0, truth[4].1, 8.0, 7.0, 80.0)),
            // Rejected: red, grey, ragged green (a 5-point star), elongated green.
            ([0.75, 0.08, 0.10], ellipse(130.0, 110.0, 9.0, 9.0, 0.0)),
            ([0.45, 0.45, 0.45], ellipse(200.0, 120.0, 9.0, 9.0, 0.0)),
            (
                GREEN,
                Box::new(|x: f64, y: f64| {
                    let (dx, dy) = (x - 250.0, y - 150.0);
                    let r = (dx * dx + dy * dy).sqrt();
                    r <= 5.0 + 9.0 * (0.5 + 0.5 * (5.0 * dy.atan2(dx)).cos()).powi(3)
                }),
            ),
            (GREEN, ellipse(110.0, 170.0, 25.0, 3.0, 10.0)),
        ];
        let rgb = render(w, h, &shapes, 7);
        let (blobs, all) = find_blobs(&rgb, w, h, &BlobParams::default()).unwrap();
        assert_eq!(blobs.len(), truth.len(), "{blobs:?}");
        assert!(
            all >= truth.len() + 2,
            "the star and the bar are colour blobs: {all}"
        );
        let mut worst: f64 = 0.0;
        for (x, y) in truth {
            let b = blobs
                .iter()
                .find(|b| (b.x_px - x).abs() < 2.0 && (b.y_px - y).abs() < 2.0)
                .unwrap_or_else(|| panic!("no blob at ({x}, {y}): {blobs:?}"));
            let err = ((b.x_px - x).powi(2) + (b.y_px - y).powi(2)).sqrt();
            worst = worst.max(err);
            assert!(
                err < 0.05,
                "({x}, {y}): found ({}, {}), {err} px",
                b.x_px,
                b.y_px
            );
        }
        // The binary centroids of the thresholded blobs, for comparison.
        let mask = open_close(&colour_mask(&rgb, &BlobParams::default()), w, h, 1);
        let (_, px) = components(&mask, w, h);
        let binary_worst = truth
            .iter()
            .map(|&(x, y)| {
                px.iter()
                    .map(|p| MomentEllipse::of(p, w).unwrap().centre_px)
                    .map(|(bx, by)| ((bx - x).powi(2) + (by - y).powi(2)).sqrt())
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(0.0, f64::max);
        eprintln!("worst centroid error {worst:.4} px (binary centroids: {binary_worst:.4} px)");
        assert!(binary_worst > 2.0 * worst, "{binary_worst} vs {worst}");
    }

    #[test]
    fn pairing_is_one_to_one_along_rows() {
        let blob = |x: f64, y: f64, area: f64| Blob {
            x_px: x,
            y_px: y,
            area_px: area,
            aspect: 1.0,
            fit: 1.0,
            image_px: (x, y),
        };
        // Two markers on one row: left A (100) and B (300); right A' (80) and
        // B' (280). B could pair with A' (disparity 220), but then A would be
        // left alone: the pairing keeps both.
        let left = [
            blob(100.0, 50.0, 200.0),
            blob(300.0, 50.5, 200.0),
            blob(150.0, 90.0, 300.0),
        ];
        let right = [
            blob(80.0, 50.4, 200.0),
            blob(280.0, 50.0, 200.0),
            blob(130.0, 90.0, 100.0),
            blob(40.0, 120.0, 300.0),
        ];
        let p = PairParams::default();
        assert_eq!(pair_blobs(&left, &right, &p).unwrap(), vec![(0, 0), (1, 1)]);
        // A disparity range excludes pairs: from 25 px only B-A' is left.
        let ranged = PairParams {
            min_disparity_px: Some(25.0),
            ..p.clone()
        };
        assert_eq!(pair_blobs(&left, &right, &ranged).unwrap(), vec![(1, 0)]);
        let ranged = PairParams {
            max_disparity_px: Some(15.0),
            ..p.clone()
        };
        assert!(pair_blobs(&left, &right, &ranged).unwrap().is_empty());
        // A swapped order (negative disparity) never pairs.
        assert!(pair_blobs(&right[..1], &left[..1], &p).unwrap().is_empty());
    }

    #[test]
    fn a_pair_with_known_disparity_triangulates_to_the_known_point() {
        let crate::phantom::Rig {
            left,
            right,
            left_to_right,
        } = crate::phantom::Rig::paper_rig();
        let rect = crate::calib::rectify(&left, &right, &left_to_right, 0.0);
        let (w, h) = (560, 300);
        // Points near the convergence distance, projected into both rectified
        // images (the principal point moved so both views fit in 560 x 300).
        let points = [
            Point3::new(-5.0, -20.0, 420.0),
            Point3::new(40.0, 10.0, 470.0),
            Point3::new(10.0, 30.0, 440.0),
        ];
        let project =
            |r: &nalgebra::Matrix3<f64>, p: &nalgebra::Matrix3x4<f64>, q: &Point3<f64>| {
                let v = p.fixed_view::<3, 3>(0, 0) * (r * q.coords);
                (v.x / v.z, v.y / v.z)
            };
        let shift = (rect.p1[(0, 2)] - 380.0, rect.p1[(1, 2)] - 150.0);
        let mut rect_small = rect.clone();
        for p in [&mut rect_small.p1, &mut rect_small.p2] {
            p[(0, 2)] -= shift.0;
            p[(1, 2)] -= shift.1;
        }
        rect_small.q[(0, 3)] += shift.0;
        rect_small.q[(1, 3)] += shift.1;
        let right_points: Vec<Point3<f64>> = points.iter().map(|p| left_to_right * p).collect();
        let xl: Vec<(f64, f64)> = points
            .iter()
            .map(|p| project(&rect_small.r1, &rect_small.p1, p))
            .collect();
        let xr: Vec<(f64, f64)> = right_points
            .iter()
            .map(|p| project(&rect_small.r2, &rect_small.p2, p))
            .collect();
        let discs = |c: &[(f64, f64)]| -> Vec<Shape> {
            c.iter()
                .map(|&(x, y)| (GREEN, ellipse(x, y, 11.0, 11.0, 0.0)))
                .collect()
        };
        let (l, r) = (render(w, h, &discs(&xl), 1), render(w, h, &discs(&xr), 2));
        let found = stereo_markers(
            (&l, w, h),
            (&r, w, h),
            &rect_small,
            &BlobParams::default(),
            &PairParams::default(),
        )
        .unwrap();
        assert_eq!((found.blobs_left, found.blobs_right), (3, 3));
        assert_eq!(found.markers.len(), 3);
        for m in &found.markers {
            let k = (0..3)
                .find(|&k| (xl[k].0 - m.left.x_px).abs() < 1.0)
                .unwrap();
            let d_true = xl[k].0 - xr[k].0;
            assert!(
                (m.disparity_px - d_true).abs() < 0.07,
                "{} vs {d_true}",
                m.disparity_px
            );
            // What a 0.07 px disparity error moves the point by, at this depth.
            let at = |d: f64| point_from_disparity(&rect_small, xl[k].0, xl[k].1, d).unwrap();
            let tol = (at(d_true + 0.07) - at(d_true)).norm() + 0.05;
            let err = (m.point_mm - points[k]).norm();
            assert!(
                err < tol,
                "marker {k}: {} vs {}: {err} mm (tol {tol})",
                m.point_mm,
                points[k]
            );
        }
        // Left and right of different sizes.
        let err = stereo_markers(
            (&l, w, h),
            (&r[..3 * w * (h - 1)], w, h - 1),
            &rect_small,
            &BlobParams::default(),
            &PairParams::default(),
        )
        .unwrap_err();
        assert!(
            err.contains("560 x 300") && err.contains("560 x 299"),
            "{err}"
        );
    }

    #[test]
    fn a_centroids_noise_is_measured_from_the_pairs_rows() {
        // Row differences 0.2, -0.2 and 0.4 px: sqrt((0.04 + 0.04 + 0.16)
        // / 3 / 2) = 0.2 px per centroid; two pairs are too few.
        let blob = |y: f64| Blob {
            x_px: 100.0,
            y_px: y,
            area_px: 50.0,
            aspect: 1.0,
            fit: 1.0,
            image_px: (100.0, y),
        };
        let pair = |dy: f64| StereoMarker {
            left: blob(50.0 + dy),
            right: blob(50.0),
            disparity_px: 30.0,
            point_mm: Point3::new(0.0, 0.0, 500.0),
        };
        let markers = [pair(0.2), pair(-0.2), pair(0.4)];
        let sigma = localisation_noise_px(&markers).unwrap();
        assert!((sigma - 0.2).abs() < 1e-12, "{sigma}");
        assert_eq!(localisation_noise_px(&markers[..2]), None);
    }
}
