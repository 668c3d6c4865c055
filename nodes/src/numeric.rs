//! Small numeric helpers the modules share; imports nothing of the crate.
//!
//! `f64::floor` is a library call on baseline x86-64 (the instruction that
//! rounds in place needs SSE4.1), and per-point and per-pixel loops show it
//! in profiles: these give the same integers with a conversion and a compare.

/// `x.floor() as i64` for every `x`: exact wherever the floor fits an i64,
/// saturating beyond it, and 0 for NaN, as the cast of the floor is.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let truncated = x as i64;
    if (truncated as f64) > x {
        truncated.saturating_sub(1)
    } else {
        truncated
    }
}

/// `x.floor() as usize` for every `x`: the cast truncates, which is the
/// floor for `x >= 0`; below 0 (and for NaN) both give 0.
#[inline]
pub fn floor_usize(x: f64) -> usize {
    x as usize
}

/// `x.round().clamp(0.0, 255.0) as u8` for every `x` (NaN gives 0, as the
/// cast does), without the library call `f64::round` is on baseline x86-64:
/// a resampled pixel's grey level. For `0 <= x < 256` the truncation `t`
/// and `x - t` are exact, and halves round up, away from zero, as
/// `f64::round` does.
#[inline]
pub fn round_to_u8(x: f64) -> u8 {
    if x.is_nan() || x < 0.0 {
        return 0;
    }
    if x >= 255.0 {
        return 255;
    }
    let t = x as u8;
    t + u8::from(x - t as f64 >= 0.5)
}

/// `x.round().clamp(0.0, 65535.0) as u16` for every `x` (NaN gives 0), as
/// [`round_to_u8`] does for 8 bits: a stored 16-bit sample.
#[inline]
pub fn round_to_u16(x: f64) -> u16 {
    if x.is_nan() || x < 0.0 {
        return 0;
    }
    if x >= 65535.0 {
        return u16::MAX;
    }
    let t = x as u16;
    t + u16::from(x - t as f64 >= 0.5)
}

/// |q| below this, [`floor_small`] is exact.
pub const EXACT_FLOOR_LIMIT: f64 = 2_251_799_813_685_248.0; // 2^51

/// The floor of `q` for |q| < 2^51 (exact, but for the sign of a zero:
/// -0 gives +0; the caller checks the range), in arithmetic that
/// vectorises: rounding by the magic number 1.5 * 2^52,
/// less one where that rounded up.
#[inline(always)]
pub fn floor_small(q: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52
    let rounded = (q + MAGIC) - MAGIC;
    if rounded > q { rounded - 1.0 } else { rounded }
}

/// `y as u64` (the floor) for `0 <= y < 2^51`, and 0 for NaN and below 0,
/// in arithmetic that vectorises (the saturating cast is a branch per
/// lane): the [`floor_small`] read from the low bits of itself plus 2^52.
#[inline(always)]
pub fn floor_small_u64(y: f64) -> u64 {
    const TWO_POW_52: f64 = 4_503_599_627_370_496.0;
    let y = if y >= 0.0 { y } else { 0.0 };
    (floor_small(y) + TWO_POW_52).to_bits() - TWO_POW_52.to_bits()
}

/// Below this many values, [`kth_smallest_f32`] selects among them all
/// (its histogram would cost more than it saves).
const RADIX_SELECT_MIN: usize = 4096;

/// `v`'s place in `f32::total_cmp`'s order as an unsigned integer: negative
/// values' bits flipped (larger magnitude, smaller key), others with the sign
/// bit set (above every negative).
#[inline(always)]
fn order_key(v: f32) -> u32 {
    let bits = v.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 0x8000_0000
    }
}

/// The value whose [`order_key`] is `key`.
fn from_order_key(key: u32) -> f32 {
    f32::from_bits(if key >> 31 == 1 {
        key & 0x7fff_ffff
    } else {
        !key
    })
}

/// The `k`-th smallest of `values` (0 the smallest) in `f32::total_cmp`'s
/// order: the value `select_nth_unstable_by(k, f32::total_cmp)` puts at
/// `k`, without reordering `values`; `None` where `k` is out of range. A
/// radix select: a histogram of the top 16 bits of each value's order key
/// finds the bucket that holds rank k, and only that bucket's values (a
/// few hundredths of a pixel's residuals, say) are selected among. Two
/// passes, where quickselect partitions several times with a branch per
/// value that the data decide.
pub fn kth_smallest_f32(values: &[f32], k: usize) -> Option<f32> {
    if k >= values.len() {
        return None;
    }
    if values.len() < RADIX_SELECT_MIN || u32::try_from(values.len()).is_err() {
        let mut all = values.to_vec();
        return Some(*all.select_nth_unstable_by(k, f32::total_cmp).1);
    }
    let mut counts = vec![0u32; 1 << 16];
    for &v in values {
        counts[(order_key(v) >> 16) as usize] += 1;
    }
    let mut below = 0usize;
    let bucket = counts.iter().position(|&c| {
        let inside = below + c as usize > k;
        if !inside {
            below += c as usize;
        }
        inside
    })? as u32;
    let mut inside: Vec<u32> = values
        .iter()
        .map(|&v| order_key(v))
        .filter(|key| key >> 16 == bucket)
        .collect();
    Some(from_order_key(*inside.select_nth_unstable(k - below).1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_floors_equal_the_cast_library_floor_everywhere() {
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            -1.0,
            1.0,
            -1e-300,
            2f64.powi(52) + 0.5,
            -(2f64.powi(52) + 0.5),
            2f64.powi(53),
            2f64.powi(63),
            -(2f64.powi(63)),
            -(2f64.powi(63)) - 4096.0,
            2f64.powi(64),
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        values.extend((0..10_000).map(|_| rng.random_range(-1e6..1e6)));
        values.extend((0..1_000).map(|_| rng.random_range(-3.0..3.0)));
        for x in values {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
            assert_eq!(floor_usize(x), x.floor() as usize, "{x}");
        }
    }

    #[test]
    fn rounding_to_a_grey_level_is_the_library_round_clamped() {
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            0.49999999999999994,
            1.5,
            2.5,
            254.5,
            254.49999999999997,
            255.0,
            255.4,
            255.5,
            256.0,
            -0.5,
            -0.49999999999999994,
            -3.0,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
        ];
        values.extend((0..=512).map(|k| k as f64 * 0.5));
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        values.extend((0..20_000).map(|_| rng.random_range(-2.0..258.0)));
        for x in values {
            assert_eq!(round_to_u8(x), x.round().clamp(0.0, 255.0) as u8, "{x}");
        }
    }

    #[test]
    fn rounding_to_a_16_bit_sample_is_the_library_round_clamped() {
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            0.49999999999999994,
            2.5,
            65534.5,
            65534.49999999999,
            65535.0,
            65535.4,
            65535.5,
            65536.0,
            -0.5,
            -0.49999999999999994,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        values.extend((0..=131_072).map(|k| k as f64 * 0.5));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        values.extend((0..20_000).map(|_| rng.random_range(-2.0..65540.0)));
        for x in values {
            assert_eq!(round_to_u16(x), x.round().clamp(0.0, 65535.0) as u16, "{x}");
        }
    }

    #[test]
    fn the_small_floors_are_the_library_floor_and_the_cast() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            255.5,
            0.49999999999999994,
        ];
        // Every half to +-256 and its neighbours on both sides.
        let halves: Vec<f64> = (-512..512).map(|k| k as f64 / 2.0).collect();
        values.extend(halves.iter().flat_map(|h| [h.next_down(), *h, h.next_up()]));
        values.extend((0..20_000).map(|_| rng.random_range(-300.0..300.0)));
        values.extend([EXACT_FLOOR_LIMIT - 0.5, -(EXACT_FLOOR_LIMIT - 0.5)]);
        for q in values {
            // Equal values (the sign of a zero floor may differ).
            assert_eq!(floor_small(q), q.floor(), "{q}");
            assert_eq!(floor_small_u64(q), q as u64, "{q}");
        }
        for y in [f64::NAN, -0.5, -1e-300, f64::NEG_INFINITY] {
            assert_eq!(floor_small_u64(y), 0, "{y}");
        }
    }

    #[test]
    fn the_kth_smallest_is_what_selection_by_total_order_gives() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let special = [
            0.0,
            -0.0,
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            1e-45,
            -1e-45,
        ];
        for n in [1, 7, 100, 4095, 4096, 5000, 60_000] {
            // Residual-like values (many near zero, repeats) and the
            // special ones mixed in.
            let values: Vec<f32> = (0..n)
                .map(|i| match i % 13 {
                    0 => special[rng.random_range(0..special.len())],
                    1 => rng.random_range(-3i32..=3) as f32,
                    _ => rng.random_range(-20.0f32..20.0) * rng.random_range(0.0f32..1.0).powi(3),
                })
                .collect();
            let mut ks = vec![0, n / 2, n - 1];
            ks.extend((0..20).map(|_| rng.random_range(0..n)));
            for k in ks {
                let mut sorted = values.clone();
                let expected = *sorted.select_nth_unstable_by(k, f32::total_cmp).1;
                let got = kth_smallest_f32(&values, k).unwrap();
                assert_eq!(got.to_bits(), expected.to_bits(), "n {n}, k {k}");
            }
            assert_eq!(kth_smallest_f32(&values, n), None);
        }
        assert_eq!(kth_smallest_f32(&[], 0), None);
    }
}
