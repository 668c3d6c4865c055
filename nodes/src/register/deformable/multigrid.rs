//! A multigrid preconditioner for the deformable fit's systems, which makes
//! their conjugate gradients converge in a few dozen iterations whatever
//! the lattice's size.
//!
//! The bending term is a biharmonic operator: its condition number grows
//! with the fourth power of the lattice's size, and conjugate gradients
//! with a block-Jacobi preconditioner stopped at their 300-iteration cap
//! with residuals of 1e-1 to 1e-5 (the field then depended on where they
//! stopped). Here each system is assembled (3 x 3 blocks between nodes at
//! most one apart, or two along an axis) on the lattice and on coarser
//! lattices (every other node, trilinear prolongation), and one V-cycle
//! (a forward block Gauss-Seidel sweep down, a backward one up, a band
//! Cholesky on the coarsest, see [`super::banded`]) is the preconditioner:
//! symmetric and positive definite, as conjugate gradients need.
//!
//! Coarse operators: a data row's coarse stencil is its trilinear stencil
//! on the coarse lattice, which is exactly the Galerkin product P^T A P (a
//! coarse trilinear field is trilinear in every fine cell). The regularisers
//! are rediscretised with the weights the Galerkin product gives smooth
//! fields: bending unchanged, the membrane doubled per level.
//!
//! Written here: no Rust crate does geometric multigrid on a lattice.

use super::lattice::{node_coords, node_index, stencil_position, trilinear_stencil};
use nalgebra::{DMatrix, Matrix3, Vector3};
use rayon::prelude::*;

/// The couplings a block row holds: the 27 offsets of a node's cell
/// neighbourhood, then the 6 two nodes along an axis (bending).
const SLOTS: usize = 33;

/// The couplings with a node itself or a later one (the offsets whose
/// (z, y, x) is lexicographically at least zero): the cell neighbourhood's
/// centre and its 13 later neighbours, then two nodes on along each axis.
/// The matrix is symmetric, so these are all the assembly sums.
const UPPER_SLOTS: usize = 17;

/// The slot of the block coupling a node with the node `d` away.
fn slot(d: [isize; 3]) -> usize {
    if d.iter().all(|c| c.abs() <= 1) {
        ((d[0] + 1) + 3 * (d[1] + 1) + 9 * (d[2] + 1)) as usize
    } else {
        let axis = d
            .iter()
            .position(|&c| c != 0)
            .expect("an offset along an axis");
        27 + 2 * axis + usize::from(d[axis] > 0)
    }
}

/// The upper slot of an offset on or after the node (see [`UPPER_SLOTS`]);
/// `None` for an earlier one.
fn upper_slot(d: [isize; 3]) -> Option<usize> {
    let s = slot(d);
    match s {
        13..27 => Some(s - 13),
        27.. => s.is_multiple_of(2).then(|| 14 + (s - 27) / 2),
        _ => None,
    }
}

/// The offset a slot stands for (the inverse of [`slot`]).
fn offset(s: usize) -> [isize; 3] {
    if s < 27 {
        let s = s as isize;
        [s % 3 - 1, (s / 3) % 3 - 1, s / 9 - 1]
    } else {
        let mut d = [0; 3];
        d[(s - 27) / 2] = if (s - 27) % 2 == 1 { 2 } else { -2 };
        d
    }
}

/// A symmetric 3 x 3 block's entries xx, xy, xz, yy, yz, zz. Every block
/// of the system is symmetric (each term's weight is, and the
/// regularisers add multiples of the identity), so the assembly sums six
/// entries, not nine.
type SymBlock = [f64; 6];

/// The (row, column) of each of a [`SymBlock`]'s entries.
const SYM_ENTRIES: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

/// Where a [`SymBlock`]'s diagonal entries are.
const SYM_DIAGONAL: [usize; 3] = [0, 3, 5];

fn sym_entries(m: &Matrix3<f64>) -> SymBlock {
    SYM_ENTRIES.map(|(i, j)| m[(i, j)])
}

fn sym_matrix(b: &SymBlock) -> Matrix3<f64> {
    Matrix3::new(b[0], b[1], b[2], b[1], b[3], b[4], b[2], b[4], b[5])
}

/// The block times `x`, each entry summed in the order nalgebra's `M * x`
/// sums it (column by column), so the result has the same bits; the
/// blocks take two thirds of the memory the sweeps stream through.
#[inline]
fn sym_times(b: &SymBlock, x: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(
        b[0] * x[0] + b[1] * x[1] + b[2] * x[2],
        b[1] * x[0] + b[3] * x[1] + b[4] * x[2],
        b[2] * x[0] + b[4] * x[1] + b[5] * x[2],
    )
}

/// A term whose rows sit at one point: its position in the finest
/// lattice's node units and its symmetric 3 x 3 weight M (the row
/// contributes w_a w_b M to the block between its stencil's nodes a and b;
/// the assembly reads M's upper triangle).
#[derive(Clone)]
pub(super) struct PointTerm {
    pub(super) at: [f64; 3],
    pub(super) weight: Matrix3<f64>,
}

/// The regularisers' weights on the finest lattice (per edge and per line
/// of three nodes).
#[derive(Clone, Copy)]
pub(super) struct Regularisers {
    pub(super) edge: f64,
    pub(super) bend: f64,
}

/// A symmetric block matrix over a lattice's nodes, in compressed rows.
pub(super) struct BlockMatrix {
    starts: Vec<usize>,
    columns: Vec<usize>,
    /// The blocks, each symmetric (see [`SymBlock`]).
    blocks: Vec<SymBlock>,
    /// Each row's diagonal block, inverted.
    diagonal_inverse: Vec<Matrix3<f64>>,
}

impl BlockMatrix {
    /// The system on a lattice of `dims` nodes whose node units are
    /// `scale` finest ones: `terms` at their stencils there, the membrane
    /// and bending over every edge and line of three.
    pub(super) fn assemble(
        dims: [usize; 3],
        scale: f64,
        terms: &[PointTerm],
        regularisers: Regularisers,
    ) -> BlockMatrix {
        let nodes = dims.iter().product::<usize>();
        let mut rows = vec![[[0.0; 6]; UPPER_SLOTS]; nodes];
        let corner = |c: usize| [(c & 1) as isize, ((c >> 1) & 1) as isize, (c >> 2) as isize];
        // A later corner of a cell is a later node: pairs (a, b >= a) are
        // the blocks on and above the diagonal.
        let corner_slots: [[usize; 8]; 8] = std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                upper_slot(std::array::from_fn(|k| corner(b)[k] - corner(a)[k])).unwrap_or(0)
            })
        });
        for t in terms {
            debug_assert_eq!(
                t.weight,
                t.weight.transpose(),
                "a term's weight is symmetric"
            );
            let weight = sym_entries(&t.weight);
            let stencil = trilinear_stencil(dims, t.at.map(|v| v / scale));
            for (a, &(na, wa)) in stencil.iter().enumerate() {
                if wa == 0.0 {
                    continue;
                }
                let row = &mut rows[na];
                for (b, &(_, wb)) in stencil.iter().enumerate().skip(a) {
                    let w = wa * wb;
                    for (entry, m) in row[corner_slots[a][b]].iter_mut().zip(&weight) {
                        *entry += m * w;
                    }
                }
            }
        }
        // Each level up, a smooth field's membrane energy doubles and its
        // bending energy stays (see the module's notes).
        let edge = regularisers.edge * scale;
        let bend = regularisers.bend;
        let upper = |d: [isize; 3]| upper_slot(d).expect("an offset on or after the node");
        let centre = upper([0, 0, 0]);
        // The slot of the node `k` on along each axis (k = 0, 1, 2).
        let along: [[usize; 3]; 3] = std::array::from_fn(|axis| {
            std::array::from_fn(|k| {
                let mut d = [0isize; 3];
                d[axis] = k as isize;
                upper(d)
            })
        });
        for n in 0..nodes {
            let at = node_coords(dims, n);
            for axis in 0..3 {
                if at[axis] + 1 < dims[axis] {
                    let next = node_index(dims, step(at, axis, 1));
                    add_identity(&mut rows[n], centre, edge);
                    add_identity(&mut rows[n], along[axis][1], -edge);
                    add_identity(&mut rows[next], centre, edge);
                }
                if at[axis] > 0 && at[axis] + 1 < dims[axis] {
                    let line = [
                        node_index(dims, step(at, axis, -1)),
                        n,
                        node_index(dims, step(at, axis, 1)),
                    ];
                    let coefficient = [1.0, -2.0, 1.0];
                    for (i, &ni) in line.iter().enumerate() {
                        for j in i..3 {
                            add_identity(
                                &mut rows[ni],
                                along[axis][j - i],
                                bend * coefficient[i] * coefficient[j],
                            );
                        }
                    }
                }
            }
        }
        BlockMatrix::compress(dims, &rows)
    }

    /// The compressed rows of the blocks on and above the diagonal that
    /// `rows` hold (those below are their mirrors, and every block is
    /// symmetric; zero blocks and offsets off the lattice are left out).
    fn compress(dims: [usize; 3], rows: &[[SymBlock; UPPER_SLOTS]]) -> BlockMatrix {
        let mut starts = Vec::with_capacity(rows.len() + 1);
        let mut columns = Vec::with_capacity(rows.len() * SLOTS);
        let mut blocks = Vec::with_capacity(rows.len() * SLOTS);
        let mut diagonal_inverse = Vec::with_capacity(rows.len());
        // Each offset in ascending column order, with the upper slot it is
        // read from and whether from the later node (mirrored).
        let mut order: Vec<([isize; 3], usize, bool)> = (0..SLOTS)
            .map(offset)
            .map(|d| match upper_slot(d) {
                Some(u) => (d, u, false),
                None => (
                    d,
                    upper_slot(d.map(|c| -c)).expect("a mirrored offset"),
                    true,
                ),
            })
            .collect();
        order.sort_by_key(|&(d, _, _)| (d[2], d[1], d[0]));
        let stride = [1, dims[0] as isize, (dims[0] * dims[1]) as isize];
        for (n, row) in rows.iter().enumerate() {
            starts.push(columns.len());
            let at = node_coords(dims, n);
            for &(d, u, mirrored) in &order {
                let inside = (0..3).all(|k| {
                    let c = at[k] as isize + d[k];
                    c >= 0 && c < dims[k] as isize
                });
                if !inside {
                    continue;
                }
                let to =
                    (n as isize + d[0] * stride[0] + d[1] * stride[1] + d[2] * stride[2]) as usize;
                let block = if mirrored { &rows[to][u] } else { &row[u] };
                if block.iter().any(|&v| v != 0.0) {
                    columns.push(to);
                    blocks.push(*block);
                }
            }
            let diagonal = sym_matrix(&row[upper_slot([0, 0, 0]).expect("the centre")]);
            diagonal_inverse.push(diagonal.try_inverse().unwrap_or_else(Matrix3::zeros));
        }
        starts.push(columns.len());
        BlockMatrix {
            starts,
            columns,
            blocks,
            diagonal_inverse,
        }
    }

    fn nodes(&self) -> usize {
        self.diagonal_inverse.len()
    }

    fn row_times(&self, n: usize, x: &[Vector3<f64>]) -> Vector3<f64> {
        let range = self.starts[n]..self.starts[n + 1];
        self.columns[range.clone()]
            .iter()
            .zip(&self.blocks[range])
            .map(|(&c, b)| sym_times(b, &x[c]))
            .sum()
    }

    /// A x, rows in parallel.
    pub(super) fn apply(&self, x: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        (0..self.nodes())
            .into_par_iter()
            .with_min_len(256)
            .map(|n| self.row_times(n, x))
            .collect()
    }

    /// One block Gauss-Seidel sweep on A z = r, in node order or reversed.
    fn sweep(&self, r: &[Vector3<f64>], z: &mut [Vector3<f64>], backward: bool) {
        let mut relax = |n: usize| {
            let mut rest = r[n];
            for i in self.starts[n]..self.starts[n + 1] {
                let c = self.columns[i];
                if c != n {
                    rest -= sym_times(&self.blocks[i], &z[c]);
                }
            }
            z[n] = self.diagonal_inverse[n] * rest;
        };
        if backward {
            (0..self.nodes()).rev().for_each(&mut relax);
        } else {
            (0..self.nodes()).for_each(&mut relax);
        }
    }

    /// The first forward sweep on A z = r, from z = 0: the blocks after
    /// the diagonal would multiply zeros, so they are not read (rows hold
    /// their columns in ascending order). Subtracting those zeros could
    /// only have turned an exact -0 into +0, so the result is the full
    /// sweep's but for the sign of exact zeros.
    fn sweep_forward_from_zero(&self, r: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let mut z = vec![Vector3::zeros(); r.len()];
        for n in 0..self.nodes() {
            let mut rest = r[n];
            for i in self.starts[n]..self.starts[n + 1] {
                let c = self.columns[i];
                if c >= n {
                    break;
                }
                rest -= sym_times(&self.blocks[i], &z[c]);
            }
            z[n] = self.diagonal_inverse[n] * rest;
        }
        z
    }

    /// A backward sweep on A z = r whose rows' earlier columns are
    /// subtracted first, for all rows in parallel: a backward sweep reads
    /// them before it updates them, and each row subtracts its columns in
    /// ascending order, earlier ones first, so only the later columns
    /// (already updated) remain for the serial pass. The same bits as
    /// [`BlockMatrix::sweep`] backward.
    fn sweep_backward(&self, r: &[Vector3<f64>], z: &mut [Vector3<f64>]) {
        let earlier_done: Vec<(Vector3<f64>, usize)> = (0..self.nodes())
            .into_par_iter()
            .with_min_len(256)
            .map(|n| {
                let mut rest = r[n];
                let mut i = self.starts[n];
                while i < self.starts[n + 1] && self.columns[i] < n {
                    rest -= sym_times(&self.blocks[i], &z[self.columns[i]]);
                    i += 1;
                }
                (rest, i)
            })
            .collect();
        for n in (0..self.nodes()).rev() {
            let (mut rest, later) = earlier_done[n];
            for i in later..self.starts[n + 1] {
                let c = self.columns[i];
                if c != n {
                    rest -= sym_times(&self.blocks[i], &z[c]);
                }
            }
            z[n] = self.diagonal_inverse[n] * rest;
        }
    }

    fn dense(&self) -> DMatrix<f64> {
        let n = self.nodes();
        let mut dense = DMatrix::zeros(3 * n, 3 * n);
        for row in 0..n {
            for i in self.starts[row]..self.starts[row + 1] {
                dense
                    .fixed_view_mut::<3, 3>(3 * row, 3 * self.columns[i])
                    .copy_from(&sym_matrix(&self.blocks[i]));
            }
        }
        dense
    }
}

fn step(at: [usize; 3], axis: usize, by: isize) -> [usize; 3] {
    let mut to = at;
    to[axis] = (at[axis] as isize + by) as usize;
    to
}

fn add_identity(row: &mut [SymBlock; UPPER_SLOTS], s: usize, w: f64) {
    for k in SYM_DIAGONAL {
        row[s][k] += w;
    }
}

/// The coarser lattice's size: every other node, the last one kept
/// (possibly one node beyond the finer lattice's end).
fn coarser(dims: [usize; 3]) -> [usize; 3] {
    dims.map(|n| (n - 1).div_ceil(2) + 1)
}

/// Lattices no larger than this are solved densely.
const COARSEST_NODES: usize = 160;

/// The largest coarsest lattice a dense Cholesky is worth (3 unknowns a
/// node); beyond it the coarsest level is relaxed instead.
const DENSE_NODES: usize = 1500;

/// Sweeps each way that stand in for the coarsest solve when it is too
/// large to factor.
const COARSEST_SWEEPS: usize = 4;

struct Level {
    dims: [usize; 3],
    matrix: BlockMatrix,
}

/// One V-cycle as a preconditioner of the finest level's system.
pub(super) struct Multigrid {
    levels: Vec<Level>,
    coarsest: Option<Cholesky>,
}

type Cholesky = super::banded::BandedCholesky;

impl Multigrid {
    /// The levels of a system on a lattice of `dims` nodes.
    pub(super) fn new(dims: [usize; 3], terms: &[PointTerm], regularisers: Regularisers) -> Self {
        let mut sizes = vec![dims];
        while let Some(&last) = sizes.last()
            && last.iter().product::<usize>() > COARSEST_NODES
            && last.iter().all(|&n| n >= 3)
        {
            sizes.push(coarser(last));
        }
        // Each level reads every term: they are assembled side by side, and
        // the coarsest is factored as soon as it is assembled.
        let coarsest_level = sizes.len() - 1;
        let (levels, mut factors): (Vec<Level>, Vec<Option<Cholesky>>) = sizes
            .par_iter()
            .enumerate()
            .map(|(l, &dims)| {
                let matrix = BlockMatrix::assemble(dims, (1u64 << l) as f64, terms, regularisers);
                let factor = (l == coarsest_level && matrix.nodes() <= DENSE_NODES)
                    .then(|| Cholesky::new(&matrix.dense()))
                    .flatten();
                (Level { dims, matrix }, factor)
            })
            .unzip();
        let coarsest = factors.pop().flatten();
        Multigrid { levels, coarsest }
    }

    /// The finest level's matrix.
    pub(super) fn matrix(&self) -> &BlockMatrix {
        &self.levels[0].matrix
    }

    /// z = M^-1 r by one V-cycle.
    pub(super) fn precondition(&self, r: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.cycle(0, r)
    }

    fn cycle(&self, level: usize, r: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let matrix = &self.levels[level].matrix;
        if level + 1 == self.levels.len() {
            let mut z = vec![Vector3::zeros(); r.len()];
            match &self.coarsest {
                Some(cholesky) => {
                    let mut x: Vec<f64> = r.iter().flat_map(|v| v.iter().copied()).collect();
                    cholesky.solve_mut(&mut x);
                    for (n, zn) in z.iter_mut().enumerate() {
                        *zn = Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2]);
                    }
                }
                None => {
                    for _ in 0..COARSEST_SWEEPS {
                        matrix.sweep(r, &mut z, false);
                    }
                    for _ in 0..COARSEST_SWEEPS {
                        matrix.sweep(r, &mut z, true);
                    }
                }
            }
            return z;
        }
        let mut z = matrix.sweep_forward_from_zero(r);
        let az = matrix.apply(&z);
        let residual: Vec<Vector3<f64>> = r.iter().zip(&az).map(|(r, a)| r - a).collect();
        let fine = self.levels[level].dims;
        let coarse = self.levels[level + 1].dims;
        let coarse_residual = restrict(fine, coarse, &residual);
        let correction = self.cycle(level + 1, &coarse_residual);
        prolong_add(fine, coarse, &correction, &mut z);
        matrix.sweep_backward(r, &mut z);
        z
    }
}

/// The coarse nodes a fine node interpolates from, with their weights:
/// along each axis, an even node sits on a coarse one, an odd node halfway
/// between two.
fn parents(fine: [usize; 3], coarse: [usize; 3], n: usize) -> impl Iterator<Item = (usize, f64)> {
    let at = node_coords(fine, n);
    let along = |a: usize| -> [(usize, f64); 2] {
        if at[a].is_multiple_of(2) {
            [(at[a] / 2, 1.0), (at[a] / 2, 0.0)]
        } else {
            [(at[a] / 2, 0.5), (at[a] / 2 + 1, 0.5)]
        }
    };
    let (x, y, z) = (along(0), along(1), along(2));
    (0..8).filter_map(move |c| {
        let (px, py, pz) = (x[c & 1], y[(c >> 1) & 1], z[c >> 2]);
        let w = px.1 * py.1 * pz.1;
        (w != 0.0).then(|| (node_index(coarse, [px.0, py.0, pz.0]), w))
    })
}

/// P^T r: the fine residual onto the coarse nodes, each coarse node's sum
/// gathered from its fine children in ascending node order (the order the
/// scatter over fine nodes, [`restrict_by_scatter`], adds them in: the
/// same bits), the coarse nodes in parallel.
fn restrict(fine: [usize; 3], coarse: [usize; 3], r: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    // Along an axis, the fine nodes a coarse node `c` takes a share of:
    // 2c - 1 and 2c + 1 half, 2c whole (those inside the fine lattice).
    let children = |c: usize, axis: usize| {
        [(2 * c).checked_sub(1), Some(2 * c), Some(2 * c + 1)]
            .into_iter()
            .zip([0.5, 1.0, 0.5])
            .filter_map(move |(f, w)| f.filter(|&f| f < fine[axis]).map(|f| (f, w)))
    };
    (0..coarse.iter().product::<usize>())
        .into_par_iter()
        .with_min_len(64)
        .map(|c| {
            let [ci, cj, ck] = node_coords(coarse, c);
            let mut sum = Vector3::zeros();
            for (k, wz) in children(ck, 2) {
                for (j, wy) in children(cj, 1) {
                    for (i, wx) in children(ci, 0) {
                        // The weight as `parents` forms it.
                        sum += r[node_index(fine, [i, j, k])] * (wx * wy * wz);
                    }
                }
            }
            sum
        })
        .collect()
}

/// z += P e: the coarse correction onto the fine nodes (in parallel).
fn prolong_add(fine: [usize; 3], coarse: [usize; 3], e: &[Vector3<f64>], z: &mut [Vector3<f64>]) {
    z.par_iter_mut()
        .with_min_len(256)
        .enumerate()
        .for_each(|(n, zn)| {
            for (c, w) in parents(fine, coarse, n) {
                *zn += e[c] * w;
            }
        });
}

/// A point term's position from its stencil on the finest lattice.
pub(super) fn term_at(
    dims: [usize; 3],
    stencil: &[(usize, f64); 8],
    weight: Matrix3<f64>,
) -> PointTerm {
    PointTerm {
        at: stencil_position(dims, stencil),
        weight,
    }
}

#[cfg(test)]
mod tests {
    use super::super::lattice::runs;
    use super::*;

    /// P^T r as a scatter over the fine nodes, in their order: the
    /// definition [`restrict`]'s gather must give bit for bit.
    fn restrict_by_scatter(
        fine: [usize; 3],
        coarse: [usize; 3],
        r: &[Vector3<f64>],
    ) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); coarse.iter().product()];
        for (n, rn) in r.iter().enumerate() {
            for (c, w) in parents(fine, coarse, n) {
                out[c] += rn * w;
            }
        }
        out
    }

    #[test]
    fn restriction_gathers_the_scatter_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // Odd and even sizes: an even one's coarse lattice reaches a node
        // past its end.
        for fine in [[18, 12, 17], [7, 6, 5], [3, 4, 3]] {
            let coarse = coarser(fine);
            let r = random_vectors(&mut rng, fine.iter().product());
            let gathered = restrict(fine, coarse, &r);
            let scattered = restrict_by_scatter(fine, coarse, &r);
            let bits = |v: &[Vector3<f64>]| -> Vec<u64> {
                v.iter()
                    .flat_map(|x| x.iter().map(|c| c.to_bits()))
                    .collect()
            };
            assert_eq!(bits(&gathered), bits(&scattered), "{fine:?}");
        }
    }
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_vectors(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
            })
            .collect()
    }

    /// Terms at random points of a lattice of `dims` nodes, each a random
    /// positive semidefinite weight of rank 1 (a surface row) or 2 (a
    /// landmark across a normal).
    fn random_terms(rng: &mut ChaCha8Rng, dims: [usize; 3], count: usize) -> Vec<PointTerm> {
        (0..count)
            .map(|i| {
                let at = std::array::from_fn(|a| rng.random_range(0.0..(dims[a] - 1) as f64));
                let n = random_vectors(rng, 1)[0].normalize();
                let weight = if i % 2 == 0 {
                    n * n.transpose() * rng.random_range(0.1..2.0)
                } else {
                    (Matrix3::identity() - n * n.transpose()) * rng.random_range(0.1..2.0)
                };
                PointTerm { at, weight }
            })
            .collect()
    }

    fn dot(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
        a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
    }

    /// The energy's quadratic form computed term by term, not assembled.
    fn energy(dims: [usize; 3], terms: &[PointTerm], reg: Regularisers, x: &[Vector3<f64>]) -> f64 {
        let mut sum = 0.0;
        for t in terms {
            let u: Vector3<f64> = trilinear_stencil(dims, t.at)
                .iter()
                .map(|&(n, w)| x[n] * w)
                .sum();
            sum += u.dot(&(t.weight * u));
        }
        for edge in runs(dims, 2) {
            sum += reg.edge * (x[edge[0]] - x[edge[1]]).norm_squared();
        }
        for line in runs(dims, 3) {
            sum += reg.bend * (x[line[0]] - x[line[1]] * 2.0 + x[line[2]]).norm_squared();
        }
        sum
    }

    #[test]
    fn symmetric_blocks_multiply_with_nalgebras_bits() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        for _ in 0..1000 {
            let a = Matrix3::from_fn(|_, _| rng.random_range(-1e3..1e3));
            let m = a + a.transpose();
            let x = random_vectors(&mut rng, 1)[0] * rng.random_range(1e-6..1e6);
            let (ours, theirs) = (sym_times(&sym_entries(&m), &x), m * x);
            assert_eq!(ours.map(f64::to_bits), theirs.map(f64::to_bits));
            assert_eq!(sym_matrix(&sym_entries(&m)), m);
        }
    }

    #[test]
    fn upper_slots_cover_the_offsets_on_and_after_a_node_once() {
        let mut seen = [false; UPPER_SLOTS];
        for s in 0..SLOTS {
            let d = offset(s);
            let later = (d[2], d[1], d[0]) >= (0, 0, 0);
            assert_eq!(upper_slot(d).is_some(), later, "{d:?}");
            if let Some(u) = upper_slot(d) {
                assert!(!seen[u], "{d:?}");
                seen[u] = true;
            }
        }
        assert!(seen.iter().all(|&v| v));
    }

    #[test]
    fn the_assembled_matrix_is_the_energys_quadratic_form() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let dims = [5, 6, 4];
        let nodes = 120;
        let terms = random_terms(&mut rng, dims, 200);
        let reg = Regularisers {
            edge: 0.3,
            bend: 0.7,
        };
        let a = BlockMatrix::assemble(dims, 1.0, &terms, reg);
        for _ in 0..5 {
            let x = random_vectors(&mut rng, nodes);
            let y = random_vectors(&mut rng, nodes);
            let form = dot(&x, &a.apply(&x));
            let direct = energy(dims, &terms, reg, &x);
            assert!(
                (form - direct).abs() < 1e-9 * direct,
                "{form} against {direct}"
            );
            // Symmetric: with the form, this fixes every entry.
            let (xay, yax) = (dot(&y, &a.apply(&x)), dot(&x, &a.apply(&y)));
            assert!((xay - yax).abs() < 1e-9 * form, "{xay} against {yax}");
        }
    }

    #[test]
    fn a_coarse_levels_point_terms_are_the_galerkin_product() {
        // A coarse trilinear field is trilinear in every fine cell, so the
        // terms rediscretised on the coarse lattice give exactly
        // P^T A P; on a lattice of even and of odd sizes.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for dims in [[7, 6, 5], [8, 9, 6]] {
            let terms = random_terms(&mut rng, dims, 150);
            let none = Regularisers {
                edge: 0.0,
                bend: 0.0,
            };
            let fine = BlockMatrix::assemble(dims, 1.0, &terms, none);
            let coarse_dims = coarser(dims);
            let coarse = BlockMatrix::assemble(coarse_dims, 2.0, &terms, none);
            let e = random_vectors(&mut rng, coarse_dims.iter().product());
            let mut pe = vec![Vector3::zeros(); dims.iter().product()];
            prolong_add(dims, coarse_dims, &e, &mut pe);
            let galerkin = dot(&pe, &fine.apply(&pe));
            let direct = dot(&e, &coarse.apply(&e));
            assert!(
                (galerkin - direct).abs() < 1e-9 * direct,
                "{dims:?}: {galerkin} against {direct}"
            );
            // And restriction is prolongation's transpose.
            let r = random_vectors(&mut rng, pe.len());
            let (rpe, ptr) = (dot(&r, &pe), dot(&restrict(dims, coarse_dims, &r), &e));
            assert!((rpe - ptr).abs() < 1e-9 * rpe.abs().max(1.0));
        }
    }

    /// The finest matrix of `count` random terms on a lattice of `dims`,
    /// with both regularisers.
    fn random_matrix(rng: &mut ChaCha8Rng, dims: [usize; 3], count: usize) -> BlockMatrix {
        let terms = random_terms(rng, dims, count);
        let regularisers = Regularisers {
            edge: 1e-3,
            bend: 0.2,
        };
        BlockMatrix::assemble(dims, 1.0, &terms, regularisers)
    }

    #[test]
    fn a_forward_sweep_from_zero_reads_only_the_earlier_columns_to_the_same_values() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let a = random_matrix(&mut rng, [7, 6, 5], 200);
        let r = random_vectors(&mut rng, a.nodes());
        let mut full = vec![Vector3::zeros(); a.nodes()];
        a.sweep(&r, &mut full, false);
        // Equal as numbers (+0 == -0): the skipped blocks met only zeros.
        assert_eq!(a.sweep_forward_from_zero(&r), full);
    }

    #[test]
    fn a_backward_sweep_with_its_earlier_columns_first_has_the_serial_sweeps_bits() {
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let a = random_matrix(&mut rng, [9, 7, 6], 300);
        let r = random_vectors(&mut rng, a.nodes());
        let start = random_vectors(&mut rng, a.nodes());
        let (mut serial, mut split) = (start.clone(), start);
        a.sweep(&r, &mut serial, true);
        a.sweep_backward(&r, &mut split);
        let bits = |v: &[Vector3<f64>]| -> Vec<u64> {
            v.iter()
                .flat_map(|x| x.iter().map(|c| c.to_bits()))
                .collect()
        };
        assert_eq!(bits(&split), bits(&serial));
    }

    #[test]
    fn the_v_cycle_is_symmetric_and_positive_definite() {
        // As conjugate gradients need of a preconditioner; on a lattice
        // large enough for three levels, the coarsest solved densely.
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let dims = [13, 11, 9];
        let terms = random_terms(&mut rng, dims, 600);
        let mg = Multigrid::new(
            dims,
            &terms,
            Regularisers {
                edge: 1e-4,
                bend: 0.5,
            },
        );
        assert!(mg.levels.len() >= 3 && mg.coarsest.is_some());
        let nodes = dims.iter().product();
        for _ in 0..3 {
            let (r, s) = (
                random_vectors(&mut rng, nodes),
                random_vectors(&mut rng, nodes),
            );
            let (smr, rms) = (dot(&s, &mg.precondition(&r)), dot(&r, &mg.precondition(&s)));
            assert!(
                (smr - rms).abs() < 1e-8 * smr.abs().max(1e-3),
                "{smr} against {rms}"
            );
            assert!(dot(&r, &mg.precondition(&r)) > 0.0);
        }
    }
}
