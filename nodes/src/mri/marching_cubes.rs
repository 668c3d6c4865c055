//! Marching cubes (Lorensen & Cline) over a scalar volume, written here because no
//! maintained crate contours a scalar field into an indexed, watertight mesh.
//!
//! The 256-case triangle table is derived at start-up rather than typed in: on
//! each cube face the crossed edges are joined so that every run of inside
//! corners is cut off on its own (the "separate" rule for the ambiguous face).
//! That choice depends only on the face's four corners, so neighbouring cubes
//! cut their shared face identically and the surface has no cracks. Joined face
//! segments form closed cycles that are fanned into triangles. Vertices are
//! shared through the lattice edge they lie on, so there are no duplicates, and
//! the volume is padded with "outside" so every surface is closed.

use fusegraph_engine::value::Grid;
use rayon::prelude::*;
use std::sync::OnceLock;

/// Cube corners as (x, y, z) offsets.
const CORNERS: [[usize; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
];

/// Nearest a vertex comes to a lattice corner, as a fraction of its edge.
///
/// Where a corner's value is within rounding of the level, the vertices on its
/// six edges would all sit within a micrometre of it: slivers whose normals are
/// noise and which nearly touch the triangles of the neighbouring cubes. Tools
/// that test intersections in floating point (Open3D's
/// `get_self_intersecting_triangles`, for one) then report intersections that
/// are not there. Keeping vertices 1 % of an edge from corners moves the
/// surface by at most 1 % of a voxel, far below marching cubes' own error.
const CORNER_CLEARANCE: f64 = 0.01;

/// Cube edges as corner pairs.
const EDGES: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [3, 0],
    [4, 5],
    [5, 6],
    [6, 7],
    [7, 4],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// One case of the table: triangles over cube edges (0..12) and cycle centres
/// (12 + c, the mean of the vertices on the edges in `centres[c]`).
#[derive(Debug, Default)]
struct Case {
    triangles: Vec<[u8; 3]>,
    centres: Vec<Vec<u8>>,
}

/// Triangles of each case (inside corners set the bits).
fn table() -> &'static [Case; 256] {
    static TABLE: OnceLock<[Case; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|case| triangulate_case(case as u8)))
}

fn edge_between(a: usize, b: usize) -> usize {
    EDGES
        .iter()
        .position(|&[p, q]| (p, q) == (a, b) || (p, q) == (b, a))
        .expect("adjacent corners")
}

/// The six faces, each as its corners in counter-clockwise order seen from
/// outside the cube.
#[allow(clippy::needless_range_loop)] // axes index corner coordinates
fn faces() -> Vec<[usize; 4]> {
    let mut faces = Vec::new();
    for axis in 0..3 {
        for side in 0..2 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let at = |a: usize, b: usize| {
                (0..8)
                    .find(|&c| CORNERS[c][axis] == side && CORNERS[c][u] == a && CORNERS[c][v] == b)
                    .expect("corner exists")
            };
            let mut f = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)];
            // (u, v, axis) is right-handed, so this order faces +axis.
            if side == 0 {
                f.reverse();
            }
            faces.push(f);
        }
    }
    faces
}

fn triangulate_case(case: u8) -> Case {
    let inside = |c: usize| case & (1 << c) != 0;
    let faces = faces();
    // Face segments, each from the edge entering a run of inside corners to the
    // edge leaving it (walking the face counter-clockwise from outside).
    let mut next_edge = [usize::MAX; 12];
    for f in &faces {
        for i in 0..4 {
            let (prev, here) = (f[(i + 3) % 4], f[i]);
            if inside(here) && !inside(prev) {
                let entering = edge_between(prev, here);
                let mut j = i;
                while inside(f[(j + 1) % 4]) {
                    j = (j + 1) % 4;
                }
                let leaving = edge_between(f[j], f[(j + 1) % 4]);
                next_edge[entering] = leaving;
            }
        }
    }
    let face_edges: Vec<Vec<usize>> = faces
        .iter()
        .map(|f| (0..4).map(|i| edge_between(f[i], f[(i + 1) % 4])).collect())
        .collect();
    let share_face =
        |a: usize, b: usize| face_edges.iter().any(|f| f.contains(&a) && f.contains(&b));
    let mut out = Case::default();
    let mut used = [false; 12];
    for start in 0..12 {
        if next_edge[start] == usize::MAX || used[start] {
            continue;
        }
        let mut cycle = vec![start];
        used[start] = true;
        let mut e = next_edge[start];
        while e != start {
            used[e] = true;
            cycle.push(e);
            e = next_edge[e];
        }
        // The cycles run counter-clockwise seen from outside the inside region,
        // so fans keep normals pointing from inside to outside. A fan diagonal
        // between two vertices on one cube face would also be built by the
        // neighbour across that face (a non-manifold edge): fan from a vertex
        // without such diagonals, or else from a new vertex at the cycle's centre.
        let n = cycle.len();
        let fan_from =
            (0..n).find(|&s| (2..n - 1).all(|d| !share_face(cycle[s], cycle[(s + d) % n])));
        match fan_from {
            Some(s) => {
                for d in 1..n - 1 {
                    out.triangles.push(
                        [cycle[s], cycle[(s + d) % n], cycle[(s + d + 1) % n]].map(|e| e as u8),
                    );
                }
            }
            None => {
                let centre = 12 + out.centres.len() as u8;
                out.centres.push(cycle.iter().map(|&e| e as u8).collect());
                for d in 0..n {
                    out.triangles
                        .push([centre, cycle[d] as u8, cycle[(d + 1) % n] as u8]);
                }
            }
        }
    }
    out
}

/// A triangle mesh in patient mm.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions, mm.
    pub vertices: Vec<[f32; 3]>,
    /// Vertex indices, counter-clockwise seen from outside (normals point to
    /// values below the level).
    pub triangles: Vec<[u32; 3]>,
}

/// Corner bits of a cube from its left (x = 0) face's column code.
///
/// A column code holds the inside bits of one lattice column's four points
/// at (y, z) = (0, 0), (1, 0), (0, 1), (1, 1) as bits 0..4; the cube's corners
/// on that face are 0, 3, 4, 7 (see [`CORNERS`]).
const LEFT: [u8; 16] = column_to_corners([0, 3, 4, 7]);
/// Corner bits from the right (x = 1) face's column code: corners 1, 2, 5, 6.
const RIGHT: [u8; 16] = column_to_corners([1, 2, 5, 6]);

const fn column_to_corners(corners: [usize; 4]) -> [u8; 16] {
    let mut out = [0u8; 16];
    let mut code = 0;
    while code < 16 {
        let mut bit = 0;
        while bit < 4 {
            if code & (1 << bit) != 0 {
                out[code] |= 1 << corners[bit];
            }
            bit += 1;
        }
        code += 1;
    }
    out
}

/// The padded lattice of a volume: point `(p, q, r)`, with `p < px`,
/// `q < py`, `r < pz`, is voxel `(p - 1, q - 1, r - 1)`, and the border is
/// outside. Inside bits are kept for every point, and per row of points the
/// span `[first, end)` of its inside points (`first == end` when none), so
/// that passes over the lattice skip what lies outside the surface's reach
/// (Flying Edges' trimming, Schroeder et al. 2015).
struct Lattice<'a> {
    values: &'a [f32],
    dims: [usize; 3],
    px: usize,
    py: usize,
    pz: usize,
    level: f32,
    inside: Vec<u8>,
    spans: Vec<(u32, u32)>,
}

impl<'a> Lattice<'a> {
    fn new(values: &'a [f32], dims: [usize; 3], level: f32) -> Self {
        let [nx, ny, nz] = dims;
        let (px, py, pz) = (nx + 2, ny + 2, nz + 2);
        let mut inside = vec![0u8; px * py * pz];
        let mut spans = vec![(0u32, 0u32); py * pz];
        inside
            .par_chunks_mut(px * py)
            .zip(spans.par_chunks_mut(py))
            .enumerate()
            .for_each(|(r, (layer, spans))| {
                if r == 0 || r > nz {
                    return;
                }
                for q in 1..=ny {
                    let src = &values[nx * (q - 1 + ny * (r - 1))..][..nx];
                    let row = &mut layer[q * px + 1..][..nx];
                    for (b, &v) in row.iter_mut().zip(src) {
                        *b = (v > level) as u8;
                    }
                    if let Some(first) = row.iter().position(|&b| b != 0) {
                        let last = row.iter().rposition(|&b| b != 0).expect("one exists");
                        spans[q] = (first as u32 + 1, last as u32 + 2);
                    }
                }
            });
        Lattice {
            values,
            dims,
            px,
            py,
            pz,
            level,
            inside,
            spans,
        }
    }

    /// The value at lattice point `(p, q, r)` (`-inf` on the border).
    fn value(&self, p: usize, q: usize, r: usize) -> f32 {
        let [nx, ny, nz] = self.dims;
        if p == 0 || q == 0 || r == 0 || p > nx || q > ny || r > nz {
            f32::NEG_INFINITY
        } else {
            self.values[p - 1 + nx * (q - 1 + ny * (r - 1))]
        }
    }

    /// Inside bits of row `q` of layer `r`.
    fn row(&self, q: usize, r: usize) -> &[u8] {
        &self.inside[(r * self.py + q) * self.px..][..self.px]
    }

    fn span(&self, q: usize, r: usize) -> (usize, usize) {
        let (a, b) = self.spans[r * self.py + q];
        (a as usize, b as usize)
    }

    /// The union of the spans of rows `rows`, widened by one point on the
    /// left (a crossing or crossed cube reaches one point beyond an inside
    /// one), as a range of `p`; empty when every row is outside.
    fn reach(&self, rows: &[(usize, usize)]) -> std::ops::Range<usize> {
        let mut lo = usize::MAX;
        let mut hi = 0;
        for &(q, r) in rows {
            let (a, b) = self.span(q, r);
            if a < b {
                lo = lo.min(a);
                hi = hi.max(b);
            }
        }
        if lo >= hi { 0..0 } else { lo - 1..hi }
    }

    /// The voxel-index position of the vertex on the edge from `(p, q, r)`
    /// along `axis`.
    fn point(&self, at: [usize; 3], axis: usize) -> [f64; 3] {
        let [p, q, r] = at;
        let mut end = at;
        end[axis] += 1;
        let (va, vb) = (self.value(p, q, r), self.value(end[0], end[1], end[2]));
        let t = if va == f32::NEG_INFINITY {
            1.0
        } else if vb == f32::NEG_INFINITY {
            0.0
        } else {
            ((self.level - va) / (vb - va)) as f64
        }
        .clamp(CORNER_CLEARANCE, 1.0 - CORNER_CLEARANCE);
        let mut out = [p as f64 - 1.0, q as f64 - 1.0, r as f64 - 1.0];
        out[axis] += t;
        out
    }

    /// Numbers the crossed X and Y edges of layer `r` from `next`: X edges row
    /// by row, then Y edges, in `maps.x` and `maps.y`. `emit` gets each
    /// vertex's position.
    fn number_xy(
        &self,
        r: usize,
        maps: &mut EdgeMaps,
        next: &mut u32,
        mut emit: impl FnMut([f64; 3]),
    ) {
        let px = self.px;
        for q in 0..self.py {
            let row = self.row(q, r);
            differing(row, &row[1..], self.reach(&[(q, r)]), |p| {
                maps.x[q * px + p] = *next;
                *next += 1;
                emit(self.point([p, q, r], 0));
            });
        }
        for q in 0..self.py - 1 {
            let (row, up) = (self.row(q, r), self.row(q + 1, r));
            differing(row, up, self.reach(&[(q, r), (q + 1, r)]), |p| {
                maps.y[q * px + p] = *next;
                *next += 1;
                emit(self.point([p, q, r], 1));
            });
        }
    }

    /// Numbers the crossed Z edges from layer `r` to `r + 1` from `next`.
    fn number_z(
        &self,
        r: usize,
        maps: &mut EdgeMaps,
        next: &mut u32,
        mut emit: impl FnMut([f64; 3]),
    ) {
        for q in 0..self.py {
            let (row, above) = (self.row(q, r), self.row(q, r + 1));
            differing(row, above, self.reach(&[(q, r), (q, r + 1)]), |p| {
                maps.z[q * self.px + p] = *next;
                *next += 1;
                emit(self.point([p, q, r], 2));
            });
        }
    }

    /// Calls `cube(p, q, case)` for every cube of layer `r` the surface
    /// crosses, in order.
    fn crossed_cubes(&self, r: usize, mut cube: impl FnMut(usize, usize, u8)) {
        for q in 0..self.py - 1 {
            let reach = self.reach(&[(q, r), (q + 1, r), (q, r + 1), (q + 1, r + 1)]);
            let rows = [
                self.row(q, r),
                self.row(q + 1, r),
                self.row(q, r + 1),
                self.row(q + 1, r + 1),
            ];
            let code =
                |i: usize| rows[0][i] | (rows[1][i] << 1) | (rows[2][i] << 2) | (rows[3][i] << 3);
            // Cube p is crossed where its corners differ: where the four rows
            // disagree at p or at p + 1, or agree at both but change between.
            let mut p = reach.start;
            while p < reach.end {
                let w: [u64; 4] = std::array::from_fn(|k| word(rows[k], p));
                let v: [u64; 4] = std::array::from_fn(|k| word(rows[k], p + 1));
                let (any, all) = (w[0] | w[1] | w[2] | w[3], w[0] & w[1] & w[2] & w[3]);
                let (any1, all1) = (v[0] | v[1] | v[2] | v[3], v[0] & v[1] & v[2] & v[3]);
                let mut x = (any ^ all) | (any1 ^ all1) | (any ^ any1);
                if reach.end - p < 8 {
                    x &= (1u64 << (8 * (reach.end - p))) - 1;
                }
                while x != 0 {
                    let at = p + x.trailing_zeros() as usize / 8;
                    cube(
                        at,
                        q,
                        LEFT[code(at) as usize] | RIGHT[code(at + 1) as usize],
                    );
                    x &= x - 1;
                }
                p += 8;
            }
        }
    }
}

/// Eight bytes of `s` from `at` as a word (zero past the end).
fn word(s: &[u8], at: usize) -> u64 {
    match s.get(at..at + 8) {
        Some(b) => u64::from_le_bytes(b.try_into().expect("eight bytes")),
        None => {
            let mut b = [0u8; 8];
            let n = s.len().saturating_sub(at).min(8);
            b[..n].copy_from_slice(&s[at..at + n]);
            u64::from_le_bytes(b)
        }
    }
}

/// Calls `f(p)` for every `p` in `range` where `a[p] != b[p]`, eight places
/// at a time: the bytes are 0 or 1, and most places agree.
fn differing(a: &[u8], b: &[u8], range: std::ops::Range<usize>, mut f: impl FnMut(usize)) {
    let mut p = range.start;
    while p < range.end {
        let mut x = word(a, p) ^ word(b, p);
        if range.end - p < 8 {
            x &= (1u64 << (8 * (range.end - p))) - 1;
        }
        while x != 0 {
            f(p + x.trailing_zeros() as usize / 8);
            x &= x - 1;
        }
        p += 8;
    }
}

/// Where each crossed edge's vertex is, by the lattice point that owns it:
/// index maps for the X and Y edges of one layer and the Z edges from it.
/// Entries of uncrossed edges are stale and never read.
struct EdgeMaps {
    x: Vec<u32>,
    y: Vec<u32>,
    z: Vec<u32>,
}

impl EdgeMaps {
    fn new(n: usize) -> Self {
        EdgeMaps {
            x: vec![0; n],
            y: vec![0; n],
            z: vec![0; n],
        }
    }
}

/// Tags on a chunk's vertex references, resolved when the chunks are joined:
/// the next chunk's edge vertex, or one of this chunk's cycle centres (no
/// tag: one of this chunk's edge vertices).
const NEXT_CHUNK: u32 = 1 << 30;
const CENTRE: u32 = 2 << 30;
const INDEX: u32 = NEXT_CHUNK - 1;

/// One chunk of cube layers' part of the mesh, with chunk-local references.
#[derive(Default)]
struct Part {
    edges: Vec<[f32; 3]>,
    centres: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
}

/// For each cube edge: the offsets of its lower corner and its axis.
const EDGE_ORIGINS: [([usize; 3], usize); 12] = {
    let mut out = [([0, 0, 0], 0); 12];
    let mut e = 0;
    while e < 12 {
        let (a, b) = (CORNERS[EDGES[e][0]], CORNERS[EDGES[e][1]]);
        let axis = if a[0] != b[0] {
            0
        } else if a[1] != b[1] {
            1
        } else {
            2
        };
        out[e] = (if a[axis] < b[axis] { a } else { b }, axis);
        e += 1;
    }
    out
};

/// The isosurface `value = level` of a volume (`values` on `grid`), enclosing
/// the voxels above `level`, in patient mm.
///
/// The lattice's inside bits and row spans are found first. Then chunks of
/// cube layers are contoured in parallel, each into its own part with
/// chunk-local vertex numbers: edge vertices numbered layer by layer (X, Y,
/// then Z edges), and the X and Y edges of its top layer, which belong to
/// the next chunk, numbered as that chunk numbers them. Joining the parts
/// offsets the numbers; centres come after every edge vertex and triangles
/// cube by cube, so the mesh is the same for any number of chunks and
/// threads.
///
/// # Examples
///
/// ```
/// use fusegraph_engine::value::Grid;
/// use fusegraph_nodes::mri::marching_cubes;
///
/// // One bright voxel in a 3 x 3 x 3 volume with 2 mm voxels: the level
/// // halfway between it and its neighbours cuts every edge from it at its
/// // midpoint, 1 mm away, giving an octahedron of radius 1 mm.
/// let mut values = vec![0.0f32; 27];
/// values[13] = 1.0;
/// let grid = Grid::axis_aligned([3, 3, 3], [2.0; 3], [0.0; 3]);
/// let mesh = marching_cubes(&values, &grid, 0.5);
/// assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (6, 8));
/// assert!(mesh.is_closed_and_oriented());
/// // Octahedron volume 4/3 r^3 with r = 1 mm, centred on the voxel at (2, 2, 2) mm.
/// assert!((mesh.volume() - 4.0 / 3.0).abs() < 1e-6);
/// for v in &mesh.vertices {
///     let r: f32 = v.iter().map(|c| (c - 2.0).powi(2)).sum::<f32>().sqrt();
///     assert!((r - 1.0).abs() < 1e-6);
/// }
/// ```
pub fn marching_cubes(values: &[f32], grid: &Grid, level: f32) -> TriangleMesh {
    let lat = Lattice::new(values, grid.dims, level);
    let table = table();
    let cube_layers = lat.pz - 1;
    let chunks = (rayon::current_num_threads() * 4).clamp(1, cube_layers);
    let plane = lat.px * lat.py;
    let to_patient = |p: [f64; 3]| grid.to_patient(p).map(|x| x as f32);
    let parts: Vec<Part> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let (r0, r1) = (c * cube_layers / chunks, (c + 1) * cube_layers / chunks);
            let mut part = Part::default();
            // Maps of the layer the cubes sit on and of the one above.
            let (mut low, mut high) = (EdgeMaps::new(plane), EdgeMaps::new(plane));
            let mut next = 0u32;
            let edges = &mut part.edges;
            let mut emit = |v: [f64; 3]| edges.push(to_patient(v));
            lat.number_xy(r0, &mut low, &mut next, &mut emit);
            for r in r0..r1 {
                lat.number_z(r, &mut low, &mut next, &mut emit);
                // The X and Y edges of layer r + 1: this chunk's own, or the
                // next chunk's first, numbered as it numbers them.
                if r + 1 < r1 {
                    lat.number_xy(r + 1, &mut high, &mut next, &mut emit);
                } else {
                    let mut theirs = NEXT_CHUNK;
                    lat.number_xy(r + 1, &mut high, &mut theirs, |_| {});
                }
                lat.crossed_cubes(r, |p, q, case| {
                    let entry = &table[case as usize];
                    let first_centre = CENTRE | part.centres.len() as u32;
                    for cycle in &entry.centres {
                        let mut sum = [0.0f64; 3];
                        for &e in cycle {
                            let (o, axis) = EDGE_ORIGINS[e as usize];
                            let v = lat.point([p + o[0], q + o[1], r + o[2]], axis);
                            (0..3).for_each(|x| sum[x] += v[x] / cycle.len() as f64);
                        }
                        part.centres.push(to_patient(sum));
                    }
                    for tri in &entry.triangles {
                        part.triangles.push(tri.map(|e| {
                            if e >= 12 {
                                return first_centre + (e - 12) as u32;
                            }
                            let (o, axis) = EDGE_ORIGINS[e as usize];
                            let at = (q + o[1]) * lat.px + p + o[0];
                            let maps = if o[2] == 0 { &low } else { &high };
                            match axis {
                                0 => maps.x[at],
                                1 => maps.y[at],
                                _ => low.z[at],
                            }
                        }));
                    }
                });
                std::mem::swap(&mut low, &mut high);
            }
            part
        })
        .collect();
    // Join: each chunk's numbers offset by the vertices before it.
    let total_edges: usize = parts.iter().map(|p| p.edges.len()).sum();
    assert!(
        total_edges + parts.iter().map(|p| p.centres.len()).sum::<usize>() < INDEX as usize,
        "more than 2^30 vertices"
    );
    let (mut edge_base, mut centre_base, mut tri_base) =
        (vec![0u32], vec![total_edges as u32], vec![0usize]);
    for p in &parts {
        edge_base.push(edge_base.last().expect("one") + p.edges.len() as u32);
        centre_base.push(centre_base.last().expect("one") + p.centres.len() as u32);
        tri_base.push(tri_base.last().expect("one") + p.triangles.len());
    }
    let mut vertices = Vec::with_capacity(*centre_base.last().expect("one") as usize);
    for p in &parts {
        vertices.extend_from_slice(&p.edges);
    }
    for p in &parts {
        vertices.extend_from_slice(&p.centres);
    }
    let flip = determinant(grid) < 0.0;
    let mut triangles = vec![[0u32; 3]; *tri_base.last().expect("one")];
    let mut slices = Vec::with_capacity(chunks);
    let mut rest = triangles.as_mut_slice();
    for p in &parts {
        let (mine, tail) = std::mem::take(&mut rest).split_at_mut(p.triangles.len());
        slices.push(mine);
        rest = tail;
    }
    parts
        .par_iter()
        .zip(slices)
        .enumerate()
        .for_each(|(c, (part, out))| {
            let resolve = |v: u32| match v & !INDEX {
                0 => edge_base[c] + v,
                NEXT_CHUNK => edge_base[c + 1] + (v & INDEX),
                _ => centre_base[c] + (v & INDEX),
            };
            for (o, t) in out.iter_mut().zip(&part.triangles) {
                let [a, b, d] = t.map(resolve);
                *o = if flip { [a, d, b] } else { [a, b, d] };
            }
        });
    TriangleMesh {
        vertices,
        triangles,
    }
}

fn determinant(grid: &Grid) -> f64 {
    let m = &grid.voxel_to_patient;
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

impl TriangleMesh {
    /// The sum of `f` over the triangles, in parallel over fixed blocks added
    /// in order: the same bits on any number of threads.
    fn sum_over_triangles(&self, f: impl Fn(&[u32; 3]) -> f64 + Sync) -> f64 {
        const BLOCK: usize = 8192;
        let blocks: Vec<f64> = self
            .triangles
            .par_chunks(BLOCK)
            .map(|b| b.iter().map(&f).sum::<f64>())
            .collect();
        blocks.iter().sum()
    }

    /// Enclosed volume (mm3, positive for outward-facing triangles).
    pub fn volume(&self) -> f64 {
        self.sum_over_triangles(|t| {
            let [a, b, c] = t.map(|i| self.vertices[i as usize].map(f64::from));
            a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0])
        }) / 6.0
    }

    /// Surface area, mm2.
    pub fn area(&self) -> f64 {
        self.sum_over_triangles(|t| {
            0.5 * self
                .face_normal(t)
                .iter()
                .map(|x| x * x)
                .sum::<f64>()
                .sqrt()
        })
    }

    /// Unnormalised face normal (twice the area).
    fn face_normal(&self, t: &[u32; 3]) -> [f64; 3] {
        self.corner_and_face_normal(t).1
    }

    /// A triangle's first corner and its unnormalised face normal (twice
    /// the area), mm and mm2. Scalar code: written with `[0, 1, 2].map` over
    /// f64 it compiled five times slower.
    #[inline]
    fn corner_and_face_normal(&self, t: &[u32; 3]) -> ([f64; 3], [f64; 3]) {
        let [a, b, c] = t.map(|i| self.vertices[i as usize]);
        let (ax, ay, az) = (f64::from(a[0]), f64::from(a[1]), f64::from(a[2]));
        let (ux, uy, uz) = (
            f64::from(b[0]) - ax,
            f64::from(b[1]) - ay,
            f64::from(b[2]) - az,
        );
        let (vx, vy, vz) = (
            f64::from(c[0]) - ax,
            f64::from(c[1]) - ay,
            f64::from(c[2]) - az,
        );
        (
            [ax, ay, az],
            [uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx],
        )
    }

    /// Unit vertex normals: area-weighted means of the adjacent face normals.
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        self.area_volume_normals().2
    }

    /// Area (mm2), enclosed volume (mm3) and unit vertex normals in one pass.
    /// The triangles are split into a fixed number of parts, each summed into
    /// its own accumulators in parallel and the parts added in order, so the
    /// bits do not depend on the number of threads.
    pub fn area_volume_normals(&self) -> (f64, f64, Vec<[f32; 3]>) {
        const PARTS: usize = 2;
        let n = self.vertices.len();
        let per = self.triangles.len().div_ceil(PARTS).max(1);
        // Normals accumulate in f32: a direction needs no more, and the
        // accumulators are half the memory to clear and add.
        let parts: Vec<(f64, f64, Vec<[f32; 3]>)> = self
            .triangles
            .par_chunks(per)
            .map(|tris| {
                let mut acc = vec![[0.0f32; 3]; n];
                let (mut area, mut volume) = (0.0, 0.0);
                for t in tris {
                    let ([ax, ay, az], [fx, fy, fz]) = self.corner_and_face_normal(t);
                    area += 0.5 * (fx * fx + fy * fy + fz * fz).sqrt();
                    // a . (b x c) = a . (u x v) for u, v from a.
                    volume += ax * fx + ay * fy + az * fz;
                    let f32s = [fx as f32, fy as f32, fz as f32];
                    for &i in t {
                        let n = &mut acc[i as usize];
                        n[0] += f32s[0];
                        n[1] += f32s[1];
                        n[2] += f32s[2];
                    }
                }
                (area, volume / 6.0, acc)
            })
            .collect();
        let normals = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut s = [0.0f64; 3];
                for p in &parts {
                    (0..3).for_each(|x| s[x] += f64::from(p.2[i][x]));
                }
                let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt().max(1e-30);
                s.map(|x| (x / len) as f32)
            })
            .collect();
        let area = parts.iter().map(|p| p.0).sum();
        let volume = parts.iter().map(|p| p.1).sum();
        (area, volume, normals)
    }

    /// Whether every edge is shared by exactly two triangles, in opposite
    /// directions (a closed, consistently oriented surface).
    pub fn is_closed_and_oriented(&self) -> bool {
        let mut directed = std::collections::HashMap::new();
        for t in &self.triangles {
            for e in 0..3 {
                *directed.entry((t[e], t[(e + 1) % 3])).or_insert(0u32) += 1;
            }
        }
        directed
            .iter()
            .all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
    }

    /// Taubin smoothing (lambda 0.5, mu -0.53): shrink-free removal of the
    /// voxel staircase, `iterations` pairs of passes. Linear in the mesh
    /// size; each pass is parallel over the vertices and reads only the
    /// previous pass's positions, so the bits do not depend on the threads.
    pub fn smooth(&mut self, iterations: usize) {
        if iterations == 0 {
            return;
        }
        let neighbours = Neighbours::of(self);
        let mut previous = self.vertices.clone();
        for _ in 0..iterations {
            for factor in [0.5f32, -0.53] {
                std::mem::swap(&mut previous, &mut self.vertices);
                self.vertices.par_iter_mut().enumerate().for_each(|(i, v)| {
                    let old = previous[i];
                    let n = neighbours.of_vertex(i);
                    *v = old;
                    if n.is_empty() {
                        return;
                    }
                    let mut mean = [0.0f32; 3];
                    for &j in n {
                        (0..3).for_each(|x| mean[x] += previous[j as usize][x]);
                    }
                    (0..3).for_each(|x| v[x] += factor * (mean[x] / n.len() as f32 - v[x]));
                });
            }
        }
    }
}

/// Each vertex's neighbours along the mesh's edges, ascending and without
/// repeats, in one flat array (compressed rows).
struct Neighbours {
    /// Vertex i's neighbours are `flat[start[i]..start[i + 1]]`.
    start: Vec<usize>,
    flat: Vec<u32>,
}

impl Neighbours {
    fn of(mesh: &TriangleMesh) -> Self {
        let n = mesh.vertices.len();
        // Every triangle names two neighbours of each of its corners (most
        // twice over: an edge has two triangles); count, place, then sort
        // and drop the repeats per vertex.
        let mut start = vec![0usize; n + 1];
        for t in &mesh.triangles {
            for &v in t {
                start[v as usize + 1] += 2;
            }
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut flat = vec![0u32; start[n]];
        let mut cursor = start[..n].to_vec();
        for t in &mesh.triangles {
            for e in 0..3 {
                let v = t[e] as usize;
                flat[cursor[v]] = t[(e + 1) % 3];
                flat[cursor[v] + 1] = t[(e + 2) % 3];
                cursor[v] += 2;
            }
        }
        let mut rows: Vec<&mut [u32]> = Vec::with_capacity(n);
        let mut rest = flat.as_mut_slice();
        for i in 0..n {
            let (row, tail) = rest.split_at_mut(start[i + 1] - start[i]);
            rows.push(row);
            rest = tail;
        }
        let lengths: Vec<usize> = rows
            .into_par_iter()
            .map(|row| {
                row.sort_unstable();
                let mut kept = 0;
                for k in 0..row.len() {
                    if k == 0 || row[k] != row[kept - 1] {
                        row[kept] = row[k];
                        kept += 1;
                    }
                }
                kept
            })
            .collect();
        // Close the gaps the repeats left.
        let mut write = 0;
        for i in 0..n {
            let read = start[i];
            flat.copy_within(read..read + lengths[i], write);
            start[i] = write;
            write += lengths[i];
        }
        start[n] = write;
        flat.truncate(write);
        Self { start, flat }
    }

    fn of_vertex(&self, i: usize) -> &[u32] {
        &self.flat[self.start[i]..self.start[i + 1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_case_is_closed_inside_its_cube() {
        // Each cube edge used by a case is crossed, and appears in its triangles
        // an even number of times per polygon boundary (checked via closedness
        // of random volumes below); here: the table uses exactly the crossed edges.
        for case in 0..=255u8 {
            let crossed: Vec<usize> = (0..12)
                .filter(|&e| {
                    let [a, b] = EDGES[e];
                    ((case >> a) & 1) != ((case >> b) & 1)
                })
                .collect();
            let entry = &table()[case as usize];
            let mut used: Vec<usize> = entry
                .triangles
                .iter()
                .flatten()
                .filter(|&&e| e < 12)
                .map(|&e| e as usize)
                .collect();
            used.sort();
            used.dedup();
            assert_eq!(used, crossed, "case {case}");
        }
        assert_eq!(table()[1].triangles.len(), 1);
        assert_eq!(
            table()[0b0110_1001].triangles.len(),
            4,
            "four separate corners"
        );
    }

    fn sphere(n: usize, radius: f64) -> (Vec<f32>, Grid) {
        let c = (n as f64 - 1.0) / 2.0;
        let values = (0..n * n * n)
            .map(|idx| {
                let (i, j, k) = (idx % n, (idx / n) % n, idx / (n * n));
                let d = ((i as f64 - c).powi(2) + (j as f64 - c).powi(2) + (k as f64 - c).powi(2))
                    .sqrt();
                (radius - d) as f32
            })
            .collect();
        (values, Grid::axis_aligned([n; 3], [1.0; 3], [0.0; 3]))
    }

    #[test]
    fn every_single_cube_case_is_closed() {
        let grid = Grid::axis_aligned([2, 2, 2], [1.0; 3], [0.0; 3]);
        let mut bad = Vec::new();
        for case in 1..255u16 {
            let values: Vec<f32> = (0..8)
                .map(|idx| {
                    let (i, j, k) = (idx % 2, (idx / 2) % 2, idx / 4);
                    let c = CORNERS.iter().position(|o| *o == [i, j, k]).unwrap();
                    if case & (1 << c) != 0 { 1.0 } else { -1.0 }
                })
                .collect();
            let mesh = marching_cubes(&values, &grid, 0.0);
            if !mesh.is_closed_and_oriented() || mesh.volume() <= 0.0 {
                bad.push(case);
            }
        }
        assert!(bad.is_empty(), "{bad:?}");
    }

    #[test]
    fn sphere_area_and_volume_within_one_percent() {
        let r = 20.0;
        let (values, grid) = sphere(48, r);
        let mesh = marching_cubes(&values, &grid, 0.0);
        assert!(mesh.is_closed_and_oriented());
        let (area, volume) = (
            4.0 * std::f64::consts::PI * r * r,
            4.0 / 3.0 * std::f64::consts::PI * r.powi(3),
        );
        assert!(
            (mesh.area() / area - 1.0).abs() < 0.01,
            "area {} vs {area}",
            mesh.area()
        );
        assert!(
            (mesh.volume() / volume - 1.0).abs() < 0.01,
            "volume {} vs {volume}",
            mesh.volume()
        );
        // No duplicate vertices.
        let mut v: Vec<[u32; 3]> = mesh.vertices.iter().map(|p| p.map(f32::to_bits)).collect();
        v.sort();
        let before = v.len();
        v.dedup();
        assert_eq!(v.len(), before);
    }

    #[test]
    fn random_volumes_give_closed_oriented_surfaces() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        for _ in 0..20 {
            let n = 7;
            let values: Vec<f32> = (0..n * n * n)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let grid = Grid::axis_aligned([n; 3], [0.5, 0.7, 1.1], [3.0, -2.0, 1.0]);
            let mesh = marching_cubes(&values, &grid, 0.1);
            assert!(mesh.is_closed_and_oriented());
            // Padding closes everything: the volume is positive.
            assert!(mesh.volume() > 0.0);
        }
    }

    #[test]
    fn the_same_mesh_on_any_number_of_threads_and_chunks() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let (nx, ny, nz) = (23, 17, 41);
        let values: Vec<f32> = (0..nx * ny * nz)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let grid = Grid::axis_aligned([nx, ny, nz], [0.6, 0.6, 1.0], [0.0, 0.0, 0.0]);
        let one = crate::on_threads(1, || marching_cubes(&values, &grid, 0.2));
        assert!(one.is_closed_and_oriented() && one.triangles.len() > 5000);
        for threads in [2, 3, 7] {
            let many = crate::on_threads(threads, || marching_cubes(&values, &grid, 0.2));
            assert!(many == one, "{threads} threads");
        }
    }

    #[test]
    fn mirrored_grids_keep_normals_outward() {
        let (values, _) = sphere(24, 8.0);
        let mut grid = Grid::axis_aligned([24; 3], [1.0; 3], [0.0; 3]);
        grid.voxel_to_patient[0][0] = -1.0;
        let mesh = marching_cubes(&values, &grid, 0.0);
        assert!(mesh.is_closed_and_oriented());
        assert!(mesh.volume() > 0.0, "{}", mesh.volume());
    }

    #[test]
    fn smoothing_keeps_volume() {
        let (values, grid) = sphere(40, 15.0);
        let binary: Vec<f32> = values
            .iter()
            .map(|&v| if v > 0.0 { 1.0 } else { 0.0 })
            .collect();
        let mut mesh = marching_cubes(&binary, &grid, 0.5);
        let before = mesh.volume();
        mesh.smooth(10);
        assert!((mesh.volume() / before - 1.0).abs() < 0.02);
        assert!(mesh.is_closed_and_oriented());
    }

    /// The compressed neighbour rows and parallel passes give the bits of
    /// the plain definition: each vertex moved towards the mean of its
    /// distinct neighbours, in ascending order, from the previous pass.
    #[test]
    fn smoothing_is_the_plain_taubin_definition_on_any_thread_count() {
        let (values, grid) = sphere(24, 8.0);
        let binary: Vec<f32> = values
            .iter()
            .map(|&v| if v > 0.0 { 1.0 } else { 0.0 })
            .collect();
        let mesh = marching_cubes(&binary, &grid, 0.5);
        let mut sets = vec![std::collections::BTreeSet::new(); mesh.vertices.len()];
        for t in &mesh.triangles {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                sets[a as usize].insert(b);
                sets[b as usize].insert(a);
            }
        }
        let mut expected = mesh.vertices.clone();
        for _ in 0..3 {
            for factor in [0.5f32, -0.53] {
                let current = expected.clone();
                for (i, v) in expected.iter_mut().enumerate() {
                    let n = &sets[i];
                    let mut mean = [0.0f32; 3];
                    for &j in n {
                        (0..3).for_each(|x| mean[x] += current[j as usize][x]);
                    }
                    (0..3).for_each(|x| v[x] += factor * (mean[x] / n.len() as f32 - v[x]));
                }
            }
        }
        for threads in [1, 3] {
            let mut smoothed = mesh.clone();
            crate::on_threads(threads, || smoothed.smooth(3));
            assert!(smoothed.vertices == expected, "{threads} threads");
        }
    }
}
