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

/// One slab's output: (edge or centre id, position in voxel indices) of every
/// vertex it used, and its triangles as vertex ids.
type Slab = (Vec<(u64, [f64; 3])>, Vec<[u64; 3]>);

/// A triangle mesh in patient mm.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleMesh {
    /// Vertex positions, mm.
    pub vertices: Vec<[f32; 3]>,
    /// Vertex indices, counter-clockwise seen from outside (normals point to
    /// values below the level).
    pub triangles: Vec<[u32; 3]>,
}

/// The isosurface `value = level` of a volume (`values` on `grid`), enclosing
/// the voxels above `level`, in patient mm.
pub fn marching_cubes(values: &[f32], grid: &Grid, level: f32) -> TriangleMesh {
    let [nx, ny, nz] = grid.dims;
    let table = table();
    // Padded lattice: indices -1..=n, outside the grid counts as outside.
    let value = |i: isize, j: isize, k: isize| -> f32 {
        if i < 0 || j < 0 || k < 0 || i >= nx as isize || j >= ny as isize || k >= nz as isize {
            f32::NEG_INFINITY
        } else {
            values[i as usize + nx * (j as usize + ny * k as usize)]
        }
    };
    let (px, py) = (nx as u64 + 2, ny as u64 + 2);
    // Ids of cycle-centre vertices come after every lattice edge id.
    let centre_base = 3 * px * py * (nz as u64 + 2);
    let edge_id = |i: isize, j: isize, k: isize, axis: u64| {
        let lattice = (i + 1) as u64 + px * ((j + 1) as u64 + py * (k + 1) as u64);
        lattice * 3 + axis
    };
    let slabs: Vec<Slab> = (-1..nz as isize)
        .into_par_iter()
        .map(|k| {
            let mut verts = Vec::new();
            let mut tris = Vec::new();
            for j in -1..ny as isize {
                for i in -1..nx as isize {
                    let interior = i >= 0
                        && j >= 0
                        && k >= 0
                        && i + 1 < nx as isize
                        && j + 1 < ny as isize
                        && k + 1 < nz as isize;
                    let v: [f32; 8] = if interior {
                        // Most cubes: direct reads, no padding checks.
                        let base = i as usize + nx * (j as usize + ny * k as usize);
                        let (dy, dz) = (nx, nx * ny);
                        [
                            values[base],
                            values[base + 1],
                            values[base + 1 + dy],
                            values[base + dy],
                            values[base + dz],
                            values[base + 1 + dz],
                            values[base + 1 + dy + dz],
                            values[base + dy + dz],
                        ]
                    } else {
                        std::array::from_fn(|c| {
                            let o = CORNERS[c];
                            value(i + o[0] as isize, j + o[1] as isize, k + o[2] as isize)
                        })
                    };
                    let case = (0..8).fold(0u8, |acc, c| acc | (((v[c] > level) as u8) << c));
                    if case == 0 || case == 255 {
                        continue;
                    }
                    let entry = &table[case as usize];
                    let edge_point = |e: usize| {
                        let [a, b] = EDGES[e];
                        let (oa, ob) = (CORNERS[a], CORNERS[b]);
                        let (va, vb) = (v[a], v[b]);
                        let t = if va == f32::NEG_INFINITY {
                            1.0
                        } else if vb == f32::NEG_INFINITY {
                            0.0
                        } else {
                            (((level - va) / (vb - va)) as f64)
                                .clamp(CORNER_CLEARANCE, 1.0 - CORNER_CLEARANCE)
                        };
                        let p: [f64; 3] = std::array::from_fn(|x| {
                            let (ca, cb) = (oa[x] as f64, ob[x] as f64);
                            [i, j, k][x] as f64 + ca + t * (cb - ca)
                        });
                        p
                    };
                    for tri in &entry.triangles {
                        let ids = tri.map(|e| {
                            if e >= 12 {
                                // A cycle centre: its own vertex, owned by this cube.
                                let c = (e - 12) as usize;
                                let cube =
                                    (i + 1) as u64 + px * ((j + 1) as u64 + py * (k + 1) as u64);
                                let id = centre_base + cube * 4 + c as u64;
                                let edges = &entry.centres[c];
                                let mut p = [0.0; 3];
                                for &ce in edges {
                                    let q = edge_point(ce as usize);
                                    (0..3).for_each(|x| p[x] += q[x] / edges.len() as f64);
                                }
                                verts.push((id, p));
                                return id;
                            }
                            let [a, b] = EDGES[e as usize];
                            let (oa, ob) = (CORNERS[a], CORNERS[b]);
                            let axis = (0..3)
                                .find(|&x| oa[x] != ob[x])
                                .expect("edge along an axis");
                            let low = if oa[axis] < ob[axis] { oa } else { ob };
                            let id = edge_id(
                                i + low[0] as isize,
                                j + low[1] as isize,
                                k + low[2] as isize,
                                axis as u64,
                            );
                            verts.push((id, edge_point(e as usize)));
                            id
                        });
                        tris.push(ids);
                    }
                }
            }
            (verts, tris)
        })
        .collect();
    let mut verts: Vec<(u64, [f64; 3])> = slabs.iter().flat_map(|s| s.0.iter().copied()).collect();
    verts.par_sort_unstable_by_key(|v| v.0);
    verts.dedup_by_key(|v| v.0);
    let flip = determinant(grid) < 0.0;
    let vertices: Vec<[f32; 3]> = verts
        .par_iter()
        .map(|(_, p)| grid.to_patient(*p).map(|x| x as f32))
        .collect();
    let index_of = |id: u64| {
        verts
            .binary_search_by_key(&id, |v| v.0)
            .expect("vertex recorded") as u32
    };
    let triangles: Vec<[u32; 3]> = slabs
        .par_iter()
        .flat_map_iter(|s| s.1.iter())
        .map(|t| {
            let [a, b, c] = t.map(index_of);
            // A left-handed voxel -> patient map mirrors the mesh: undo it.
            if flip { [a, c, b] } else { [a, b, c] }
        })
        .collect();
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
    /// Enclosed volume (mm3, positive for outward-facing triangles).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize].map(f64::from));
                a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0])
            })
            .sum::<f64>()
            / 6.0
    }

    /// Surface area, mm2.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                0.5 * self
                    .face_normal(t)
                    .iter()
                    .map(|x| x * x)
                    .sum::<f64>()
                    .sqrt()
            })
            .sum()
    }

    /// Unnormalised face normal (twice the area).
    fn face_normal(&self, t: &[u32; 3]) -> [f64; 3] {
        let [a, b, c] = t.map(|i| self.vertices[i as usize].map(f64::from));
        let (u, v) = (
            [0, 1, 2].map(|x| b[x] - a[x]),
            [0, 1, 2].map(|x| c[x] - a[x]),
        );
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    }

    /// Unit vertex normals: area-weighted means of the adjacent face normals.
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        let mut acc = vec![[0.0f64; 3]; self.vertices.len()];
        for t in &self.triangles {
            let n = self.face_normal(t);
            for &i in t {
                (0..3).for_each(|x| acc[i as usize][x] += n[x]);
            }
        }
        acc.iter()
            .map(|n| {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-30);
                n.map(|x| (x / len) as f32)
            })
            .collect()
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
    /// voxel staircase, `iterations` pairs of passes.
    pub fn smooth(&mut self, iterations: usize) {
        if iterations == 0 {
            return;
        }
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); self.vertices.len()];
        for t in &self.triangles {
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                neighbours[a as usize].push(b);
                neighbours[b as usize].push(a);
            }
        }
        neighbours.par_iter_mut().for_each(|n| {
            n.sort_unstable();
            n.dedup();
        });
        for _ in 0..iterations {
            for factor in [0.5f32, -0.53] {
                let current = self.vertices.clone();
                self.vertices.par_iter_mut().enumerate().for_each(|(i, v)| {
                    let n = &neighbours[i];
                    if n.is_empty() {
                        return;
                    }
                    let mut mean = [0.0f32; 3];
                    for &j in n {
                        (0..3).for_each(|x| mean[x] += current[j as usize][x]);
                    }
                    (0..3).for_each(|x| v[x] += factor * (mean[x] / n.len() as f32 - v[x]));
                });
            }
        }
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
}
