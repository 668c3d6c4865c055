//! Inner loops compiled twice: for the baseline target (the scalar
//! fallback, which the compiler still vectorises with SSE2) and for AVX2 +
//! POPCNT, chosen at run time by [`Isa::detect`]. The loops are plain safe
//! Rust over slices; only the call into the AVX2 build is `unsafe`, and only
//! after the CPU has reported the features it needs. No multiply and add are
//! fused (Rust never contracts them), so both builds give the same bits.
//!
//! Used by the dense matchers (`stereo`), the MRI filters and the
//! phantom's renderer; imports nothing of the crate.

/// The instruction set the kernels run with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// Baseline x86-64 / any other architecture.
    Scalar,
    /// x86-64 with AVX2 and POPCNT.
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Isa {
    /// The best instruction set this CPU supports.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            return Isa::Avx2;
        }
        Isa::Scalar
    }
}

/// Defines each kernel once as an always-inlined body, a copy compiled with
/// AVX2 + POPCNT enabled, and an `Isa` method that picks one. Usable from any
/// module (`use crate::simd::kernels;`); the method's argument types
/// must be visible where it is invoked.
macro_rules! kernels {
    ($(
        $(#[$doc:meta])*
        fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block
    )*) => {
        impl $crate::simd::Isa {
            $(
                $(#[$doc])*
                #[inline]
                #[allow(clippy::too_many_arguments)]
                pub(crate) fn $name(self, $($arg: $ty),*) $(-> $ret)? {
                    #[inline(always)]
                    #[allow(clippy::too_many_arguments)]
                    fn generic($($arg: $ty),*) $(-> $ret)? $body

                    #[cfg(target_arch = "x86_64")]
                    #[target_feature(enable = "avx2,popcnt")]
                    #[allow(clippy::too_many_arguments)]
                    fn avx2($($arg: $ty),*) $(-> $ret)? { generic($($arg),*) }

                    match self {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the
                        // CPU reported AVX2 and POPCNT, the only features `avx2`
                        // is compiled with beyond the baseline; the body is safe code.
                        $crate::simd::Isa::Avx2 => unsafe { avx2($($arg),*) },
                        $crate::simd::Isa::Scalar => generic($($arg),*),
                    }
                }
            )*
        }
    };
}
pub(crate) use kernels;

/// Outputs a weighted sum keeps in registers across its taps.
const SUM_BLOCK: usize = 32;

/// `out[i] = sum over t of weights[t] * tap(t)[i]`, each output summed from
/// 0 in tap order (the bits of adding the taps' products one tap at a time);
/// every tap is at least `out.len()` long. A block of outputs stays in
/// registers while every tap is added, where a tap at a time over the whole
/// run loaded and stored each output once a tap.
#[inline(always)]
fn weighted_sum_by<'a>(out: &mut [f32], weights: &[f32], tap: impl Fn(usize) -> &'a [f32]) {
    let n = out.len();
    let full = n - n % SUM_BLOCK;
    for start in (0..full).step_by(SUM_BLOCK) {
        let mut acc = [0.0f32; SUM_BLOCK];
        for (t, &w) in weights.iter().enumerate() {
            let src: &[f32; SUM_BLOCK] = tap(t)[start..start + SUM_BLOCK]
                .try_into()
                .expect("a block's run is a block long");
            for (a, &s) in acc.iter_mut().zip(src) {
                *a += w * s;
            }
        }
        out[start..start + SUM_BLOCK].copy_from_slice(&acc);
    }
    let tail = &mut out[full..];
    tail.fill(0.0);
    for (t, &w) in weights.iter().enumerate() {
        for (o, &s) in tail.iter_mut().zip(&tap(t)[full..n]) {
            *o += w * s;
        }
    }
}

kernels! {
    /// A correlation along a run: `out[i] = sum over t of weights[t] *
    /// src[i + t * step]`, summed from 0 in tap order (the convolutions'
    /// inner loop, in the MRI filters and the phantom's blur). `src` must
    /// reach `out.len() + (weights.len() - 1) * step`.
    fn correlate(out: &mut [f32], src: &[f32], weights: &[f32], step: usize) {
        weighted_sum_by(out, weights, |t| &src[t * step..])
    }

    /// `out[i] = sum over t of weights[t] * rows[t][i]`, summed from 0 in
    /// tap order (a convolution across rows); every row is at least
    /// `out.len()` long.
    fn weighted_rows(out: &mut [f32], rows: &[&[f32]], weights: &[f32]) {
        weighted_sum_by(out, weights, |t| rows[t])
    }
}

impl Isa {
    /// Row `y` of `rows` (row-major, each `row_len` floats) convolved across
    /// the rows with `kernel` (odd length, centred), rows past either end
    /// clamped to the nearest, into `out` (`row_len` long): each output
    /// summed from 0 in kernel order. Inside, the taps' rows lie one row
    /// apart ([`Isa::correlate`]); at the ends they are gathered.
    pub(crate) fn convolve_across_rows(
        self,
        out: &mut [f32],
        rows: &[f32],
        row_len: usize,
        y: usize,
        kernel: &[f32],
    ) {
        if row_len == 0 {
            return;
        }
        let (n, r) = (rows.len() / row_len, kernel.len() / 2);
        if y >= r && y + r < n {
            self.correlate(out, &rows[row_len * (y - r)..], kernel, row_len);
        } else {
            let taps: Vec<&[f32]> = (0..kernel.len())
                .map(|t| {
                    let at = (y + t).saturating_sub(r).min(n - 1);
                    &rows[row_len * at..row_len * (at + 1)]
                })
                .collect();
            self.weighted_rows(out, &taps, kernel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The weighted sums as the convolutions first took them: the outputs
    /// zeroed, then each tap's products added over the whole run.
    fn tap_by_tap(n: usize, weights: &[f32], tap: impl Fn(usize) -> Vec<f32>) -> Vec<f32> {
        let mut out = vec![0.0f32; n];
        for (t, &w) in weights.iter().enumerate() {
            for (o, s) in out.iter_mut().zip(tap(t)) {
                *o += w * s;
            }
        }
        out
    }

    #[test]
    fn weighted_sums_have_the_tap_by_tap_bits_on_every_instruction_set() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
        for n in [0, 1, 7, 31, 32, 33, 64, 95, 200] {
            for taps in [1, 3, 13, 41] {
                let weights: Vec<f32> = (0..taps).map(|_| rng.random_range(-0.2..0.6)).collect();
                let step = rng.random_range(1..5);
                let src: Vec<f32> = (0..n + (taps - 1) * step + 3)
                    .map(|_| rng.random_range(-1e3..1e3))
                    .collect();
                let rows: Vec<Vec<f32>> = (0..taps)
                    .map(|_| (0..n + 2).map(|_| rng.random_range(-1e3..1e3)).collect())
                    .collect();
                let row_refs: Vec<&[f32]> = rows.iter().map(|r| &r[..]).collect();
                let along = tap_by_tap(n, &weights, |t| src[t * step..t * step + n].to_vec());
                let across = tap_by_tap(n, &weights, |t| rows[t][..n].to_vec());
                for isa in [Isa::Scalar, Isa::detect()] {
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    let mut out = vec![f32::NAN; n];
                    isa.correlate(&mut out, &src, &weights, step);
                    assert_eq!(bits(&out), bits(&along), "{isa:?}: n {n}, {taps} taps");
                    let mut out = vec![f32::NAN; n];
                    isa.weighted_rows(&mut out, &row_refs, &weights);
                    assert_eq!(bits(&out), bits(&across), "{isa:?}: n {n}, {taps} taps");
                }
            }
        }
    }

    #[test]
    fn rows_convolved_across_clamp_at_both_ends() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(22);
        let (row_len, n) = (45, 9);
        let rows: Vec<f32> = (0..row_len * n)
            .map(|_| rng.random_range(0.0..255.0))
            .collect();
        let kernel: Vec<f32> = (0..7).map(|_| rng.random_range(0.0..0.3)).collect();
        for y in 0..n {
            let want = tap_by_tap(row_len, &kernel, |t| {
                let at = (y as isize + t as isize - 3).clamp(0, n as isize - 1) as usize;
                rows[row_len * at..row_len * (at + 1)].to_vec()
            });
            for isa in [Isa::Scalar, Isa::detect()] {
                let mut out = vec![f32::NAN; row_len];
                isa.convolve_across_rows(&mut out, &rows, row_len, y, &kernel);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&out), bits(&want), "{isa:?}, row {y}");
            }
        }
    }
}
