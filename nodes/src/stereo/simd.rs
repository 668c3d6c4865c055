//! The matchers' inner loops, compiled twice: for the baseline target (the
//! scalar fallback, which the compiler still vectorises with SSE2) and for
//! AVX2 + POPCNT, chosen at run time by [`Isa::detect`]. The loops are plain
//! safe Rust over slices; only the call into the AVX2 build is `unsafe`, and
//! only after the CPU has reported the features it needs.

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
/// AVX2 + POPCNT enabled, and an `Isa` method that picks one.
macro_rules! kernels {
    ($(
        $(#[$doc:meta])*
        fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block
    )*) => {
        impl Isa {
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
                        Isa::Avx2 => unsafe { avx2($($arg),*) },
                        Isa::Scalar => generic($($arg),*),
                    }
                }
            )*
        }
    };
}

kernels! {
    /// One census comparison for a whole row: shifts every code left and sets
    /// the new bit where the neighbour is darker than the centre.
    fn census_bits(codes: &mut [u64], neighbour: &[u8], centre: &[u8]) {
        let n = codes.len().min(neighbour.len()).min(centre.len());
        let (codes, neighbour, centre) = (&mut codes[..n], &neighbour[..n], &centre[..n]);
        for i in 0..n {
            codes[i] = (codes[i] << 1) | (neighbour[i] < centre[i]) as u64;
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
    /// sub-pixel refinement cannot take from prefix sums. Accumulated per
    /// column so the loop is elementwise vector code, not one addition chain.
    fn window_dots(
        left: &[f32],
        grad: &[f32],
        w: usize,
        x_left: usize,
        c: usize,
        y0: usize,
        side: usize,
    ) -> (f32, f32) {
        const MAX: usize = 32;
        let side = side.min(MAX - 1);
        let (mut acc0, mut acc1) = ([0f32; MAX], [0f32; MAX]);
        for j in 0..side {
            let base = (y0 + j) * w;
            let l = &left[base + x_left..base + x_left + side];
            let g0 = &grad[base + c..base + c + side];
            let g1 = &grad[base + c + 1..base + c + 1 + side];
            for i in 0..side {
                acc0[i] += g0[i] * l[i];
                acc1[i] += g1[i] * l[i];
            }
        }
        (acc0[..side].iter().sum(), acc1[..side].iter().sum())
    }

    /// One row of a semi-global aggregation pass ([`super::sgm::row_body`]).
    fn sgm_row(job: &mut super::sgm::RowJob<'_>) {
        super::sgm::row_body(job)
    }
}

/// The recurrence of Hirschmüller's semi-global matching for one pixel:
/// `L(k) = C(k) + min(L'(k), L'(k-1) + P1, L'(k+1) + P1, min L' + P2) - min L'`.
/// For path p, `prev[p]` holds the previous pixel's path costs in lanes
/// 1..=n (lane 0 and n + 1 are large sentinels), `prev_min[p]` their minimum;
/// the new path costs go to lanes 1..=n of `out[p]`, their (saturating) sum
/// over paths to `sum`, and the new minima are returned. `cost` has the n
/// matching costs; `pad` is added to every new cost (0, or a sentinel for
/// lanes past the disparity count, which then never win).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn sgm_pixel_body<const N: usize>(
    cost: &[u8],
    pad: &[u16],
    prev: [&[u16]; N],
    prev_min: [u16; N],
    p1: u16,
    p2: [u16; N],
    out: [&mut [u16]; N],
    sum: &mut [u16],
) -> [u16; N] {
    let n = cost.len();
    let sum = &mut sum[..n];
    let pad = &pad[..n];
    let mut new_min = [u16::MAX; N];
    // One path at a time: each loop is a plain elementwise pass over the
    // disparities that the compiler turns into vector code.
    for (p, out) in out.into_iter().enumerate() {
        let (below, same, above) = (&prev[p][0..n], &prev[p][1..n + 1], &prev[p][2..n + 2]);
        let out = &mut out[1..n + 1];
        let (floor, base) = (prev_min[p], prev_min[p] + p2[p]);
        let mut lowest = u16::MAX;
        // The first path sets the sum, the others add to it, in the same loop
        // (a separate copy would be a call to memcpy per pixel).
        if p == 0 {
            for k in 0..n {
                let m = same[k].min(below[k].min(above[k]) + p1).min(base);
                let v = cost[k] as u16 + m - floor + pad[k];
                out[k] = v;
                sum[k] = v;
                lowest = lowest.min(v);
            }
        } else {
            for k in 0..n {
                let m = same[k].min(below[k].min(above[k]) + p1).min(base);
                let v = cost[k] as u16 + m - floor + pad[k];
                out[k] = v;
                sum[k] = sum[k].saturating_add(v);
                lowest = lowest.min(v);
            }
        }
        new_min[p] = lowest;
    }
    new_min
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_by_hand() {
        let isa = Isa::detect();
        let cost: Vec<u8> = (0..37).map(|k| ((k * 29) % 41) as u8).collect();
        let big = 16383u16;
        let mk = |seed: u16| -> Vec<u16> {
            let mut v: Vec<u16> = (0..39).map(|k| (k as u16 * seed) % 97 + 5).collect();
            (v[0], v[38]) = (big, big);
            v
        };
        let prev = [mk(3), mk(7), mk(11), mk(13)];
        let mins = prev.clone().map(|p| *p[1..38].iter().min().unwrap());
        let mut outs = [
            vec![0u16; 39],
            vec![0u16; 39],
            vec![0u16; 39],
            vec![0u16; 39],
        ];
        let mut sum = vec![0u16; 37];
        let [a, b, c, d] = &mut outs;
        let new_mins = sgm_pixel_body(
            &cost,
            &[0u16; 37],
            [&prev[0], &prev[1], &prev[2], &prev[3]],
            mins,
            8,
            [100, 90, 80, 70],
            [a, b, c, d],
            &mut sum,
        );
        // By hand for path 0, k = 0: min(L'(0), L'(1) + P1, minL' + P2) etc.
        let pr = &prev[0];
        let m = pr[1].min(pr[2] + 8).min(mins[0] + 100);
        assert_eq!(outs[0][1], cost[0] as u16 + m - mins[0]);
        assert_eq!(new_mins[0], *outs[0][1..38].iter().min().unwrap());
        assert_eq!(sum[5], (0..4).map(|p| outs[p][6]).sum::<u16>());

        let mut codes = vec![0u64; 5];
        isa.census_bits(&mut codes, &[1, 5, 3, 9, 0], &[2, 2, 2, 2, 2]);
        assert_eq!(codes, [1, 0, 0, 0, 1]);
        let mut costs = [0u8; 3];
        isa.hamming_descending(&mut costs, 0b1011, &[0b0000, 0b1000, 0b1011]);
        assert_eq!(costs, [0, 2, 3]);
    }
}
