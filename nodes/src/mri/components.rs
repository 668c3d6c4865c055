//! Connected components of a binary volume (6-, 18- or 26-connectivity) by
//! union-find over runs of voxels along x. Written here: no crate labels 3D
//! volumes.

use rayon::prelude::*;

/// Which neighbours touch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Connectivity {
    /// Face neighbours only.
    Six,
    /// Faces and edges.
    Eighteen,
    /// Faces, edges and corners.
    TwentySix,
}

impl Connectivity {
    /// From 6, 18 or 26.
    pub fn from_count(n: i64) -> Option<Self> {
        match n {
            6 => Some(Connectivity::Six),
            18 => Some(Connectivity::Eighteen),
            26 => Some(Connectivity::TwentySix),
            _ => None,
        }
    }
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

/// How runs in two neighbouring rows touch: not at all, where they share an
/// x (`Exact`), or also where they are one x apart (`Diagonal`).
#[derive(Clone, Copy, PartialEq)]
enum Touch {
    Never,
    Exact,
    Diagonal,
}

impl Connectivity {
    /// How runs touch in a row one step away in y or z (a face row), and in
    /// a row one step away in both (an edge row).
    fn touch(self) -> (Touch, Touch) {
        match self {
            Connectivity::Six => (Touch::Exact, Touch::Never),
            Connectivity::Eighteen => (Touch::Diagonal, Touch::Exact),
            Connectivity::TwentySix => (Touch::Diagonal, Touch::Diagonal),
        }
    }
}

/// One slice's runs `[start, end)` along x, row by row, and where each row's
/// runs start in that list (one entry per row, and one past the last).
type SliceRuns = (Vec<(u32, u32)>, Vec<u32>);

/// Unions the runs of two rows that touch (runs `[start, end)` in x, with
/// their global numbers from `first_a` and `first_b`).
fn union_rows(
    a: &[(u32, u32)],
    first_a: u32,
    b: &[(u32, u32)],
    first_b: u32,
    touch: Touch,
    parent: &mut [u32],
) {
    if touch == Touch::Never {
        return;
    }
    let reach = (touch == Touch::Diagonal) as u32;
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let ((sa, ea), (sb, eb)) = (a[i], b[j]);
        if sa < eb + reach && sb < ea + reach {
            let (ra, rb) = (
                find(parent, first_a + i as u32),
                find(parent, first_b + j as u32),
            );
            if ra != rb {
                parent[ra.max(rb) as usize] = ra.min(rb);
            }
        }
        // Step past the run that ends first.
        if ea < eb { i += 1 } else { j += 1 }
    }
}

/// Labels the non-zero voxels of `mask` (dims nx, ny, nz): 0 is background,
/// components are numbered 1..=count in the order their first voxel is met in
/// the raster scan. Returns the labels and the voxel count of each component
/// (index 0 unused).
///
/// Works on runs of voxels along x rather than voxels: runs are found slice
/// by slice in parallel, runs of neighbouring rows that touch are joined by
/// union-find, and the labels are written run by run in parallel.
pub fn label_components(
    mask: &[u8],
    dims: [usize; 3],
    connectivity: Connectivity,
) -> (Vec<u32>, Vec<usize>) {
    let [nx, ny, nz] = dims;
    // Runs per slice, and where each row's runs start within its slice.
    let slices: Vec<SliceRuns> = (0..nz)
        .into_par_iter()
        .map(|k| {
            let mut runs = Vec::new();
            let mut row_start = Vec::with_capacity(ny + 1);
            for j in 0..ny {
                row_start.push(runs.len() as u32);
                let row = &mask[nx * (j + ny * k)..][..nx];
                let mut i = 0;
                while let Some(s) = row[i..].iter().position(|&v| v != 0) {
                    let start = i + s;
                    let len = row[start..]
                        .iter()
                        .position(|&v| v == 0)
                        .unwrap_or(nx - start);
                    runs.push((start as u32, (start + len) as u32));
                    i = start + len;
                    if i >= nx {
                        break;
                    }
                }
            }
            row_start.push(runs.len() as u32);
            (runs, row_start)
        })
        .collect();
    let mut slice_first = Vec::with_capacity(nz + 1);
    let mut total = 0u32;
    for (runs, _) in &slices {
        slice_first.push(total);
        total += runs.len() as u32;
    }
    slice_first.push(total);
    let row = |j: usize, k: usize| -> (&[(u32, u32)], u32) {
        let (runs, starts) = &slices[k];
        let (a, b) = (starts[j] as usize, starts[j + 1] as usize);
        (&runs[a..b], slice_first[k] + a as u32)
    };
    let mut parent: Vec<u32> = (0..total).collect();
    let (face, edge) = connectivity.touch();
    for k in 0..nz {
        for j in 0..ny {
            let (here, first) = row(j, k);
            if here.is_empty() {
                continue;
            }
            if j > 0 {
                let (r, f) = row(j - 1, k);
                union_rows(here, first, r, f, face, &mut parent);
            }
            if k > 0 {
                let (r, f) = row(j, k - 1);
                union_rows(here, first, r, f, face, &mut parent);
                if j > 0 {
                    let (r, f) = row(j - 1, k - 1);
                    union_rows(here, first, r, f, edge, &mut parent);
                }
                if j + 1 < ny {
                    let (r, f) = row(j + 1, k - 1);
                    union_rows(here, first, r, f, edge, &mut parent);
                }
            }
        }
    }
    // Labels by first appearance: runs are in raster order.
    let mut final_label = vec![0u32; total as usize];
    let mut run_label = vec![0u32; total as usize];
    let mut sizes = vec![0usize];
    for r in 0..total {
        let root = find(&mut parent, r) as usize;
        if final_label[root] == 0 {
            final_label[root] = sizes.len() as u32;
            sizes.push(0);
        }
        run_label[r as usize] = final_label[root];
    }
    for (k, (runs, _)) in slices.iter().enumerate() {
        for (n, &(a, b)) in runs.iter().enumerate() {
            sizes[run_label[slice_first[k] as usize + n] as usize] += (b - a) as usize;
        }
    }
    let mut labels = vec![0u32; mask.len()];
    labels
        .par_chunks_mut(nx * ny)
        .zip(&slices)
        .enumerate()
        .for_each(|(k, (slice, (runs, starts)))| {
            for j in 0..ny {
                let out = &mut slice[nx * j..][..nx];
                for n in starts[j] as usize..starts[j + 1] as usize {
                    let (a, b) = runs[n];
                    out[a as usize..b as usize].fill(run_label[slice_first[k] as usize + n]);
                }
            }
        });
    (labels, sizes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diagonal_voxels_join_only_with_enough_connectivity() {
        // Three voxels touching by a corner, then by an edge.
        let dims = [3, 3, 3];
        let mut mask = vec![0u8; 27];
        mask[0] = 1; // (0,0,0)
        mask[1 + 3 + 9] = 1; // (1,1,1): corner neighbour of (0,0,0)
        mask[2 + 3 * 2 + 9] = 1; // (2,2,1): edge neighbour of (1,1,1)
        let count = |c| label_components(&mask, dims, c).1.len() - 1;
        assert_eq!(count(Connectivity::TwentySix), 1);
        assert_eq!(count(Connectivity::Eighteen), 2);
        assert_eq!(count(Connectivity::Six), 3);
    }

    /// Flood fill from each unlabelled voxel in raster order: the reference.
    fn flood(mask: &[u8], [nx, ny, nz]: [usize; 3], c: Connectivity) -> Vec<u32> {
        let max_order = match c {
            Connectivity::Six => 1,
            Connectivity::Eighteen => 2,
            Connectivity::TwentySix => 3,
        };
        let mut labels = vec![0u32; mask.len()];
        let mut next = 0;
        for start in 0..mask.len() {
            if mask[start] == 0 || labels[start] != 0 {
                continue;
            }
            next += 1;
            labels[start] = next;
            let mut stack = vec![start];
            while let Some(idx) = stack.pop() {
                let (i, j, k) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
                for dk in -1..=1isize {
                    for dj in -1..=1isize {
                        for di in -1..=1isize {
                            let order = di.abs() + dj.abs() + dk.abs();
                            let (a, b, d) = (i as isize + di, j as isize + dj, k as isize + dk);
                            if order == 0 || order > max_order || a < 0 || b < 0 || d < 0 {
                                continue;
                            }
                            if a >= nx as isize || b >= ny as isize || d >= nz as isize {
                                continue;
                            }
                            let n = a as usize + nx * (b as usize + ny * d as usize);
                            if mask[n] != 0 && labels[n] == 0 {
                                labels[n] = next;
                                stack.push(n);
                            }
                        }
                    }
                }
            }
        }
        labels
    }

    #[test]
    fn runs_give_the_labels_of_a_flood_fill_on_random_masks() {
        let mut state = 12345u64;
        for round in 0..30 {
            let dims = [13 + round % 5, 9 + round % 3, 7 + round % 4];
            let density = [0.2, 0.35, 0.5][round % 3];
            let mask: Vec<u8> = (0..dims[0] * dims[1] * dims[2])
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    ((state >> 40) as f64 / (1u64 << 24) as f64) < density
                })
                .map(u8::from)
                .collect();
            for c in [
                Connectivity::Six,
                Connectivity::Eighteen,
                Connectivity::TwentySix,
            ] {
                let (labels, sizes) = label_components(&mask, dims, c);
                assert_eq!(labels, flood(&mask, dims, c), "round {round} {c:?}");
                for (l, &n) in sizes.iter().enumerate().skip(1) {
                    assert_eq!(labels.iter().filter(|&&x| x as usize == l).count(), n);
                }
            }
        }
    }

    #[test]
    fn u_shapes_merge_and_labels_follow_the_scan() {
        // A U in one slice: two arms meet at the bottom row, after both arms
        // have labels of their own.
        let dims = [5, 4, 1];
        #[rustfmt::skip]
        let mask = vec![
            1, 0, 0, 0, 1,
            1, 0, 0, 0, 1,
            1, 1, 1, 1, 1,
            0, 0, 1, 0, 0,
        ];
        let (labels, sizes) = label_components(&mask, dims, Connectivity::Six);
        assert_eq!(sizes, vec![0, 10]);
        assert!(
            labels
                .iter()
                .zip(&mask)
                .all(|(&l, &m)| (l == 1) == (m == 1))
        );
        let mask2 = vec![1, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1];
        let (labels, sizes) = label_components(&mask2, dims, Connectivity::TwentySix);
        assert_eq!(sizes, vec![0, 1, 1, 1]);
        assert_eq!((labels[0], labels[2], labels[19]), (1, 2, 3));
    }
}
