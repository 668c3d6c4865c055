//! Volume filters on anisotropic voxel grids (spacing in mm per axis, as MRI
//! slices are usually thicker than their pixels): separable Gaussian
//! smoothing, the Laplacian, the exact Euclidean distance to a mask's outside
//! and hole filling. Written here: the ndarray image crates take one sigma in
//! voxels for every axis and no voxel spacing, which would blur a scan with
//! 0.6 x 0.6 x 1.0 mm voxels unevenly in millimetres.
//!
//! Volumes are `f32` (or `u8` masks) with i fastest, then j, then k, as
//! [`fusegraph_engine::value::Grid::index`] lays them out.

use crate::simd::Isa;
use rayon::prelude::*;

/// The volume smoothed by a Gaussian of standard deviation `sigma_mm` along
/// every axis (`spacing_mm` the voxel spacing), kernel cut at 3 sigma; the
/// edges repeat the border voxel. A zero sigma leaves the volume as it is.
pub fn gaussian_smooth(
    data: &[f32],
    dims: [usize; 3],
    spacing_mm: [f64; 3],
    sigma_mm: f64,
) -> Vec<f32> {
    gaussian_smooth_owned(data.to_vec(), dims, spacing_mm, sigma_mm)
}

/// [`gaussian_smooth`] of a volume the caller hands over: it is smoothed in
/// its own memory (a plane's scratch per task), so one volume is held, not
/// two.
pub fn gaussian_smooth_owned(
    mut data: Vec<f32>,
    dims: [usize; 3],
    spacing_mm: [f64; 3],
    sigma_mm: f64,
) -> Vec<f32> {
    for (axis, spacing) in spacing_mm.iter().enumerate() {
        let sigma_vox = sigma_mm / spacing.max(1e-9);
        if sigma_vox < 1e-3 {
            continue;
        }
        let kernel = gaussian_kernel(sigma_vox);
        convolve_axis_in_place(&mut data, dims, axis, &kernel);
    }
    data
}

/// A normalised Gaussian kernel of `sigma` samples, radius ceil(3 sigma).
fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let radius = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|x| (-0.5 * (x as f64 / sigma).powi(2)).exp())
        .collect();
    let total: f64 = weights.iter().sum();
    weights.iter().map(|w| (w / total) as f32).collect()
}

/// `data` convolved in place along one axis with the odd-length `kernel`,
/// borders clamped: each line of the axis is copied out and its outputs
/// written back (along i a row, along j a slice, along k the rows of one j
/// in every slice). Along j and k whole rows are weighted and summed
/// (contiguous, so they vectorise, with AVX2 where the CPU has it), a block
/// of outputs held in registers across the taps ([`Isa::correlate`]). Each
/// output is summed in kernel order, as [`convolve_axis_into`] sums it (the
/// same bits).
fn convolve_axis_in_place(data: &mut [f32], dims: [usize; 3], axis: usize, kernel: &[f32]) {
    let [nx, ny, nz] = dims;
    let radius = kernel.len() / 2;
    let isa = Isa::detect();
    // Rows `lines` of `nx` values, as copied out: the outputs along them.
    let smooth_rows = |rows: &mut [&mut [f32]], copy: &mut Vec<f32>| {
        copy.clear();
        rows.iter().for_each(|r| copy.extend_from_slice(r));
        for (own, row_out) in rows.iter_mut().enumerate() {
            isa.convolve_across_rows(row_out, copy, nx, own, kernel);
        }
    };
    match axis {
        0 => data
            .par_chunks_mut(nx)
            .for_each_init(Vec::new, |copy, row| {
                copy.clear();
                copy.extend_from_slice(row);
                let copy = &*copy;
                let clamped = |i: usize| {
                    let mut s = 0.0f32;
                    for (t, w) in kernel.iter().enumerate() {
                        let at =
                            (i as isize + t as isize - radius as isize).clamp(0, nx as isize - 1);
                        s += w * copy[at as usize];
                    }
                    s
                };
                if nx > 2 * radius {
                    // Inside, no clamping: a correlation along the row
                    // (vectorised across outputs), each output still
                    // summed in kernel order.
                    isa.correlate(&mut row[radius..nx - radius], copy, kernel, 1);
                    for i in (0..radius).chain(nx - radius..nx) {
                        row[i] = clamped(i);
                    }
                } else {
                    for (i, o) in row.iter_mut().enumerate() {
                        *o = clamped(i);
                    }
                }
            }),
        1 => data
            .par_chunks_mut(nx * ny)
            .for_each_init(Vec::new, |copy, slice| {
                let mut rows: Vec<&mut [f32]> = slice.chunks_mut(nx).collect();
                smooth_rows(&mut rows, copy);
            }),
        _ => {
            // Row j of every slice, for each j: disjoint, so they are
            // handed out as groups of mutable rows.
            let mut lines: Vec<Vec<&mut [f32]>> = (0..ny).map(|_| Vec::with_capacity(nz)).collect();
            for (r, row) in data.chunks_mut(nx).enumerate() {
                lines[r % ny].push(row);
            }
            lines
                .par_iter_mut()
                .for_each_init(Vec::new, |copy, rows| smooth_rows(rows, copy));
        }
    }
}

/// `data` convolved along one axis with the odd-length `kernel`, borders
/// clamped, into `out`: the reference [`convolve_axis_in_place`] is
/// checked against.
#[cfg(test)]
fn convolve_axis_into(
    data: &[f32],
    out: &mut [f32],
    dims: [usize; 3],
    axis: usize,
    kernel: &[f32],
) {
    let [nx, ny, nz] = dims;
    let radius = (kernel.len() / 2) as isize;
    // Along j and k the taps accumulate into the output.
    if axis != 0 {
        out.par_iter_mut().for_each(|o| *o = 0.0);
    }
    out.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(k, slice)| {
            for j in 0..ny {
                let row_out = &mut slice[nx * j..nx * (j + 1)];
                match axis {
                    0 => {
                        let row = &data[nx * (j + ny * k)..][..nx];
                        let r = radius as usize;
                        for (i, o) in row_out.iter_mut().enumerate() {
                            let mut s = 0.0f32;
                            if i >= r && i + r < nx {
                                // Inside: a plain window, no clamping per
                                // tap, summed in the same order.
                                for (w, v) in kernel.iter().zip(&row[i - r..=i + r]) {
                                    s += w * v;
                                }
                            } else {
                                for (t, w) in kernel.iter().enumerate() {
                                    let at = (i as isize + t as isize - radius)
                                        .clamp(0, nx as isize - 1);
                                    s += w * row[at as usize];
                                }
                            }
                            *o = s;
                        }
                    }
                    _ => {
                        let (n, own) = if axis == 1 { (ny, j) } else { (nz, k) };
                        for (t, &w) in kernel.iter().enumerate() {
                            let at = (own as isize + t as isize - radius).clamp(0, n as isize - 1)
                                as usize;
                            let start = if axis == 1 {
                                nx * (at + ny * k)
                            } else {
                                nx * (j + ny * at)
                            };
                            for (o, v) in row_out.iter_mut().zip(&data[start..start + nx]) {
                                *o += w * v;
                            }
                        }
                    }
                }
            }
        });
}

/// The Laplacian (sum of second central differences, per mm^2) of a volume;
/// zero on the border voxels.
pub fn laplacian(data: &[f32], dims: [usize; 3], spacing_mm: [f64; 3]) -> Vec<f32> {
    let mut out = vec![0.0f32; data.len()];
    laplacian_into(data, &mut out, dims, spacing_mm);
    out
}

/// [`laplacian`] written into `out` (a volume of the same size, whose
/// memory is reused).
pub fn laplacian_into(data: &[f32], out: &mut [f32], dims: [usize; 3], spacing_mm: [f64; 3]) {
    let [nx, ny, nz] = dims;
    let inv: [f32; 3] = std::array::from_fn(|a| (1.0 / (spacing_mm[a] * spacing_mm[a])) as f32);
    out.par_iter_mut().for_each(|o| *o = 0.0);
    out.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each(|(k, slice)| {
            if k == 0 || k + 1 >= nz {
                return;
            }
            for j in 1..ny.saturating_sub(1) {
                for i in 1..nx.saturating_sub(1) {
                    let c = i + nx * (j + ny * k);
                    let v = 2.0 * data[c];
                    slice[i + nx * j] = (data[c - 1] + data[c + 1] - v) * inv[0]
                        + (data[c - nx] + data[c + nx] - v) * inv[1]
                        + (data[c - nx * ny] + data[c + nx * ny] - v) * inv[2];
                }
            }
        });
}

/// For every voxel of `mask` (non-zero = inside), its Euclidean distance in
/// mm to the nearest voxel outside (0 outside); voxels beyond the volume's
/// edge count as outside. Exact, by Felzenszwalb and Huttenlocher's
/// separable lower envelope of parabolas ("Distance transforms of sampled
/// functions", Theory of Computing 8, 2012), one axis at a time.
///
/// The first axis needs no envelope: its samples are 0 or infinite, so each
/// voxel's squared distance is the step to the nearest 0 along its row,
/// squared, as the envelope would give it. Lines that are all 0 (outside),
/// most of a scan's, stay 0 and are skipped; the rest reuse one scratch
/// per task, and the lines along j and k are taken a tile of neighbouring
/// columns at a time, so each row is read in runs, not a voxel a line.
pub fn distance_to_outside_mm(mask: &[u8], dims: [usize; 3], spacing_mm: [f64; 3]) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    let slice_len = nx * ny;
    // Neighbouring lines along j and k are transformed this many at a time.
    const TILE: usize = 64;
    if mask.is_empty() {
        return Vec::new();
    }
    let mut d2: Vec<f64> = vec![0.0; mask.len()];
    // Along i: the nearest outside voxel (or the edge) on each side.
    let step2 = spacing_mm[0] * spacing_mm[0];
    d2.par_chunks_mut(nx)
        .zip(mask.par_chunks(nx))
        .for_each(|(row, inside)| nearest_outside_along_row(inside, row, step2));
    // Along j each slice's lines stay in the slice: slices in parallel.
    let step2 = spacing_mm[1] * spacing_mm[1];
    d2.par_chunks_mut(slice_len).for_each_init(
        || (Envelope::new(ny), Vec::new()),
        |(envelope, tile), slice| {
            for start in (0..nx).step_by(TILE) {
                let columns = start..(start + TILE).min(nx);
                if envelope.transform_tile(slice, nx, columns.clone(), step2, tile) {
                    put_tile(slice, nx, columns, tile);
                }
            }
        },
    );
    // Along k a line crosses every slice: tiles of neighbouring columns are
    // transformed in parallel, then written back slice by slice.
    let step2 = spacing_mm[2] * spacing_mm[2];
    let tiles: Vec<Option<Vec<f64>>> = (0..slice_len.div_ceil(TILE))
        .into_par_iter()
        .map_init(
            || Envelope::new(nz),
            |envelope, t| {
                let columns = t * TILE..((t + 1) * TILE).min(slice_len);
                let mut tile = Vec::new();
                envelope
                    .transform_tile(&d2, slice_len, columns, step2, &mut tile)
                    .then_some(tile)
            },
        )
        .collect();
    d2.par_chunks_mut(slice_len)
        .enumerate()
        .for_each(|(k, slice)| {
            for (t, tile) in tiles.iter().enumerate() {
                let Some(tile) = tile else { continue };
                let start = t * TILE;
                let width = tile.len() / nz;
                for (c, v) in slice[start..start + width].iter_mut().enumerate() {
                    *v = tile[c * nz + k];
                }
            }
        });
    drop(tiles);
    // In place: the f32 distances reuse the squared distances' memory.
    d2.into_iter().map(|v| v.sqrt() as f32).collect()
}

/// Writes a tile from [`Envelope::transform_tile`] back to the rows of
/// `volume` it came from.
fn put_tile(volume: &mut [f64], row_stride: usize, columns: std::ops::Range<usize>, tile: &[f64]) {
    let n = tile.len() / columns.len();
    for r in 0..n {
        let row = &mut volume[r * row_stride + columns.start..r * row_stride + columns.end];
        for (c, v) in row.iter_mut().enumerate() {
            *v = tile[c * n + r];
        }
    }
}

/// One row of the first axis's transform: `inside` (non-zero = inside) to
/// squared distances (a step costs `step2`) to the nearest outside voxel,
/// the row's ends one step beyond its edge counting as outside. Each is
/// computed as the lower envelope computes it from its nearest 0 sample
/// (`step2 * d * d + 0`), so the bits are the envelope's.
fn nearest_outside_along_row(inside: &[u8], out: &mut [f64], step2: f64) {
    let n = inside.len();
    // Steps to the nearest outside voxel on the left (the edge at -1).
    let mut last_outside: isize = -1;
    for (p, (&m, o)) in inside.iter().zip(out.iter_mut()).enumerate() {
        if m == 0 {
            last_outside = p as isize;
        }
        *o = (p as isize - last_outside) as f64;
    }
    // And on the right (the edge at n); the nearer one wins.
    let mut next_outside = n as isize;
    for p in (0..n).rev() {
        if inside[p] == 0 {
            next_outside = p as isize;
        }
        let d = out[p].min((next_outside - p as isize) as f64);
        out[p] = step2 * d * d + 0.0;
    }
}

/// Scratch for the 1-D squared distance transform of one line at a time.
struct Envelope {
    /// The lines' length.
    len: usize,
    /// The line, with a 0 sample one step beyond each end (the outside).
    f: Vec<f64>,
    /// The parabolas of the lower envelope, and where each starts to be
    /// lowest.
    v: Vec<usize>,
    z: Vec<f64>,
}

impl Envelope {
    fn new(n: usize) -> Envelope {
        Envelope {
            len: n,
            f: Vec::with_capacity(n + 2),
            v: vec![0; n + 2],
            z: vec![0.0; n + 3],
        }
    }

    /// Transforms `line` in place (samples spaced so that a step costs
    /// `step2`, squared mm); a line all 0 is left as it is. Whether it
    /// changed anything.
    fn transform(&mut self, line: &mut [f64], step2: f64) -> bool {
        if line.iter().all(|&v| v == 0.0) {
            return false;
        }
        self.f.clear();
        self.f.push(0.0);
        self.f.extend_from_slice(line);
        self.f.push(0.0);
        self.envelope(step2);
        self.write(line.iter_mut(), step2);
        true
    }

    /// Transforms the lines across the rows of `volume` (`row_stride`
    /// apart, [`Envelope::len`] of them) at `columns` into
    /// `tile` (a line a column, along the rows); whether any line changed
    /// (is not all 0).
    fn transform_tile(
        &mut self,
        volume: &[f64],
        row_stride: usize,
        columns: std::ops::Range<usize>,
        step2: f64,
        tile: &mut Vec<f64>,
    ) -> bool {
        let n = self.len;
        let width = columns.len();
        tile.clear();
        tile.resize(width * n, 0.0);
        for r in 0..n {
            let row = &volume[r * row_stride + columns.start..r * row_stride + columns.end];
            for (c, &v) in row.iter().enumerate() {
                tile[c * n + r] = v;
            }
        }
        let mut changed = false;
        for line in tile.chunks_mut(n) {
            changed |= self.transform(line, step2);
        }
        changed
    }

    /// The lower envelope of the parabolas at `f`'s finite samples (both
    /// padding samples are finite, so there is one).
    fn envelope(&mut self, step2: f64) {
        let (f, v, z) = (&self.f, &mut self.v, &mut self.z);
        let cross = |q: usize, p: usize| {
            let (q, p) = (q as f64, p as f64);
            ((f[q as usize] / step2 + q * q) - (f[p as usize] / step2 + p * p)) / (2.0 * (q - p))
        };
        let mut k = 0usize;
        v[0] = 0;
        z[0] = f64::NEG_INFINITY;
        z[1] = f64::INFINITY;
        for (q, fq) in f.iter().enumerate().skip(1) {
            if !fq.is_finite() {
                continue;
            }
            let mut s = cross(q, v[k]);
            while s <= z[k] {
                k -= 1;
                s = cross(q, v[k]);
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
        }
    }

    /// The envelope's values at the line's own samples (not the padding),
    /// into `out`.
    fn write<'a>(&self, out: impl Iterator<Item = &'a mut f64>, step2: f64) {
        let (f, v, z) = (&self.f, &self.v, &self.z);
        let mut k = 0;
        for (p, o) in (1..f.len() - 1).zip(out) {
            while z[k + 1] < p as f64 {
                k += 1;
            }
            let dp = p as f64 - v[k] as f64;
            *o = step2 * dp * dp + f[v[k]];
        }
    }
}

/// `mask` with its holes filled: outside voxels (zero) that no 6-connected
/// path of outside voxels joins to the volume's edge become inside (1).
pub fn fill_holes(mask: &[u8], dims: [usize; 3]) -> Vec<u8> {
    let [nx, ny, nz] = dims;
    let mut reached = vec![false; mask.len()];
    let mut stack: Vec<usize> = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let edge = i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny || k + 1 == nz;
                let c = i + nx * (j + ny * k);
                if edge && mask[c] == 0 && !reached[c] {
                    reached[c] = true;
                    stack.push(c);
                }
            }
        }
    }
    while let Some(c) = stack.pop() {
        let (i, j, k) = (c % nx, (c / nx) % ny, c / (nx * ny));
        let mut visit = |n: usize| {
            if mask[n] == 0 && !reached[n] {
                reached[n] = true;
                stack.push(n);
            }
        };
        if i > 0 {
            visit(c - 1);
        }
        if i + 1 < nx {
            visit(c + 1);
        }
        if j > 0 {
            visit(c - nx);
        }
        if j + 1 < ny {
            visit(c + nx);
        }
        if k > 0 {
            visit(c - nx * ny);
        }
        if k + 1 < nz {
            visit(c + nx * ny);
        }
    }
    mask.iter()
        .zip(&reached)
        .map(|(&m, &r)| u8::from(m != 0 || !r))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_in_place_gives_the_bits_of_smoothing_into_another_volume() {
        // Random values on an odd-sized volume, a kernel longer than one
        // axis (every line clamps at both ends) and a short one.
        use rand::{Rng, SeedableRng};
        let dims = [23, 9, 14];
        let mut rng = rand::rngs::StdRng::seed_from_u64(12345);
        let data: Vec<f32> = (0..dims.iter().product::<usize>())
            .map(|_| rng.random::<f32>())
            .collect();
        for sigma in [0.8, 4.0] {
            let kernel = gaussian_kernel(sigma);
            for axis in 0..3 {
                let mut reference = vec![0.0f32; data.len()];
                convolve_axis_into(&data, &mut reference, dims, axis, &kernel);
                let mut in_place = data.clone();
                convolve_axis_in_place(&mut in_place, dims, axis, &kernel);
                let same = reference
                    .iter()
                    .zip(&in_place)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "sigma {sigma}, axis {axis}");
            }
        }
    }

    #[test]
    fn smoothing_keeps_a_constant_and_spreads_a_spike_by_sigma_in_mm() {
        let dims = [41, 41, 21];
        let spacing = [0.5, 0.5, 1.0];
        let flat = vec![3.0f32; 41 * 41 * 21];
        let s = gaussian_smooth(&flat, dims, spacing, 2.0);
        assert!(s.iter().all(|v| (v - 3.0).abs() < 1e-4));
        let mut spike = vec![0.0f32; flat.len()];
        let centre = 20 + 41 * (20 + 41 * 10);
        spike[centre] = 1.0;
        let s = gaussian_smooth(&spike, dims, spacing, 2.0);
        // The variance along each axis, in mm^2, is sigma^2 = 4.
        for (axis, stride, step) in [(0, 1usize, 0.5), (2, 41 * 41, 1.0)] {
            let n = dims[axis] as isize;
            let (mut total, mut var) = (0.0, 0.0);
            for t in -(n / 2)..=(n / 2) {
                let at = (centre as isize + t * stride as isize) as usize;
                let w = s[at] as f64;
                total += w;
                var += w * (t as f64 * step).powi(2);
            }
            let var = var / total;
            assert!((var - 4.0).abs() < 0.15, "axis {axis}: variance {var} mm^2");
        }
    }

    #[test]
    fn the_laplacian_of_a_quadratic_is_its_constant() {
        let dims = [9, 8, 7];
        let spacing = [0.5, 1.0, 2.0];
        let mut q = vec![0.0f32; 9 * 8 * 7];
        for k in 0..7 {
            for j in 0..8 {
                for i in 0..9 {
                    let (x, y, z) = (i as f32 * 0.5, j as f32, k as f32 * 2.0);
                    q[i + 9 * (j + 8 * k)] = x * x + 2.0 * y * y + 3.0 * z * z;
                }
            }
        }
        let l = laplacian(&q, dims, spacing);
        assert!((l[4 + 9 * (4 + 8 * 3)] - 12.0).abs() < 1e-3);
    }

    #[test]
    fn distances_to_the_outside_are_euclidean_in_mm() {
        // A ball of radius 6 mm at the centre of a 1 x 1 x 2 mm grid.
        let dims = [25, 25, 13];
        let spacing = [1.0, 1.0, 2.0];
        let mut mask = vec![0u8; 25 * 25 * 13];
        let at = |i: usize, j: usize, k: usize| i + 25 * (j + 25 * k);
        for k in 0..13 {
            for j in 0..25 {
                for i in 0..25 {
                    let (x, y, z) = (i as f64 - 12.0, j as f64 - 12.0, 2.0 * (k as f64 - 6.0));
                    mask[at(i, j, k)] = u8::from((x * x + y * y + z * z).sqrt() <= 6.0);
                }
            }
        }
        let d = distance_to_outside_mm(&mask, dims, spacing);
        // Nearest outside voxels from the centre: (13, 18, 6) and the like,
        // sqrt(1 + 36) mm away.
        let d0 = d[at(12, 12, 6)];
        assert!((d0 - 37f32.sqrt()).abs() < 1e-4, "{d0}");
        assert_eq!(d[at(0, 0, 0)], 0.0);
        // The voxel 4 mm above the centre (k = 8): of the slice above, 6 mm
        // up, only the centre's column is inside, so (13, 12, 9) is the
        // nearest outside, sqrt(1 + 4) mm away.
        let d8 = d[at(12, 12, 8)];
        assert!((d8 - 5f32.sqrt()).abs() < 1e-4, "{d8}");
        // Whole volume inside: the edge is outside.
        let full = vec![1u8; 5 * 5 * 5];
        let d = distance_to_outside_mm(&full, [5, 5, 5], [1.0, 1.0, 1.0]);
        assert!((d[2 + 5 * (2 + 5 * 2)] - 3.0).abs() < 1e-4);
        assert!((d[0] - 1.0).abs() < 1e-4);
    }

    #[test]
    fn distances_match_a_brute_force_search_on_a_random_mask() {
        // Unequal sides and spacings, so a mix-up of axes shows; the second
        // mask is wider than a tile of lines (and not a whole number of
        // them), mostly outside (lines all 0 are skipped), with a solid
        // block whose rows hold no outside voxel.
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut random = |inside_in_10: u64, n: usize| -> Vec<u8> {
            (0..n)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    u8::from(state % 10 < inside_in_10)
                })
                .collect()
        };
        let small = ([7usize, 9, 6], [0.7, 1.1, 1.9]);
        let wide = ([71usize, 5, 4], [0.6, 0.6, 1.0]);
        let mut sparse = random(2, 71 * 5 * 4);
        for k in 1..3 {
            for j in 0..5 {
                sparse[71 * (j + 5 * k)..71 * (j + 5 * k + 1)].fill(1);
            }
        }
        let cases = [(small, random(8, 7 * 9 * 6)), (wide, sparse)];
        for ((dims, spacing), mask) in cases {
            assert_matches_brute_force(&mask, dims, spacing);
        }
    }

    fn assert_matches_brute_force(mask: &[u8], dims: [usize; 3], spacing: [f64; 3]) {
        let d = distance_to_outside_mm(mask, dims, spacing);
        let inside = |c: [i64; 3]| {
            (0..3).all(|a| c[a] >= 0 && c[a] < dims[a] as i64)
                && mask[c[0] as usize + dims[0] * (c[1] as usize + dims[1] * c[2] as usize)] != 0
        };
        for k in 0..dims[2] as i64 {
            for j in 0..dims[1] as i64 {
                for i in 0..dims[0] as i64 {
                    // Outside: every voxel not in the mask, and one layer
                    // beyond the volume's edge.
                    let mut best = f64::INFINITY;
                    for z in -1..=dims[2] as i64 {
                        for y in -1..=dims[1] as i64 {
                            for x in -1..=dims[0] as i64 {
                                if !inside([x, y, z]) {
                                    let e = [x - i, y - j, z - k];
                                    let d2: f64 =
                                        (0..3).map(|a| (e[a] as f64 * spacing[a]).powi(2)).sum();
                                    best = best.min(d2);
                                }
                            }
                        }
                    }
                    let got = d[i as usize + dims[0] * (j as usize + dims[1] * k as usize)];
                    assert!(
                        (got as f64 - best.sqrt()).abs() < 1e-5,
                        "{dims:?} ({i}, {j}, {k}): {got} against {}",
                        best.sqrt()
                    );
                }
            }
        }
    }

    #[test]
    fn enclosed_holes_are_filled_and_open_ones_are_not() {
        let dims = [7, 7, 7];
        let at = |i: usize, j: usize, k: usize| i + 7 * (j + 7 * k);
        let mut mask = vec![0u8; 343];
        for k in 1..6 {
            for j in 1..6 {
                for i in 1..6 {
                    mask[at(i, j, k)] = 1;
                }
            }
        }
        mask[at(3, 3, 3)] = 0;
        // A channel from the surface in: stays open.
        mask[at(3, 1, 2)] = 0;
        mask[at(3, 2, 2)] = 0;
        let filled = fill_holes(&mask, dims);
        assert_eq!(filled[at(3, 3, 3)], 1);
        assert_eq!(filled[at(3, 2, 2)], 0);
        assert_eq!(filled[at(0, 0, 0)], 0);
    }
}
