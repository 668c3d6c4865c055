//! Sheared voxel grids (a gantry-tilted CT, slices offset in-plane) resampled
//! onto an orthogonal grid, as dcm2niix's tilt correction does, for formats
//! whose readers need orthogonal axes: ITK (and so SimpleITK and 3D Slicer)
//! refuses a NIfTI whose sform is not orthogonal.
//!
//! Written here: it is a per-slice in-plane shift, a few lines, and no crate
//! of the field does it on our grid type.

use crate::numeric::floor_usize;
use fusegraph_engine::value::Grid;

/// How a grid's slice axis leans off its slices' normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shear {
    /// Angle between the slice step and the slice normal, degrees.
    pub angle_deg: f64,
    /// In-plane shift of each slice from the one before, in voxels along
    /// i and j.
    pub shift_per_slice_vox: [f64; 2],
    /// Length of that shift, mm.
    pub shift_per_slice_mm: f64,
}

/// Shear below this is rounding in the slice positions, not a tilt.
pub const MAX_IGNORED_SHEAR_DEG: f64 = 0.01;

fn column(grid: &Grid, c: usize) -> [f64; 3] {
    std::array::from_fn(|r| grid.voxel_to_patient[r][c])
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The shear of `grid`'s slice axis (k) against the normal of its i and j
/// axes. An error when i and j themselves are not orthogonal, which no
/// per-slice shift can fix.
pub fn grid_shear(grid: &Grid) -> Result<Shear, String> {
    let (ci, cj, ck) = (column(grid, 0), column(grid, 1), column(grid, 2));
    let (li, lj) = (dot(ci, ci).sqrt(), dot(cj, cj).sqrt());
    let cos_ij = dot(ci, cj) / (li * lj);
    if cos_ij.abs() > 1e-6 {
        return Err(format!(
            "the voxel grid's i and j axes are {:.3} deg apart, not 90: only a grid with orthogonal slices can be resampled",
            cos_ij.clamp(-1.0, 1.0).acos().to_degrees()
        ));
    }
    let normal = {
        let n = [
            ci[1] * cj[2] - ci[2] * cj[1],
            ci[2] * cj[0] - ci[0] * cj[2],
            ci[0] * cj[1] - ci[1] * cj[0],
        ];
        let l = dot(n, n).sqrt();
        n.map(|x| x / l)
    };
    let along = dot(ck, normal);
    let lateral: [f64; 3] = std::array::from_fn(|r| ck[r] - along * normal[r]);
    let shift_mm = dot(lateral, lateral).sqrt();
    Ok(Shear {
        angle_deg: shift_mm.atan2(along.abs()).to_degrees(),
        shift_per_slice_vox: [dot(lateral, ci) / (li * li), dot(lateral, cj) / (lj * lj)],
        shift_per_slice_mm: shift_mm,
    })
}

/// The grid with the slice axis turned onto the slices' normal (same slice
/// planes, same i and j axes and origin): what [`deshear`] resamples onto.
pub fn orthogonal_grid(grid: &Grid, shear: &Shear) -> Grid {
    let mut out = grid.clone();
    let (ci, cj) = (column(grid, 0), column(grid, 1));
    let [a, b] = shear.shift_per_slice_vox;
    for r in 0..3 {
        out.voxel_to_patient[r][2] -= a * ci[r] + b * cj[r];
    }
    out
}

/// Resamples `values` on a sheared `grid` onto [`orthogonal_grid`]: slice k
/// keeps its plane and is shifted in-plane by k times the shear's step, so
/// every voxel keeps its patient position. `sample` reads a slice (`width` x
/// `height`, row-major) at a continuous (x, y) voxel position and returns
/// `None` outside it; voxels shifted in from outside the field of view get
/// `fill`.
pub fn deshear<T: Copy + Send + Sync>(
    grid: &Grid,
    values: &[T],
    shear: &Shear,
    fill: T,
    sample: impl Fn(&[T], usize, usize, f64, f64) -> Option<T> + Sync,
) -> (Grid, Vec<T>) {
    use rayon::prelude::*;
    let [w, h, d] = grid.dims;
    let [a, b] = shear.shift_per_slice_vox;
    let mut out = vec![fill; values.len()];
    out.par_chunks_mut(w * h)
        .zip(values.par_chunks(w * h))
        .take(d)
        .enumerate()
        .for_each(|(k, (dst, src))| {
            // New voxel (i, j, k) sits where old voxel (i - k a, j - k b, k) did.
            let (dx, dy) = (k as f64 * a, k as f64 * b);
            for j in 0..h {
                for i in 0..w {
                    if let Some(v) = sample(src, w, h, i as f64 - dx, j as f64 - dy) {
                        dst[i + w * j] = v;
                    }
                }
            }
        });
    (orthogonal_grid(grid, shear), out)
}

/// Bilinear interpolation of an f32 slice; `None` outside it.
pub fn bilinear(slice: &[f32], w: usize, h: usize, x: f64, y: f64) -> Option<f32> {
    const EDGE: f64 = 1e-9;
    if x < -EDGE || y < -EDGE || x > (w - 1) as f64 + EDGE || y > (h - 1) as f64 + EDGE {
        return None;
    }
    let (x, y) = (x.clamp(0.0, (w - 1) as f64), y.clamp(0.0, (h - 1) as f64));
    let (x0, y0) = (floor_usize(x), floor_usize(y));
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let at = |i: usize, j: usize| slice[i + w * j];
    let top = at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx;
    let bottom = at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Nearest-neighbour sample of a slice (for masks); `None` outside it.
pub fn nearest<T: Copy>(slice: &[T], w: usize, h: usize, x: f64, y: f64) -> Option<T> {
    let (i, j) = (x.round(), y.round());
    (i >= 0.0 && j >= 0.0 && i < w as f64 && j < h as f64)
        .then(|| slice[i as usize + w * j as usize])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 4 x 3 slices of 0.5 mm pixels, 2 mm apart and each 1 mm further
    /// along +x (2 voxels) than the one before: 26.565 deg.
    fn sheared() -> Grid {
        let mut g = Grid::axis_aligned([4, 3, 3], [0.5, 0.5, 2.0], [10.0, 20.0, 30.0]);
        g.voxel_to_patient[0][2] = 1.0;
        g
    }

    #[test]
    fn the_shear_is_measured_in_degrees_and_voxels() {
        let s = grid_shear(&sheared()).unwrap();
        assert!(
            (s.angle_deg - 0.5f64.atan().to_degrees()).abs() < 1e-9,
            "{s:?}"
        );
        assert_eq!(s.shift_per_slice_vox, [2.0, 0.0]);
        assert_eq!(s.shift_per_slice_mm, 1.0);
        let straight = Grid::axis_aligned([4, 3, 3], [0.5, 0.5, 2.0], [0.0; 3]);
        assert_eq!(grid_shear(&straight).unwrap().angle_deg, 0.0);
        let mut skewed = straight.clone();
        skewed.voxel_to_patient[1][0] = 0.1;
        assert!(grid_shear(&skewed).unwrap_err().contains("not 90"));
    }

    #[test]
    fn every_voxel_keeps_its_patient_position() {
        let grid = sheared();
        // A value that is a function of patient x and y alone, so a voxel
        // moved to its old patient position reads the same value.
        let value = |p: [f64; 3]| (p[0] * 10.0 + p[1]) as f32;
        let mut values = vec![0.0f32; grid.len()];
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..4 {
                    values[grid.index(i, j, k)] =
                        value(grid.to_patient([i as f64, j as f64, k as f64]));
                }
            }
        }
        let shear = grid_shear(&grid).unwrap();
        let (out_grid, out) = deshear(&grid, &values, &shear, f32::NAN, bilinear);
        assert!(grid_shear(&out_grid).unwrap().angle_deg < 1e-12);
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..4 {
                    let v = out[out_grid.index(i, j, k)];
                    let p = out_grid.to_patient([i as f64, j as f64, k as f64]);
                    // Slice k moved 2k voxels: the rest came from outside.
                    if i >= 2 * k {
                        assert!(
                            (v - value(p)).abs() < 1e-4,
                            "({i},{j},{k}): {v} vs {}",
                            value(p)
                        );
                    } else {
                        assert!(v.is_nan(), "({i},{j},{k}) is outside the slice: {v}");
                    }
                }
            }
        }
        let mask: Vec<u8> = (0..grid.len()).map(|n| (n % 2) as u8).collect();
        let (_, m) = deshear(&grid, &mask, &shear, 0, nearest);
        // Slice 1 shifted by 2 voxels: its voxel (2, 0) is old (0, 0).
        assert_eq!(m[grid.index(2, 0, 1)], mask[grid.index(0, 0, 1)]);
        assert_eq!(m[grid.index(0, 0, 1)], 0);
    }
}
