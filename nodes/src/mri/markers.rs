//! From labelled components to marker centres: keeping the components whose
//! size fits a marker, and their (intensity-weighted) centroids.

use fusegraph_engine::value::Grid;

/// Which components to keep.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerSelection {
    /// Smallest component volume kept, mm3.
    pub min_volume_mm3: f64,
    /// Largest component volume kept, mm3.
    pub max_volume_mm3: f64,
    /// If non-zero: keep at most this many, those closest to `target_volume_mm3`.
    pub expected: usize,
    /// The volume a marker's gel core should have, mm3.
    pub target_volume_mm3: f64,
}

/// The labels (1-based, as in `sizes`) of the components to keep, in label
/// order. `voxel_mm3` is the volume of one voxel.
pub fn select_components(sizes: &[usize], voxel_mm3: f64, s: &MarkerSelection) -> Vec<u32> {
    let mut kept: Vec<(u32, f64)> = sizes
        .iter()
        .enumerate()
        .skip(1)
        .map(|(l, &n)| (l as u32, n as f64 * voxel_mm3))
        .filter(|&(_, v)| v >= s.min_volume_mm3 && v <= s.max_volume_mm3)
        .collect();
    if s.expected > 0 && kept.len() > s.expected {
        kept.sort_by(|a, b| {
            (a.1 - s.target_volume_mm3)
                .abs()
                .total_cmp(&(b.1 - s.target_volume_mm3).abs())
        });
        kept.truncate(s.expected);
    }
    let mut labels: Vec<u32> = kept.into_iter().map(|(l, _)| l).collect();
    labels.sort_unstable();
    labels
}

/// How to weight voxels in a centroid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Weighting {
    /// Every voxel of the component counts 1.
    Binary,
    /// Each voxel counts its intensity above `background`; the component is
    /// first grown by `dilate` voxels (26-neighbours) so the partial-volume
    /// voxels just below the threshold count too, which is what makes the
    /// centroid sub-voxel accurate.
    Intensity {
        /// Intensity that counts as zero.
        background: f32,
        /// Voxels to grow the component by.
        dilate: usize,
    },
}

/// Centroid of each component `label` (1..=count) in patient mm, in label order.
/// Components that another label's voxels border are grown only into unlabelled
/// voxels.
pub fn centroids(
    labels: &[u32],
    count: usize,
    grid: &Grid,
    intensity: Option<&[f32]>,
    weighting: Weighting,
) -> Vec<[f64; 3]> {
    let [nx, ny, nz] = grid.dims;
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); count + 1];
    for (idx, &l) in labels.iter().enumerate() {
        if l != 0 && (l as usize) <= count {
            members[l as usize].push(idx);
        }
    }
    (1..=count)
        .map(|l| {
            let voxels = &members[l];
            let (set, background) = match (weighting, intensity) {
                (Weighting::Intensity { background, dilate }, Some(_)) => {
                    let mut set: std::collections::BTreeSet<usize> =
                        voxels.iter().copied().collect();
                    for _ in 0..dilate {
                        let frontier: Vec<usize> = set.iter().copied().collect();
                        for idx in frontier {
                            let (i, j, k) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
                            for dk in -1..=1isize {
                                for dj in -1..=1isize {
                                    for di in -1..=1isize {
                                        let (a, b, c) =
                                            (i as isize + di, j as isize + dj, k as isize + dk);
                                        if a < 0
                                            || b < 0
                                            || c < 0
                                            || a >= nx as isize
                                            || b >= ny as isize
                                            || c >= nz as isize
                                        {
                                            continue;
                                        }
                                        let n = a as usize + nx * (b as usize + ny * c as usize);
                                        if labels[n] == 0 || labels[n] as usize == l {
                                            set.insert(n);
                                        }
                                    }
                                }
                            }
                        }
                    }
                    (set.into_iter().collect::<Vec<_>>(), background)
                }
                _ => (voxels.clone(), 0.0),
            };
            let (mut sum, mut acc) = (0.0f64, [0.0f64; 3]);
            for idx in set {
                let w = match (weighting, intensity) {
                    (Weighting::Intensity { .. }, Some(v)) => (v[idx] - background).max(0.0) as f64,
                    _ => 1.0,
                };
                let (i, j, k) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
                sum += w;
                acc[0] += w * i as f64;
                acc[1] += w * j as f64;
                acc[2] += w * k as f64;
            }
            let ijk = if sum > 0.0 {
                acc.map(|a| a / sum)
            } else {
                [f64::NAN; 3]
            };
            grid.to_patient(ijk)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_by_volume_and_expected_count() {
        let sizes = [0, 5000, 60, 55, 2, 70, 58];
        let s = MarkerSelection {
            min_volume_mm3: 10.0,
            max_volume_mm3: 1000.0,
            expected: 0,
            target_volume_mm3: 56.0,
        };
        assert_eq!(select_components(&sizes, 1.0, &s), vec![2, 3, 5, 6]);
        let s = MarkerSelection { expected: 2, ..s };
        assert_eq!(select_components(&sizes, 1.0, &s), vec![3, 6]);
        assert_eq!(
            select_components(&sizes, 0.1, &MarkerSelection { expected: 0, ..s }),
            vec![1]
        );
    }

    #[test]
    fn intensity_weighting_finds_a_sub_voxel_centre() {
        // A 1D blob along i: partial voxel 0.25 | 1 | 1 | 0.75, label only on
        // the two full voxels; the true mass centre is (0.25*1 + 2 + 3 + 0.75*4) / 3.
        let grid = Grid::axis_aligned([6, 1, 1], [0.5, 1.0, 1.0], [10.0, 0.0, 0.0]);
        let intensity = [0.0, 0.25, 1.0, 1.0, 0.75, 0.0];
        let labels = [0, 0, 1, 1, 0, 0];
        let weighted = centroids(
            &labels,
            1,
            &grid,
            Some(&intensity),
            Weighting::Intensity {
                background: 0.0,
                dilate: 1,
            },
        );
        let expected_i = (0.25 * 1.0 + 2.0 + 3.0 + 0.75 * 4.0) / 3.0;
        assert!(
            (weighted[0][0] - (10.0 + 0.5 * expected_i)).abs() < 1e-12,
            "{:?}",
            weighted[0]
        );
        let binary = centroids(&labels, 1, &grid, Some(&intensity), Weighting::Binary);
        assert!((binary[0][0] - (10.0 + 0.5 * 2.5)).abs() < 1e-12);
    }
}
