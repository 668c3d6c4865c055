//! A rectified grey pair and the disparity search range, checked once so every
//! matcher can rely on them.

use fusegraph_engine::value::{Image, Pixels};

/// An 8-bit grey image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// `width * height` grey levels.
    pub data: Vec<u8>,
}

impl GreyImage {
    /// The luma (Rec. 601 weights) of an RGB image, or the grey channel of a
    /// grey one; float images are read as 0..1.
    pub fn from_image(img: &Image) -> Self {
        let n = img.width * img.height;
        let to_u8 = |v: f32| (v * 255.0).round().clamp(0.0, 255.0) as u8;
        let data = match (&img.pixels, img.channels) {
            (Pixels::U8(p), 3) => p
                .chunks_exact(3)
                .map(|c| {
                    ((299 * c[0] as u32 + 587 * c[1] as u32 + 114 * c[2] as u32 + 500) / 1000) as u8
                })
                .collect(),
            (Pixels::U8(p), _) => p.to_vec(),
            (Pixels::F32(p), 3) => p
                .chunks_exact(3)
                .map(|c| to_u8(0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]))
                .collect(),
            (Pixels::F32(p), _) => p.iter().map(|&v| to_u8(v)).collect(),
        };
        debug_assert_eq!(data.len(), n);
        GreyImage {
            width: img.width,
            height: img.height,
            data,
        }
    }

    /// Grey level at (x, y).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }

    /// Row `y`.
    #[inline]
    pub fn row(&self, y: usize) -> &[u8] {
        &self.data[y * self.width..(y + 1) * self.width]
    }
}

/// The disparities searched, `min_px ..= max_px` (integers, px): a pixel at x
/// in the left image is compared with x - d in the right image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DisparityRange {
    /// Smallest disparity searched, px (may be negative for verged rigs).
    pub min_px: i32,
    /// Number of disparities searched.
    pub count: usize,
}

impl DisparityRange {
    /// The range `min_px ..= max_px` for images `width` px wide, or why it
    /// cannot be searched: empty, or wider than the image.
    pub fn new(min_px: i32, max_px: i32, width: usize) -> Result<Self, String> {
        if max_px < min_px {
            return Err(format!(
                "empty disparity range: max {max_px} px is below min {min_px} px"
            ));
        }
        let w = width as i64;
        if max_px as i64 >= w || (min_px as i64) <= -w {
            return Err(format!(
                "disparity range {min_px}..={max_px} px is wider than the image ({width} px): \
                 no pixel could be matched at {}",
                if max_px as i64 >= w { max_px } else { min_px }
            ));
        }
        Ok(DisparityRange {
            min_px,
            count: (max_px - min_px + 1) as usize,
        })
    }

    /// Largest disparity searched, px.
    pub fn max_px(&self) -> i32 {
        self.min_px + self.count as i32 - 1
    }
}

/// Checks that two rectified images can be matched: same size, not empty.
pub fn check_pair(left: &GreyImage, right: &GreyImage) -> Result<(), String> {
    if (left.width, left.height) != (right.width, right.height) {
        return Err(format!(
            "left and right images differ in size: {} x {} and {} x {} px (rectify both with the same rectification)",
            left.width, left.height, right.width, right.height
        ));
    }
    if left.width < 2 || left.height < 2 {
        return Err(format!(
            "images of {} x {} px are too small to match",
            left.width, left.height
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn range_checks() {
        assert_eq!(DisparityRange::new(0, 63, 450).unwrap().count, 64);
        assert_eq!(DisparityRange::new(-8, 7, 450).unwrap().max_px(), 7);
        let e = DisparityRange::new(10, 5, 450).unwrap_err();
        assert!(e.contains("empty"), "{e}");
        let e = DisparityRange::new(0, 450, 450).unwrap_err();
        assert!(e.contains("wider than the image"), "{e}");
        assert!(DisparityRange::new(-450, 0, 450).is_err());
    }

    #[test]
    fn pair_sizes_must_match() {
        let a = GreyImage {
            width: 4,
            height: 3,
            data: vec![0; 12],
        };
        let b = GreyImage {
            width: 3,
            height: 4,
            data: vec![0; 12],
        };
        assert!(check_pair(&a, &b).unwrap_err().contains("differ in size"));
        assert!(check_pair(&a, &a).is_ok());
    }
}
