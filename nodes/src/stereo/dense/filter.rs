//! Speckle removal: small islands of disparity that disagree with their
//! surroundings are almost always mismatches (OpenCV's filterSpeckles).

/// Invalidates (NaN) every 4-connected region of valid disparities (NaN =
/// invalid) whose neighbours differ by at most `max_diff_px` and that holds at
/// most `max_size` pixels. Returns the number of pixels removed.
pub fn filter_speckles(
    disparity: &mut [f32],
    width: usize,
    height: usize,
    max_size: usize,
    max_diff_px: f32,
) -> usize {
    if max_size == 0 {
        return 0;
    }
    let n = width * height;
    let mut region = vec![u32::MAX; n];
    let mut stack = Vec::new();
    let mut members = Vec::new();
    let mut removed = 0;
    let mut next_label = 0u32;
    for start in 0..n {
        if region[start] != u32::MAX || disparity[start].is_nan() {
            continue;
        }
        let label = next_label;
        next_label += 1;
        region[start] = label;
        // Positions travel with their coordinates: no division per pixel.
        stack.push((start, start % width, start / width));
        members.clear();
        let mut size = 0usize;
        while let Some((p, x, y)) = stack.pop() {
            size += 1;
            // Only a region that may still be a speckle needs its members.
            if size <= max_size + 1 {
                members.push(p);
            }
            let d = disparity[p];
            let mut visit = |q: usize, qx: usize, qy: usize| {
                if region[q] == u32::MAX
                    && !disparity[q].is_nan()
                    && (disparity[q] - d).abs() <= max_diff_px
                {
                    region[q] = label;
                    stack.push((q, qx, qy));
                }
            };
            if x > 0 {
                visit(p - 1, x - 1, y);
            }
            if x + 1 < width {
                visit(p + 1, x + 1, y);
            }
            if y > 0 {
                visit(p - width, x, y - 1);
            }
            if y + 1 < height {
                visit(p + width, x, y + 1);
            }
        }
        if size <= max_size {
            for &p in &members {
                disparity[p] = f32::NAN;
            }
            removed += members.len();
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn removes_small_islands_only() {
        let (w, h) = (8, 6);
        let mut d = vec![10.0f32; w * h];
        // A 2-pixel island of 30 px disparity and a 6-pixel one of 20.
        d[9] = 30.0;
        d[10] = 30.5;
        for p in [33, 34, 35, 41, 42, 43] {
            d[p] = 20.0;
        }
        let removed = filter_speckles(&mut d, w, h, 4, 1.0);
        assert_eq!(removed, 2);
        assert!(d[9].is_nan() && d[10].is_nan());
        assert_eq!(d[33], 20.0);
        assert_eq!(d[0], 10.0);
        // Regions are split where neighbours differ by more than the range.
        let mut e = vec![1.0f32, 1.5, 3.0, 3.2];
        assert_eq!(filter_speckles(&mut e, 4, 1, 2, 0.6), 4);
    }
}
