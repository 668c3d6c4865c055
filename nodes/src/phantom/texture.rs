//! Procedural textures: seeded 3D value noise and its fractal sum, used for the
//! skin's fine random texture (what dense stereo matches on), the table cloth and
//! the clutter behind the calibration board.

use crate::numeric::floor_i64;
use nalgebra::Point3;

/// The lattice cell holding `p` (mm) at lattice spacing `1 / frequency` mm:
/// its lowest corner, and `p`'s position in it along each axis eased by
/// smoothstep (0..1).
fn cell(p: &Point3<f64>, frequency: f64) -> ([i64; 3], [f64; 3]) {
    let q = p.coords * frequency;
    let (ix, iy, iz) = (floor_i64(q.x), floor_i64(q.y), floor_i64(q.z));
    let smooth = |t: f64| t * t * (3.0 - 2.0 * t);
    (
        [ix, iy, iz],
        [
            smooth(q.x - ix as f64),
            smooth(q.y - iy as f64),
            smooth(q.z - iz as f64),
        ],
    )
}

/// The lattice cell [`ValueNoise::at_near`] met last: the noise's seed,
/// the cell's lowest corner and its corner values.
#[derive(Debug, Clone, Default)]
pub struct RecentCell(Option<(u64, [i64; 3], [f64; 8])>);

impl RecentCell {
    /// No cell met yet.
    pub const EMPTY: RecentCell = RecentCell(None);
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

    /// The hash's state after mixing in one more coordinate.
    fn mix(h: u64, v: i64) -> u64 {
        let h = (h ^ v as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^ (h >> 31)
    }

    /// The lattice value from the hash's state after all three coordinates,
    /// in [0, 1).
    fn finish(h: u64) -> f64 {
        let h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
        // Under 2^53, so exact as a signed integer too, whose conversion is
        // one instruction (an unsigned one is several on baseline x86-64).
        ((h ^ (h >> 29)) >> 11) as i64 as f64 / (1u64 << 53) as f64
    }

    #[cfg(test)]
    fn lattice(&self, x: i64, y: i64, z: i64) -> f64 {
        let h = self.seed ^ 0x9E37_79B9_7F4A_7C15;
        Self::finish(Self::mix(Self::mix(Self::mix(h, x), y), z))
    }

    /// The lattice values at the eight corners of the cell whose lowest
    /// corner is (ix, iy, iz), indexed dx | dy << 1 | dz << 2.
    fn corner_values(&self, [ix, iy, iz]: [i64; 3]) -> [f64; 8] {
        // The corners share their hashes' prefixes: 2 states after x, 4
        // after y, 8 after z (14 mixes instead of 24).
        let start = self.seed ^ 0x9E37_79B9_7F4A_7C15;
        let mut value = [0.0; 8];
        for dx in 0..2 {
            let hx = Self::mix(start, ix + dx);
            for dy in 0..2 {
                let hy = Self::mix(hx, iy + dy);
                for dz in 0..2 {
                    value[(dx | dy << 1 | dz << 2) as usize] = Self::finish(Self::mix(hy, iz + dz));
                }
            }
        }
        value
    }

    /// Noise at `p` (mm) with lattice spacing `1 / frequency` mm: the
    /// definition [`ValueNoise::at_near`] is tested against.
    #[cfg(test)]
    pub fn at(&self, p: &Point3<f64>, frequency: f64) -> f64 {
        let (lowest, weights) = cell(p, frequency);
        Self::interpolate(&self.corner_values(lowest), weights)
    }

    /// [`ValueNoise::at`] for a run of nearby points, such as the rays of
    /// a row of pixels: the corner values of the cell `recent` holds are
    /// not hashed again (they depend on the seed and the cell alone, not
    /// on the frequency: the same bits).
    pub fn at_near(&self, p: &Point3<f64>, frequency: f64, recent: &mut RecentCell) -> f64 {
        let (lowest, weights) = cell(p, frequency);
        match &recent.0 {
            // Compared a coordinate at a time: the cell was stored as three
            // words, and a wider load of them just after (a vector compare)
            // stalls waiting for the stores.
            Some((seed, [x, y, z], values))
                if *seed == self.seed && *x == lowest[0] && *y == lowest[1] && *z == lowest[2] =>
            {
                Self::interpolate(values, weights)
            }
            _ => {
                let values = self.corner_values(lowest);
                recent.0 = Some((self.seed, lowest, values));
                Self::interpolate(&values, weights)
            }
        }
    }

    /// The trilinear mix of a cell's corner values at eased position
    /// `weights` in it.
    fn interpolate(value: &[f64; 8], [tx, ty, tz]: [f64; 3]) -> f64 {
        let mut acc = 0.0;
        for (corner, v) in value.iter().enumerate() {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let w = if dx == 1 { tx } else { 1.0 - tx }
                * if dy == 1 { ty } else { 1.0 - ty }
                * if dz == 1 { tz } else { 1.0 - tz };
            acc += w * v;
        }
        acc
    }

    /// Sum of `octaves` octaves starting at `frequency`, each half as strong and
    /// twice as fine, normalised to [0, 1]: the definition
    /// [`ValueNoise::fractal_near`] is tested against.
    #[cfg(test)]
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

    /// [`ValueNoise::fractal`] with `recent.len()` octaves for a run of
    /// nearby points: each octave's cell is remembered in its own
    /// `recent` (the coarse octaves' cells span several pixels; the same
    /// bits).
    pub fn fractal_near(&self, p: &Point3<f64>, frequency: f64, recent: &mut [RecentCell]) -> f64 {
        let (mut sum, mut norm, mut amp, mut f) = (0.0, 0.0, 1.0, frequency);
        for octave in recent {
            sum += amp * self.at_near(p, f, octave);
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

    /// The noise as first written: each corner hashed on its own.
    fn noise_by_corners(n: &ValueNoise, p: &Point3<f64>, frequency: f64) -> f64 {
        let ([ix, iy, iz], [tx, ty, tz]) = cell(p, frequency);
        let mut acc = 0.0;
        for corner in 0..8i64 {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, corner >> 2);
            let w = if dx == 1 { tx } else { 1.0 - tx }
                * if dy == 1 { ty } else { 1.0 - ty }
                * if dz == 1 { tz } else { 1.0 - tz };
            acc += w * n.lattice(ix + dx, iy + dy, iz + dz);
        }
        acc
    }

    #[test]
    fn shared_hash_prefixes_give_the_same_bits() {
        let n = ValueNoise::new(11);
        for i in 0..5000 {
            let p = Point3::new(
                i as f64 * 0.731 - 900.0,
                (i as f64 * 0.013).cos() * 300.0,
                i as f64 * -0.217,
            );
            for f in [1.0 / 40.0, 1.0 / 1.6, 2.5] {
                assert_eq!(n.at(&p, f).to_bits(), noise_by_corners(&n, &p, f).to_bits());
            }
        }
    }

    #[test]
    fn noise_near_the_last_point_gives_the_same_bits() {
        let n = ValueNoise::new(7);
        for f in [1.0 / 40.0, 0.9] {
            let mut recent = RecentCell::default();
            let mut cells = std::collections::HashSet::new();
            for i in 0..3000 {
                // A slanted line, crossing cells now and then, and back.
                let s = if i < 1500 { i } else { 3000 - i } as f64 * 0.05;
                let p = Point3::new(s - 37.0, 0.3 * s + 2.0, -0.7 * s);
                cells.insert(cell(&p, f).0);
                let near = n.at_near(&p, f, &mut recent);
                assert_eq!(
                    near.to_bits(),
                    n.at(&p, f).to_bits(),
                    "point {i}, frequency {f}"
                );
            }
            assert!(cells.len() > 3, "{} cells", cells.len());
        }
        // One cell shared by two noises and two frequencies, alternately.
        let (other, mut recent) = (ValueNoise::new(8), RecentCell::default());
        for i in 0..200 {
            let p = Point3::new(0.3 + 1e-3 * i as f64, 0.1, 0.2);
            for (noise, f) in [(&n, 1.0), (&other, 1.0), (&n, 0.5)] {
                let near = noise.at_near(&p, f, &mut recent);
                assert_eq!(near.to_bits(), noise.at(&p, f).to_bits(), "point {i}");
            }
        }
    }

    #[test]
    fn fractal_near_the_last_point_gives_the_same_bits() {
        let n = ValueNoise::new(3);
        let mut recent = [RecentCell::EMPTY, RecentCell::EMPTY, RecentCell::EMPTY];
        for i in 0..4000 {
            // Along a curve with small steps (shared coarse cells), then
            // jumping about (none shared), with two and three octaves.
            let s = if i < 2000 {
                i as f64 * 0.07
            } else {
                (i * 7919 % 2000) as f64
            };
            let p = Point3::new(s.sin() * 30.0 - 2.0, 0.4 * s, -0.3 * s + 5.0);
            let octaves = 2 + i % 2;
            let near = n.fractal_near(&p, 1.0 / 1.6, &mut recent[..octaves]);
            assert_eq!(
                near.to_bits(),
                n.fractal(&p, 1.0 / 1.6, octaves).to_bits(),
                "point {i}"
            );
        }
    }

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
