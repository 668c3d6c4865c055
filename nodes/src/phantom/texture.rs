//! Procedural textures: seeded 3D value noise and its fractal sum, used for the
//! skin's fine random texture (what dense stereo matches on), the table cloth and
//! the clutter behind the calibration board.

use nalgebra::Point3;

/// `x.floor()` as an integer. `f64::floor` is a library call on baseline x86-64
/// and shows in render profiles; this is exact for |x| < 2^52.
pub fn fast_floor(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x { i - 1 } else { i }
}

/// Smooth pseudo-random noise in [0, 1] over 3D space, with features about
/// `1 / frequency` mm across.
#[derive(Debug, Clone, Copy)]
pub struct ValueNoise {
    seed: u64,
}

impl ValueNoise {
    /// Noise for `seed`.
    pub fn new(seed: u64) -> Self {
        ValueNoise { seed }
    }

    fn lattice(&self, x: i64, y: i64, z: i64) -> f64 {
        let mut h = self.seed ^ 0x9E37_79B9_7F4A_7C15;
        for v in [x, y, z] {
            h ^= v as u64;
            h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            h ^= h >> 31;
        }
        h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
        h ^= h >> 29;
        (h >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Noise at `p` (mm) with lattice spacing `1 / frequency` mm.
    pub fn at(&self, p: &Point3<f64>, frequency: f64) -> f64 {
        let q = p.coords * frequency;
        let (ix, iy, iz) = (fast_floor(q.x), fast_floor(q.y), fast_floor(q.z));
        let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
        let (tx, ty, tz) = (
            smooth(q.x - ix as f64),
            smooth(q.y - iy as f64),
            smooth(q.z - iz as f64),
        );
        let mut acc = 0.0;
        for corner in 0..8 {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let w = if dx == 1 { tx } else { 1.0 - tx }
                * if dy == 1 { ty } else { 1.0 - ty }
                * if dz == 1 { tz } else { 1.0 - tz };
            acc += w * self.lattice(ix + dx, iy + dy, iz + dz);
        }
        acc
    }

    /// Sum of `octaves` octaves starting at `frequency`, each half as strong and
    /// twice as fine, normalised to [0, 1].
    pub fn fractal(&self, p: &Point3<f64>, frequency: f64, octaves: usize) -> f64 {
        let (mut sum, mut norm, mut amp, mut f) = (0.0, 0.0, 1.0, frequency);
        for _ in 0..octaves {
            sum += amp * self.at(p, f);
            norm += amp;
            amp *= 0.5;
            f *= 2.0;
        }
        sum / norm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_bounded_smooth_and_seeded() {
        let n = ValueNoise::new(4);
        let mut values = Vec::new();
        for i in 0..2000 {
            let p = Point3::new(
                i as f64 * 0.37,
                (i as f64 * 0.11).sin() * 40.0,
                i as f64 * -0.05,
            );
            let v = n.fractal(&p, 0.5, 3);
            assert!((0.0..=1.0).contains(&v));
            // Lipschitz: a 0.01 mm step changes the value very little.
            let w = n.fractal(&(p + nalgebra::Vector3::new(0.01, 0.0, 0.0)), 0.5, 3);
            assert!((v - w).abs() < 0.05);
            values.push(v);
        }
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        assert!((mean - 0.5).abs() < 0.1, "{mean}");
        let other = ValueNoise::new(5).at(&Point3::new(1.3, 2.7, 0.2), 1.0);
        assert_ne!(other, n.at(&Point3::new(1.3, 2.7, 0.2), 1.0));
    }
}
