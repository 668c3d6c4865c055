//! The layout of matching costs that the cost functions write, semi-global
//! matching aggregates and the selection reads: a volume (or rows) of 8-bit
//! costs per pixel and disparity, padded to whole vectors, and which
//! disparities of a column can match at all. The lowest layer of the dense
//! matchers after the SIMD kernels: [`super::cost`], [`super::sgm`] and
//! [`super::select`] all build on it, and it on none of them.

use super::pair::DisparityRange;

/// Costs of every pixel and disparity: `data[(y * width + x) * lanes + k]` is
/// the cost of matching left pixel (x, y) with right pixel (x - min - k, y),
/// for k below the disparity count (the lanes after it are padding, so a
/// pixel's costs fill whole vectors).
/// Where the right pixel falls outside the image the cost is [`CostVolume::max_cost`].
#[derive(Debug, Clone, PartialEq)]
pub struct CostVolume {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Disparities searched.
    pub range: DisparityRange,
    /// Largest cost any pixel can have (and the cost of impossible matches).
    pub max_cost: u8,
    /// Entries per pixel in `data` (at least the disparity count).
    pub lanes: usize,
    /// Costs, `[y][x][k]`.
    pub data: Vec<u8>,
}

impl CostVolume {
    /// A volume of `count` costs per pixel, unpadded.
    pub fn unpadded(
        width: usize,
        height: usize,
        range: DisparityRange,
        max_cost: u8,
        data: Vec<u8>,
    ) -> Self {
        CostVolume {
            width,
            height,
            range,
            max_cost,
            lanes: range.count,
            data,
        }
    }

    /// The costs of pixel (x, y), one per disparity.
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &[u8] {
        let i = (y * self.width + x) * self.lanes;
        &self.data[i..i + self.range.count]
    }
}

/// Matching costs one image row at a time: `[x][lane]`, [`CostRows::lanes`]
/// entries per pixel, of which the first `range().count` are the costs of
/// disparities `min .. min + count` (the rest padding). Lets semi-global
/// matching compute costs as it goes instead of holding a whole volume.
pub trait CostRows: Sync {
    /// Width, px.
    fn width(&self) -> usize;
    /// Height, px.
    fn height(&self) -> usize;
    /// Disparities.
    fn range(&self) -> DisparityRange;
    /// Entries per pixel in a row (at least the disparity count).
    fn lanes(&self) -> usize;
    /// The costs of row `y`, written into `scratch` (`width * lanes` long) or
    /// borrowed from storage.
    fn row<'a>(&'a self, y: usize, scratch: &'a mut [u8]) -> &'a [u8];
}

impl CostRows for CostVolume {
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
    fn row<'a>(&'a self, y: usize, _scratch: &'a mut [u8]) -> &'a [u8] {
        let len = self.width * self.lanes;
        &self.data[y * len..(y + 1) * len]
    }
}

/// Lanes per pixel for `n` disparities: a whole number of 16-lane vectors, so
/// the kernels never fall back to scalar code for a remainder.
pub fn lanes_for(n: usize) -> usize {
    n.div_ceil(16) * 16
}

/// The k (disparity index) whose right pixel x - min - k lies in `0..w`: `lo..hi`.
#[inline]
pub fn valid_ks(x: usize, w: usize, range: DisparityRange) -> (usize, usize) {
    let n = range.count as i64;
    let base = x as i64 - range.min_px as i64; // right x at k = 0
    let lo = (base - (w as i64 - 1)).clamp(0, n);
    let hi = (base + 1).clamp(0, n);
    (lo as usize, hi.max(lo) as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn valid_disparity_indices() {
        let r = DisparityRange::new(-2, 5, 10).unwrap();
        // x = 0: x - d in 0..10 for d in -2..=0 -> k 0..=2.
        assert_eq!(valid_ks(0, 10, r), (0, 3));
        // x = 9: d >= 0 -> k >= 2.
        assert_eq!(valid_ks(9, 10, r), (2, 8));
    }
}
