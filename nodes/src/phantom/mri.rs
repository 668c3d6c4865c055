//! Synthetic MRI of the phantom: partial-volume voxel intensities (supersampled
//! where a voxel straddles a boundary), a smooth multiplicative bias field and
//! Rician noise, on an axial (optionally oblique) grid in patient LPS mm.

use super::row_materials::RowMaterials;
use super::shape::{Material, PhantomShape};
use fusegraph_engine::value::Grid;
use nalgebra::{Isometry3, Point3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

/// How to image the phantom.
#[derive(Debug, Clone, PartialEq)]
pub struct MriParams {
    /// Voxel spacing along i (columns), j (rows), k (slices), mm.
    pub spacing_mm: [f64; 3],
    /// Samples per axis inside a voxel that straddles a boundary.
    pub supersample: usize,
    /// Empty space around the phantom, mm.
    pub margin_mm: f64,
    /// Rotation of the slice plane about the patient x axis, deg (0 = axial).
    pub oblique_deg: f64,
    /// Standard deviation of the complex Gaussian noise (signal units; tissue = 0.55).
    pub noise_sigma: f64,
    /// Peak relative deviation of the bias field (0.1 = +-10 %).
    pub bias_amplitude: f64,
    /// Seed of the noise and the bias field.
    pub seed: u64,
}

/// Noise-free signal of each material, as on a T1-weighted scan: fat-like tissue
/// bright, petroleum jelly brighter, plastic and air dark, the lesions at
/// `lesion_signal` (0.35 by default: darker).
pub fn signal_of(material: Material, lesion_signal: f32) -> f32 {
    match material {
        Material::Background | Material::Plastic => 0.0,
        Material::Tissue => 0.55,
        Material::Lesion => lesion_signal,
        Material::Gel => 1.0,
    }
}

/// A grid covering the phantom (in patient coordinates, via `phantom_to_mri`),
/// with the slice orientation of `p`.
pub fn covering_grid(shape: &PhantomShape, phantom_to_mri: &Isometry3<f64>, p: &MriParams) -> Grid {
    let axes = Rotation3::from_axis_angle(&Vector3::x_axis(), p.oblique_deg.to_radians());
    let (lo, hi) = phantom_bounds(shape);
    let mut min = Vector3::repeat(f64::INFINITY);
    let mut max = Vector3::repeat(f64::NEG_INFINITY);
    for corner in 0..8 {
        let c = Point3::new(
            if corner & 1 == 0 { lo.x } else { hi.x },
            if corner & 2 == 0 { lo.y } else { hi.y },
            if corner & 4 == 0 { lo.z } else { hi.z },
        );
        let in_grid_axes = axes.inverse() * (phantom_to_mri * c).coords;
        min = min.inf(&in_grid_axes);
        max = max.sup(&in_grid_axes);
    }
    min -= Vector3::repeat(p.margin_mm);
    max += Vector3::repeat(p.margin_mm);
    let dims: [usize; 3] =
        std::array::from_fn(|a| ((max[a] - min[a]) / p.spacing_mm[a]).ceil() as usize + 1);
    let origin = axes * min;
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            m[r][c] = axes[(r, c)] * p.spacing_mm[c];
        }
        m[r][3] = origin[r];
    }
    m[3][3] = 1.0;
    Grid {
        dims,
        voxel_to_patient: m,
    }
}

/// Axis-aligned bounds of the phantom (dome and markers) in its own frame, mm.
fn phantom_bounds(shape: &PhantomShape) -> (Point3<f64>, Point3<f64>) {
    let r = shape.rotation();
    let a = Vector3::from(shape.semi_axes_mm);
    let c = Vector3::from(shape.ellipsoid_center_mm);
    // Half-extent of a rotated ellipsoid along world axis e: sqrt(sum_j (R_ej a_j)^2).
    let half = Vector3::from_fn(|e, _| {
        (0..3)
            .map(|j| (r[(e, j)] * a[j]).powi(2))
            .sum::<f64>()
            .sqrt()
    });
    let mut lo = Point3::from(c - half);
    let mut hi = Point3::from(c + half);
    lo.z = 0.0;
    for m in &shape.markers {
        let reach = Vector3::repeat(m.height_mm + m.radius_mm);
        lo = lo.inf(&(Point3::from(m.skin_point_mm) - reach));
        hi = hi.sup(&(Point3::from(m.skin_point_mm) + reach));
    }
    (lo, hi)
}

/// How far a voxel position computed through the grid's affine map may stray
/// from the straight line of its row, mm (rounding, with room to spare).
const ROUNDING_MM: f64 = 1e-6;

/// The noisy MR signal of every voxel of `grid` (f32, in [`Grid::index`] order).
pub fn synthesize(
    shape: &PhantomShape,
    phantom_to_mri: &Isometry3<f64>,
    grid: &Grid,
    p: &MriParams,
) -> Vec<f32> {
    let [nx, ny, nz] = grid.dims;
    let mri_to_phantom = phantom_to_mri.inverse();
    let at_voxel =
        |i: f64, j: f64, k: f64| mri_to_phantom * Point3::from(grid.to_patient([i, j, k]));
    // The shape near the line of voxel positions (j, k) from i = `from` to
    // `to`, give or take `margin_mm`: each row meets few markers and lesions.
    let near_row = |(from, to): (f64, f64), j: f64, k: f64, margin_mm: f64| {
        shape.near_segment(&at_voxel(from, j, k), &at_voxel(to, j, k), margin_mm)
    };
    // The line of positions (j, k) from i = `from` (t = 0) by `count`
    // unit steps, which the materials along the row are classified by
    // where no part is near (the positions stray from it by rounding only).
    let row_line = |from: f64, count: usize, j: f64, k: f64| {
        let start = at_voxel(from, j, k);
        let step = (at_voxel(from + count as f64, j, k) - start) / count.max(1) as f64;
        (start, step)
    };
    // Materials at voxel corners, to find the voxels that straddle a boundary.
    let (cx, cy) = (nx + 1, ny + 1);
    let corners: Vec<Material> = (0..nz + 1)
        .into_par_iter()
        .flat_map_iter(|k| {
            let (k, at_voxel) = (k as f64 - 0.5, &at_voxel);
            (0..cy).flat_map(move |j| {
                let j = j as f64 - 0.5;
                let near = near_row((-0.5, nx as f64 - 0.5), j, k, ROUNDING_MM);
                let (start, step) = row_line(-0.5, nx, j, k);
                let row = RowMaterials::new(shape, &near, (&start, &step), nx as f64, ROUNDING_MM);
                (0..cx)
                    .map(|i| row.material_at(i as f64, || at_voxel(i as f64 - 0.5, j, k)))
                    .collect::<Vec<_>>()
            })
        })
        .collect();
    let corner = |i: usize, j: usize, k: usize| corners[i + cx * (j + cy * k)];
    let n = p.supersample.max(1);
    let sub: Vec<f64> = (0..n).map(|s| (s as f64 + 0.5) / n as f64 - 0.5).collect();
    // The sub-samples' (dj, dk) offsets, in the order they are summed.
    let sub_offsets: Vec<(f64, f64)> = sub
        .iter()
        .flat_map(|&dk| sub.iter().map(move |&dj| (dj, dk)))
        .collect();
    // Every sample of a voxel lies within half its diagonal of its centre.
    let half_diagonal_mm = 0.5 * Vector3::from(grid.spacing_mm()).norm() + ROUNDING_MM;
    let bias = BiasField::new(shape, p.seed, p.bias_amplitude);
    let noise = Normal::new(0.0, p.noise_sigma.max(0.0)).expect("finite sigma");
    let mut signal = vec![0.0f32; nx * ny * nz];
    signal
        .par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(k, slice)| {
            let mut rng =
                ChaCha8Rng::seed_from_u64(p.seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            for j in 0..ny {
                let near = near_row((0.0, (nx - 1) as f64), j as f64, k as f64, half_diagonal_mm);
                let (start, step) = row_line(0.0, nx - 1, j as f64, k as f64);
                let span = (nx - 1) as f64;
                let row = RowMaterials::new(shape, &near, (&start, &step), span, ROUNDING_MM);
                // The rows of sub-samples (dj, dk) along the voxels, from i =
                // -1/2 (t = 0), once a voxel of the row straddles a boundary.
                let mut sub_rows: Vec<RowMaterials> = Vec::new();
                for i in 0..nx {
                    let c0 = corner(i, j, k);
                    let centre = at_voxel(i as f64, j as f64, k as f64);
                    let pure = (0..8)
                        .all(|b| corner(i + (b & 1), j + ((b >> 1) & 1), k + (b >> 2)) == c0)
                        && row.material_at(i as f64, || centre) == c0;
                    let clean = if pure {
                        signal_of(c0, shape.lesion_signal)
                    } else {
                        if sub_rows.is_empty() {
                            sub_rows = sub_offsets
                                .iter()
                                .map(|&(dj, dk)| {
                                    let line = row_line(-0.5, nx, j as f64 + dj, k as f64 + dk);
                                    let t_max = nx as f64;
                                    RowMaterials::new(
                                        shape,
                                        &near,
                                        (&line.0, &line.1),
                                        t_max,
                                        ROUNDING_MM,
                                    )
                                })
                                .collect();
                        }
                        let mut sum = 0.0f32;
                        for (row, &(dj, dk)) in sub_rows.iter().zip(&sub_offsets) {
                            for &di in &sub {
                                let (i, j, k) = (i as f64, j as f64, k as f64);
                                let material = row
                                    .material_at(i + di + 0.5, || at_voxel(i + di, j + dj, k + dk));
                                sum += signal_of(material, shape.lesion_signal);
                            }
                        }
                        sum / (n * n * n) as f32
                    };
                    let s = clean as f64 * bias.at(&centre);
                    let (re, im) = (s + noise.sample(&mut rng), noise.sample(&mut rng));
                    slice[i + nx * j] = (re * re + im * im).sqrt() as f32;
                }
            }
        });
    signal
}

/// A smooth multiplicative field over the phantom, like a receive coil's
/// sensitivity: 1 + amplitude * (seeded low-order polynomial in [-1, 1]).
struct BiasField {
    center: Vector3<f64>,
    scale: f64,
    coefficients: [f64; 5],
    amplitude: f64,
}

impl BiasField {
    fn new(shape: &PhantomShape, seed: u64, amplitude: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_add(0xB1A5));
        let mut coefficients: [f64; 5] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let total: f64 = coefficients.iter().map(|c| c.abs()).sum();
        coefficients.iter_mut().for_each(|c| *c /= total.max(1e-9));
        let a = Vector3::from(shape.semi_axes_mm);
        BiasField {
            center: Vector3::new(0.0, 0.0, 0.5 * a.z),
            scale: a.max(),
            coefficients,
            amplitude,
        }
    }

    fn at(&self, p: &Point3<f64>) -> f64 {
        let q = (p.coords - self.center) / self.scale;
        let (u, v, w) = (
            q.x.clamp(-1.0, 1.0),
            q.y.clamp(-1.0, 1.0),
            q.z.clamp(-1.0, 1.0),
        );
        let c = &self.coefficients;
        1.0 + self.amplitude
            * (c[0] * u + c[1] * v + c[2] * w + c[3] * u * v + c[4] * (w * w - 0.5))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::shape::ShapeParams;

    fn params(spacing: f64) -> MriParams {
        MriParams {
            spacing_mm: [spacing; 3],
            supersample: 4,
            margin_mm: 5.0,
            oblique_deg: 0.0,
            noise_sigma: 0.0,
            bias_amplitude: 0.0,
            seed: 3,
        }
    }

    #[test]
    fn partial_volume_preserves_gel_volume_and_centre() {
        let shape = PhantomShape::build(&ShapeParams::default(), &mut ChaCha8Rng::seed_from_u64(1))
            .unwrap();
        let to_mri = Isometry3::new(Vector3::new(3.0, -20.0, 7.0), Vector3::new(0.05, -0.1, 0.2));
        let p = params(1.0);
        let grid = covering_grid(&shape, &to_mri, &p);
        let signal = synthesize(&shape, &to_mri, &grid, &p);
        // Gel voxels of marker 0: signal above tissue level near its centre.
        let m = &shape.markers[0];
        let centre = to_mri * m.gel_center();
        let (skin, axis) = (
            to_mri * Point3::from(m.skin_point_mm),
            to_mri * Vector3::from(m.normal),
        );
        let (mut sum, mut weighted) = (0.0, Vector3::zeros());
        for k in 0..grid.dims[2] {
            for j in 0..grid.dims[1] {
                for i in 0..grid.dims[0] {
                    let pos = Point3::from(grid.to_patient([i as f64, j as f64, k as f64]));
                    let h = (pos - skin).dot(&axis);
                    let radial = ((pos - skin).norm_squared() - h * h).sqrt();
                    // Voxels wholly inside the marker's disc or above it: gel,
                    // plastic and air only, no tissue.
                    if (1.0..=5.5).contains(&h) && radial <= 4.0 {
                        let s = signal[grid.index(i, j, k)] as f64;
                        sum += s;
                        weighted += pos.coords * s;
                    }
                }
            }
        }
        // The gel has signal 1 and the rest 0, so the sum is the gel volume in
        // mm3 (1 mm voxels).
        let gel_volume =
            std::f64::consts::PI * m.gel_radius_mm.powi(2) * (m.gel_span_mm[1] - m.gel_span_mm[0]);
        assert!(
            (sum - gel_volume).abs() < 0.01 * gel_volume,
            "{sum} vs {gel_volume}"
        );
        let found = weighted / sum;
        assert!((found - centre.coords).norm() < 0.05, "{found} vs {centre}");
    }

    #[test]
    fn noise_is_rician_and_deterministic() {
        let shape = PhantomShape::build(&ShapeParams::default(), &mut ChaCha8Rng::seed_from_u64(1))
            .unwrap();
        let to_mri = Isometry3::identity();
        let p = MriParams {
            noise_sigma: 0.02,
            ..params(3.0)
        };
        let grid = covering_grid(&shape, &to_mri, &p);
        let a = synthesize(&shape, &to_mri, &grid, &p);
        let b = synthesize(&shape, &to_mri, &grid, &p);
        assert_eq!(a, b);
        // Corner voxels are air: Rayleigh-distributed, mean sigma * sqrt(pi / 2).
        let air: Vec<f64> = (0..grid.dims[0])
            .map(|i| a[grid.index(i, 0, 0)] as f64)
            .collect();
        let mean = air.iter().sum::<f64>() / air.len() as f64;
        assert!(air.iter().all(|&x| x >= 0.0));
        assert!(
            (mean - 0.02 * (std::f64::consts::PI / 2.0).sqrt()).abs() < 0.008,
            "{mean}"
        );
    }

    #[test]
    fn oblique_grids_cover_the_phantom() {
        let shape = PhantomShape::build(&ShapeParams::default(), &mut ChaCha8Rng::seed_from_u64(1))
            .unwrap();
        let p = MriParams {
            oblique_deg: 20.0,
            ..params(2.0)
        };
        let grid = covering_grid(&shape, &Isometry3::identity(), &p);
        let m = grid.voxel_to_patient;
        // Slice normal tilted by 20 deg from patient z.
        let normal = Vector3::new(m[0][2], m[1][2], m[2][2]).normalize();
        assert!((normal.z.acos().to_degrees() - 20.0).abs() < 1e-9);
        let signal = synthesize(&shape, &Isometry3::identity(), &grid, &p);
        let tissue = signal.iter().filter(|&&s| s > 0.5).count() as f64 * 8.0;
        assert!(tissue > 250_000.0 && tissue < 600_000.0, "{tissue} mm3");
    }
}
