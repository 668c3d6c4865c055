//! Connected components of a binary volume (6-, 18- or 26-connectivity) by
//! union-find over one raster scan. Written here: no crate labels 3D volumes.

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

    /// Neighbour offsets (di, dj, dk) already visited in a raster scan.
    fn previous(self) -> Vec<[isize; 3]> {
        let mut out = Vec::new();
        for dk in -1..=0isize {
            for dj in -1..=1isize {
                for di in -1..=1isize {
                    let earlier = dk < 0 || (dk == 0 && (dj < 0 || (dj == 0 && di < 0)));
                    let order = di.abs() + dj.abs() + dk.abs();
                    let touches = match self {
                        Connectivity::Six => order == 1,
                        Connectivity::Eighteen => order <= 2,
                        Connectivity::TwentySix => true,
                    };
                    if earlier && touches && order > 0 {
                        out.push([di, dj, dk]);
                    }
                }
            }
        }
        out
    }
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        parent[x as usize] = parent[parent[x as usize] as usize];
        x = parent[x as usize];
    }
    x
}

/// Labels the non-zero voxels of `mask` (dims nx, ny, nz): 0 is background,
/// components are numbered 1..=count in the order their first voxel is met in
/// the raster scan. Returns the labels and the voxel count of each component
/// (index 0 unused).
pub fn label_components(
    mask: &[u8],
    dims: [usize; 3],
    connectivity: Connectivity,
) -> (Vec<u32>, Vec<usize>) {
    let [nx, ny, nz] = dims;
    let offsets = connectivity.previous();
    let mut labels = vec![0u32; mask.len()];
    let mut parent: Vec<u32> = vec![0];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let idx = i + nx * (j + ny * k);
                if mask[idx] == 0 {
                    continue;
                }
                let mut current = 0u32;
                for [di, dj, dk] in &offsets {
                    let (a, b, c) = (i as isize + di, j as isize + dj, k as isize + dk);
                    if a < 0 || b < 0 || c < 0 || a >= nx as isize || b >= ny as isize {
                        continue;
                    }
                    let l = labels[a as usize + nx * (b as usize + ny * c as usize)];
                    if l == 0 {
                        continue;
                    }
                    if current == 0 {
                        current = find(&mut parent, l);
                    } else {
                        let (ra, rb) = (find(&mut parent, current), find(&mut parent, l));
                        if ra != rb {
                            let (lo, hi) = (ra.min(rb), ra.max(rb));
                            parent[hi as usize] = lo;
                            current = lo;
                        }
                    }
                }
                if current == 0 {
                    current = parent.len() as u32;
                    parent.push(current);
                }
                labels[idx] = current;
            }
        }
    }
    // Resolve to roots, then renumber roots in order of first appearance.
    let mut final_label = vec![0u32; parent.len()];
    let mut sizes = vec![0usize];
    for l in labels.iter_mut() {
        if *l == 0 {
            continue;
        }
        let root = find(&mut parent, *l);
        if final_label[root as usize] == 0 {
            final_label[root as usize] = sizes.len() as u32;
            sizes.push(0);
        }
        *l = final_label[root as usize];
        sizes[*l as usize] += 1;
    }
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
