//! Chessboard detection: saddle-point candidates, a grid grown from seeds by
//! prediction, and checks that refuse anything but the whole board. Written
//! here: calib-targets cannot be told the board size and its labels can shift
//! (see ../shared/CRATES.md), and a detector must never return wrong corners.
//!
//! Corners come out row by row (`cols` per row), ordered so that the board is
//! seen from its printed side with the first row's outer square dark: the same
//! physical corner gets the same index in both images of a stereo pair. That
//! needs a pattern with one odd and one even count of inner corners (e.g. 9 x 6);
//! symmetric patterns are refused.

use super::subpixel::{refine_corner, window_for_square};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point2, Vector2};
use std::collections::{BTreeMap, HashMap};
use std::num::NonZero;

/// The candidates by position: the `n` nearest to a point (a kiddo k-d tree).
struct CandidateIndex {
    tree: ImmutableKdTree<f64, 2>,
}

impl CandidateIndex {
    fn new(cands: &[Candidate]) -> Option<Self> {
        let raw: Vec<[f64; 2]> = cands.iter().map(|c| [c.p.x, c.p.y]).collect();
        ImmutableKdTree::new_from_slice(&raw)
            .ok()
            .map(|tree| CandidateIndex { tree })
    }

    /// Up to `n` candidates nearest to `p`, nearest first: (distance px, index).
    fn nearest(&self, p: Point2<f64>, n: usize) -> Vec<(f64, usize)> {
        self.tree
            .query(&[p.x, p.y])
            .nearest_n::<SquaredEuclidean<f64>>(NonZero::new(n.max(1)).expect("n >= 1"))
            .execute()
            .iter()
            .map(|r| (r.distance.sqrt(), r.item as usize))
            .collect()
    }
}

/// Smooths with a Gaussian of `sigma` px (separable, clamped borders). Each
/// pass adds one tap to a whole row at a time, so the inner loop has no
/// branches or index clamping and vectorises.
pub(crate) fn gaussian(img: &[f32], w: usize, h: usize, sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as usize;
    let k: Vec<f32> = (-(r as isize)..=r as isize)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let total: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|x| x / total).collect();
    // Horizontal: each row padded by its edge values.
    let mut tmp = vec![0.0f32; w * h];
    let mut padded = vec![0.0f32; w + 2 * r];
    for (src, dst) in img.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        padded[..r].fill(src[0]);
        padded[r..r + w].copy_from_slice(src);
        padded[r + w..].fill(src[w - 1]);
        for (i, &kw) in k.iter().enumerate() {
            for (d, &s) in dst.iter_mut().zip(&padded[i..i + w]) {
                *d += kw * s;
            }
        }
    }
    // Vertical: rows above and below the image repeat its first and last.
    let mut out = vec![0.0f32; w * h];
    for (y, dst) in out.chunks_exact_mut(w).enumerate() {
        for (i, &kw) in k.iter().enumerate() {
            let sy = (y + i).saturating_sub(r).min(h - 1);
            for (d, &s) in dst.iter_mut().zip(&tmp[sy * w..(sy + 1) * w]) {
                *d += kw * s;
            }
        }
    }
    out
}

/// A candidate corner: position (px) and saddle strength.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    p: Point2<f64>,
    strength: f32,
}

/// Saddle points: local maxima of -det(Hessian) of the smoothed image that look
/// like an X-junction (four alternations around a small circle).
fn candidates(grey: &[f32], w: usize, h: usize) -> Vec<Candidate> {
    let s = gaussian(grey, w, h, 1.5);
    let at = |x: usize, y: usize| s[y * w + x];
    let mut response = vec![0.0f32; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let c = at(x, y);
            let ixx = at(x + 1, y) - 2.0 * c + at(x - 1, y);
            let iyy = at(x, y + 1) - 2.0 * c + at(x, y - 1);
            let ixy =
                0.25 * (at(x + 1, y + 1) - at(x - 1, y + 1) - at(x + 1, y - 1) + at(x - 1, y - 1));
            response[y * w + x] = (ixy * ixy - ixx * iyy).max(0.0);
        }
    }
    let mut positive: Vec<f32> = response.iter().copied().filter(|&r| r > 0.0).collect();
    if positive.is_empty() {
        return Vec::new();
    }
    // A robust maximum (the 99.9th percentile) by selection, not a full sort.
    let rank = ((positive.len() as f64 * 0.999) as usize).min(positive.len() - 1);
    let (_, &mut robust_max, _) = positive.select_nth_unstable_by(rank, f32::total_cmp);
    let threshold = 0.02 * robust_max;
    let radius = 4usize;
    let mut out = Vec::new();
    for y in radius..h - radius {
        for x in radius..w - radius {
            let r = response[y * w + x];
            if r <= threshold {
                continue;
            }
            let is_max = (y - radius..=y + radius).all(|yy| {
                (x - radius..=x + radius).all(|xx| {
                    (xx, yy) == (x, y)
                        || response[yy * w + xx] < r
                        || (response[yy * w + xx] == r && (yy, xx) > (y, x))
                })
            });
            if is_max && looks_like_x(grey, w, h, x as f64, y as f64, 3.5) {
                out.push(Candidate {
                    p: Point2::new(x as f64, y as f64),
                    strength: r,
                });
            }
        }
    }
    out.sort_by(|a, b| b.strength.total_cmp(&a.strength));
    out.truncate(3000);
    out
}

/// Whether the ring of `radius` px around (x, y) alternates dark-light four
/// times (an X-junction), not twice (an edge) or never (flat or a blob).
fn looks_like_x(grey: &[f32], w: usize, h: usize, x: f64, y: f64, radius: f64) -> bool {
    let n = 32;
    let ring: Vec<f32> = (0..n)
        .filter_map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let (sx, sy) = (
                (x + radius * a.cos()).round(),
                (y + radius * a.sin()).round(),
            );
            (sx >= 0.0 && sy >= 0.0 && (sx as usize) < w && (sy as usize) < h)
                .then(|| grey[sy as usize * w + sx as usize])
        })
        .collect();
    if ring.len() < n {
        return false;
    }
    let (lo, hi) = ring
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    if hi - lo < 0.08 {
        return false;
    }
    let mid = 0.5 * (lo + hi);
    let sides: Vec<bool> = ring.iter().map(|&v| v > mid).collect();
    let changes = (0..n).filter(|&i| sides[i] != sides[(i + 1) % n]).count();
    changes == 4
}

/// Whether the segment from corner `a` to corner `b` runs along an edge of
/// the board (a dark square on one side, a light one on the other) rather
/// than across a square (a diagonal neighbour, whose midpoint is inside one
/// square of one colour). Under strong perspective a diagonal neighbour can
/// be nearer than a side one, and a grid grown on it is sheared.
fn along_an_edge(grey: &[f32], w: usize, h: usize, a: Point2<f64>, b: Point2<f64>) -> bool {
    let d = b - a;
    let mid = a + d * 0.5;
    let across = Vector2::new(-d.y, d.x) / d.norm();
    // Close to the midpoint: a square seen obliquely is thin across, and
    // far-off samples would leave it.
    let contrast = |offset_px: f64| {
        let side = across * offset_px;
        Some(patch(grey, w, h, mid + side)? - patch(grey, w, h, mid - side)?)
    };
    let norm = d.norm();
    match (
        contrast((0.06 * norm).max(1.5)),
        contrast((0.12 * norm).max(2.5)),
    ) {
        (Some(near), Some(far)) => near.abs() > 0.05 && far.abs() > 0.05 && near * far > 0.0,
        _ => false,
    }
}

/// A grid grown from a seed: grid coordinates -> corner position (px), each
/// refined to sub-pixel as it is taken.
///
/// Every step predicts the next corner from those behind it, takes the
/// nearest candidates within 30 % of a step, refines each at the scale of
/// the local squares and keeps the first that is an X-junction at that scale
/// and not a corner already taken. Checking at the squares' scale matters on
/// large, blurred or JPEG-compressed squares: the saddle detector's small
/// scale also fires along their edges, and such a point is only seen to be on
/// an edge from a quarter of a square away.
fn grow(
    grey: (&[f32], usize, usize),
    (cands, index): (&[Candidate], &CandidateIndex),
    seed: usize,
    limit: (usize, usize),
    refined: &mut HashMap<(usize, usize), Point2<f64>>,
) -> Option<BTreeMap<(i32, i32), Point2<f64>>> {
    let (img, w, h) = grey;
    let s = cands[seed].p;
    let mut near: Vec<(f64, usize)> = index.nearest(s, 9);
    near.retain(|&(_, i)| i != seed);
    near.truncate(8);
    // A first step must run along an edge and the lattice must go on beyond
    // it (or behind the seed): a spurious candidate a fraction of a square
    // from a corner passes the edge test but has no lattice behind it.
    let lattice_goes_on = |step: Vector2<f64>| {
        let tolerance = 0.2 * step.norm();
        [s + 2.0 * step, s - step].iter().any(|&q| {
            index
                .nearest(q, 1)
                .first()
                .is_some_and(|&(d, _)| d < tolerance)
        })
    };
    near.retain(|&(_, i)| {
        along_an_edge(img, w, h, s, cands[i].p) && lattice_goes_on(cands[i].p - s)
    });
    let (d1, n1) = *near.first()?;
    let u = cands[n1].p - s;
    let (_, n2) = *near.iter().skip(1).find(|(d, i)| {
        let v = cands[*i].p - s;
        let cos = u.dot(&v) / (u.norm() * v.norm());
        // Any two edge steps that are not one line: a steep oblique view
        // squeezes the angle between the board's axes well below 60 deg.
        cos.abs() < 0.95 && *d < 3.0 * d1
    })?;
    let v = cands[n2].p - s;
    let first_step = u.norm().min(v.norm());
    // Seeds share their candidates: each is refined once per window size.
    let mut take = |i: usize, step: f64| -> Option<Point2<f64>> {
        let p = cands[i].p;
        let half = window_for_square(step);
        let q = *refined.entry((i, half)).or_insert_with(|| {
            refine_corner(img, w, h, (p.x, p.y), half)
                .map(|(x, y)| Point2::new(x, y))
                .unwrap_or(p)
        });
        looks_like_x(img, w, h, q.x, q.y, x_ring_radius(step)).then_some(q)
    };
    let mut grid: BTreeMap<(i32, i32), Point2<f64>> = BTreeMap::new();
    for (key, idx) in [((0, 0), seed), ((1, 0), n1), ((0, 1), n2)] {
        grid.insert(key, take(idx, first_step)?);
    }
    let mut frontier: Vec<(i32, i32)> = grid.keys().copied().collect();
    let max_cells = (limit.0 + 2) * (limit.1 + 2);
    while let Some(cell) = frontier.pop() {
        if grid.len() > max_cells {
            return None;
        }
        for dir in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            let target = (cell.0 + dir.0, cell.1 + dir.1);
            if grid.contains_key(&target) {
                continue;
            }
            let p = |k: &(i32, i32)| grid.get(k).copied();
            let here = p(&cell)?;
            // Extrapolate along the line if possible (to second order when two
            // cells back are known: lens distortion bends rows and perspective
            // changes the step), else copy a parallel step.
            let back = (cell.0 - dir.0, cell.1 - dir.1);
            let back2 = (cell.0 - 2 * dir.0, cell.1 - 2 * dir.1);
            let step: Option<Vector2<f64>> = p(&back)
                .map(|b| match p(&back2) {
                    Some(b2) => (here - b) + ((here - b) - (b - b2)),
                    None => here - b,
                })
                .or_else(|| {
                    let side = (dir.1, dir.0);
                    [side, (-side.0, -side.1)].iter().find_map(|sd| {
                        let (a, b) = (
                            (cell.0 + sd.0, cell.1 + sd.1),
                            (cell.0 + sd.0 + dir.0, cell.1 + sd.1 + dir.1),
                        );
                        Some(p(&b)? - p(&a)?)
                    })
                });
            let step = match step {
                Some(s) => s,
                None if dir.1 == 0 => u * dir.0 as f64,
                None => v * dir.1 as f64,
            };
            let predicted = here + step;
            let tolerance = 0.3 * step.norm();
            let mut nearby = index.nearest(predicted, 4);
            nearby.retain(|&(d, _)| d < tolerance);
            let taken = nearby.iter().find_map(|&(_, i)| {
                let q = take(i, step.norm())?;
                let fresh = grid.values().all(|g| (g - q).norm() > 0.3 * step.norm());
                (fresh && (q - predicted).norm() < tolerance).then_some(q)
            });
            if let Some(q) = taken {
                grid.insert(target, q);
                frontier.push(target);
            }
        }
    }
    Some(grid)
}

/// The radius (px) at which a corner is tested as an X-junction, for squares
/// `step` px across: a quarter of a square, so that a point on an edge
/// near a corner is seen as an edge.
fn x_ring_radius(step: f64) -> f64 {
    (0.25 * step).clamp(3.5, 12.0)
}

/// Mean of a 3 x 3 patch at (x, y), if inside the image.
fn patch(grey: &[f32], w: usize, h: usize, p: Point2<f64>) -> Option<f32> {
    let (x, y) = (p.x.round() as isize, p.y.round() as isize);
    if x < 1 || y < 1 || x + 1 >= w as isize || y + 1 >= h as isize {
        return None;
    }
    let mut sum = 0.0;
    for dy in -1..=1 {
        for dx in -1..=1 {
            sum += grey[(y + dy) as usize * w + (x + dx) as usize];
        }
    }
    Some(sum / 9.0)
}

/// Why a board was not found. [`Refusal::code`] gives each kind a stable
/// number for tables (`calib.find_chessboard`'s `views`).
#[derive(Debug, Clone, PartialEq)]
pub enum Refusal {
    /// The pattern's counts cannot be oriented (both odd or both even) or are
    /// below 2.
    AmbiguousPattern {
        /// Inner corners per row.
        cols: usize,
        /// Inner corners per column.
        rows: usize,
    },
    /// The image is under 16 px across or its buffer does not match its size.
    ImageTooSmall,
    /// Fewer corner candidates than the board has corners.
    FewCandidates {
        /// Candidates found.
        found: usize,
        /// Inner corners of the board.
        needed: usize,
    },
    /// No grid grown from any seed held exactly one complete board.
    NoCompleteGrid {
        /// Inner corners per row.
        cols: usize,
        /// Inner corners per column.
        rows: usize,
        /// Corners of the largest grid grown.
        largest: usize,
    },
    /// A corner's sub-pixel refinement failed (at the border, or blurred).
    CornerDoesNotRefine {
        /// Where, px.
        at: Point2<f64>,
    },
    /// A corner stays off its row or column after re-locating it.
    CornerOffLine {
        /// Its index in the board's order.
        corner: usize,
        /// Where, px.
        at: Point2<f64>,
    },
}

impl Refusal {
    /// A stable number for the kind of refusal (0 and 1 are kept for a board
    /// found and a photo that could not be read: `calib::PhotoRecord`).
    pub fn code(&self) -> u8 {
        match self {
            Refusal::AmbiguousPattern { .. } => 2,
            Refusal::ImageTooSmall => 3,
            Refusal::FewCandidates { .. } => 4,
            Refusal::NoCompleteGrid { .. } => 5,
            Refusal::CornerDoesNotRefine { .. } => 6,
            Refusal::CornerOffLine { .. } => 7,
        }
    }

    /// A short phrase for the refusal of code `code` (see [`Refusal::code`]).
    pub fn describe_code(code: u8) -> &'static str {
        match code {
            0 => "found",
            1 => "photo unreadable",
            2 => "pattern ambiguous",
            3 => "image too small",
            4 => "too few corner candidates",
            5 => "no complete grid",
            6 => "a corner does not refine",
            7 => "a corner off its row or column",
            _ => "refused",
        }
    }
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::AmbiguousPattern { cols, rows } => write!(
                f,
                "pattern {cols} x {rows}: use one odd and one even count of inner corners, or the board's orientation is ambiguous"
            ),
            Refusal::ImageTooSmall => write!(f, "image too small"),
            Refusal::FewCandidates { found, needed } => write!(
                f,
                "{found} corner candidates, fewer than the {needed} inner corners"
            ),
            Refusal::NoCompleteGrid {
                cols,
                rows,
                largest,
            } => write!(
                f,
                "no complete {cols} x {rows} grid (largest grid grown: {largest} corners)"
            ),
            Refusal::CornerDoesNotRefine { at } => write!(
                f,
                "corner near ({:.1}, {:.1}) does not refine (too close to the border or blurred)",
                at.x, at.y
            ),
            Refusal::CornerOffLine { corner, at } => write!(
                f,
                "corner {corner} at ({:.1}, {:.1}) does not line up with its neighbours",
                at.x, at.y
            ),
        }
    }
}

/// Finds the whole `cols x rows` board (inner corners) in a grey image (0..1,
/// row-major) and returns its corners to sub-pixel accuracy (px, integer
/// values at pixel centres), or why not.
///
/// # Examples
///
/// A board of 5 x 4 squares (4 x 3 inner corners, squares 12 px, the
/// top-left square dark) on white, drawn with hard edges so that its corners
/// lie between pixels:
///
/// ```
/// use fusegraph_nodes::calib::find_chessboard;
///
/// let (w, h) = (88, 76);
/// let grey: Vec<f32> = (0..w * h)
///     .map(|i| {
///         // The square (column, row) of pixel i; the board starts at (12.5, 12.5) px.
///         let (x, y) = ((i % w) as f64 - 12.5, (i / w) as f64 - 12.5);
///         let (c, r) = ((x / 12.0).floor(), (y / 12.0).floor());
///         let on_board = (0.0..5.0).contains(&c) && (0.0..4.0).contains(&r);
///         if on_board && (c + r) % 2.0 == 0.0 { 0.1 } else { 0.9 }
///     })
///     .collect();
/// let corners = find_chessboard(&grey, w, h, 4, 3).unwrap();
/// // Row by row, from the corner next to the dark outer square.
/// assert_eq!(corners.len(), 12);
/// for (k, p) in corners.iter().enumerate() {
///     let (x, y) = (24.5 + 12.0 * (k % 4) as f64, 24.5 + 12.0 * (k / 4) as f64);
///     assert!((p.x - x).abs() < 0.05 && (p.y - y).abs() < 0.05, "corner {k}: {p}");
/// }
/// ```
pub fn find_chessboard(
    grey: &[f32],
    w: usize,
    h: usize,
    cols: usize,
    rows: usize,
) -> Result<Vec<Point2<f64>>, Refusal> {
    if cols < 2 || rows < 2 || (cols % 2) == (rows % 2) {
        return Err(Refusal::AmbiguousPattern { cols, rows });
    }
    if w < 16 || h < 16 || grey.len() != w * h {
        return Err(Refusal::ImageTooSmall);
    }
    let cands = candidates(grey, w, h);
    if cands.len() < cols * rows {
        return Err(Refusal::FewCandidates {
            found: cands.len(),
            needed: cols * rows,
        });
    }
    let mut best_size = 0;
    let no_grid = |largest| Refusal::NoCompleteGrid {
        cols,
        rows,
        largest,
    };
    let index = CandidateIndex::new(&cands).ok_or(no_grid(0))?;
    let mut refined = HashMap::new();
    for seed in 0..cands.len().min(40) {
        let Some(grid) = grow(
            (grey, w, h),
            (&cands, &index),
            seed,
            (cols, rows),
            &mut refined,
        ) else {
            continue;
        };
        best_size = best_size.max(grid.len());
        // The board is the one full pattern-sized window of the grid; a stray
        // candidate that the growth picked up beyond the board is left out, but
        // if two windows fit (a whole extra row or column) the labels would be
        // ambiguous, and the seed is given up.
        let windows: Vec<(i32, i32, bool)> = full_windows(&grid, cols, rows);
        let [(min_i, min_j, transpose)] = windows[..] else {
            continue;
        };
        let at = |c: usize, r: usize| {
            let (i, j) = if transpose { (r, c) } else { (c, r) };
            grid[&(min_i + i as i32, min_j + j as i32)]
        };
        let mut corners: Vec<Point2<f64>> = (0..rows)
            .flat_map(|r| (0..cols).map(move |c| (c, r)))
            .map(|(c, r)| at(c, r))
            .collect();
        if let Some(ordered) = orient(grey, w, h, &mut corners, cols, rows) {
            return refine_all(grey, w, h, ordered, cols);
        }
    }
    Err(no_grid(best_size))
}

/// Origins (and whether transposed) of every fully populated `cols x rows`
/// window of the grid, in either orientation.
fn full_windows(
    grid: &BTreeMap<(i32, i32), Point2<f64>>,
    cols: usize,
    rows: usize,
) -> Vec<(i32, i32, bool)> {
    let (min_i, max_i) = grid
        .keys()
        .fold((i32::MAX, i32::MIN), |(a, b), k| (a.min(k.0), b.max(k.0)));
    let (min_j, max_j) = grid
        .keys()
        .fold((i32::MAX, i32::MIN), |(a, b), k| (a.min(k.1), b.max(k.1)));
    let mut out = Vec::new();
    for transpose in [false, true] {
        let (ni, nj) = if transpose {
            (rows as i32, cols as i32)
        } else {
            (cols as i32, rows as i32)
        };
        for i0 in min_i..=max_i - ni + 1 {
            for j0 in min_j..=max_j - nj + 1 {
                if (i0..i0 + ni).all(|i| (j0..j0 + nj).all(|j| grid.contains_key(&(i, j)))) {
                    out.push((i0, j0, transpose));
                }
            }
        }
    }
    out
}

/// Puts the corners in the canonical order (see the module doc), or `None`
/// when the squares do not alternate in colour like a chessboard's.
fn orient(
    grey: &[f32],
    w: usize,
    h: usize,
    corners: &mut [Point2<f64>],
    cols: usize,
    rows: usize,
) -> Option<Vec<Point2<f64>>> {
    let get = |c: &[Point2<f64>], i: usize, j: usize| c[j * cols + i];
    // Brightness at the centre of the inner square right of and below corner (i, j).
    let centre_value = |c: &[Point2<f64>], i: usize, j: usize| {
        patch(
            grey,
            w,
            h,
            Point2::from((get(c, i, j).coords + get(c, i + 1, j + 1).coords) * 0.5),
        )
    };
    let values: Vec<f32> = (0..rows - 1)
        .flat_map(|j| (0..cols - 1).map(move |i| (i, j)))
        .map(|(i, j)| centre_value(corners, i, j))
        .collect::<Option<_>>()?;
    let mean = values.iter().sum::<f32>() / values.len() as f32;
    let dark: Vec<bool> = values.iter().map(|&v| v < mean).collect();
    let alternates = (0..rows - 1)
        .all(|j| (0..cols - 1).all(|i| dark[j * (cols - 1) + i] == (dark[0] ^ ((i + j) % 2 == 1))));
    if !alternates {
        return None;
    }
    // Handedness: seen from the printed side, with columns to the right, rows
    // run downwards (x right, y down in the image, as on the board).
    let u = get(corners, 1, 0) - get(corners, 0, 0);
    let v = get(corners, 0, 1) - get(corners, 0, 0);
    let mut ordered: Vec<Point2<f64>> = corners.to_vec();
    if u.x * v.y - u.y * v.x < 0.0 {
        ordered = (0..rows)
            .flat_map(|j| (0..cols).map(move |i| (i, j)))
            .map(|(i, j)| get(corners, cols - 1 - i, j))
            .collect();
    }
    // Of the two orders left (180 degrees apart) take the one whose square
    // beyond corner 0 is dark; the inner square (0, 0) has the same colour
    // (same parity), and with one odd and one even corner count the two
    // orders disagree on it.
    if centre_value(&ordered, 0, 0)? >= mean {
        ordered.reverse();
    }
    Some(ordered)
}

fn refine_all(
    grey: &[f32],
    w: usize,
    h: usize,
    corners: Vec<Point2<f64>>,
    cols: usize,
) -> Result<Vec<Point2<f64>>, Refusal> {
    let spacing = corners
        .iter()
        .enumerate()
        .filter(|(k, _)| (k + 1) % cols != 0)
        .map(|(k, p)| (corners[k + 1] - p).norm())
        .fold(f64::INFINITY, f64::min);
    let half = window_for_square(spacing);
    let refine = |p: &Point2<f64>| {
        refine_corner(grey, w, h, (p.x, p.y), half)
            .map(|(x, y)| Point2::new(x, y))
            .ok_or(Refusal::CornerDoesNotRefine { at: *p })
    };
    // A candidate that does not refine stays where it is for now: the check
    // below finds it out of line and re-locates it.
    let mut refined: Vec<Point2<f64>> = corners.iter().map(|p| refine(p).unwrap_or(*p)).collect();
    // A corner the grid growth took from a nearby artefact (JPEG blocks, clutter)
    // breaks the straight, evenly stepping rows and columns: re-locate it from
    // its neighbours; if it still does not fit, refuse the board.
    for _ in 0..3 {
        let bad = inconsistent_corners(&refined, cols);
        if bad.is_empty() {
            return Ok(refined);
        }
        for k in bad {
            let guess =
                predict_from_neighbours(&refined, cols, k).ok_or(Refusal::CornerOffLine {
                    corner: k,
                    at: refined[k],
                })?;
            refined[k] = refine(&guess)?;
        }
    }
    match inconsistent_corners(&refined, cols).first() {
        None => Ok(refined),
        Some(&k) => Err(Refusal::CornerOffLine {
            corner: k,
            at: refined[k],
        }),
    }
}

/// Neighbour triples (a, b) around corner k along rows and columns: either both
/// sides (a, k, b) or two on one side (k, a, b).
fn neighbour_lines(cols: usize, rows: usize, k: usize) -> Vec<(usize, usize, bool)> {
    let (i, j) = ((k % cols) as isize, (k / cols) as isize);
    let at = |i: isize, j: isize| {
        (i >= 0 && j >= 0 && (i as usize) < cols && (j as usize) < rows)
            .then(|| j as usize * cols + i as usize)
    };
    let mut out = Vec::new();
    for (di, dj) in [(1, 0), (0, 1)] {
        match (at(i - di, j - dj), at(i + di, j + dj)) {
            (Some(a), Some(b)) => out.push((a, b, true)),
            (None, Some(a)) => out.extend(at(i + 2 * di, j + 2 * dj).map(|b| (a, b, false))),
            (Some(a), None) => out.extend(at(i - 2 * di, j - 2 * dj).map(|b| (a, b, false))),
            (None, None) => {}
        }
    }
    out
}

/// Corners that do not fit their row and column: off the curve through their
/// neighbours (across it by more than 2 px or 5 % of the step: a candidate
/// taken from an artefact lies a good part of a square off, measurement noise
/// of JPEG photos reaches 1-2 px) or unevenly placed along it (neighbouring steps
/// differing by more than half: perspective and barrel distortion at the
/// image's edge change them by up to a third). The curve is second order where enough neighbours
/// exist (two on each side, or three on one side at the board's edge): lens
/// distortion bends a row by 1-2 px over a few squares, and a straight line
/// through two neighbours would refuse correct corners.
fn inconsistent_corners(corners: &[Point2<f64>], cols: usize) -> Vec<usize> {
    let rows = corners.len() / cols;
    (0..corners.len())
        .filter(|&k| {
            let p = corners[k];
            let spaced_badly = neighbour_lines(cols, rows, k)
                .iter()
                .any(|&(a, b, between)| {
                    let (pa, pb) = (corners[a], corners[b]);
                    let (step_here, step_there) = if between {
                        ((p - pa).norm(), (pb - p).norm())
                    } else {
                        ((pa - p).norm(), (pb - pa).norm())
                    };
                    !((2.0 / 3.0)..=1.5).contains(&(step_here / step_there))
                });
            // Across the curve only: along it, perspective moves corners off
            // the midpoint legitimately, and the spacing test has that.
            let off_curve = [(1isize, 0isize), (0, 1)].iter().any(|&dir| {
                curve_prediction(corners, cols, rows, k, dir).is_some_and(|c| {
                    let across = (p - c.point).perp(&c.along).abs() / c.along.norm();
                    let (fraction, floor_px) = if c.extrapolated {
                        (0.12, 3.0)
                    } else {
                        (0.05, 2.0)
                    };
                    across > (fraction * c.along.norm()).max(floor_px)
                })
            });
            // Along the line: four corners a square apart have the cross ratio
            // 4/3 under any perspective.
            let off_ratio = [(1isize, 0isize), (0, 1)].iter().any(|&dir| {
                cross_ratio_around(corners, cols, rows, k, dir)
                    .is_some_and(|cr| (cr - 4.0 / 3.0).abs() > 0.08)
            });
            spaced_badly || off_curve || off_ratio
        })
        .collect()
}

/// The index of the corner `n` steps from corner k along `dir` (a row or a
/// column of a `cols x rows` board), if it is on the board.
fn step_from(cols: usize, rows: usize, k: usize, dir: (isize, isize), n: isize) -> Option<usize> {
    let (i, j) = (
        (k % cols) as isize + n * dir.0,
        (k / cols) as isize + n * dir.1,
    );
    (i >= 0 && j >= 0 && (i as usize) < cols && (j as usize) < rows)
        .then(|| j as usize * cols + i as usize)
}

/// The cross ratio of four consecutive corners on corner k's row or column
/// (k among them), from their positions along the line.
fn cross_ratio_around(
    corners: &[Point2<f64>],
    cols: usize,
    rows: usize,
    k: usize,
    dir: (isize, isize),
) -> Option<f64> {
    let idx = |n: isize| step_from(cols, rows, k, dir, n);
    // The first window of four that holds k and fits on the board.
    let start = (-3..=0).find(|s| (0..4).all(|n| idx(s + n).is_some()))?;
    let pts: Vec<Point2<f64>> = (0..4).map(|n| corners[idx(start + n).unwrap()]).collect();
    let axis = (pts[3] - pts[0]).normalize();
    let t: Vec<f64> = pts.iter().map(|p| (p - pts[0]).dot(&axis)).collect();
    Some(((t[2] - t[0]) * (t[3] - t[1])) / ((t[2] - t[1]) * (t[3] - t[0])))
}

/// Where a corner should be from its neighbours on one row or column.
struct CurvePrediction {
    /// The predicted position (px).
    point: Point2<f64>,
    /// The local step along the line (px).
    along: Vector2<f64>,
    /// Whether the neighbours are all on one side (the board's edge). The
    /// error of a quadratic extrapolated one step from nodes 1, 2, 3 steps away
    /// is f''' h^3, six times the f'''' h^4 / 6 scale of the cubic's
    /// interpolation error: lens distortion's third-order bending shows there
    /// (measured on real wide-angle photos: 6-8 % of the step at the edge rows).
    extrapolated: bool,
}

/// Where corner k should be along direction `dir` (row or column) from its
/// neighbours on that line: cubic interpolation from two on each side,
/// quadratic extrapolation from three on one side, else the line through one
/// on each side or two on one side.
fn curve_prediction(
    corners: &[Point2<f64>],
    cols: usize,
    rows: usize,
    k: usize,
    dir: (isize, isize),
) -> Option<CurvePrediction> {
    let at = |n: isize| step_from(cols, rows, k, dir, n).map(|c| corners[c].coords);
    let predict = |v: Vector2<f64>, along: Vector2<f64>, extrapolated: bool| CurvePrediction {
        point: Point2::from(v),
        along,
        extrapolated,
    };
    match (at(-2), at(-1), at(1), at(2)) {
        (Some(m2), Some(m1), Some(p1), Some(p2)) => Some(predict(
            (-m2 + 4.0 * m1 + 4.0 * p1 - p2) / 6.0,
            (p1 - m1) / 2.0,
            false,
        )),
        (_, Some(m1), Some(p1), _) => Some(predict((m1 + p1) / 2.0, (p1 - m1) / 2.0, false)),
        (None, None, Some(p1), Some(p2)) => Some(match at(3) {
            Some(p3) => predict(3.0 * p1 - 3.0 * p2 + p3, p2 - p1, true),
            None => predict(2.0 * p1 - p2, p2 - p1, true),
        }),
        (Some(m2), Some(m1), None, None) => Some(match at(-3) {
            Some(m3) => predict(3.0 * m1 - 3.0 * m2 + m3, m1 - m2, true),
            None => predict(2.0 * m1 - m2, m1 - m2, true),
        }),
        _ => None,
    }
}

/// Where corner k should be, from its neighbours (midpoint or extrapolation).
fn predict_from_neighbours(corners: &[Point2<f64>], cols: usize, k: usize) -> Option<Point2<f64>> {
    let rows = corners.len() / cols;
    let guesses: Vec<Point2<f64>> = neighbour_lines(cols, rows, k)
        .iter()
        .map(|&(a, b, between)| {
            if between {
                Point2::from((corners[a].coords + corners[b].coords) * 0.5)
            } else {
                corners[a] + (corners[a] - corners[b])
            }
        })
        .collect();
    (!guesses.is_empty()).then(|| {
        Point2::from(guesses.iter().map(|g| g.coords).sum::<Vector2<f64>>() / guesses.len() as f64)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 9 x 6 board (squares `s` px, square (-1, -1) dark, white margin)
    /// rotated by `angle` about `centre`, drawn by the lens tests' renderer,
    /// with `crop_right` columns greyed out; the image and the true corners.
    fn board_image(
        angle: f64,
        s: f64,
        centre: (f64, f64),
        crop_right: usize,
    ) -> (Vec<f32>, Vec<Point2<f64>>) {
        let (sin, cos) = angle.sin_cos();
        let origin = (
            centre.0 - (4.0 * s * cos - 2.5 * s * sin),
            centre.1 - (4.0 * s * sin + 2.5 * s * cos),
        );
        let to_board = move |x: f64, y: f64| {
            let (ix, iy) = (x - origin.0, y - origin.1);
            ((ix * cos + iy * sin) / s, (-ix * sin + iy * cos) / s)
        };
        let (mut img, corners) = super::lens_and_perspective_tests::render(&to_board);
        let w = 640;
        for row in img.chunks_exact_mut(w) {
            row[w - crop_right..].fill(0.5);
        }
        (img, corners)
    }

    #[test]
    fn finds_the_board_in_its_own_order_at_any_rotation() {
        for angle_deg in [0.0, 17.0, 90.0, 180.0, 250.0] {
            let (img, truth) = board_image(f64::to_radians(angle_deg), 40.0, (320.0, 240.0), 0);
            let found = find_chessboard(&img, 640, 480, 9, 6)
                .unwrap_or_else(|e| panic!("{angle_deg} deg: {e}"));
            for (k, (f, t)) in found.iter().zip(&truth).enumerate() {
                assert!(
                    (f - t).norm() < 0.1,
                    "{angle_deg} deg, corner {k}: {f} vs {t}"
                );
            }
        }
    }

    #[test]
    fn refuses_partial_boards_noise_and_symmetric_patterns() {
        let (img, _) = board_image(0.3, 40.0, (430.0, 240.0), 120);
        assert!(
            find_chessboard(&img, 640, 480, 9, 6).is_err(),
            "cropped board"
        );
        let mut state = 12345u64;
        let noise: Vec<f32> = (0..640 * 480)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
                (state >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        assert!(find_chessboard(&gaussian(&noise, 640, 480, 1.0), 640, 480, 9, 6).is_err());
        let (img, _) = board_image(0.0, 40.0, (320.0, 240.0), 0);
        assert!(
            find_chessboard(&img, 640, 480, 8, 6)
                .unwrap_err()
                .to_string()
                .contains("one odd and one even")
        );
        assert!(
            find_chessboard(&img, 640, 480, 7, 6).is_err(),
            "a 7 x 6 window of a 9 x 6 board is ambiguous"
        );
    }
}

#[cfg(test)]
mod lens_and_perspective_tests {
    use super::*;

    /// A 9 x 6 board drawn through `to_board` (image px -> board coordinates in
    /// squares, origin at the first inner corner) with 8 x 8 supersampling and
    /// a 0.6 px blur, on a mid-grey background, 640 x 480; and the true
    /// corners, found by inverting `to_board` with Newton's method. (4 x 4
    /// samples place an edge along a pixel row only to 1/8 px, which moves a
    /// corner there by up to 0.2 px.)
    pub(super) fn render(
        to_board: &dyn Fn(f64, f64) -> (f64, f64),
    ) -> (Vec<f32>, Vec<Point2<f64>>) {
        let (w, h) = (640usize, 480usize);
        let mut img = vec![0.5f32; w * h];
        for py in 0..h {
            for px in 0..w {
                let mut acc = 0.0;
                for sy in 0..8 {
                    for sx in 0..8 {
                        let (bx, by) = to_board(
                            px as f64 + (sx as f64 + 0.5) / 8.0 - 0.5,
                            py as f64 + (sy as f64 + 0.5) / 8.0 - 0.5,
                        );
                        let (qx, qy) = (bx.floor() as i64, by.floor() as i64);
                        acc += if !(-1.6..=9.6).contains(&bx) || !(-1.6..=6.6).contains(&by) {
                            0.5
                        } else if (-1..=8).contains(&qx)
                            && (-1..=5).contains(&qy)
                            && (qx + qy).rem_euclid(2) == 0
                        {
                            0.08
                        } else {
                            0.85
                        };
                    }
                }
                img[py * w + px] = acc / 64.0;
            }
        }
        let img = gaussian(&img, w, h, 0.6);
        let invert = |target: (f64, f64)| {
            let mut p = Vector2::new(320.0, 240.0);
            for _ in 0..50 {
                let f = |p: &Vector2<f64>| {
                    let b = to_board(p.x, p.y);
                    Vector2::new(b.0 - target.0, b.1 - target.1)
                };
                let e = 1e-4;
                let (f0, fx, fy) = (
                    f(&p),
                    f(&(p + Vector2::new(e, 0.0))),
                    f(&(p + Vector2::new(0.0, e))),
                );
                let j = nalgebra::Matrix2::from_columns(&[(fx - f0) / e, (fy - f0) / e]);
                p -= j.try_inverse().expect("a regular map") * f0;
            }
            Point2::from(p)
        };
        let corners = (0..6)
            .flat_map(|r| (0..9).map(move |c| (c, r)))
            .map(|(c, r)| invert((c as f64, r as f64)))
            .collect();
        (img, corners)
    }

    fn assert_found(img: &[f32], truth: &[Point2<f64>], what: &str) {
        let found = find_chessboard(img, 640, 480, 9, 6).unwrap_or_else(|e| panic!("{what}: {e}"));
        let errors: Vec<f64> = found
            .iter()
            .zip(truth)
            .map(|(f, t)| (f - t).norm())
            .collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let worst = errors.iter().copied().fold(0.0, f64::max);
        // 8 x 8 samples place an edge along a pixel row to 1/16 px, so a
        // corner whose edges are nearly axis-aligned may be 0.1 px off.
        assert!(
            mean < 0.05 && worst < 0.15,
            "{what}: corners {mean} px off on average, worst {worst} px"
        );
    }

    #[test]
    fn finds_a_board_bent_by_strong_barrel_distortion() {
        // Undistorted = distorted * (1 + k r^2) in units of a 500 px focal
        // length: 12 % at the image corners, the bending of a wide-angle lens
        // (rows near the edge bow by several px over a few squares).
        let k = 0.3;
        let to_board = move |x: f64, y: f64| {
            let (u, v) = ((x - 320.0) / 500.0, (y - 240.0) / 500.0);
            let g = 1.0 + k * (u * u + v * v);
            let (ux, uy) = (u * g * 500.0, v * g * 500.0);
            ((ux + 300.0) / 68.0, (uy + 200.0) / 68.0)
        };
        let (img, truth) = render(&to_board);
        let edge_bow = {
            let row: Vec<_> = truth[..9].to_vec();
            let chord = row[8] - row[0];
            row.iter()
                .map(|p| (p - row[0]).perp(&chord).abs() / chord.norm())
                .fold(0.0, f64::max)
        };
        assert!(edge_bow > 8.0, "the first row bows by {edge_bow} px");
        assert_found(&img, &truth, "barrel");
    }

    #[test]
    fn finds_a_board_seen_steeply_where_a_diagonal_is_nearer_than_a_side() {
        // An oblique view of a turned board (as in a real photo where the
        // squares look like thin diamonds): the steps along a row and down a
        // column are 24 deg apart, and a corner's diagonal neighbour is nearer
        // than either side neighbour.
        let h = nalgebra::Matrix3::new(
            30.0, 22.0, 150.0, //
            8.0, 18.0, 130.0, //
            0.0004, 0.0003, 1.0,
        );
        let inv = h.try_inverse().unwrap();
        let to_board = move |x: f64, y: f64| {
            let b = inv * nalgebra::Vector3::new(x, y, 1.0);
            (b.x / b.z, b.y / b.z)
        };
        let (img, truth) = render(&to_board);
        let side = (truth[9] - truth[0])
            .norm()
            .min((truth[1] - truth[0]).norm());
        let diagonal = (truth[10] - truth[0])
            .norm()
            .min((truth[9] - truth[1]).norm());
        assert!(diagonal < side, "diagonal {diagonal} px, side {side} px");
        assert_found(&img, &truth, "steep");
    }

    #[test]
    fn an_edge_between_squares_is_told_from_a_diagonal() {
        let to_board = |x: f64, y: f64| ((x - 150.0) / 40.0, (y - 100.0) / 40.0);
        let (img, truth) = render(&to_board);
        assert!(along_an_edge(&img, 640, 480, truth[0], truth[1]));
        assert!(along_an_edge(&img, 640, 480, truth[0], truth[9]));
        assert!(!along_an_edge(&img, 640, 480, truth[0], truth[10]));
        assert!(!along_an_edge(&img, 640, 480, truth[1], truth[9]));
    }
}

#[cfg(test)]
mod real_photo_tests {
    use super::*;
    use rayon::prelude::*;

    fn data_dir() -> std::path::PathBuf {
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/chessboard")
    }

    /// A photo from tests/data/chessboard as grey 0..1, decoded as the op
    /// decodes it.
    fn photo(name: &str) -> (Vec<f32>, usize, usize) {
        let img = crate::io::load_grey(&data_dir().join(name)).unwrap();
        (img.levels, img.width, img.height)
    }

    #[test]
    fn real_photos_give_opencvs_corners_in_opencvs_order() {
        // OpenCV 5.0's findChessboardCorners + cornerSubPix (winSize 5 x 5,
        // an 11 x 11 window) on the same files: tests/data/chessboard/README.md.
        let text = std::fs::read_to_string(data_dir().join("opencv_corners.csv")).unwrap();
        for name in ["calibration03.jpg", "calibration13.jpg"] {
            let theirs: Vec<Point2<f64>> = text
                .lines()
                .filter(|l| l.starts_with(name))
                .map(|l| {
                    let f: Vec<f64> = l.split(',').skip(2).map(|v| v.parse().unwrap()).collect();
                    Point2::new(f[0], f[1])
                })
                .collect();
            assert_eq!(theirs.len(), 54);
            let (grey, w, h) = photo(name);
            let ours = find_chessboard(&grey, w, h, 9, 6).unwrap_or_else(|e| panic!("{name}: {e}"));
            let d: Vec<f64> = ours
                .iter()
                .zip(&theirs)
                .map(|(a, b)| (a - b).norm())
                .collect();
            let mean = d.iter().sum::<f64>() / d.len() as f64;
            let worst = d.iter().copied().fold(0.0, f64::max);
            // Same order (a reversed or turned order would be squares off),
            // within JPEG noise of each other.
            assert!(
                mean < 0.1 && worst < 0.3,
                "{name}: mean {mean} px, worst {worst} px"
            );
        }
    }

    /// The outcome as bits: corners' coordinates, or the refusal.
    fn outcome(grey: &[f32], w: usize, h: usize) -> Result<Vec<(u64, u64)>, Refusal> {
        find_chessboard(grey, w, h, 9, 6)
            .map(|c| c.iter().map(|p| (p.x.to_bits(), p.y.to_bits())).collect())
    }

    #[test]
    fn the_same_photo_gives_the_same_result_every_time_on_any_thread() {
        for name in ["calibration03.jpg", "calibration13.jpg"] {
            let (grey, w, h) = photo(name);
            let first = outcome(&grey, w, h);
            let again: Vec<_> = (0..8)
                .into_par_iter()
                .map(|_| outcome(&grey, w, h))
                .collect();
            for other in again {
                assert_eq!(other, first, "{name}");
            }
        }
    }
}
