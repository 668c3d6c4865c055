//! Census-transform stereo matching with winner-takes-all over box-aggregated
//! Hamming costs (Zabih & Woodfill 1994), a left-right check and parabola
//! sub-pixel refinement. Plain functions on plain buffers; memory O(width x
//! height), whatever the disparity range: one cost plane at a time.

/// Matching settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CensusParams {
    /// Census window width and height, px (odd; area at most 64 bits).
    pub census: [usize; 2],
    /// Side of the square window the costs are summed over, px (odd).
    pub aggregate: usize,
    /// Lowest and highest disparity, px (`x_left - x_right`).
    pub range: [i32; 2],
    /// Largest left-right disagreement kept, px (negative: no check).
    pub lr_max_diff_px: f32,
    /// The best cost must be this % below the second best (not adjacent).
    pub uniqueness_pct: f32,
}

/// Census codes of a grey image: bit `k` set where the k-th window pixel is
/// darker than the centre. Pixels whose window leaves the image get 0.
pub fn census_transform(grey: &[u8], width: usize, height: usize, window: [usize; 2]) -> Vec<u64> {
    let (hw, hh) = (window[0] / 2, window[1] / 2);
    let mut out = vec![0u64; width * height];
    for y in hh..height.saturating_sub(hh) {
        for x in hw..width.saturating_sub(hw) {
            let centre = grey[y * width + x];
            let mut code = 0u64;
            for dy in 0..window[1] {
                let row = &grey[(y + dy - hh) * width + x - hw..][..window[0]];
                for &v in row {
                    code = (code << 1) | (v < centre) as u64;
                }
            }
            out[y * width + x] = code;
        }
    }
    out
}

/// Box sums of `plane` over `side x side` windows (clamped at the borders),
/// through a summed-area table.
fn box_sum(
    plane: &[u16],
    width: usize,
    height: usize,
    side: usize,
    out: &mut [u32],
    sat: &mut [u32],
) {
    let w1 = width + 1;
    for y in 0..height {
        let mut row = 0u32;
        for x in 0..width {
            row += plane[y * width + x] as u32;
            sat[(y + 1) * w1 + x + 1] = sat[y * w1 + x + 1] + row;
        }
    }
    let r = side / 2;
    for y in 0..height {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(height));
        for x in 0..width {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(width));
            out[y * width + x] =
                sat[y1 * w1 + x1] + sat[y0 * w1 + x0] - sat[y0 * w1 + x1] - sat[y1 * w1 + x0];
        }
    }
}

/// Per pixel: the best and second-best cost and disparity, and the costs
/// beside the best for the parabola.
#[derive(Clone, Copy)]
struct Best {
    cost: u32,
    d: i32,
    second: u32,
    below: u32,
    above: u32,
}

impl Best {
    const NONE: Best = Best {
        cost: u32::MAX,
        d: i32::MIN,
        second: u32::MAX,
        below: u32::MAX,
        above: u32::MAX,
    };

    fn offer(&mut self, cost: u32, d: i32, previous: u32) {
        if cost < self.cost {
            if self.d != d - 1 {
                self.second = self.second.min(self.cost);
            }
            *self = Best {
                cost,
                d,
                second: self.second,
                below: previous,
                above: u32::MAX,
            };
        } else if d == self.d + 1 {
            self.above = cost;
        } else {
            self.second = self.second.min(cost);
        }
    }

    fn disparity(&self, uniqueness_pct: f32) -> f32 {
        if self.cost == u32::MAX {
            return f32::NAN;
        }
        if self.second != u32::MAX
            && (self.cost as f32) > (1.0 - uniqueness_pct / 100.0) * self.second as f32
        {
            return f32::NAN;
        }
        let d = self.d as f32;
        if self.below == u32::MAX || self.above == u32::MAX {
            return d;
        }
        let (a, b, c) = (self.below as f32, self.cost as f32, self.above as f32);
        let denom = a - 2.0 * b + c;
        if denom > 0.0 {
            d + 0.5 * (a - c) / denom
        } else {
            d
        }
    }
}

/// Disparities (px, NaN = none) of the left image of a rectified grey pair.
pub fn census_match(
    left: &[u8],
    right: &[u8],
    width: usize,
    height: usize,
    p: &CensusParams,
) -> Vec<f32> {
    let cl = census_transform(left, width, height, p.census);
    let cr = census_transform(right, width, height, p.census);
    let n = width * height;
    let mut plane = vec![0u16; n];
    let mut agg = vec![0u32; n];
    let mut previous = vec![u32::MAX; n];
    let mut sat = vec![0u32; (width + 1) * (height + 1)];
    let mut best_left = vec![Best::NONE; n];
    let mut best_right = vec![Best::NONE; n];
    // A cost where the right pixel is outside the image: never the best.
    let outside = (p.census[0] * p.census[1]) as u16 + 1;
    for d in p.range[0]..=p.range[1] {
        for y in 0..height {
            for x in 0..width {
                let xr = x as i64 - d as i64;
                plane[y * width + x] = if xr >= 0 && (xr as usize) < width {
                    (cl[y * width + x] ^ cr[y * width + xr as usize]).count_ones() as u16
                } else {
                    outside
                };
            }
        }
        box_sum(&plane, width, height, p.aggregate, &mut agg, &mut sat);
        let full = outside as u32 * (p.aggregate * p.aggregate) as u32;
        for y in 0..height {
            for x in 0..width {
                let i = y * width + x;
                let xr = x as i64 - d as i64;
                if xr < 0 || xr as usize >= width || agg[i] >= full {
                    previous[i] = u32::MAX;
                    continue;
                }
                best_left[i].offer(agg[i], d, previous[i]);
                // The same cost seen from right pixel xr.
                let j = y * width + xr as usize;
                let before = if best_right[j].d == d - 1 {
                    best_right[j].cost
                } else {
                    u32::MAX
                };
                best_right[j].offer(agg[i], d, before);
                previous[i] = agg[i];
            }
        }
    }
    let mut out = vec![f32::NAN; n];
    for y in 0..height {
        for x in 0..width {
            let b = &best_left[y * width + x];
            let d = b.disparity(p.uniqueness_pct);
            if d.is_nan() {
                continue;
            }
            if p.lr_max_diff_px >= 0.0 {
                let xr = x as i64 - b.d as i64;
                if xr < 0 || xr as usize >= width {
                    continue;
                }
                let dr = best_right[y * width + xr as usize].d;
                if (dr - b.d).abs() as f32 > p.lr_max_diff_px {
                    continue;
                }
            }
            out[y * width + x] = d;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_dot(w: usize, h: usize, seed: u64) -> Vec<u8> {
        let mut s = seed;
        (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect()
    }

    fn params() -> CensusParams {
        CensusParams {
            census: [7, 5],
            aggregate: 5,
            range: [0, 15],
            lr_max_diff_px: 1.0,
            uniqueness_pct: 5.0,
        }
    }

    #[test]
    fn census_codes_by_hand() {
        // 3 x 3 around a centre of 5: bits for the pixels darker than it.
        let grey = [1, 9, 1, 9, 5, 9, 1, 9, 1];
        let c = census_transform(&grey, 3, 3, [3, 3]);
        assert_eq!(c[4], 0b101_000_101);
        assert_eq!(c[0], 0, "the window leaves the image");
    }

    #[test]
    fn box_sums_equal_direct_sums() {
        let (w, h) = (13, 9);
        let plane: Vec<u16> = (0..w * h).map(|i| (i * 7 % 11) as u16).collect();
        let (mut out, mut sat) = (vec![0; w * h], vec![0; (w + 1) * (h + 1)]);
        box_sum(&plane, w, h, 5, &mut out, &mut sat);
        for y in 0..h {
            for x in 0..w {
                let mut s = 0u32;
                for yy in y.saturating_sub(2)..(y + 3).min(h) {
                    for xx in x.saturating_sub(2)..(x + 3).min(w) {
                        s += plane[yy * w + xx] as u32;
                    }
                }
                assert_eq!(out[y * w + x], s, "{x},{y}");
            }
        }
    }

    #[test]
    fn a_constant_shift_is_found_exactly_away_from_the_borders() {
        let (w, h, shift) = (80, 40, 6usize);
        let base = random_dot(w + shift, h, 3);
        let crop = |off: usize| -> Vec<u8> {
            (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| base[y * (w + shift) + x + off])
                .collect()
        };
        let (left, right) = (crop(0), crop(shift));
        let d = census_match(&left, &right, w, h, &params());
        let mut checked = 0;
        for y in 5..h - 5 {
            for x in shift + 8..w - 8 {
                let v = d[y * w + x];
                assert!((v - shift as f32).abs() < 0.1, "{x},{y}: {v}");
                checked += 1;
            }
        }
        assert!(checked > 1500);
    }
}
