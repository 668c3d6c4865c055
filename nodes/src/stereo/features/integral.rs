//! Integral image (summed-area table): the sum over any axis-aligned box in
//! four look-ups, which makes SURF's box filters cost the same at every scale.

use rayon::prelude::*;

/// Summed-area table of a grey image: `sum(x0, y0, x1, y1)` is the sum of the
/// pixels with `x0 <= x < x1`, `y0 <= y < y1` (px, clipped to the image).
#[derive(Debug, Clone)]
pub struct Integral {
    width: usize,
    height: usize,
    /// `(width + 1) * (height + 1)` partial sums; row 0 and column 0 are zero.
    /// f64 because differences of large sums in f32 lose the fine detail.
    table: Vec<f64>,
}

impl Integral {
    /// The table of `grey` (row-major, `width * height` values). The caller
    /// checks the length.
    pub fn new(grey: &[f32], width: usize, height: usize) -> Self {
        let stride = width + 1;
        let mut table = vec![0.0f64; stride * (height + 1)];
        // Row prefix sums in parallel, then the column accumulation row by row.
        table[stride..]
            .par_chunks_mut(stride)
            .zip(grey.par_chunks(width.max(1)))
            .for_each(|(row, src)| {
                let mut acc = 0.0f64;
                for (x, &v) in src.iter().enumerate() {
                    acc += v as f64;
                    row[x + 1] = acc;
                }
            });
        for y in 1..=height {
            let (prev, cur) = table.split_at_mut(y * stride);
            let prev = &prev[(y - 1) * stride..];
            for (c, p) in cur[..stride].iter_mut().zip(prev) {
                *c += p;
            }
        }
        Integral {
            width,
            height,
            table,
        }
    }

    /// Image width, px.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Image height, px.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The raw table, `(width + 1) * (height + 1)` values, row-major: entry
    /// (x, y) is the sum of the pixels left of x and above y.
    pub fn table(&self) -> &[f64] {
        &self.table
    }

    /// Entries per table row (`width + 1`).
    pub fn stride(&self) -> usize {
        self.width + 1
    }

    /// Sum of the pixels with `x0 <= x < x1`, `y0 <= y < y1`; the box is clipped
    /// to the image (pixels outside count as zero).
    #[inline]
    pub fn sum(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> f64 {
        let cx = |x: i64| x.clamp(0, self.width as i64) as usize;
        let cy = |y: i64| y.clamp(0, self.height as i64) as usize;
        let (x0, x1, y0, y1) = (cx(x0), cx(x1), cy(y0), cy(y1));
        if x1 <= x0 || y1 <= y0 {
            return 0.0;
        }
        let s = self.width + 1;
        self.table[y1 * s + x1] - self.table[y0 * s + x1] - self.table[y1 * s + x0]
            + self.table[y0 * s + x0]
    }

    /// Sum over the `w` x `h` box whose top-left pixel is (`x`, `y`).
    #[inline]
    pub fn box_sum(&self, x: i64, y: i64, w: i64, h: i64) -> f64 {
        self.sum(x, y, x + w, y + h)
    }

    /// Haar wavelet responses (`dx`, `dy`) of side `size` (px, even) centred on
    /// pixel (`x`, `y`): right half minus left half, bottom half minus top half.
    #[inline]
    pub fn haar(&self, x: i64, y: i64, size: i64) -> (f64, f64) {
        let h = size / 2;
        let (w, ht) = (self.width as i64, self.height as i64);
        if x >= h && y >= h && x + h <= w && y + h <= ht {
            // Inside: six table entries per axis, no clamping.
            let s = self.stride() as i64;
            let t = |xx: i64, yy: i64| self.table[(yy * s + xx) as usize];
            let (x0, x1, x2, y0, y1, y2) = (x - h, x, x + h, y - h, y, y + h);
            let dx = (t(x2, y2) - t(x2, y0) - t(x1, y2) + t(x1, y0))
                - (t(x1, y2) - t(x1, y0) - t(x0, y2) + t(x0, y0));
            let dy = (t(x2, y2) - t(x2, y1) - t(x0, y2) + t(x0, y1))
                - (t(x2, y1) - t(x2, y0) - t(x0, y1) + t(x0, y0));
            return (dx, dy);
        }
        let dx = self.box_sum(x, y - h, h, size) - self.box_sum(x - h, y - h, h, size);
        let dy = self.box_sum(x - h, y, size, h) - self.box_sum(x - h, y - h, size, h);
        (dx, dy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_sums_match_direct_sums() {
        let (w, h) = (7usize, 5usize);
        let grey: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 * 0.1).collect();
        let ii = Integral::new(&grey, w, h);
        let direct = |x0: usize, y0: usize, x1: usize, y1: usize| -> f64 {
            let mut s = 0.0;
            for y in y0..y1 {
                for x in x0..x1 {
                    s += grey[y * w + x] as f64;
                }
            }
            s
        };
        for (x0, y0, x1, y1) in [(0, 0, 7, 5), (2, 1, 5, 4), (6, 4, 7, 5), (3, 3, 3, 4)] {
            let got = ii.sum(x0 as i64, y0 as i64, x1 as i64, y1 as i64);
            assert!((got - direct(x0, y0, x1, y1)).abs() < 1e-9);
        }
        // Clipping: a box reaching outside sums only the pixels inside.
        assert!((ii.sum(-3, -2, 2, 2) - direct(0, 0, 2, 2)).abs() < 1e-9);
        assert!((ii.sum(5, 3, 20, 20) - direct(5, 3, 7, 5)).abs() < 1e-9);
        assert_eq!(ii.sum(4, 2, 3, 4), 0.0);
    }

    #[test]
    fn haar_sees_a_ramp() {
        // grey = 0.01 x + 0.02 y: a size-4 Haar gives 2*4 pixels * 2 px * slope.
        let (w, h) = (20usize, 20usize);
        let grey: Vec<f32> = (0..w * h)
            .map(|i| 0.01 * (i % w) as f32 + 0.02 * (i / w) as f32)
            .collect();
        let ii = Integral::new(&grey, w, h);
        let (dx, dy) = ii.haar(10, 10, 4);
        assert!((dx - 8.0 * 2.0 * 0.01).abs() < 1e-5, "dx {dx}");
        assert!((dy - 8.0 * 2.0 * 0.02).abs() < 1e-5, "dy {dy}");
    }
}
