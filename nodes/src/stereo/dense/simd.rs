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

    /// Sums over a `side x side` window (rows `y0..`) of the left image
    /// `left` (columns from `x_left`) times the gradient `grad` (columns from
    /// `c`, and from `c + 1`), images `w` px wide: the two products the
    /// sub-pixel refinement cannot take from prefix sums. Exact in i32 for
    /// grey levels times differences of grey levels over up to 31 x 31 px.
    fn window_dots_exact(
        left: &[i16],
        grad: &[i16],
        w: usize,
        x_left: usize,
        c: usize,
        y0: usize,
        side: usize,
    ) -> (i32, i32) {
        let (mut dot0, mut dot1) = (0i32, 0i32);
        for j in 0..side {
            let base = (y0 + j) * w;
            let l = &left[base + x_left..base + x_left + side];
            let g0 = &grad[base + c..base + c + side];
            let g1 = &grad[base + c + 1..base + c + 1 + side];
            for i in 0..side {
                dot0 += l[i] as i32 * g0[i] as i32;
                dot1 += l[i] as i32 * g1[i] as i32;
            }
        }
        (dot0, dot1)
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

impl Isa {
    /// [`Isa::window_dots_exact`]; with AVX2, a window up to 16 px wide whose
    /// rows have 16 px of room in both images takes one multiply-add
    /// instruction per row and product (the compiler's own vector code for
    /// 9-wide rows was a quarter as fast).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn window_dots(
        self,
        left: &[i16],
        grad: &[i16],
        w: usize,
        x_left: usize,
        c: usize,
        y0: usize,
        side: usize,
    ) -> (i32, i32) {
        #[cfg(target_arch = "x86_64")]
        if self == Isa::Avx2 && side <= 16 && side > 0 {
            let last = (y0 + side - 1) * w;
            if last + x_left + 16 <= left.len() && last + c + 17 <= grad.len() {
                // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the
                // CPU reported AVX2; the function reads through slices it
                // bounds-checks itself.
                return unsafe { window_dots_avx2(left, grad, w, x_left, c, y0, side) };
            }
        }
        self.window_dots_exact(left, grad, w, x_left, c, y0, side)
    }
}

/// [`Isa::window_dots_exact`] with AVX2 for `side <= 16`, where every window
/// row has 16 px of room in `left` from `x_left` and in `grad` from `c + 1`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn window_dots_avx2(
    left: &[i16],
    grad: &[i16],
    w: usize,
    x_left: usize,
    c: usize,
    y0: usize,
    side: usize,
) -> (i32, i32) {
    use std::arch::x86_64::*;
    /// Sixteen values from the start of `s` (which must hold them).
    #[inline(always)]
    fn load(s: &[i16]) -> __m256i {
        let s = &s[..16];
        // SAFETY: `s` holds 16 i16 (32 bytes), checked just above, and the
        // unaligned load has no alignment requirement.
        unsafe { _mm256_loadu_si256(s.as_ptr().cast()) }
    }
    let keep: [i16; 16] = std::array::from_fn(|q| if q < side { -1 } else { 0 });
    let keep = load(&keep);
    let (mut acc0, mut acc1) = (_mm256_setzero_si256(), _mm256_setzero_si256());
    for j in 0..side {
        let base = (y0 + j) * w;
        // The left row masked to the window: lanes past it multiply to 0.
        let l = _mm256_and_si256(load(&left[base + x_left..]), keep);
        let g0 = load(&grad[base + c..]);
        let g1 = load(&grad[base + c + 1..]);
        acc0 = _mm256_add_epi32(acc0, _mm256_madd_epi16(l, g0));
        acc1 = _mm256_add_epi32(acc1, _mm256_madd_epi16(l, g1));
    }
    let total = |v: __m256i| {
        let mut lanes = [0i32; 8];
        // SAFETY: `lanes` is 8 i32 (32 bytes); unaligned store.
        unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), v) };
        lanes.iter().sum()
    };
    (total(acc0), total(acc1))
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
            let mut dots = (0i32, 0i32);
            for j in 0..side {
                for i in 0..side {
                    let l = left[(y0 + j) * w + x_left + i] as i32;
                    dots.0 += l * grad[(y0 + j) * w + c + i] as i32;
                    dots.1 += l * grad[(y0 + j) * w + c + 1 + i] as i32;
                }
            }
            dots
        };
        // Windows with room for whole vectors and windows against the
        // image's end (the exact-width path), 1 to 16 px wide.
        for side in [1usize, 3, 9, 15, 16] {
            for (x_left, c, y0) in [(0, 2, 0), (5, 1, 3), (w - side, w - side - 1, h - side)] {
                let expect = by_hand(x_left, c, y0, side);
                for isa in [Isa::Scalar, Isa::detect()] {
                    assert_eq!(
                        isa.window_dots(&left, &grad, w, x_left, c, y0, side),
                        expect,
                        "{isa:?} side {side} at ({x_left}, {c}, {y0})"
                    );
                }
            }
        }
    }
}
