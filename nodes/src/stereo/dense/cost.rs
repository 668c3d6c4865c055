//! Matching costs of a rectified pair over a disparity range, as a volume of
//! 8-bit costs `[y][x][d - min]`: census (Hamming distance between census
//! transforms; robust to gain, offset and JPEG) and Birchfield-Tomasi (sampling
//! insensitive absolute difference, averaged over a window like OpenCV's SGBM).
//!
//! Written here: no maintained Rust crate computes stereo cost volumes
//! (../shared/CRATES.md). The inner loops are plain slices that the compiler
//! vectorises; [`super::simd`] compiles them for AVX2 where the CPU has it.

use super::pair::{DisparityRange, GreyImage};
use super::simd::Isa;
use super::volume::{CostRows, CostVolume, lanes_for, valid_ks};
use rayon::prelude::*;

/// Largest census window: its bits (window area - 1) must fit in 64.
pub fn check_census_window(w: usize, h: usize) -> Result<(), String> {
    if w.is_multiple_of(2) || h.is_multiple_of(2) || w * h < 9 || w * h > 65 {
        return Err(format!(
            "census window {w} x {h}: both sides must be odd and the area between 9 and 65 px (e.g. 9 x 7)"
        ));
    }
    Ok(())
}

/// The census transform over a `win_w x win_h` window: one bit per neighbour
/// (row-major, centre skipped, the first in the most significant used bit), set
/// when the neighbour is darker than the centre. Borders replicate the edge
/// pixels.
pub fn census_transform(img: &GreyImage, win_w: usize, win_h: usize, isa: Isa) -> Vec<u64> {
    let (w, h) = (img.width, img.height);
    let (rx, ry) = ((win_w / 2) as isize, (win_h / 2) as isize);
    let mut codes = vec![0u64; w * h];
    codes.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let centre = img.row(y);
        let mut padded = vec![0u8; w + 2 * rx as usize];
        // Comparisons are gathered eight to a byte (32 pixels per vector
        // instruction), then shifted into the codes a byte at a time.
        let mut byte = vec![0u8; w];
        let mut bits_in_byte = 0u32;
        for dy in -ry..=ry {
            let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
            let row = img.row(yy);
            padded[rx as usize..rx as usize + w].copy_from_slice(row);
            for i in 0..rx as usize {
                padded[i] = row[0];
                padded[rx as usize + w + i] = row[w - 1];
            }
            for dx in -rx..=rx {
                if dx == 0 && dy == 0 {
                    continue;
                }
                let start = (rx + dx) as usize;
                isa.census_bits(&mut byte, &padded[start..start + w], centre);
                bits_in_byte += 1;
                if bits_in_byte == 8 {
                    isa.shift_in_byte(out, &byte, 8);
                    bits_in_byte = 0;
                }
            }
        }
        if bits_in_byte > 0 {
            isa.shift_in_byte(out, &byte, bits_in_byte);
        }
    });
    codes
}

/// Census costs computed on demand from the two images' census codes
/// (8 bytes per pixel each) rather than stored (one byte per pixel and
/// disparity).
#[derive(Debug, Clone)]
pub struct CensusCosts {
    left: Vec<u64>,
    right: Vec<u64>,
    width: usize,
    height: usize,
    range: DisparityRange,
    lanes: usize,
    max_cost: u8,
    isa: Isa,
}

impl CensusCosts {
    /// The census codes of a pair over a `win_w x win_h` window (checked by
    /// [`check_census_window`]).
    pub fn new(
        left: &GreyImage,
        right: &GreyImage,
        range: DisparityRange,
        win_w: usize,
        win_h: usize,
    ) -> Self {
        let isa = Isa::detect();
        let (cl, cr) = rayon::join(
            || census_transform(left, win_w, win_h, isa),
            || census_transform(right, win_w, win_h, isa),
        );
        CensusCosts {
            left: cl,
            right: cr,
            width: left.width,
            height: left.height,
            range,
            lanes: lanes_for(range.count),
            max_cost: (win_w * win_h - 1) as u8,
            isa,
        }
    }

    /// Largest cost (the window's bit count; also the cost of impossible matches).
    pub fn max_cost(&self) -> u8 {
        self.max_cost
    }

    /// Every row's costs as a volume.
    pub fn volume(&self) -> CostVolume {
        let (w, h, lanes) = (self.width, self.height, self.lanes);
        let mut data = vec![0u8; w * h * lanes];
        data.par_chunks_mut(w * lanes)
            .enumerate()
            .for_each(|(y, out)| self.fill_row(y, out));
        CostVolume {
            width: w,
            height: h,
            range: self.range,
            max_cost: self.max_cost,
            lanes,
            data,
        }
    }

    fn fill_row(&self, y: usize, out: &mut [u8]) {
        let (w, n, lanes, range) = (self.width, self.range.count, self.lanes, self.range);
        let (l, r) = (
            &self.left[y * w..(y + 1) * w],
            &self.right[y * w..(y + 1) * w],
        );
        for x in 0..w {
            let (costs, padding) = out[x * lanes..(x + 1) * lanes].split_at_mut(n);
            padding.fill(0);
            // Valid k: 0 <= x - min - k < w.
            let (k_lo, k_hi) = valid_ks(x, w, range);
            costs[..k_lo].fill(self.max_cost);
            costs[k_hi..].fill(self.max_cost);
            if k_lo < k_hi {
                let xr_first = (x as i64 - range.min_px as i64 - k_lo as i64) as usize;
                self.isa
                    .hamming_descending(&mut costs[k_lo..k_hi], l[x], &r[..=xr_first]);
            }
        }
    }
}

impl CostRows for CensusCosts {
    fn width(&self) -> usize {
        self.width
    }
    fn height(&self) -> usize {
        self.height
    }
    fn range(&self) -> DisparityRange {
        self.range
    }
    fn lanes(&self) -> usize {
        self.lanes
    }
    fn row<'a>(&'a self, y: usize, scratch: &'a mut [u8]) -> &'a [u8] {
        let out = &mut scratch[..self.width * self.lanes];
        self.fill_row(y, out);
        out
    }
}

/// Census costs: Hamming distances between the left and right census codes.
pub fn census_costs(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
    win_w: usize,
    win_h: usize,
) -> CostVolume {
    CensusCosts::new(left, right, range, win_w, win_h).volume()
}

/// Birchfield-Tomasi costs (insensitive to image sampling), each the mean over
/// a `window x window` block, in grey levels (0..255).
pub fn bt_costs(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
    window: usize,
) -> CostVolume {
    let (w, h, n) = (left.width, left.height, range.count);
    // Half-pixel interpolated minima and maxima around every pixel.
    let extremes = |img: &GreyImage| -> (Vec<u8>, Vec<u8>) {
        let mut lo = vec![0u8; w * h];
        let mut hi = vec![0u8; w * h];
        for y in 0..h {
            let row = img.row(y);
            for x in 0..w {
                let c = row[x] as u16;
                let a = (c + row[x.saturating_sub(1)] as u16) / 2;
                let b = (c + row[(x + 1).min(w - 1)] as u16) / 2;
                lo[y * w + x] = c.min(a).min(b) as u8;
                hi[y * w + x] = c.max(a).max(b) as u8;
            }
        }
        (lo, hi)
    };
    let ((l_lo, l_hi), (r_lo, r_hi)) = rayon::join(|| extremes(left), || extremes(right));
    // Per-pixel costs, then a box mean over rows and columns.
    let mut raw = vec![255u8; w * h * n];
    raw.par_chunks_mut(w * n).enumerate().for_each(|(y, out)| {
        for x in 0..w {
            let (k_lo, k_hi) = valid_ks(x, w, range);
            let il = left.at(x, y) as i16;
            for k in k_lo..k_hi {
                let xr = (x as i64 - range.min_px as i64 - k as i64) as usize;
                let ir = right.at(xr, y) as i16;
                let i = y * w;
                let d1 = (il - r_hi[i + xr] as i16)
                    .max(r_lo[i + xr] as i16 - il)
                    .max(0);
                let d2 = (ir - l_hi[i + x] as i16)
                    .max(l_lo[i + x] as i16 - ir)
                    .max(0);
                out[x * n + k] = d1.min(d2) as u8;
            }
        }
    });
    let data = box_mean(&raw, w, h, n, window);
    CostVolume::unpadded(w, h, range, 255, data)
}

/// Mean of every `[y][x][k]` cost over a `window x window` block of pixels
/// (clamped at the borders), per disparity.
fn box_mean(raw: &[u8], w: usize, h: usize, n: usize, window: usize) -> Vec<u8> {
    let r = (window / 2) as isize;
    if r == 0 {
        return raw.to_vec();
    }
    // Horizontal sums, then vertical.
    let mut horizontal = vec![0u16; w * h * n];
    horizontal
        .par_chunks_mut(w * n)
        .enumerate()
        .for_each(|(y, out)| {
            let row = &raw[y * w * n..(y + 1) * w * n];
            for x in 0..w {
                let acc = &mut out[x * n..(x + 1) * n];
                for dx in -r..=r {
                    let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                    for (a, &c) in acc.iter_mut().zip(&row[xx * n..(xx + 1) * n]) {
                        *a += c as u16;
                    }
                }
            }
        });
    let area = ((2 * r + 1) * (2 * r + 1)) as u32;
    let mut out = vec![0u8; w * h * n];
    out.par_chunks_mut(w * n).enumerate().for_each(|(y, out)| {
        let mut acc = vec![0u32; w * n];
        for dy in -r..=r {
            let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
            for (a, &c) in acc
                .iter_mut()
                .zip(&horizontal[yy * w * n..(yy + 1) * w * n])
            {
                *a += c as u32;
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o = ((a + area / 2) / area) as u8;
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> GreyImage {
        GreyImage {
            width: w,
            height: h,
            data: (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .collect(),
        }
    }

    #[test]
    fn census_bits_by_hand() {
        // 3 x 3 window on a 3 x 3 image: the centre (1, 1) = 50 against its
        // neighbours in row-major order, darker neighbours set a bit.
        let g = img(3, 3, |x, y| {
            [[10, 60, 50], [90, 50, 20], [50, 70, 40]][y][x]
        });
        for isa in [Isa::Scalar, Isa::detect()] {
            let c = census_transform(&g, 3, 3, isa);
            // Neighbours: 10 60 50 90 | 20 50 70 40 -> darker: 1 0 0 0 1 0 0 1.
            assert_eq!(c[4], 0b1000_1001, "{isa:?}");
        }
    }

    #[test]
    fn census_costs_are_zero_at_the_true_shift() {
        let (w, h, shift) = (40, 12, 5);
        let pattern = |x: i64, y: usize| {
            // splitmix64 of the position: no structure a census could see.
            let mut z = ((x + 1000) as u64 * 7919 + y as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 56) as u8
        };
        let left = img(w, h, |x, y| pattern(x as i64, y));
        let right = img(w, h, |x, y| pattern(x as i64 + shift, y));
        let range = DisparityRange::new(0, 15, w).unwrap();
        let v = census_costs(&left, &right, range, 5, 5);
        // The true disparity costs 0; another one rarely does (only where the
        // centre is the darkest or brightest pixel of both windows).
        let (mut pixels, mut ambiguous) = (0, 0);
        for y in 0..h {
            // (The right border is replicated from different columns.)
            for x in 15..w - 2 {
                let c = v.pixel(x, y);
                assert_eq!(c[shift as usize], 0, "({x}, {y})");
                pixels += 1;
                if c.iter()
                    .enumerate()
                    .any(|(k, &v)| k != shift as usize && v == 0)
                {
                    ambiguous += 1;
                }
            }
        }
        assert!(ambiguous * 20 < pixels, "{ambiguous} of {pixels}");
        // Impossible matches (right pixel left of the image) cost the maximum.
        assert!(v.pixel(3, 5)[4..].iter().all(|&c| c == 24));
    }

    #[test]
    fn bt_is_zero_for_identical_rows_and_half_pixel_shifts() {
        let (w, h) = (30, 5);
        let left = img(w, h, |x, _| (x * 8) as u8);
        // A ramp shifted by half a pixel: BT sees no difference.
        let right = img(w, h, |x, _| (x * 8 + 4) as u8);
        let range = DisparityRange::new(0, 3, w).unwrap();
        let v = bt_costs(&left, &right, range, 1);
        assert_eq!(v.pixel(10, 2)[0], 0);
        // d = 2: 8 grey levels off after allowing half a pixel either way.
        assert_eq!(v.pixel(10, 2)[2], 8);
    }
}
