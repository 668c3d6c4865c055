//! The displacement field's lattice: trilinear between nodes, and its
//! table form (one row per node) for passing between ops.

use crate::numeric::floor_usize;
use nalgebra::{Point3, Vector3};

/// The columns of a field as a table: each node's position and its
/// displacement, mm.
pub const FIELD_COLUMNS: [&str; 6] = ["x_mm", "y_mm", "z_mm", "u_x_mm", "u_y_mm", "u_z_mm"];

/// A displacement field on a lattice (one frame, mm): trilinear between
/// nodes, the nearest border cell's value beyond the lattice.
#[derive(Debug, Clone, PartialEq)]
pub struct Lattice {
    /// The first node, mm.
    pub origin: Point3<f64>,
    /// Node spacing, mm.
    pub spacing_mm: f64,
    /// Nodes along x, y, z.
    pub dims: [usize; 3],
    /// Each node's displacement, mm (x fastest, then y, then z).
    pub displacements: Vec<Vector3<f64>>,
}

impl Lattice {
    /// A zero field over the box around `points` grown by `margin_mm`.
    pub fn covering(points: &[Point3<f64>], spacing_mm: f64, margin_mm: f64) -> Lattice {
        let mut lo = Point3::from([f64::INFINITY; 3]);
        let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
        for p in points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let origin = lo - Vector3::repeat(margin_mm);
        let dims: [usize; 3] = std::array::from_fn(|a| {
            ((hi[a] - lo[a] + 2.0 * margin_mm) / spacing_mm).ceil() as usize + 1
        });
        Lattice {
            origin,
            spacing_mm,
            dims,
            displacements: vec![Vector3::zeros(); dims[0] * dims[1] * dims[2]],
        }
    }

    pub(super) fn node(&self, i: usize, j: usize, k: usize) -> usize {
        node_index(self.dims, [i, j, k])
    }

    /// The 8 nodes around `p` and their trilinear weights (clamped to the
    /// lattice).
    pub fn stencil(&self, p: &Point3<f64>) -> [(usize, f64); 8] {
        let at: [f64; 3] = std::array::from_fn(|a| (p[a] - self.origin[a]) / self.spacing_mm);
        trilinear_stencil(self.dims, at)
    }

    /// The displacement at `p`, mm.
    pub fn displacement(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.stencil(p)
            .iter()
            .map(|&(n, w)| self.displacements[n] * w)
            .sum()
    }

    /// Every node's position and displacement, one row each in the order
    /// of [`Lattice::displacements`] (columns [`FIELD_COLUMNS`]).
    pub fn to_rows(&self) -> Vec<[f64; 6]> {
        let mut rows = Vec::with_capacity(self.displacements.len());
        for k in 0..self.dims[2] {
            for j in 0..self.dims[1] {
                for i in 0..self.dims[0] {
                    let p =
                        self.origin + Vector3::new(i as f64, j as f64, k as f64) * self.spacing_mm;
                    let u = self.displacements[self.node(i, j, k)];
                    rows.push([p.x, p.y, p.z, u.x, u.y, u.z]);
                }
            }
        }
        rows
    }

    /// The lattice whose rows [`Lattice::to_rows`] gave; an error naming the
    /// first row off a regular lattice.
    pub fn from_rows(rows: &[[f64; 6]]) -> Result<Lattice, String> {
        let at = |r: &[f64; 6]| Point3::new(r[0], r[1], r[2]);
        if rows.len() < 8 {
            return Err(format!("{} nodes: a lattice has at least 8", rows.len()));
        }
        let origin = at(&rows[0]);
        let spacing_mm = rows[1][0] - rows[0][0];
        if !(spacing_mm.is_finite() && spacing_mm > 0.0) {
            return Err(format!(
                "the first two nodes are {spacing_mm} mm apart along x"
            ));
        }
        let run = |axis: usize, stride: usize| {
            (1..)
                .take_while(|&n| {
                    n * stride < rows.len() && rows[n * stride][axis] > rows[(n - 1) * stride][axis]
                })
                .count()
                + 1
        };
        let nx = run(0, 1);
        let ny = run(1, nx);
        let nz = rows.len() / (nx * ny);
        if nx < 2 || ny < 2 || nz < 2 || nx * ny * nz != rows.len() {
            return Err(format!(
                "{} nodes do not make a lattice ({nx} x {ny} along x and y)",
                rows.len()
            ));
        }
        let mut lattice = Lattice {
            origin,
            spacing_mm,
            dims: [nx, ny, nz],
            displacements: Vec::with_capacity(rows.len()),
        };
        for (n, r) in rows.iter().enumerate() {
            let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
            let expected = origin + Vector3::new(i as f64, j as f64, k as f64) * spacing_mm;
            if (at(r) - expected).norm() > 1e-6 * spacing_mm.max(1.0) {
                return Err(format!(
                    "node {n} is at ({:.3}, {:.3}, {:.3}) mm, off the lattice's ({:.3}, {:.3}, {:.3})",
                    r[0], r[1], r[2], expected.x, expected.y, expected.z
                ));
            }
            lattice.displacements.push(Vector3::new(r[3], r[4], r[5]));
        }
        Ok(lattice)
    }
}

/// How many edges a lattice of `dims` nodes has (node pairs one spacing
/// apart).
pub(super) fn edge_count(dims: [usize; 3]) -> usize {
    (0..3)
        .map(|a| (dims[a] - 1) * dims[(a + 1) % 3] * dims[(a + 2) % 3])
        .sum()
}

/// How many lines of three nodes a lattice of `dims` nodes has.
pub(super) fn triple_count(dims: [usize; 3]) -> usize {
    (0..3)
        .map(|a| dims[a].saturating_sub(2) * dims[(a + 1) % 3] * dims[(a + 2) % 3])
        .sum()
}

/// Every run of `length` consecutive nodes along an axis of a lattice of
/// `dims` nodes (`length` 2: its edges; 3: its lines of three, middle node
/// second), each in ascending order.
#[cfg(test)]
pub(super) fn runs(dims: [usize; 3], length: usize) -> Vec<Vec<usize>> {
    let mut runs = Vec::new();
    for n in 0..dims.iter().product() {
        let at = node_coords(dims, n);
        for axis in 0..3 {
            if at[axis] + length <= dims[axis] {
                runs.push(
                    (0..length)
                        .map(|t| {
                            let mut to = at;
                            to[axis] += t;
                            node_index(dims, to)
                        })
                        .collect(),
                );
            }
        }
    }
    runs
}

/// The 8 nodes around `at` (in node units: node (i, j, k) is at (i, j, k))
/// on a lattice of `dims` nodes, and their trilinear weights, corner `c`
/// being the cell's corner (c & 1, c >> 1 & 1, c >> 2 & 1); `at` is
/// clamped to the lattice.
pub(super) fn trilinear_stencil(dims: [usize; 3], at: [f64; 3]) -> [(usize, f64); 8] {
    let cell: [(usize, f64); 3] = std::array::from_fn(|a| {
        let f = at[a].clamp(0.0, (dims[a] - 1) as f64);
        let i = floor_usize(f).min(dims[a] - 2);
        (i, f - i as f64)
    });
    std::array::from_fn(|c| {
        let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let w = |(_, t): (usize, f64), d: usize| if d == 1 { t } else { 1.0 - t };
        (
            node_index(dims, [cell[0].0 + dx, cell[1].0 + dy, cell[2].0 + dz]),
            w(cell[0], dx) * w(cell[1], dy) * w(cell[2], dz),
        )
    })
}

/// Where a [`trilinear_stencil`] was taken, in node units (its cell's first
/// corner plus the weights' fractions).
pub(super) fn stencil_position(dims: [usize; 3], stencil: &[(usize, f64); 8]) -> [f64; 3] {
    let base = node_coords(dims, stencil[0].0);
    let share = |corners: [usize; 4]| corners.iter().map(|&c| stencil[c].1).sum::<f64>();
    [
        base[0] as f64 + share([1, 3, 5, 7]),
        base[1] as f64 + share([2, 3, 6, 7]),
        base[2] as f64 + share([4, 5, 6, 7]),
    ]
}

/// Node (i, j, k)'s index on a lattice of `dims` nodes (x fastest).
pub(super) fn node_index(dims: [usize; 3], [i, j, k]: [usize; 3]) -> usize {
    i + dims[0] * (j + dims[1] * k)
}

/// Node `n`'s (i, j, k) on a lattice of `dims` nodes.
pub(super) fn node_coords(dims: [usize; 3], n: usize) -> [usize; 3] {
    [
        n % dims[0],
        (n / dims[0]) % dims[1],
        n / (dims[0] * dims[1]),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lattice_interpolates_a_linear_field_exactly() {
        let pts = [Point3::new(0.0, 0.0, 0.0), Point3::new(40.0, 30.0, 20.0)];
        let mut l = Lattice::covering(&pts, 10.0, 5.0);
        let f = |p: &Point3<f64>| Vector3::new(0.1 * p.x, -0.05 * p.y + 1.0, 0.02 * p.z);
        for k in 0..l.dims[2] {
            for j in 0..l.dims[1] {
                for i in 0..l.dims[0] {
                    let p = l.origin + Vector3::new(i as f64, j as f64, k as f64) * 10.0;
                    let n = l.node(i, j, k);
                    l.displacements[n] = f(&p);
                }
            }
        }
        let p = Point3::new(13.3, 7.9, 18.2);
        assert!((l.displacement(&p) - f(&p)).norm() < 1e-9);
        // Through its table and back.
        let mut rows = l.to_rows();
        assert_eq!(Lattice::from_rows(&rows).unwrap(), l);
        rows[7][1] += 0.5;
        let e = Lattice::from_rows(&rows).unwrap_err();
        assert!(e.contains("node 7"), "{e}");
        let e = Lattice::from_rows(&rows[..5]).unwrap_err();
        assert!(e.contains("5 nodes"), "{e}");
        // The regularisers' counts, against the runs they count.
        for dims in [[2, 2, 2], [5, 3, 4], [7, 2, 6]] {
            assert_eq!(edge_count(dims), runs(dims, 2).len(), "{dims:?}");
            assert_eq!(triple_count(dims), runs(dims, 3).len(), "{dims:?}");
        }
    }
}
