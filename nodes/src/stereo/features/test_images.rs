//! Synthetic images for the feature and matching tests: a texture of random
//! Gaussian blobs defined in continuous coordinates, so that exactly shifted
//! or warped copies can be rendered (ground truth to any sub-pixel amount).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const CELL: f32 = 16.0;

/// Random Gaussian blobs over a rectangle of texture coordinates.
pub struct BlobTexture {
    /// (x, y, sigma, amplitude) per blob, binned by cell.
    cells: Vec<Vec<[f32; 4]>>,
    cols: usize,
    rows: usize,
    x0: f32,
    y0: f32,
}

impl BlobTexture {
    /// Blobs of sigma 1.5..4 px and amplitude +-(0.15..0.35) covering texture
    /// coordinates `x0..x1`, `y0..y1`, one per 30 px^2 on average.
    pub fn new(x0: f32, y0: f32, x1: f32, y1: f32, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let cols = ((x1 - x0) / CELL).ceil() as usize + 1;
        let rows = ((y1 - y0) / CELL).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); cols * rows];
        let n = ((x1 - x0) * (y1 - y0) / 30.0) as usize;
        for _ in 0..n {
            let x = rng.random_range(x0..x1);
            let y = rng.random_range(y0..y1);
            let sigma = rng.random_range(1.5f32..4.0);
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let a = sign * rng.random_range(0.15f32..0.35);
            let c = ((x - x0) / CELL) as usize + ((y - y0) / CELL) as usize * cols;
            cells[c].push([x, y, sigma, a]);
        }
        BlobTexture {
            cells,
            cols,
            rows,
            x0,
            y0,
        }
    }

    /// Grey level at texture point (`x`, `y`), about 0.5 +- 0.5.
    pub fn value(&self, x: f32, y: f32) -> f32 {
        let cx = ((x - self.x0) / CELL).floor() as i64;
        let cy = ((y - self.y0) / CELL).floor() as i64;
        let mut v = 0.5f32;
        for gy in cy - 1..=cy + 1 {
            for gx in cx - 1..=cx + 1 {
                if gx < 0 || gy < 0 || gx >= self.cols as i64 || gy >= self.rows as i64 {
                    continue;
                }
                for &[bx, by, s, a] in &self.cells[gy as usize * self.cols + gx as usize] {
                    let d2 = (x - bx) * (x - bx) + (y - by) * (y - by);
                    v += a * (-d2 / (2.0 * s * s)).exp();
                }
            }
        }
        v.clamp(0.0, 1.0)
    }

    /// A `w` x `h` image whose pixel (x, y) shows texture point `to_texture(x, y)`.
    pub fn render(
        &self,
        w: usize,
        h: usize,
        to_texture: impl Fn(f32, f32) -> (f32, f32),
    ) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (tx, ty) = to_texture((i % w) as f32, (i / w) as f32);
                self.value(tx, ty)
            })
            .collect()
    }
}

/// A `w` x `h` blob texture whose content is moved by (`shift_x`, `shift_y`) px:
/// pixel (x, y) shows what pixel (x - shift_x, y - shift_y) shows unshifted.
pub fn blob_texture(w: usize, h: usize, shift_x: f32, shift_y: f32, seed: u64) -> Vec<f32> {
    let t = BlobTexture::new(-20.0, -20.0, w as f32 + 20.0, h as f32 + 20.0, seed);
    t.render(w, h, |x, y| (x - shift_x, y - shift_y))
}

/// One bright Gaussian blob (amplitude 0.6, `sigma` px) at (`cx`, `cy`) on 0.2.
pub fn gaussian_blob_image(w: usize, h: usize, cx: f32, cy: f32, sigma: f32) -> Vec<f32> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 - cx, (i / w) as f32 - cy);
            0.2 + 0.6 * (-(x * x + y * y) / (2.0 * sigma * sigma)).exp()
        })
        .collect()
}
