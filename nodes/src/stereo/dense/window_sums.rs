//! The slanted refinement's inner loop: the sums over one window of the
//! left image and the right image sampled along the window's warp. Two
//! builds of one computation: a portable kernel (plain Rust, which the
//! compiler vectorises for the baseline) and, on AVX2, the same arithmetic
//! written with intrinsics, whose loads of the right image are gathers. Both give the same bits: the same f32 interpolation, the same
//! f64 products, each accumulated in the same lane in the same order.

use super::simd::Isa;

impl Isa {
    /// Sums over the window of half-size `half` around (`x`, `y`) warped by
    /// `shape` at disparity `d` (see `slanted_window_sums_portable`):
    /// sum(l - r), sum((l - r)^2), sum(g), sum((l - r) g), sum(g^2);
    /// `None` where a warped column leaves the right image's interior.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn slanted_window_sums(
        self,
        left: &[f32],
        right: &[f32],
        w: usize,
        x: isize,
        y: isize,
        half: isize,
        d: f32,
        shape: [f32; 5],
    ) -> Option<[f64; 5]> {
        #[cfg(target_arch = "x86_64")]
        if self == Isa::Avx2 {
            // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the
            // CPU reported AVX2.
            return unsafe { slanted_window_sums_avx2(left, right, w, x, y, half, d, shape) };
        }
        slanted_window_sums_portable(left, right, w, x, y, half, d, shape)
    }
}

/// Lanes of the window kernel's f64 sums (one AVX2 register).
const LANES: usize = 4;

/// A window row's samples, padded to whole lanes: the largest side
/// (`2 * 15 + 1`) rounded up.
const ROW_CAPACITY: usize = 32;

/// 2^23: a float in [2^23, 2^24) holds an integer in its low mantissa bits.
const TWO_POW_23: f32 = 8_388_608.0;

/// 0, 1, 2, ...: a row's column offsets as floats, for whole registers.
const COLUMN: [f32; ROW_CAPACITY] = {
    let mut c = [0.0f32; ROW_CAPACITY];
    let mut k = 0;
    while k < ROW_CAPACITY {
        c[k] = k as f32;
        k += 1;
    }
    c
};

/// One pass of sums over the window of half-size `half` around (`x`,
/// `y`) warped by `shape` at disparity `d` (`left` and `right` row-major
/// grey levels, `w` px wide): sum(l - r), sum((l - r)^2), sum(g),
/// sum((l - r) g), sum(g^2), with r the right image linearly
/// interpolated at the warped column and g its slope there. No buffer
/// per window (this runs for every pixel and iteration): with
/// e = (l - r) - mean(l - r) and gz = g - mean(g), the caller takes
/// sum(e gz) = sum((l - r) g) - n mean(l - r) mean(g) and
/// sum(gz^2) = sum(g^2) - n mean(g)^2 from these. `None` where a warped
/// column leaves the right image's interior. Each row is taken in three
/// passes (columns, the samples they read, the sums) so the first and
/// last vectorise: the loads between them are a gather.
#[allow(clippy::too_many_arguments)]
fn slanted_window_sums_portable(
    left: &[f32],
    right: &[f32],
    w: usize,
    x: isize,
    y: isize,
    half: isize,
    d: f32,
    shape: [f32; 5],
) -> Option<[f64; 5]> {
    let side = (2 * half + 1) as usize;
    if side > ROW_CAPACITY {
        return None;
    }
    let [gx, gy, gxx, gxy, gyy] = shape;
    let (mut x0, mut t) = ([0u32; ROW_CAPACITY], [0.0f32; ROW_CAPACITY]);
    // Lanes past `side` are never written: zeros, they add nothing.
    let (mut l, mut r0, mut r1) = (
        [0.0f32; ROW_CAPACITY],
        [0.0f32; ROW_CAPACITY],
        [0.0f32; ROW_CAPACITY],
    );
    let mut sums = [[0.0f64; LANES]; 5];
    let (lowest, highest) = (1.0f32, (w - 2) as f32);
    let (first, half_f, side_f) = ((x - half) as usize, half as f32, side as f32);
    let first_f = first as f32;
    for j in -half..=half {
        let yy = (y + j) as usize;
        let row = yy * w..(yy + 1) * w;
        let (left_row, right_row) = (&left[row.clone()], &right[row]);
        let jf = j as f32;
        // The warp along this row: d + (gy j + gyy j^2) + (gx + gxy j) i + gxx i^2.
        let (base, linear) = (d + gy * jf + gyy * jf * jf, gx + gxy * jf);
        // Whole registers, past `side` too (those lanes are not read):
        // the warped columns, their floors and fractions.
        let mut outside = 0u32;
        for k in 0..ROW_CAPACITY {
            let (col, i) = (first_f + COLUMN[k], COLUMN[k] - half_f);
            let at = col - (base + linear * i + gxx * i * i);
            let used = COLUMN[k] < side_f;
            outside |= (used & !(at >= lowest && at < highest)) as u32;
            let floor = at.floor();
            // The floor as an integer without a saturating conversion
            // per lane (which does not vectorise): below 2^23 its bits
            // past 2^23 are the integer. Lanes outside are not read.
            x0[k] = (floor + TWO_POW_23)
                .to_bits()
                .wrapping_sub(TWO_POW_23.to_bits());
            t[k] = at - floor;
        }
        if outside != 0 {
            return None;
        }
        for k in 0..side {
            let &[a, b] = right_row[x0[k] as usize..].first_chunk()?;
            (r0[k], r1[k]) = (a, b);
        }
        l[..side].copy_from_slice(&left_row[first..first + side]);
        for lane in (0..side).step_by(LANES) {
            for k in lane..lane + LANES {
                let r = (r0[k] + (r1[k] - r0[k]) * t[k]) as f64;
                // The derivative of what is matched, the interpolated
                // row: its slope between the samples around. (An
                // interpolated central difference is not the cost's
                // gradient, so its fixed point is not the cost's
                // minimum: on the lab phantom at 6 DN it left the
                // disparities 0.01 px lower and their spread 10 % wider.)
                let g = (r1[k] - r0[k]) as f64;
                let lr = l[k] as f64 - r;
                let m = k - lane;
                sums[0][m] += lr;
                sums[1][m] += lr * lr;
                sums[2][m] += g;
                sums[3][m] += lr * g;
                sums[4][m] += g * g;
            }
        }
    }
    Some(sums.map(|s| s.iter().sum()))
}

/// `slanted_window_sums_portable` with AVX2 intrinsics: eight columns of a
/// row at a time, the right samples gathered. The portable kernel's
/// arithmetic operation by operation (no fused multiply-add), so its bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
fn slanted_window_sums_avx2(
    left: &[f32],
    right: &[f32],
    w: usize,
    x: isize,
    y: isize,
    half: isize,
    d: f32,
    shape: [f32; 5],
) -> Option<[f64; 5]> {
    use std::arch::x86_64::*;
    /// Eight floats from the start of `s`.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn load8(s: &[f32]) -> __m256 {
        let s = &s[..8];
        // SAFETY: `s` holds 8 f32 (32 bytes), checked just above; the
        // unaligned load has no alignment requirement.
        unsafe { _mm256_loadu_ps(s.as_ptr()) }
    }
    /// Adds four samples' terms to the sums' four lanes.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn accumulate(sums: &mut [__m256d; 5], r: __m128, g: __m128, l: __m128) {
        let (r, g, l) = (_mm256_cvtps_pd(r), _mm256_cvtps_pd(g), _mm256_cvtps_pd(l));
        let lr = _mm256_sub_pd(l, r);
        sums[0] = _mm256_add_pd(sums[0], lr);
        sums[1] = _mm256_add_pd(sums[1], _mm256_mul_pd(lr, lr));
        sums[2] = _mm256_add_pd(sums[2], g);
        sums[3] = _mm256_add_pd(sums[3], _mm256_mul_pd(lr, g));
        sums[4] = _mm256_add_pd(sums[4], _mm256_mul_pd(g, g));
    }
    /// `row[x0]` and `row[x0 + 1]` in the used lanes (0 in the others)
    /// where every used lane's x0 and x0 + 1 lie in the 16 samples from
    /// lane 0's x0 less 4: two loads and permutes instead of two gathers,
    /// which are slow on every x86 (a window's warped columns move by
    /// about one sample a column, so nearly every chunk fits). `None`
    /// where they do not, or the 16 samples leave the row.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn samples_from_span(row: &[f32], x0: __m256i, used: __m256) -> Option<(__m256, __m256)> {
        let start = _mm256_cvtsi256_si32(x0).checked_sub(4)?;
        let span = row.get(usize::try_from(start).ok()?..)?.get(..16)?;
        let index = _mm256_sub_epi32(x0, _mm256_set1_epi32(start));
        let fits = _mm256_and_si256(
            _mm256_cmpgt_epi32(index, _mm256_set1_epi32(-1)),
            _mm256_cmpgt_epi32(_mm256_set1_epi32(15), index),
        );
        if _mm256_movemask_ps(_mm256_andnot_ps(_mm256_castsi256_ps(fits), used)) != 0 {
            return None;
        }
        let (low, high) = (load8(span), load8(&span[8..]));
        // A lane's index picks from the low eight (0-7) or the high eight
        // (8-15); the permute reads its low three bits.
        let pick = |index: __m256i| {
            let upper = _mm256_castsi256_ps(_mm256_cmpgt_epi32(index, _mm256_set1_epi32(7)));
            let from = _mm256_blendv_ps(
                _mm256_permutevar8x32_ps(low, index),
                _mm256_permutevar8x32_ps(high, index),
                upper,
            );
            _mm256_and_ps(from, used)
        };
        Some((
            pick(index),
            pick(_mm256_add_epi32(index, _mm256_set1_epi32(1))),
        ))
    }
    let side = (2 * half + 1) as usize;
    if side > ROW_CAPACITY || x - half < 0 || y - half < 0 || w < 3 {
        return None;
    }
    let first = (x - half) as usize;
    let last_row = (y + half) as usize;
    if first + side > w || (last_row + 1) * w > left.len().min(right.len()) {
        return None;
    }
    let [gx, gy, gxx, gxy, gyy] = shape;
    let (lowest, highest) = (_mm256_set1_ps(1.0), _mm256_set1_ps((w - 2) as f32));
    let (first_f, half_f) = (_mm256_set1_ps(first as f32), _mm256_set1_ps(half as f32));
    let (gxx_v, side_f) = (_mm256_set1_ps(gxx), _mm256_set1_ps(side as f32));
    let mut sums = [_mm256_setzero_pd(); 5];
    for j in -half..=half {
        let row_start = (y + j) as usize * w;
        let (left_row, right_row) = (
            &left[row_start..row_start + w],
            &right[row_start..row_start + w],
        );
        let jf = j as f32;
        let (base, linear) = (d + gy * jf + gyy * jf * jf, gx + gxy * jf);
        let (base, linear) = (_mm256_set1_ps(base), _mm256_set1_ps(linear));
        for chunk in (0..side).step_by(8) {
            let column = load8(&COLUMN[chunk..]);
            let used_count = (side - chunk).min(8);
            let used = _mm256_cmp_ps::<_CMP_LT_OQ>(column, side_f);
            let col = _mm256_add_ps(first_f, column);
            let i = _mm256_sub_ps(column, half_f);
            // col - ((base + linear i) + (gxx i) i), as the portable kernel.
            let warp = _mm256_add_ps(
                _mm256_add_ps(base, _mm256_mul_ps(linear, i)),
                _mm256_mul_ps(_mm256_mul_ps(gxx_v, i), i),
            );
            let at = _mm256_sub_ps(col, warp);
            let inside = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(at, lowest),
                _mm256_cmp_ps::<_CMP_LT_OQ>(at, highest),
            );
            // A used lane not inside (NaN included) leaves the interior.
            if _mm256_movemask_ps(_mm256_andnot_ps(inside, used)) != 0 {
                return None;
            }
            let floor = _mm256_floor_ps(at);
            let t = _mm256_sub_ps(at, floor);
            let x0 = _mm256_cvttps_epi32(floor);
            let (r0, r1) = match samples_from_span(right_row, x0, used) {
                Some(pair) => pair,
                // SAFETY: every used lane's x0 is in [1, w - 3] (checked
                // just above), so x0 and x0 + 1 index `right_row` (w
                // samples); unused lanes are masked off and read nothing.
                None => unsafe {
                    (
                        _mm256_mask_i32gather_ps::<4>(
                            _mm256_setzero_ps(),
                            right_row.as_ptr(),
                            x0,
                            used,
                        ),
                        _mm256_mask_i32gather_ps::<4>(
                            _mm256_setzero_ps(),
                            right_row.as_ptr(),
                            _mm256_add_epi32(x0, _mm256_set1_epi32(1)),
                            used,
                        ),
                    )
                },
            };
            let l = {
                let l = &left_row[first + chunk..first + chunk + used_count];
                // SAFETY: the mask reads the `used_count` floats `l` holds
                // (its used lanes are its first ones) and no others.
                unsafe { _mm256_maskload_ps(l.as_ptr(), _mm256_castps_si256(used)) }
            };
            let g = _mm256_sub_ps(r1, r0);
            let r = _mm256_add_ps(r0, _mm256_mul_ps(g, t));
            // Unused lanes: r0 = r1 = l = 0, so each of their products is 0.
            // Four lanes of f64 at a time, in the portable kernel's order;
            // a last half with no used lane is skipped, as it skips it.
            accumulate(
                &mut sums,
                _mm256_castps256_ps128(r),
                _mm256_castps256_ps128(g),
                _mm256_castps256_ps128(l),
            );
            if used_count > LANES {
                accumulate(
                    &mut sums,
                    _mm256_extractf128_ps::<1>(r),
                    _mm256_extractf128_ps::<1>(g),
                    _mm256_extractf128_ps::<1>(l),
                );
            }
        }
    }
    Some(sums.map(|s| {
        let mut lanes = [0.0f64; LANES];
        // SAFETY: `lanes` is four f64 (32 bytes); unaligned store.
        unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), s) };
        lanes.iter().sum()
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The window sums as first written: one scalar loop, sample by
    /// sample.
    #[allow(clippy::too_many_arguments)]
    fn window_sums_by_sample(
        left: &[f32],
        right: &[f32],
        w: usize,
        x: isize,
        y: isize,
        half: isize,
        d: f32,
        [gx, gy, gxx, gxy, gyy]: [f32; 5],
    ) -> Option<[f64; 5]> {
        let mut sums = [0.0f64; 5];
        for j in -half..=half {
            let row = (y + j) as usize * w;
            let jf = j as f32;
            let (base, linear) = (d + gy * jf + gyy * jf * jf, gx + gxy * jf);
            for ii in -half..=half {
                let i = ii as f32;
                let xr = (x + ii) as f32 - (base + linear * i + gxx * i * i);
                if xr < 1.0 || xr >= (w - 2) as f32 {
                    return None;
                }
                let x0 = xr.floor() as usize;
                let (r0, r1) = (right[row + x0], right[row + x0 + 1]);
                let r = (r0 + (r1 - r0) * (xr - x0 as f32)) as f64;
                let g = (r1 - r0) as f64;
                let lr = left[row + (x + ii) as usize] as f64 - r;
                for (s, v) in sums.iter_mut().zip([lr, lr * lr, g, lr * g, g * g]) {
                    *s += v;
                }
            }
        }
        Some(sums)
    }

    #[test]
    fn the_window_kernel_sums_what_the_plain_loop_sums_on_every_instruction_set() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (w, h) = (90, 40);
        let image = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f32> {
            (0..w * h)
                .map(|_| rng.random_range(0..256) as f32)
                .collect()
        };
        let (left, right) = (image(&mut rng), image(&mut rng));
        let (mut compared, mut outside) = (0, 0);
        // Mild warps (nearly every chunk's samples from one span of 16) and
        // steep ones (gathered: a column moves by 2-3 samples).
        for k in 0..600 {
            let steep = k % 3 == 2;
            let half = rng.random_range(1..=15i64) as isize;
            let (x, y) = (
                rng.random_range(half as i64..w as i64 - half as i64) as isize,
                rng.random_range(half as i64..h as i64 - half as i64) as isize,
            );
            let d = rng.random_range(-3.0..20.0f32);
            let shape = [
                if steep {
                    rng.random_range(1.5..2.5f32) * if rng.random_bool(0.5) { 1.0 } else { -1.0 }
                } else {
                    rng.random_range(-0.5..0.5f32)
                },
                rng.random_range(-0.5..0.5f32),
                rng.random_range(-0.02..0.02f32),
                rng.random_range(-0.02..0.02f32),
                rng.random_range(-0.02..0.02f32),
            ];
            let plain = window_sums_by_sample(&left, &right, w, x, y, half, d, shape);
            for isa in [Isa::Scalar, Isa::detect()] {
                let kernel = isa.slanted_window_sums(&left, &right, w, x, y, half, d, shape);
                match (plain, kernel) {
                    (Some(a), Some(b)) => {
                        for (a, b) in a.iter().zip(b) {
                            assert!((a - b).abs() <= 1e-9 * a.abs().max(1.0), "{a} vs {b}");
                        }
                        compared += 1;
                    }
                    (None, None) => outside += 1,
                    (a, b) => panic!("plain loop {a:?}, kernel on {isa:?} {b:?}"),
                }
                // Every build gives the portable kernel's bits (the
                // refinement's figures do not depend on the machine).
                let portable = slanted_window_sums_portable(&left, &right, w, x, y, half, d, shape);
                let bits = |s: Option<[f64; 5]>| s.map(|s| s.map(f64::to_bits));
                assert_eq!(bits(kernel), bits(portable), "{isa:?}, half {half}");
            }
        }
        assert!(
            compared > 300 && outside > 20,
            "{compared} compared, {outside} outside"
        );
    }
}
