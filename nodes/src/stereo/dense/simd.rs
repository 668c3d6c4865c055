//! The matchers' inner loops, compiled twice (see [`crate::simd`]): for
//! the baseline target (the scalar fallback, which the compiler still
//! vectorises with SSE2) and for AVX2 + POPCNT, chosen at run time. The loops
//! are plain safe Rust over slices.
//!
//! The lowest layer of the dense matchers: it imports none of them. A matcher
//! whose loop needs its own types (semi-global matching's row pass) compiles
//! it twice with [`kernels!`] in its own module.

pub use crate::simd::Isa;
pub(crate) use crate::simd::kernels;

kernels! {
    /// One census comparison for a whole row: shifts every pixel's byte of
    /// bits left and sets the new bit where the neighbour is darker than the
    /// centre.
    fn census_bits(bits: &mut [u8], neighbour: &[u8], centre: &[u8]) {
        let n = bits.len().min(neighbour.len()).min(centre.len());
        let (bits, neighbour, centre) = (&mut bits[..n], &neighbour[..n], &centre[..n]);
        for i in 0..n {
            bits[i] = (bits[i] << 1) | (neighbour[i] < centre[i]) as u8;
        }
    }

    /// Appends the low `count` (1..=8) bits of each byte to the codes.
    fn shift_in_byte(codes: &mut [u64], bits: &[u8], count: u32) {
        let n = codes.len().min(bits.len());
        let mask = ((1u16 << count) - 1) as u64;
        for (c, &b) in codes[..n].iter_mut().zip(&bits[..n]) {
            *c = (*c << count) | (b as u64 & mask);
        }
    }

    /// `costs[j] = popcount(code ^ right[right.len() - 1 - j])`: Hamming
    /// distances to right codes taken from the end backwards (rising disparity).
    fn hamming_descending(costs: &mut [u8], code: u64, right: &[u64]) {
        let n = costs.len().min(right.len());
        let last = right.len() - n;
        let right = &right[last..];
        for (j, c) in costs[..n].iter_mut().enumerate() {
            *c = (code ^ right[n - 1 - j]).count_ones() as u8;
        }
    }

    /// The lowest of `c`, its first index, and the lowest more than one index
    /// from it (`u16::MAX` when none); `None` for an empty `c`. Whole-vector
    /// minima, then a search of the one 16-lane block that holds the winner.
    fn winner_u16(c: &[u16]) -> Option<(u16, usize, u16)> {
        let min = |s: &[u16]| s.iter().fold(u16::MAX, |a, &b| a.min(b));
        let best = min(c);
        let block = c
            .chunks(16)
            .position(|b| b.iter().fold(false, |f, &v| f | (v == best)))?;
        let k = block * 16 + c[block * 16..].iter().position(|&v| v == best)?;
        let runner_up = min(&c[..k.saturating_sub(1)]).min(min(&c[(k + 2).min(c.len())..]));
        Some((best, k, runner_up))
    }

}

/// Where the intensity refinement's window products are taken: a `side x
/// side` window from row `y0`, the left image's columns from `x_left`, the
/// gradient's from `c`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct DotWindow {
    pub x_left: usize,
    pub c: usize,
    pub y0: usize,
    pub side: usize,
}

/// Sums over a [`DotWindow`] of the left image `left` times the gradient
/// `grad` (columns from `c`, `c + 1`, ... up to `c + N - 1`), images `w` px
/// wide: the products the sub-pixel refinement cannot take from prefix
/// sums. Exact in i32 for grey levels times differences of grey levels over
/// up to 31 x 31 px.
fn window_dots_exact<const N: usize>(
    left: &[i16],
    grad: &[i16],
    w: usize,
    at: DotWindow,
) -> [i32; N] {
    let DotWindow {
        x_left,
        c,
        y0,
        side,
    } = at;
    let mut dots = [0i32; N];
    for j in 0..side {
        let base = (y0 + j) * w;
        let l = &left[base + x_left..base + x_left + side];
        for (k, dot) in dots.iter_mut().enumerate() {
            let g = &grad[base + c + k..base + c + k + side];
            for i in 0..side {
                *dot += l[i] as i32 * g[i] as i32;
            }
        }
    }
    dots
}

impl Isa {
    /// [`window_dots_exact`]; with AVX2, a window up to 16 px wide whose
    /// rows have 16 px of room in both images takes one multiply-add
    /// instruction per row and product (the compiler's own vector code for
    /// 9-wide rows was a quarter as fast).
    #[inline]
    pub(crate) fn window_dots<const N: usize>(
        self,
        left: &[i16],
        grad: &[i16],
        w: usize,
        at: DotWindow,
    ) -> [i32; N] {
        #[cfg(target_arch = "x86_64")]
        if self == Isa::Avx2 && at.side <= 16 && at.side > 0 {
            let last = (at.y0 + at.side - 1) * w;
            if last + at.x_left + 16 <= left.len() && last + at.c + N + 15 <= grad.len() {
                // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the
                // CPU reported AVX2; the function reads through slices it
                // bounds-checks itself.
                return unsafe { window_dots_avx2(left, grad, w, at) };
            }
        }
        window_dots_exact(left, grad, w, at)
    }
}

impl Isa {
    /// Running sums along x of eight columns of integers, interleaved:
    /// `out[0]` is 0 and `out[x + 1][q]` the sum of `cols[q][..=x]`, each
    /// added from the left in f64 (exact while the sums stay under 2^53).
    /// `out` is as long as the shortest column and one more. With AVX2, eight
    /// columns at a time are transposed so that a position's eight values
    /// are added as two vectors.
    pub(crate) fn prefix_sums8(self, cols: [&[i32]; 8], out: &mut Vec<[f64; 8]>) {
        let w = cols.iter().map(|c| c.len()).min().unwrap_or(0);
        out.clear();
        out.resize(w + 1, [0.0; 8]);
        let mut total = [0.0f64; 8];
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if self == Isa::Avx2 {
            // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the CPU
            // reported AVX2; the function reads and writes through slices.
            done = unsafe { prefix_sums8_avx2(cols, &mut out[1..], &mut total) };
        }
        for x in done..w {
            for q in 0..8 {
                total[q] += cols[q][x] as f64;
            }
            out[x + 1] = total;
        }
    }
}

/// [`Isa::prefix_sums8`]'s whole blocks of eight positions into `out` (from
/// position 0, each entry the sums through its position), carrying `total`;
/// returns how many positions it did.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn prefix_sums8_avx2(cols: [&[i32]; 8], out: &mut [[f64; 8]], total: &mut [f64; 8]) -> usize {
    use std::arch::x86_64::*;
    let blocks = out
        .len()
        .min(cols.iter().map(|c| c.len()).min().unwrap_or(0))
        / 8;
    // SAFETY: `total` is 8 f64 (64 bytes); unaligned loads.
    let (mut low, mut high) = unsafe {
        (
            _mm256_loadu_pd(total[..4].as_ptr()),
            _mm256_loadu_pd(total[4..].as_ptr()),
        )
    };
    for b in 0..blocks {
        let x = b * 8;
        let r: [__m256i; 8] = std::array::from_fn(|q| {
            let c = &cols[q][x..x + 8];
            // SAFETY: `c` holds 8 i32 (32 bytes); unaligned load.
            unsafe { _mm256_loadu_si256(c.as_ptr().cast()) }
        });
        // 8 x 8 transpose: t interleaves pairs of quantities, u fours, and
        // `position` takes a whole position's eight from two of u.
        let t: [__m256i; 8] = std::array::from_fn(|i| {
            let (a, b) = (r[i / 2 * 2], r[i / 2 * 2 + 1]);
            if i % 2 == 0 {
                _mm256_unpacklo_epi32(a, b)
            } else {
                _mm256_unpackhi_epi32(a, b)
            }
        });
        let u: [__m256i; 8] = std::array::from_fn(|i| {
            let pair = i / 4 * 4 + i % 4 / 2;
            let (a, b) = (t[pair], t[pair + 2]);
            if i % 2 == 0 {
                _mm256_unpacklo_epi64(a, b)
            } else {
                _mm256_unpackhi_epi64(a, b)
            }
        });
        // Position k of the block: u[k % 4]'s and u[k % 4 + 4]'s low (k < 4)
        // or high 128 bits.
        let position = |k: usize| {
            let (a, b) = (u[k % 4], u[k % 4 + 4]);
            if k < 4 {
                _mm256_permute2x128_si256(a, b, 0x20)
            } else {
                _mm256_permute2x128_si256(a, b, 0x31)
            }
        };
        for k in 0..8 {
            let v = position(k);
            low = _mm256_add_pd(low, _mm256_cvtepi32_pd(_mm256_castsi256_si128(v)));
            high = _mm256_add_pd(high, _mm256_cvtepi32_pd(_mm256_extracti128_si256(v, 1)));
            let entry = &mut out[x + k];
            // SAFETY: `entry` is 8 f64 (64 bytes); unaligned stores.
            unsafe {
                _mm256_storeu_pd(entry[..4].as_mut_ptr(), low);
                _mm256_storeu_pd(entry[4..].as_mut_ptr(), high);
            }
        }
    }
    // SAFETY: `total` is 8 f64; unaligned stores.
    unsafe {
        _mm256_storeu_pd(total[..4].as_mut_ptr(), low);
        _mm256_storeu_pd(total[4..].as_mut_ptr(), high);
    }
    blocks * 8
}

impl Isa {
    /// [`Isa::winner_u16`] of every pixel of a row: pixel x's costs are
    /// `costs[x * stride..x * stride + n]` (`n >= 1`), and `out[x]` gets its
    /// lowest cost, that cost's first index and the lowest cost more than
    /// one index from it (`u16::MAX` when none). With AVX2 the row runs in
    /// one call, each pixel's costs in one pass of 16-lane registers that
    /// keep every lane's lowest, its first index and its second lowest
    /// (the three searches of [`Isa::winner_u16`] read a pixel's costs three
    /// times, from a row of sums too large for the first-level cache).
    pub(crate) fn winners_u16(
        self,
        costs: &[u16],
        stride: usize,
        n: usize,
        out: &mut [(u16, usize, u16)],
    ) {
        if n == 0 {
            return;
        }
        let fits = out.is_empty() || (out.len() - 1) * stride + n <= costs.len();
        #[cfg(target_arch = "x86_64")]
        if self == Isa::Avx2 && (16..=MAX_WINNER_LANES).contains(&n) && fits {
            // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the
            // CPU reported AVX2; the function reads through slices it
            // bounds-checks itself.
            return unsafe { winners_u16_avx2(costs, stride, n, out) };
        }
        for (x, o) in out.iter_mut().enumerate() {
            let Some(c) = costs.get(x * stride..x * stride + n) else {
                return;
            };
            if let Some(w) = self.winner_u16(c) {
                *o = w;
            }
        }
    }
}

/// The most costs per pixel [`Isa::winners_u16`] takes in registers: their
/// indices are compared as signed 16-bit lanes.
const MAX_WINNER_LANES: usize = 1 << 14;

/// [`Isa::winners_u16`] with AVX2, for `16 <= n <= MAX_WINNER_LANES`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn winners_u16_avx2(costs: &[u16], stride: usize, n: usize, out: &mut [(u16, usize, u16)]) {
    use std::arch::x86_64::*;
    /// Sixteen costs from the start of `s` (which must hold them).
    #[inline(always)]
    fn load(s: &[u16]) -> __m256i {
        let s = &s[..16];
        // SAFETY: `s` holds 16 u16 (32 bytes), checked just above; the
        // unaligned load has no alignment requirement.
        unsafe { _mm256_loadu_si256(s.as_ptr().cast()) }
    }
    /// The lowest of the sixteen lanes.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn lowest(v: __m256i) -> u16 {
        let m = _mm_min_epu16(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
        _mm_cvtsi128_si32(_mm_minpos_epu16(m)) as u16
    }
    // One pass over chunks of 16 lanes from 0, and over the lanes past the
    // last whole chunk (loaded as the last 16 costs, the ones already met
    // raised to u16::MAX): every cost is met once, in lane `index % 16`, or
    // `index - (n - 16)` in that last chunk. Each lane keeps its lowest
    // cost, the first index holding it and its second lowest (equal to the
    // lowest where two costs share it); no branch the costs decide.
    let whole = n / 16 * 16;
    let tail = n - 16;
    let iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let step = _mm256_set1_epi16(16);
    let met = _mm256_cmpgt_epi16(_mm256_set1_epi16((whole - tail) as i16), iota);
    let tail_index = _mm256_add_epi16(_mm256_set1_epi16(tail as i16), iota);
    let lane_of = |index: usize| {
        if index < whole {
            index % 16
        } else {
            index - tail
        }
    };
    for (x, o) in out.iter_mut().enumerate() {
        let c = &costs[x * stride..x * stride + n];
        let (mut low, mut second, mut first) = (
            _mm256_set1_epi16(-1),
            _mm256_set1_epi16(-1),
            _mm256_setzero_si256(),
        );
        let mut index = iota;
        let mut take = |v: __m256i, index: __m256i| {
            let lower = _mm256_min_epu16(v, low);
            // Not lower than the lane's lowest so far: its first index stays.
            let kept = _mm256_cmpeq_epi16(lower, low);
            first = _mm256_blendv_epi8(index, first, kept);
            second = _mm256_min_epu16(second, _mm256_max_epu16(v, low));
            low = lower;
        };
        for s in (0..whole).step_by(16) {
            take(load(&c[s..]), index);
            index = _mm256_add_epi16(index, step);
        }
        if whole < n {
            take(_mm256_or_si256(load(&c[tail..]), met), tail_index);
        }
        let best = lowest(low);
        let holds_best = _mm256_cmpeq_epi16(low, _mm256_set1_epi16(best as i16));
        let k = lowest(_mm256_blendv_epi8(_mm256_set1_epi16(-1), first, holds_best)) as usize;
        // The runner-up leaves out k - 1 ..= k + 1, three lanes: in each,
        // its lowest stands unless the cost left out is it, then its
        // second lowest does.
        let mut replaced = _mm256_setzero_si256();
        let beside = k.saturating_sub(1)..(k + 2).min(n);
        for (left_out, &cost) in beside.clone().zip(&c[beside]) {
            let in_lane = _mm256_cmpeq_epi16(iota, _mm256_set1_epi16(lane_of(left_out) as i16));
            let is_low = _mm256_cmpeq_epi16(low, _mm256_set1_epi16(cost as i16));
            replaced = _mm256_or_si256(replaced, _mm256_and_si256(in_lane, is_low));
        }
        let runner_up = lowest(_mm256_blendv_epi8(low, second, replaced));
        *o = (best, k, runner_up);
    }
}

/// [`window_dots_exact`] with AVX2 for `side <= 16`, where every window
/// row has 16 px of room in `left` from `x_left` and in `grad` from
/// `c + N - 1`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn window_dots_avx2<const N: usize>(
    left: &[i16],
    grad: &[i16],
    w: usize,
    at: DotWindow,
) -> [i32; N] {
    use std::arch::x86_64::*;
    /// Sixteen values from the start of `s` (which must hold them).
    #[inline(always)]
    fn load(s: &[i16]) -> __m256i {
        let s = &s[..16];
        // SAFETY: `s` holds 16 i16 (32 bytes), checked just above, and the
        // unaligned load has no alignment requirement.
        unsafe { _mm256_loadu_si256(s.as_ptr().cast()) }
    }
    // Lanes 0 .. side all ones, the rest zero: 16 - side lanes into a row
    // of sixteen -1s and sixteen 0s.
    const ONES_THEN_ZEROS: [i16; 32] = {
        let mut m = [0i16; 32];
        let mut q = 0;
        while q < 16 {
            m[q] = -1;
            q += 1;
        }
        m
    };
    let keep = load(&ONES_THEN_ZEROS[16 - at.side..]);
    let mut acc = [_mm256_setzero_si256(); N];
    for j in 0..at.side {
        let base = (at.y0 + j) * w;
        // The left row masked to the window: lanes past it multiply to 0.
        let l = _mm256_and_si256(load(&left[base + at.x_left..]), keep);
        for (k, acc) in acc.iter_mut().enumerate() {
            let g = load(&grad[base + at.c + k..]);
            *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(l, g));
        }
    }
    acc.map(|v| {
        // The eight lanes' sum: halves added, then pairs.
        let half = _mm_add_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
        let pairs = _mm_add_epi32(half, _mm_shuffle_epi32(half, 0b01_00_11_10));
        let one = _mm_add_epi32(pairs, _mm_shuffle_epi32(pairs, 0b10_11_00_01));
        _mm_cvtsi128_si32(one)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_by_hand() {
        let isa = Isa::detect();
        let mut bits = vec![0b1u8; 5];
        isa.census_bits(&mut bits, &[1, 5, 3, 9, 0], &[2, 2, 2, 2, 2]);
        assert_eq!(bits, [0b11, 0b10, 0b10, 0b10, 0b11]);
        let mut codes = vec![0b1u64; 2];
        isa.shift_in_byte(&mut codes, &[0b1111_0101, 0b11], 3);
        assert_eq!(codes, [0b1101, 0b1011]);
        let mut costs = [0u8; 3];
        isa.hamming_descending(&mut costs, 0b1011, &[0b0000, 0b1000, 0b1011]);
        assert_eq!(costs, [0, 2, 3]);
    }

    /// The row of winners, on every instruction set, is each pixel's own
    /// winner: costs with many ties (the first index counts), winners at
    /// either end and inside, widths that are and are not whole registers.
    #[test]
    fn a_rows_winners_are_each_pixels_own() {
        let mut seed = 11u64;
        let mut next = |m: u64| {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            (seed >> 33) % m
        };
        for n in [1usize, 2, 3, 15, 16, 17, 31, 32, 48, 64, 100, 128] {
            let stride = n.div_ceil(16) * 16 + 3;
            let width = 40;
            // Half the pixels with many ties, half with nearly none (where
            // the costs left out beside the winner are often the lowest of
            // their lane).
            let mut costs: Vec<u16> = (0..width * stride)
                .map(|i| {
                    if i / stride < width / 2 {
                        5 + next(6) as u16
                    } else {
                        next(60_000) as u16
                    }
                })
                .collect();
            // Pixels 0..3: the lowest at the first, second and last index;
            // pixel 3 with its neighbours as low as it (ties beside it).
            for (x, at) in [(0, 0), (1, 1.min(n - 1)), (2, n - 1), (3, n / 2)] {
                costs[x * stride + at] = 1;
            }
            if n > 2 {
                costs[3 * stride + n / 2 - 1] = 1;
                costs[3 * stride + (n / 2 + 1).min(n - 1)] = 1;
            }
            let expect: Vec<(u16, usize, u16)> = (0..width)
                .map(|x| {
                    Isa::Scalar
                        .winner_u16(&costs[x * stride..x * stride + n])
                        .unwrap()
                })
                .collect();
            for isa in [Isa::Scalar, Isa::detect()] {
                let mut got = vec![(0, 0, 0); width];
                isa.winners_u16(&costs, stride, n, &mut got);
                assert_eq!(got, expect, "{isa:?}, {n} costs");
            }
        }
    }

    #[test]
    fn window_dots_agree_on_every_path() {
        let (w, h) = (40usize, 20usize);
        let mut seed = 7u64;
        let mut next = |m: i64| {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((seed >> 33) as i64 % m) as i16
        };
        let left: Vec<i16> = (0..w * h).map(|_| next(256)).collect();
        let grad: Vec<i16> = (0..w * h).map(|_| next(511) - 255).collect();
        let by_hand = |x_left: usize, c: usize, y0: usize, side: usize| {
            let mut dots = [0i32; 3];
            for j in 0..side {
                for i in 0..side {
                    let l = left[(y0 + j) * w + x_left + i] as i32;
                    for (k, dot) in dots.iter_mut().enumerate() {
                        *dot += l * grad[(y0 + j) * w + c + k + i] as i32;
                    }
                }
            }
            dots
        };
        // Windows with room for whole vectors and windows against the
        // image's end (the exact-width path), 1 to 16 px wide.
        for side in [1usize, 3, 9, 15, 16] {
            for (x_left, c, y0) in [(0, 2, 0), (5, 1, 3), (w - side, w - side - 2, h - side)] {
                let [d0, d1, d2] = by_hand(x_left, c, y0, side);
                for isa in [Isa::Scalar, Isa::detect()] {
                    let at = format!("{isa:?} side {side} at ({x_left}, {c}, {y0})");
                    let at_window = DotWindow {
                        x_left,
                        c,
                        y0,
                        side,
                    };
                    assert_eq!(isa.window_dots(&left, &grad, w, at_window), [d0], "{at}");
                    let two = isa.window_dots(&left, &grad, w, at_window);
                    assert_eq!(two, [d0, d1], "{at}");
                    let three = isa.window_dots(&left, &grad, w, at_window);
                    assert_eq!(three, [d0, d1, d2], "{at}");
                }
            }
        }
    }

    #[test]
    fn prefix_sums8_agree_on_every_path() {
        // Whole blocks and a tail, and sums large enough to use f64's range.
        for w in [0usize, 5, 8, 21] {
            let cols: Vec<Vec<i32>> = (0..8)
                .map(|q| {
                    (0..w)
                        .map(|x| (x as i32 * 7919 + q * 104_729) % 200_003 - 90_000 + q * 1_000_000)
                        .collect()
                })
                .collect();
            let cols: [&[i32]; 8] = std::array::from_fn(|q| &cols[q][..]);
            let mut expect = vec![[0.0f64; 8]; w + 1];
            for x in 0..w {
                for q in 0..8 {
                    expect[x + 1][q] = expect[x][q] + cols[q][x] as f64;
                }
            }
            for isa in [Isa::Scalar, Isa::detect()] {
                let mut got = vec![[1.0; 8]; 3];
                isa.prefix_sums8(cols, &mut got);
                assert_eq!(got, expect, "{isa:?}, {w} positions");
            }
        }
    }
}
