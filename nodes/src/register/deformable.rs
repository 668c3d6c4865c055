//! Nonrigid registration after a rigid one: a smooth displacement field u
//! that takes the scanned skin (and the scan's markers) onto the skin seen
//! now (and the markers seen now), so that a point of the scan at x lies
//! now at x + u(x) in the same (rigidly registered) frame. Interior points,
//! the lesions, move by the same field.
//!
//! **The field** is trilinear on a lattice of nodes `spacing_mm` apart
//! covering the scanned skin (and a margin): defined everywhere inside the
//! breast, not only on its surface.
//!
//! **The fit** is a nonrigid ICP (Amberg, Romdhani & Vetter, "Optimal step
//! nonrigid ICP algorithms for surface registration", CVPR 2007) on that
//! lattice. Each step pairs every point seen now with the nearest point of
//! the moved scan and minimises, over the nodes' displacements,
//!
//! E(u) = 1/N_s sum_j (n_j . (s_j + u(s_j) - c_j))^2
//!      + w_L / N_L sum_i |P_i (m_i + u(m_i) - k_i)|^2
//!      + L^4 / N_t sum_lines |u_a - 2 u_b + u_c|^2 / h^4,
//!
//! - the surface term point-to-plane along the scan's normal n_j: a smooth
//!   surface says how far it moved across itself, never along (a dome slides
//!   along itself unseen; point-to-point pairs would drag it);
//! - the landmark term across the normal only (P_i = I - n n^T): the camera
//!   sees a marker's face, the scan its gel a few mm deeper, but both sit at
//!   the same place along the skin, which is what the surfaces cannot say;
//! - the bending term over every three nodes in a line along an axis (h the
//!   spacing): the mean squared second derivative of the field, weighted by
//!   `stiffness_mm` L to the fourth (L: the surface residual, mm, that a
//!   bend of 1 / L is worth). Where there are no data (the breast's inside,
//!   the skin the camera does not see) the field continues the surfaces'
//!   trend, linearly: a membrane (first derivatives) would fill it with the
//!   surfaces' mean instead, which on a sag seen from above moved the
//!   inside 2-3 times too far (0.6-1.8 mm off at 15-40 mm depth where this
//!   gives 0.15-0.7). A membrane term 1e-4 as heavy keeps the lattice's far
//!   corners, which no data reach, from drifting.
//!
//! Stiffness starts 16 times higher and is lowered by 4 twice (coarse
//! motion first, as Amberg et al. do). Each system is solved by conjugate
//! gradients with a block-Jacobi preconditioner, matrix-free (a data row
//! touches 8 nodes). Written here: no Rust crate registers surfaces
//! nonrigidly.

use crate::cloud::Nearest;
use nalgebra::{Matrix3, Point3, Vector3};
use rayon::prelude::*;

/// The membrane's weight against the bending's (both scaled by the
/// stiffness): enough to keep the lattice's far corners, which no data
/// reach, from drifting along the bending's free (linear) fields, and too
/// little to pull the inside towards the surfaces' mean.
const MEMBRANE_SHARE: f64 = 0.0001;

/// The columns of a field as a table: each node's position and its
/// displacement, mm.
pub const FIELD_COLUMNS: [&str; 6] = ["x_mm", "y_mm", "z_mm", "u_x_mm", "u_y_mm", "u_z_mm"];

/// How [`fit_deformation`] fits.
#[derive(Debug, Clone, PartialEq)]
pub struct DeformParams {
    /// Lattice spacing, mm.
    pub spacing_mm: f64,
    /// Bending length L, mm: a bend of the field of 1 / L costs as much as
    /// a surface residual of L; larger gives a stiffer, smoother field.
    pub stiffness_mm: f64,
    /// The landmarks' total weight against the whole surface's.
    pub landmark_weight: f64,
    /// Pairs farther apart than this are left out, mm.
    pub max_distance_mm: f64,
    /// Share of the closest pairs kept each step (0..1].
    pub trim_ratio: f64,
    /// Correspondence steps at each stiffness.
    pub steps_per_stage: usize,
}

impl Default for DeformParams {
    fn default() -> Self {
        DeformParams {
            spacing_mm: 10.0,
            stiffness_mm: 10.0,
            landmark_weight: 0.1,
            max_distance_mm: 15.0,
            trim_ratio: 0.9,
            steps_per_stage: 4,
        }
    }
}

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

    fn node(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// The 8 nodes around `p` and their trilinear weights (clamped to the
    /// lattice).
    pub fn stencil(&self, p: &Point3<f64>) -> [(usize, f64); 8] {
        let cell: [(usize, f64); 3] = std::array::from_fn(|a| {
            let f =
                ((p[a] - self.origin[a]) / self.spacing_mm).clamp(0.0, (self.dims[a] - 1) as f64);
            let i = (f.floor() as usize).min(self.dims[a] - 2);
            (i, f - i as f64)
        });
        std::array::from_fn(|c| {
            let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let w = |(_, t): (usize, f64), d: usize| if d == 1 { t } else { 1.0 - t };
            (
                self.node(cell[0].0 + dx, cell[1].0 + dy, cell[2].0 + dz),
                w(cell[0], dx) * w(cell[1], dy) * w(cell[2], dz),
            )
        })
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

    /// The lattice's node triples in a line (one spacing apart along an
    /// axis), middle node second.
    fn triples(&self) -> Vec<[usize; 3]> {
        let [nx, ny, nz] = self.dims;
        let mut triples = Vec::with_capacity(3 * nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let b = self.node(i, j, k);
                    if i > 0 && i + 1 < nx {
                        triples.push([self.node(i - 1, j, k), b, self.node(i + 1, j, k)]);
                    }
                    if j > 0 && j + 1 < ny {
                        triples.push([self.node(i, j - 1, k), b, self.node(i, j + 1, k)]);
                    }
                    if k > 0 && k + 1 < nz {
                        triples.push([self.node(i, j, k - 1), b, self.node(i, j, k + 1)]);
                    }
                }
            }
        }
        triples
    }

    /// The lattice's edges (node pairs one spacing apart).
    fn edges(&self) -> Vec<(usize, usize)> {
        let [nx, ny, nz] = self.dims;
        let mut edges = Vec::with_capacity(3 * nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let a = self.node(i, j, k);
                    if i + 1 < nx {
                        edges.push((a, self.node(i + 1, j, k)));
                    }
                    if j + 1 < ny {
                        edges.push((a, self.node(i, j + 1, k)));
                    }
                    if k + 1 < nz {
                        edges.push((a, self.node(i, j, k + 1)));
                    }
                }
            }
        }
        edges
    }
}

/// What [`fit_deformation`] found.
#[derive(Debug, Clone)]
pub struct Deformation {
    /// The field, in the scan's (rigidly registered) frame.
    pub field: Lattice,
    /// RMS point-to-plane residual of the pairs before (no field), mm.
    pub rigid_residual_mm: f64,
    /// The same after, mm.
    pub residual_mm: f64,
    /// RMS landmark residual across the normals before and after, mm
    /// (NaN without landmarks).
    pub rigid_landmark_residual_mm: f64,
    /// The same after, mm.
    pub landmark_residual_mm: f64,
    /// Scan points paired with a point seen now at the end (the skin both
    /// see).
    pub seen: Vec<usize>,
}

/// Landmark pairs for the fit: scan positions, positions now (same frame,
/// same order).
pub struct LandmarkPairs<'a> {
    /// In the scan.
    pub scan: &'a [Point3<f64>],
    /// Now.
    pub now: &'a [Point3<f64>],
}

/// One data row: a scan point's stencil, the direction(s) it is measured
/// along, and its target.
struct SurfaceRow {
    stencil: [(usize, f64); 8],
    normal: Vector3<f64>,
    /// n . (c - s), mm.
    target: f64,
}

struct LandmarkRow {
    stencil: [(usize, f64); 8],
    /// I - n n^T.
    across: Matrix3<f64>,
    /// P (k - m), mm.
    target: Vector3<f64>,
}

/// The field taking `scan` (skin points with unit `normals`, one frame, mm,
/// already rigidly registered) onto `now` (skin points seen now, same
/// frame), with `landmarks` pulled together across the skin. An error for
/// empty or mismatched inputs or bad parameters.
pub fn fit_deformation(
    scan: &[Point3<f64>],
    normals: &[Vector3<f64>],
    now: &[Point3<f64>],
    landmarks: Option<LandmarkPairs>,
    p: &DeformParams,
) -> Result<Deformation, String> {
    check(scan, normals, now, &landmarks, p)?;
    let mut field = Lattice::covering(scan, p.spacing_mm, 2.0 * p.spacing_mm);
    let edges = field.edges();
    let triples = field.triples();
    let scan_tree = Nearest::new(scan).ok_or("the scan's skin is empty")?;
    // A landmark's row is fixed: its stencil is at its scan position.
    let lrows: Vec<LandmarkRow> = landmarks
        .as_ref()
        .map(|l| {
            l.scan
                .iter()
                .zip(l.now)
                .map(|(m, k)| {
                    let n = normals[scan_tree.nearest(m).0];
                    let across = Matrix3::identity() - n * n.transpose();
                    LandmarkRow {
                        stencil: field.stencil(m),
                        across,
                        target: across * (k - m),
                    }
                })
                .collect()
        })
        .unwrap_or_default();
    let landmark_rms = |field: &Lattice| -> f64 {
        if lrows.is_empty() {
            return f64::NAN;
        }
        let sum: f64 = lrows
            .iter()
            .map(|r| {
                let u: Vector3<f64> = r
                    .stencil
                    .iter()
                    .map(|&(n, w)| field.displacements[n] * w)
                    .sum();
                (r.across * u - r.target).norm_squared()
            })
            .sum();
        (sum / lrows.len() as f64).sqrt()
    };
    let rigid_landmark_residual_mm = landmark_rms(&field);
    let mut rigid_residual_mm = f64::NAN;
    let mut residual_mm = f64::NAN;
    let mut seen = Vec::new();
    let stages = [16.0, 4.0, 1.0];
    for (stage, &factor) in stages.iter().enumerate() {
        let stiffness2 = factor * p.stiffness_mm * p.stiffness_mm;
        for _ in 0..p.steps_per_stage {
            let (rows, paired, rms) = surface_rows(scan, normals, now, &field, p)?;
            if rigid_residual_mm.is_nan() {
                rigid_residual_mm = rms;
            }
            residual_mm = rms;
            seen = paired;
            let system = System {
                surface: &rows,
                landmarks: &lrows,
                edges: &edges,
                triples: &triples,
                nodes: field.displacements.len(),
                surface_weight: 1.0 / rows.len() as f64,
                landmark_weight: if lrows.is_empty() {
                    0.0
                } else {
                    p.landmark_weight / lrows.len() as f64
                },
                edge_weight: MEMBRANE_SHARE * stiffness2
                    / (edges.len() as f64 * p.spacing_mm * p.spacing_mm),
                bend_weight: stiffness2 * stiffness2
                    / (triples.len() as f64 * p.spacing_mm.powi(4)),
            };
            let before = field.displacements.clone();
            // The stiffer stages only set the next one's start: a rougher
            // solve serves them.
            let tolerance = if stage + 1 < stages.len() { 1e-4 } else { 1e-6 };
            field.displacements = system.solve(&field.displacements, tolerance);
            let change = before
                .iter()
                .zip(&field.displacements)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            if change < 0.01 && stage + 1 < stages.len() {
                break;
            }
        }
    }
    let (_, paired, rms) = surface_rows(scan, normals, now, &field, p)?;
    residual_mm = if paired.is_empty() { residual_mm } else { rms };
    if !paired.is_empty() {
        seen = paired;
    }
    Ok(Deformation {
        landmark_residual_mm: landmark_rms(&field),
        field,
        rigid_residual_mm,
        residual_mm,
        rigid_landmark_residual_mm,
        seen,
    })
}

fn check(
    scan: &[Point3<f64>],
    normals: &[Vector3<f64>],
    now: &[Point3<f64>],
    landmarks: &Option<LandmarkPairs>,
    p: &DeformParams,
) -> Result<(), String> {
    if scan.is_empty() || now.is_empty() {
        return Err("both skins need points".into());
    }
    if normals.len() != scan.len() {
        return Err(format!(
            "{} scan points but {} normals",
            scan.len(),
            normals.len()
        ));
    }
    if let Some(l) = landmarks
        && l.scan.len() != l.now.len()
    {
        return Err(format!(
            "{} scan landmarks and {} now: they pair in order",
            l.scan.len(),
            l.now.len()
        ));
    }
    let positive = [
        ("spacing_mm", p.spacing_mm),
        ("stiffness_mm", p.stiffness_mm),
        ("max_distance_mm", p.max_distance_mm),
    ];
    for (name, v) in positive {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!("{name} = {v}: must be positive"));
        }
    }
    if !(p.trim_ratio > 0.0 && p.trim_ratio <= 1.0) {
        return Err(format!("trim_ratio = {}: must be in (0, 1]", p.trim_ratio));
    }
    if p.landmark_weight.is_nan() || p.landmark_weight < 0.0 {
        return Err(format!(
            "landmark_weight = {}: must be >= 0",
            p.landmark_weight
        ));
    }
    Ok(())
}

/// Pairs every point seen now with the nearest point of the moved scan:
/// the rows (closest `trim_ratio` within `max_distance_mm`), the scan
/// points paired and their RMS point-to-plane residual.
fn surface_rows(
    scan: &[Point3<f64>],
    normals: &[Vector3<f64>],
    now: &[Point3<f64>],
    field: &Lattice,
    p: &DeformParams,
) -> Result<(Vec<SurfaceRow>, Vec<usize>, f64), String> {
    let moved: Vec<Point3<f64>> = scan.par_iter().map(|s| s + field.displacement(s)).collect();
    let tree = Nearest::new(&moved).ok_or("the scan's skin is empty")?;
    let max2 = p.max_distance_mm * p.max_distance_mm;
    let mut pairs: Vec<(usize, f64, f64)> = now
        .par_iter()
        .filter_map(|c| {
            let (j, d2) = tree.nearest(c);
            (d2 <= max2).then(|| {
                let n = normals[j];
                (j, n.dot(&(c - scan[j])), n.dot(&(c - moved[j])))
            })
        })
        .collect();
    if pairs.is_empty() {
        return Err(format!(
            "no point seen now lies within {} mm of the scan's skin",
            p.max_distance_mm
        ));
    }
    pairs.sort_by(|a, b| a.2.abs().total_cmp(&b.2.abs()));
    pairs.truncate(((pairs.len() as f64 * p.trim_ratio).ceil() as usize).max(1));
    let rms = (pairs.iter().map(|x| x.2 * x.2).sum::<f64>() / pairs.len() as f64).sqrt();
    let mut paired: Vec<usize> = pairs.iter().map(|x| x.0).collect();
    paired.sort_unstable();
    paired.dedup();
    let rows = pairs
        .into_iter()
        .map(|(j, target, _)| SurfaceRow {
            stencil: field.stencil(&scan[j]),
            normal: normals[j],
            target,
        })
        .collect();
    Ok((rows, paired, rms))
}

/// One step's least-squares system over the nodes' displacements.
struct System<'a> {
    surface: &'a [SurfaceRow],
    landmarks: &'a [LandmarkRow],
    edges: &'a [(usize, usize)],
    triples: &'a [[usize; 3]],
    nodes: usize,
    surface_weight: f64,
    landmark_weight: f64,
    edge_weight: f64,
    bend_weight: f64,
}

impl System<'_> {
    /// (A^T W A) u. The data rows in parallel chunks, each into a buffer
    /// of its own (a row touches 8 nodes anywhere), summed in chunk order
    /// (the same sums on any number of threads).
    fn apply(&self, u: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        const CHUNK: usize = 4096;
        let mut out = self
            .surface
            .par_chunks(CHUNK)
            .map(|rows| {
                let mut part = vec![Vector3::zeros(); self.nodes];
                for r in rows {
                    let v: f64 = r
                        .stencil
                        .iter()
                        .map(|&(n, w)| w * r.normal.dot(&u[n]))
                        .sum();
                    let g = r.normal * (self.surface_weight * v);
                    for &(n, w) in &r.stencil {
                        part[n] += g * w;
                    }
                }
                part
            })
            .collect::<Vec<_>>()
            .into_iter()
            .reduce(|mut a, b| {
                a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
                a
            })
            .unwrap_or_else(|| vec![Vector3::zeros(); self.nodes]);
        for r in self.landmarks {
            let v: Vector3<f64> = r.stencil.iter().map(|&(n, w)| u[n] * w).sum();
            let g = r.across * (r.across * v) * self.landmark_weight;
            for &(n, w) in &r.stencil {
                out[n] += g * w;
            }
        }
        for &(a, b) in self.edges {
            let d = (u[a] - u[b]) * self.edge_weight;
            out[a] += d;
            out[b] -= d;
        }
        for &[a, b, c] in self.triples {
            let d = (u[a] - u[b] * 2.0 + u[c]) * self.bend_weight;
            out[a] += d;
            out[b] -= d * 2.0;
            out[c] += d;
        }
        out
    }

    /// A^T W b.
    fn rhs(&self) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.nodes];
        for r in self.surface {
            let g = r.normal * (self.surface_weight * r.target);
            for &(n, w) in &r.stencil {
                out[n] += g * w;
            }
        }
        for r in self.landmarks {
            let g = r.across * r.target * self.landmark_weight;
            for &(n, w) in &r.stencil {
                out[n] += g * w;
            }
        }
        out
    }

    /// The inverse of each node's 3 x 3 diagonal block.
    fn preconditioner(&self) -> Vec<Matrix3<f64>> {
        let mut blocks = vec![Matrix3::zeros(); self.nodes];
        for r in self.surface {
            let nn = r.normal * r.normal.transpose() * self.surface_weight;
            for &(n, w) in &r.stencil {
                blocks[n] += nn * (w * w);
            }
        }
        for r in self.landmarks {
            for &(n, w) in &r.stencil {
                blocks[n] += r.across * (self.landmark_weight * w * w);
            }
        }
        for &(a, b) in self.edges {
            blocks[a] += Matrix3::identity() * self.edge_weight;
            blocks[b] += Matrix3::identity() * self.edge_weight;
        }
        for &[a, b, c] in self.triples {
            blocks[a] += Matrix3::identity() * self.bend_weight;
            blocks[b] += Matrix3::identity() * (4.0 * self.bend_weight);
            blocks[c] += Matrix3::identity() * self.bend_weight;
        }
        blocks
            .into_iter()
            .map(|b| b.try_inverse().unwrap_or_else(Matrix3::identity))
            .collect()
    }

    /// Preconditioned conjugate gradients from `start`, until the residual
    /// is `tolerance` of the right-hand side's norm.
    fn solve(&self, start: &[Vector3<f64>], tolerance: f64) -> Vec<Vector3<f64>> {
        const MAX_ITERATIONS: usize = 300;
        let dot = |a: &[Vector3<f64>], b: &[Vector3<f64>]| -> f64 {
            a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
        };
        let m = self.preconditioner();
        let b = self.rhs();
        let mut x = start.to_vec();
        let ax = self.apply(&x);
        let mut r: Vec<Vector3<f64>> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        let norm_b = dot(&b, &b).sqrt().max(f64::MIN_POSITIVE);
        let mut z: Vec<Vector3<f64>> = m.iter().zip(&r).map(|(m, r)| m * r).collect();
        let mut d = z.clone();
        let mut rz = dot(&r, &z);
        for _ in 0..MAX_ITERATIONS {
            if dot(&r, &r).sqrt() <= tolerance * norm_b {
                break;
            }
            let ad = self.apply(&d);
            let alpha = rz / dot(&d, &ad).max(f64::MIN_POSITIVE);
            for i in 0..x.len() {
                x[i] += d[i] * alpha;
                r[i] -= ad[i] * alpha;
            }
            z = m.iter().zip(&r).map(|(m, r)| m * r).collect();
            let rz_next = dot(&r, &z);
            let beta = rz_next / rz.max(f64::MIN_POSITIVE);
            rz = rz_next;
            for i in 0..d.len() {
                d[i] = z[i] + d[i] * beta;
            }
        }
        x
    }
}

/// Peak and RMS of the field's displacement over `points`, mm.
pub fn displacement_stats(field: &Lattice, points: &[Point3<f64>]) -> (f64, f64) {
    if points.is_empty() {
        return (0.0, 0.0);
    }
    let norms: Vec<f64> = points
        .iter()
        .map(|p| field.displacement(p).norm())
        .collect();
    let peak = norms.iter().copied().fold(0.0, f64::max);
    let rms = (norms.iter().map(|v| v * v).sum::<f64>() / norms.len() as f64).sqrt();
    (peak, rms)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A dome: a sphere of radius 70 mm cut 25 mm below its centre (apex 95
    /// mm above the table z = 0), its skin sampled about every `step_mm`,
    /// with outward normals.
    pub(crate) fn dome(step_mm: f64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
        let (r, c) = (70.0, Point3::new(0.0, 0.0, 25.0));
        let mut points = Vec::new();
        let mut normals = Vec::new();
        let max_polar = (-25.0f64 / r).acos();
        let rings = (max_polar * r / step_mm).ceil() as usize;
        for i in 0..=rings {
            let polar = max_polar * i as f64 / rings as f64;
            let around = ((2.0 * std::f64::consts::PI * r * polar.sin()) / step_mm)
                .ceil()
                .max(1.0) as usize;
            for k in 0..around {
                let az = 2.0 * std::f64::consts::PI * k as f64 / around as f64;
                let n = Vector3::new(polar.sin() * az.cos(), polar.sin() * az.sin(), polar.cos());
                points.push(c + n * r);
                normals.push(n);
            }
        }
        (points, normals)
    }

    /// A sag of `peak_mm` at the apex: down and sideways (+x), growing with
    /// height as a smoothstep (none on the table).
    fn sag(p: &Point3<f64>, peak_mm: f64) -> Vector3<f64> {
        let t = (p.z / 95.0).clamp(0.0, 1.0);
        let w = t * t * (3.0 - 2.0 * t);
        Vector3::new(1.0, 0.0, -1.0).normalize() * (peak_mm * w)
    }

    /// Points inside the dome, 15-40 mm under its skin.
    fn interior() -> Vec<Point3<f64>> {
        let mut points = Vec::new();
        for &(x, y, z) in &[
            (0.0, 0.0, 55.0),
            (20.0, -10.0, 50.0),
            (-25.0, 15.0, 45.0),
            (10.0, 30.0, 40.0),
            (-15.0, -20.0, 60.0),
        ] {
            points.push(Point3::new(x, y, z));
        }
        points
    }

    /// Twelve markers on the upper skin.
    fn markers(points: &[Point3<f64>]) -> Vec<Point3<f64>> {
        (0..12)
            .map(|k| {
                let az = 2.0 * std::f64::consts::PI * k as f64 / 12.0;
                let polar: f64 = if k % 2 == 0 { 0.5 } else { 0.9 };
                let target = Point3::new(0.0, 0.0, 25.0)
                    + Vector3::new(polar.sin() * az.cos(), polar.sin() * az.sin(), polar.cos())
                        * 70.0;
                *points
                    .iter()
                    .min_by(|a, b| (*a - target).norm().total_cmp(&(*b - target).norm()))
                    .unwrap()
            })
            .collect()
    }

    #[test]
    fn a_sagged_dome_seen_from_above_is_followed_inside_too() {
        // The camera sees the skin above 30 mm, moved by 8 mm of sag at the
        // apex; both see 12 markers. With no field the interior points (15-40
        // mm deep) are 3-5 mm off; the field brings them within a quarter
        // of that (0.15-0.7 mm: the bending's fill, linear where the sag's
        // smoothstep bends).
        let (scan, normals) = dome(2.5);
        let now: Vec<Point3<f64>> = dome(2.0)
            .0
            .into_iter()
            .filter(|p| p.z > 30.0)
            .map(|p| p + sag(&p, 8.0))
            .collect();
        let m = markers(&scan);
        let k: Vec<Point3<f64>> = m.iter().map(|p| p + sag(p, 8.0)).collect();
        let d = fit_deformation(
            &scan,
            &normals,
            &now,
            Some(LandmarkPairs { scan: &m, now: &k }),
            &DeformParams::default(),
        )
        .unwrap();
        assert!(d.rigid_residual_mm > 2.0, "{}", d.rigid_residual_mm);
        assert!(d.residual_mm < 0.3, "{}", d.residual_mm);
        let mut sum = 0.0;
        for p in interior() {
            let truth = sag(&p, 8.0);
            let err = (d.field.displacement(&p) - truth).norm();
            assert!(truth.norm() > 3.0);
            assert!(
                err < 0.25 * truth.norm(),
                "{p}: {err:.2} mm off (truth {:.2})",
                truth.norm()
            );
            sum += err;
        }
        assert!(sum / 5.0 < 0.5, "mean error {:.2} mm", sum / 5.0);
    }

    #[test]
    fn an_unmoved_dome_gets_almost_no_field() {
        let (scan, normals) = dome(2.5);
        let now: Vec<Point3<f64>> = dome(2.0).0.into_iter().filter(|p| p.z > 30.0).collect();
        let m = markers(&scan);
        let d = fit_deformation(
            &scan,
            &normals,
            &now,
            Some(LandmarkPairs { scan: &m, now: &m }),
            &DeformParams::default(),
        )
        .unwrap();
        let (peak, _) = displacement_stats(&d.field, &scan);
        assert!(peak < 0.3, "{peak}");
    }

    #[test]
    fn landmarks_pin_a_slide_the_surface_cannot_see() {
        // The dome turned 3 degrees about its own axis: every skin point
        // stays on the skin, only the markers show the turn.
        let (scan, normals) = dome(2.5);
        let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 3f64.to_radians());
        let now: Vec<Point3<f64>> = dome(2.0)
            .0
            .into_iter()
            .filter(|p| p.z > 30.0)
            .map(|p| turn * p)
            .collect();
        let m = markers(&scan);
        let k: Vec<Point3<f64>> = m.iter().map(|p| turn * p).collect();
        let with = fit_deformation(
            &scan,
            &normals,
            &now,
            Some(LandmarkPairs { scan: &m, now: &k }),
            &DeformParams::default(),
        )
        .unwrap();
        let p = Point3::new(50.0, 0.0, 60.0);
        let truth = turn * p - p;
        let err = (with.field.displacement(&p) - truth).norm();
        assert!(
            err < 0.5 * truth.norm(),
            "{err:.2} of {:.2} mm",
            truth.norm()
        );
        assert!(with.landmark_residual_mm < 0.5 * with.rigid_landmark_residual_mm);
    }

    #[test]
    fn bad_input_is_refused_by_name() {
        let (scan, normals) = dome(5.0);
        let run = |p: DeformParams| fit_deformation(&scan, &normals, &scan, None, &p).unwrap_err();
        let e = run(DeformParams {
            stiffness_mm: 0.0,
            ..DeformParams::default()
        });
        assert!(e.contains("stiffness_mm"), "{e}");
        let e = run(DeformParams {
            trim_ratio: 1.5,
            ..DeformParams::default()
        });
        assert!(e.contains("trim_ratio"), "{e}");
        let e = fit_deformation(&scan, &normals[1..], &scan, None, &DeformParams::default())
            .unwrap_err();
        assert!(e.contains("normals"), "{e}");
        let far: Vec<Point3<f64>> = scan
            .iter()
            .map(|p| p + Vector3::new(500.0, 0.0, 0.0))
            .collect();
        let e = fit_deformation(&scan, &normals, &far, None, &DeformParams::default()).unwrap_err();
        assert!(e.contains("within"), "{e}");
    }

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
    }
}
