//! Semi-global matching (Hirschmüller, PAMI 2008): matching costs aggregated
//! along 4, 5 or 8 straight paths with a small penalty P1 for disparity steps
//! of one pixel and a large one P2 for jumps, then selected by
//! [`super::select`].
//!
//! Our own implementation (no maintained Rust crate does SGM; `sgm-rs` is
//! from 2021 on an old image crate, ../shared/CRATES.md). Five paths run in
//! one top-down pass (as OpenCV's `MODE_SGBM`): left-to-right, the vertical
//! and the two downward diagonals pixel by pixel, then right-to-left along
//! the finished row, whose disparities are then selected; only the previous
//! row's path costs are kept, and horizontal stripes run in parallel. Four or
//! eight paths run in two passes on two threads: top-down with left-to-right
//! (and the two downward diagonals with 8 paths), and bottom-up with
//! right-to-left (and the upward diagonals), meeting in the middle.

use super::pair::{DisparityRange, GreyImage};
use super::select::{SelectParams, select_row};
use super::simd::{Isa, kernels};
use super::volume::{CostRows, lanes_for};
use std::ops::Range;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

/// Lane value that never wins a minimum (and cannot overflow with P1 added).
const SENTINEL: u16 = 16383;

/// Which paths to aggregate along.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Paths {
    /// Horizontal and vertical, both ways (two passes).
    Four,
    /// Horizontal both ways, down and the two downward diagonals, in one
    /// top-down pass (OpenCV's default `MODE_SGBM`): nothing is stored
    /// between rows but the previous row's path costs, and the image is
    /// matched in horizontal stripes in parallel.
    Five,
    /// Horizontal, vertical and both diagonals, both ways (two passes).
    Eight,
}

impl Paths {
    /// The number of paths.
    pub fn count(self) -> usize {
        match self {
            Paths::Four => 4,
            Paths::Five => 5,
            Paths::Eight => 8,
        }
    }

    /// Paths from their number (4, 5 or 8).
    pub fn from_count(n: i64) -> Result<Self, String> {
        match n {
            4 => Ok(Paths::Four),
            5 => Ok(Paths::Five),
            8 => Ok(Paths::Eight),
            _ => Err(format!(
                "paths = {n}: use 4 or 8 (two passes), or 5 (one top-down pass)"
            )),
        }
    }
}

/// Penalties and paths of semi-global matching.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgmParams {
    /// Penalty for a disparity change of one pixel between neighbours, in cost units.
    pub p1: u16,
    /// Penalty for a larger change, in cost units (> p1).
    pub p2: u16,
    /// Paths aggregated.
    pub paths: Paths,
    /// Where the guide image has an edge of |dI| grey levels between two
    /// neighbours, P2 drops to `max(P1 + 1, P2 * gamma / (gamma + |dI|))`, so
    /// disparity jumps follow intensity edges (Hirschmüller); 0 = constant P2.
    pub p2_gamma: f32,
}

impl SgmParams {
    /// Checks the penalties: 0 < p1 < p2 <= 4000 (so 16-bit sums cannot overflow).
    pub fn check(&self) -> Result<(), String> {
        check_penalties(self.p1, self.p2)
    }
}

/// Checks SGM penalties `p1`, `p2` (cost units): 0 < p1 < p2 <= 4000.
pub fn check_penalties(p1: u16, p2: u16) -> Result<(), String> {
    if p1 == 0 || p1 >= p2 || p2 > 4000 {
        return Err(format!(
            "SGM penalties P1 = {p1} and P2 = {p2}: need 0 < P1 < P2 <= 4000"
        ));
    }
    Ok(())
}

/// Aggregated costs `[y][x][k]` as the two passes' sums (their sum is the total).
#[derive(Debug, Clone, PartialEq)]
pub struct Aggregated {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Disparities.
    pub range: DisparityRange,
    /// Sum of the top-down pass's paths.
    pub down: Vec<u16>,
    /// Sum of the bottom-up pass's paths.
    pub up: Vec<u16>,
}

impl Aggregated {
    /// Lanes per pixel in `down` and `up`: the disparity count rounded up to a
    /// whole number of vectors (the lanes beyond the count hold nothing).
    pub fn lanes(&self) -> usize {
        lanes_for(self.range.count)
    }

    /// The total aggregated costs of row `y`, `[x][lane]` ([`Aggregated::lanes`]
    /// per pixel), into `out`.
    pub fn total_row(&self, y: usize, out: &mut Vec<u16>) {
        let len = self.width * self.lanes();
        let span = y * len..(y + 1) * len;
        out.clear();
        out.extend(
            self.down[span.clone()]
                .iter()
                .zip(&self.up[span])
                .map(|(a, b)| a.saturating_add(*b)),
        );
    }
}

/// Aggregates `costs` along the paths of `params` (checked by
/// [`SgmParams::check`]) over the whole image, with no stripes (for tests and
/// inspection; [`aggregate_and_select`] is the fast way); `guide` (the left
/// image) adapts P2 to its edges. With [`Paths::Five`] the single pass's
/// sums are in `down` and `up` is zero.
pub fn aggregate<C: CostRows>(
    costs: &C,
    params: &SgmParams,
    guide: Option<&GreyImage>,
) -> Aggregated {
    let isa = Isa::detect();
    let (w, h) = (costs.width(), costs.height());
    // P2 by grey-level step between neighbours.
    let p2_of = p2_table(params, guide);
    let guide = guide.filter(|g| (g.width, g.height) == (w, h));
    let whole = |plan: PassPlan| pass(costs, params, &p2_of, guide, &plan, isa);
    let (down, up) = match params.paths {
        Paths::Five => (
            whole(PassPlan::single(0..h)),
            vec![0; h * w * lanes_for(costs.range().count)],
        ),
        paths => rayon::join(
            || whole(PassPlan::two_way(paths, 0..h, false)),
            || whole(PassPlan::two_way(paths, 0..h, true)),
        ),
    };
    Aggregated {
        width: w,
        height: h,
        range: costs.range(),
        down,
        up,
    }
}

impl PassPlan {
    /// The one top-down pass of [`Paths::Five`] over `rows`.
    fn single(rows: Range<usize>) -> Self {
        PassPlan {
            rows,
            reverse: false,
            vertical_paths: 3,
            back_horizontal: true,
        }
    }

    /// One of the two passes of 4 or 8 paths.
    fn two_way(paths: Paths, rows: Range<usize>, reverse: bool) -> Self {
        PassPlan {
            rows,
            reverse,
            vertical_paths: if paths == Paths::Four { 1 } else { 3 },
            back_horizontal: false,
        }
    }
}

/// The rows a pass runs over and the ways it goes.
#[derive(Debug, Clone)]
struct PassPlan {
    /// Image rows, visited in order or reversed.
    rows: Range<usize>,
    /// Bottom-up and right to left (else top-down and left to right).
    reverse: bool,
    /// Paths from the previous row: 1 (vertical) or 3 (and the diagonals).
    vertical_paths: usize,
    /// Also the horizontal path against the pass's direction, within each row.
    back_horizontal: bool,
}

/// One pass over rows of the image. In the pass's own frame, pixel i of row
/// j continues the paths from (i - 1, j) and, from the row before, (i, j - 1),
/// (i - 1, j - 1), (i + 1, j - 1); with `back_horizontal`, also from (i + 1, j).
/// `on_row(y, sums)` gets each row's sum of the pass's paths, `[x][lane]`.
fn run_pass<C: CostRows>(
    costs: &C,
    params: &SgmParams,
    p2_of: &[u16; 256],
    guide: Option<&GreyImage>,
    plan: &PassPlan,
    isa: Isa,
    mut on_row: impl FnMut(usize, &[u16]),
) {
    let (w, n) = (costs.width(), costs.range().count);
    let vertical_paths = plan.vertical_paths;
    let reverse = plan.reverse;
    let lanes = lanes_for(n);
    let stride = lanes + 2;
    // Lanes past the disparity count get a sentinel added, so they never win.
    let pad: Vec<u16> = (0..lanes)
        .map(|k| if k < n { 0 } else { SENTINEL })
        .collect();
    let mut cost_lanes = vec![0u8; lanes];
    let mut cost_scratch = vec![0u8; w * costs.lanes()];
    // Path costs of the previous and current rows, per vertical path, with a
    // virtual pixel on each side (index 0 and w + 1) that starts paths: its
    // costs are 0, so a path's first pixel gets just its matching cost.
    let fresh = || {
        let mut b = vec![0u16; vertical_paths * (w + 2) * stride];
        for px in b.chunks_exact_mut(stride) {
            px[0] = SENTINEL;
            px[n + 1..].fill(SENTINEL);
        }
        b
    };
    let (mut prev, mut cur) = (fresh(), fresh());
    let (mut prev_min, mut cur_min) = (
        vec![0u16; vertical_paths * (w + 2)],
        vec![0u16; vertical_paths * (w + 2)],
    );
    let mut h_prev = vec![0u16; stride];
    let mut h_cur = vec![0u16; stride];
    for b in [&mut h_prev, &mut h_cur] {
        b[0] = SENTINEL;
        b[n + 1..].fill(SENTINEL);
    }
    // The pass's sum of paths for the current row, `[x][lane]`, handed to
    // `on_row` when the row is done.
    let mut sum_row = vec![0u16; w * lanes];
    let p1 = params.p1;
    let mut p2_row = vec![[params.p2; 4]; w];
    let mut p2_back = vec![params.p2; if plan.back_horizontal { w } else { 0 }];
    let rows: Box<dyn Iterator<Item = usize>> = if reverse {
        Box::new(plan.rows.clone().rev())
    } else {
        Box::new(plan.rows.clone())
    };
    for (j, y) in rows.enumerate() {
        if let Some(g) = guide {
            let above = (j > 0).then(|| g.row(if reverse { y + 1 } else { y - 1 }));
            p2_rows(
                g.row(y),
                above,
                reverse,
                p2_of,
                params.p2,
                &mut p2_row,
                &mut p2_back,
            );
        }
        let mut job = RowJob {
            cost_row: costs.row(y, &mut cost_scratch),
            cost_stride: costs.lanes(),
            n,
            lanes,
            vertical_paths,
            reverse,
            p1,
            pad: &pad,
            p2: &p2_row,
            p2_back: &p2_back,
            prev: &prev,
            prev_min: &prev_min,
            cur: &mut cur,
            cur_min: &mut cur_min,
            h_prev: &mut h_prev,
            h_cur: &mut h_cur,
            cost_lanes: &mut cost_lanes,
            sum_row: &mut sum_row,
        };
        isa.sgm_row(&mut job);
        std::mem::swap(&mut prev, &mut cur);
        std::mem::swap(&mut prev_min, &mut cur_min);
        on_row(y, &sum_row);
    }
}

/// P2 towards each path's previous pixel for one row, by pass position i:
/// horizontal (x + dx, y), vertical (x, y + dy), diagonals (x + dx, y + dy)
/// and (x - dx, y + dy), with dx, dy pointing back along the pass; and into
/// `back` (if not empty), by image x, towards (x - dx, y) for the horizontal
/// path against the pass. `above` is the row the pass came from (`None` on
/// its first row); steps leaving the image keep `p2`.
fn p2_rows(
    row: &[u8],
    above: Option<&[u8]>,
    reverse: bool,
    p2_of: &[u16; 256],
    p2: u16,
    out: &mut [[u16; 4]],
    back: &mut [u16],
) {
    let w = row.len();
    let step = |a: u8, b: u8| p2_of[a.abs_diff(b) as usize];
    // In image order: to the left neighbour (x - 1) and the right (x + 1).
    let to_left = |x: usize| if x > 0 { step(row[x], row[x - 1]) } else { p2 };
    let to_right = |x: usize| {
        if x + 1 < w {
            step(row[x], row[x + 1])
        } else {
            p2
        }
    };
    for (i, p) in out.iter_mut().enumerate() {
        let x = if reverse { w - 1 - i } else { i };
        let (horizontal, up_left, up_right) = match above {
            Some(up) => (
                if reverse { to_right(x) } else { to_left(x) },
                if x > 0 { step(row[x], up[x - 1]) } else { p2 },
                if x + 1 < w {
                    step(row[x], up[x + 1])
                } else {
                    p2
                },
            ),
            None => (if reverse { to_right(x) } else { to_left(x) }, p2, p2),
        };
        let vertical = above.map_or(p2, |up| step(row[x], up[x]));
        // Diagonals: back along the pass is up-left going right, up-right
        // going left.
        *p = if reverse {
            [horizontal, vertical, up_right, up_left]
        } else {
            [horizontal, vertical, up_left, up_right]
        };
    }
    for (x, p) in back.iter_mut().enumerate() {
        *p = if reverse { to_left(x) } else { to_right(x) };
    }
}

/// One row of a pass: everything [`row_body`] reads and writes.
pub(crate) struct RowJob<'a> {
    /// The row's matching costs, `[x][k]`, `cost_stride` per pixel.
    pub cost_row: &'a [u8],
    /// Costs per pixel in `cost_row` (the lanes when the volume is padded).
    pub cost_stride: usize,
    /// Disparities.
    pub n: usize,
    /// Lanes per pixel (n rounded up to whole vectors).
    pub lanes: usize,
    /// 1 (vertical) or 3 (vertical and diagonals) paths from the previous row.
    pub vertical_paths: usize,
    /// Whether the pass runs right to left (and bottom-up).
    pub reverse: bool,
    /// Small-step penalty.
    pub p1: u16,
    /// 0 for real lanes, a sentinel for padding lanes.
    pub pad: &'a [u16],
    /// P2 per pass position, per path (horizontal, vertical, two diagonals).
    pub p2: &'a [[u16; 4]],
    /// P2 of the horizontal path against the pass, per image x; empty when
    /// the pass has no such path.
    pub p2_back: &'a [u16],
    /// Path costs of the previous row, per vertical path and padded pixel.
    pub prev: &'a [u16],
    /// Their minima.
    pub prev_min: &'a [u16],
    /// Path costs of this row (written).
    pub cur: &'a mut [u16],
    /// Their minima (written).
    pub cur_min: &'a mut [u16],
    /// Horizontal path costs of the previous pixel.
    pub h_prev: &'a mut Vec<u16>,
    /// Horizontal path costs of this pixel (scratch).
    pub h_cur: &'a mut Vec<u16>,
    /// One pixel's costs, padded to `lanes`.
    pub cost_lanes: &'a mut [u8],
    /// The sums of paths of this row (written).
    pub sum_row: &'a mut [u16],
}

kernels! {
    /// One row of a semi-global aggregation pass ([`row_body`]).
    fn sgm_row(job: &mut RowJob<'_>) {
        row_body(job)
    }
}

/// The pixels of one row of a pass, in the pass's order.
#[inline(always)]
pub(crate) fn row_body(job: &mut RowJob<'_>) {
    let (n, lanes) = (job.n, job.lanes);
    let w = job.p2.len();
    let stride = lanes + 2;
    let plane = (w + 2) * stride;
    let mut h_min = 0u16;
    job.h_prev[1..=n].fill(0);
    for i in 0..w {
        let x = if job.reverse { w - 1 - i } else { i };
        let cost = pixel_costs(job.cost_row, job.cost_stride, n, lanes, job.cost_lanes, x);
        let sum = &mut job.sum_row[x * lanes..(x + 1) * lanes];
        let p2 = job.p2[i];
        let at = |path: usize, px: usize| path * plane + px * stride;
        let o = (i + 1) * stride;
        if job.vertical_paths == 3 {
            let (c0, rest) = job.cur.split_at_mut(plane);
            let (c1, c2) = rest.split_at_mut(plane);
            let prev = job.prev;
            let (m0, rest) = job.cur_min.split_at_mut(w + 2);
            let (m1, m2) = rest.split_at_mut(w + 2);
            sgm_pixel_body(
                cost,
                job.pad,
                [
                    &job.h_prev[..],
                    &prev[at(0, i + 1)..at(0, i + 1) + stride],
                    &prev[at(1, i)..at(1, i) + stride],
                    &prev[at(2, i + 2)..at(2, i + 2) + stride],
                ],
                [
                    h_min,
                    job.prev_min[i + 1],
                    job.prev_min[(w + 2) + i],
                    job.prev_min[2 * (w + 2) + i + 2],
                ],
                job.p1,
                p2,
                [
                    &mut job.h_cur[..],
                    &mut c0[o..o + stride],
                    &mut c1[o..o + stride],
                    &mut c2[o..o + stride],
                ],
                [&mut h_min, &mut m0[i + 1], &mut m1[i + 1], &mut m2[i + 1]],
                sum,
                false,
            );
        } else {
            sgm_pixel_body(
                cost,
                job.pad,
                [&job.h_prev[..], &job.prev[o..o + stride]],
                [h_min, job.prev_min[i + 1]],
                job.p1,
                [p2[0], p2[1]],
                [&mut job.h_cur[..], &mut job.cur[o..o + stride]],
                [&mut h_min, &mut job.cur_min[i + 1]],
                sum,
                false,
            );
        }
        std::mem::swap(job.h_prev, job.h_cur);
    }
    if !job.p2_back.is_empty() {
        back_horizontal(job);
    }
}

/// The recurrence of Hirschmüller's semi-global matching for one pixel:
/// `L(k) = C(k) + min(L'(k), L'(k-1) + P1, L'(k+1) + P1, min L' + P2) - min L'`.
/// For path p, `prev[p]` holds the previous pixel's path costs in lanes
/// 1..=n (lane 0 and n + 1 are large sentinels), `prev_min[p]` their minimum;
/// the new path costs go to lanes 1..=n of `out[p]`, their (saturating) sum
/// over paths to `sum` (replacing it, or added to it with `add_to_sum`), and
/// the new minima to `out_min` (each written where it is kept, rather than
/// returned as an array: packing and unpacking that array stalled on store
/// forwarding, a sixth of the aggregation time). `cost` has the n
/// matching costs; `pad` is added to every new cost (0, or a sentinel for
/// lanes past the disparity count, which then never win).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn sgm_pixel_body<const N: usize>(
    cost: &[u8],
    pad: &[u16],
    prev: [&[u16]; N],
    prev_min: [u16; N],
    p1: u16,
    p2: [u16; N],
    out: [&mut [u16]; N],
    out_min: [&mut u16; N],
    sum: &mut [u16],
    add_to_sum: bool,
) {
    let n = cost.len();
    let (cost, pad, sum) = (&cost[..n], &pad[..n], &mut sum[..n]);
    let below: [&[u16]; N] = std::array::from_fn(|p| &prev[p][0..n]);
    let same: [&[u16]; N] = std::array::from_fn(|p| &prev[p][1..n + 1]);
    let above: [&[u16]; N] = std::array::from_fn(|p| &prev[p][2..n + 2]);
    let out = out.map(|o| &mut o[1..n + 1]);
    let base: [u16; N] = std::array::from_fn(|p| prev_min[p] + p2[p]);
    let mut lowest = [u16::MAX; N];
    // All paths in one pass over the disparities, so the cost is loaded and
    // the sum kept in registers once for all of them; the compiler turns the
    // loop into vector code over k.
    for k in 0..n {
        let c = cost[k] as u16 + pad[k];
        let mut total = if add_to_sum { sum[k] } else { 0 };
        for p in 0..N {
            let m = same[p][k]
                .min(below[p][k].min(above[p][k]) + p1)
                .min(base[p]);
            let v = c + m - prev_min[p];
            out[p][k] = v;
            total = total.saturating_add(v);
            lowest[p] = lowest[p].min(v);
        }
        sum[k] = total;
    }
    for (dst, v) in out_min.into_iter().zip(lowest) {
        *dst = v;
    }
}

/// Pixel x's costs from a row of `stride` per pixel, as `lanes` values:
/// borrowed when the row is padded to whole vectors, else copied into
/// `scratch` (whose padding lanes the kernels ignore).
#[inline(always)]
fn pixel_costs<'a>(
    row: &'a [u8],
    stride: usize,
    n: usize,
    lanes: usize,
    scratch: &'a mut [u8],
    x: usize,
) -> &'a [u8] {
    let at = x * stride;
    if stride >= lanes {
        &row[at..at + lanes]
    } else {
        scratch[..n].copy_from_slice(&row[at..at + n]);
        scratch
    }
}

/// The horizontal path against the pass's direction along the row, added to
/// the row's sums.
#[inline(always)]
fn back_horizontal(job: &mut RowJob<'_>) {
    let (n, lanes) = (job.n, job.lanes);
    let w = job.p2_back.len();
    let mut h_min = 0u16;
    job.h_prev[1..=n].fill(0);
    for i in 0..w {
        let x = if job.reverse { i } else { w - 1 - i };
        let cost = pixel_costs(job.cost_row, job.cost_stride, n, lanes, job.cost_lanes, x);
        sgm_pixel_body(
            cost,
            job.pad,
            [&job.h_prev[..]],
            [h_min],
            job.p1,
            [job.p2_back[x]],
            [&mut job.h_cur[..]],
            [&mut h_min],
            &mut job.sum_row[x * lanes..(x + 1) * lanes],
            true,
        );
        std::mem::swap(job.h_prev, job.h_cur);
    }
}

/// One pass's sums of paths as a whole volume `[y][x][lane]`.
fn pass<C: CostRows>(
    costs: &C,
    params: &SgmParams,
    p2_of: &[u16; 256],
    guide: Option<&GreyImage>,
    plan: &PassPlan,
    isa: Isa,
) -> Vec<u16> {
    let len = costs.width() * lanes_for(costs.range().count);
    let mut sums = vec![0u16; costs.height() * len];
    run_pass(costs, params, p2_of, guide, plan, isa, |y, row| {
        sums[y * len..(y + 1) * len].copy_from_slice(row)
    });
    sums
}

/// Semi-global matching from costs to disparities (px, NaN = invalid),
/// selected by `select` row by row as the aggregation reaches them.
pub fn aggregate_and_select<C: CostRows>(
    costs: &C,
    params: &SgmParams,
    guide: Option<&GreyImage>,
    select: &SelectParams,
) -> Vec<f32> {
    let guide = guide.filter(|g| (g.width, g.height) == (costs.width(), costs.height()));
    match params.paths {
        Paths::Five => in_stripes(costs, params, guide, select),
        _ => meeting_in_the_middle(costs, params, guide, select),
    }
}

/// Rows of warm-up a stripe of [`in_stripes`] aggregates above its first row,
/// so its vertical and diagonal paths do not start cold there.
const STRIPE_WARM_UP_ROWS: usize = 24;

/// Stripes for `h` rows: a power of two that leaves each at least 128 rows,
/// at most 16. It depends on the image alone, never on the threads, so the
/// result is the same on any machine.
fn stripe_count(h: usize) -> usize {
    let mut n = 1;
    while n < 16 && h / (2 * n) >= 128 {
        n *= 2;
    }
    n
}

/// The rows of each stripe of `h` rows: [`stripe_count`] stripes, the first
/// longer by the warm-up the others aggregate, so all take the same time.
fn stripe_bounds(h: usize) -> Vec<Range<usize>> {
    let stripes = stripe_count(h);
    let warm_up = STRIPE_WARM_UP_ROWS.min(h / stripes);
    let work = (h + (stripes - 1) * warm_up).div_ceil(stripes);
    let mut bounds = Vec::with_capacity(stripes);
    let mut start = 0;
    for s in 0..stripes {
        let rows = if s == 0 { work } else { work - warm_up };
        let end = if s + 1 == stripes {
            h
        } else {
            (start + rows).min(h)
        };
        bounds.push(start..end);
        start = end;
    }
    bounds
}

/// The single top-down pass of [`Paths::Five`], in horizontal stripes
/// matched in parallel; each stripe starts [`STRIPE_WARM_UP_ROWS`] above its
/// first row and selects disparities as each row's sums are complete.
fn in_stripes<C: CostRows>(
    costs: &C,
    params: &SgmParams,
    guide: Option<&GreyImage>,
    select: &SelectParams,
) -> Vec<f32> {
    use rayon::prelude::*;
    let (w, h) = (costs.width(), costs.height());
    let lanes = lanes_for(costs.range().count);
    let isa = Isa::detect();
    let p2_of = p2_table(params, guide);
    let bounds = stripe_bounds(h);
    let mut disparity = vec![f32::NAN; w * h];
    let mut chunks = Vec::with_capacity(bounds.len());
    let mut rest = &mut disparity[..];
    for rows in &bounds {
        let (chunk, tail) = rest.split_at_mut(rows.len() * w);
        chunks.push((rows.clone(), chunk));
        rest = tail;
    }
    chunks.into_par_iter().for_each(|(rows, out)| {
        let first = rows.start;
        let plan = PassPlan::single(first.saturating_sub(STRIPE_WARM_UP_ROWS)..rows.end);
        run_pass(costs, params, &p2_of, guide, &plan, isa, |y, total| {
            if y >= first {
                let r = y - first;
                let row = &mut out[r * w..(r + 1) * w];
                select_row(total, w, costs.range(), lanes, select, row);
            }
        });
    });
    disparity
}

/// 4 or 8 paths without holding two whole volumes: the top-down and
/// bottom-up passes run on two threads and meet in the middle. Each keeps its
/// sums only for the half of the rows the other reaches last; when it
/// reaches a row the other has already summed, it adds the two and selects
/// that row's disparities at once. So one volume of sums instead of two, and
/// selection runs in the passes, in parallel.
fn meeting_in_the_middle<C: CostRows>(
    costs: &C,
    params: &SgmParams,
    guide: Option<&GreyImage>,
    select: &SelectParams,
) -> Vec<f32> {
    let (w, h) = (costs.width(), costs.height());
    let lanes = lanes_for(costs.range().count);
    let isa = Isa::detect();
    let p2_of = p2_table(params, guide);
    let mid = h / 2;
    // Rows 0..mid summed by the top-down pass (read by the bottom-up one),
    // rows mid..h by the bottom-up pass.
    let handed: Vec<OnceLock<Vec<u16>>> = (0..h).map(|_| OnceLock::new()).collect();
    let failed = AtomicBool::new(false);
    let mut disparity = vec![f32::NAN; w * h];
    let (top, bottom) = disparity.split_at_mut(mid * w);
    let half = |reverse: bool, out: &mut [f32], first_row: usize| {
        // If this thread panics, the other must stop waiting for its rows.
        let guard = PanicFlag(&failed);
        let mut total = vec![0u16; w * lanes];
        let plan = PassPlan::two_way(params.paths, 0..h, reverse);
        run_pass(costs, params, &p2_of, guide, &plan, isa, |y, row| {
            let mine_to_hand = if reverse { y >= mid } else { y < mid };
            if mine_to_hand {
                let _ = handed[y].set(row.to_vec());
                return;
            }
            let Some(other) = wait_for(&handed[y], &failed) else {
                return;
            };
            for ((t, a), b) in total.iter_mut().zip(row).zip(other) {
                *t = a.saturating_add(*b);
            }
            let r = y - first_row;
            select_row(
                &total,
                w,
                costs.range(),
                lanes,
                select,
                &mut out[r * w..(r + 1) * w],
            );
        });
        drop(guard);
    };
    std::thread::scope(|scope| {
        scope.spawn(|| half(false, bottom, mid));
        half(true, top, 0);
    });
    disparity
}

/// The P2 of every grey-level step between neighbours (0..=255).
fn p2_table(params: &SgmParams, guide: Option<&GreyImage>) -> [u16; 256] {
    std::array::from_fn(|step| match guide {
        Some(_) if params.p2_gamma > 0.0 => {
            let g = params.p2_gamma;
            ((params.p2 as f32 * g / (g + step as f32)).round() as u16).max(params.p1 + 1)
        }
        _ => params.p2,
    })
}

/// Raises its flag when dropped during a panic.
struct PanicFlag<'a>(&'a AtomicBool);

impl Drop for PanicFlag<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.store(true, Ordering::Release);
        }
    }
}

/// The row another thread hands over, or `None` when that thread failed.
fn wait_for<'a>(cell: &'a OnceLock<Vec<u16>>, failed: &AtomicBool) -> Option<&'a Vec<u16>> {
    loop {
        if let Some(v) = cell.get() {
            return Some(v);
        }
        if failed.load(Ordering::Acquire) {
            return None;
        }
        std::thread::yield_now();
    }
}

#[cfg(test)]
mod tests {
    use super::super::volume::CostVolume;
    use super::*;

    #[test]
    fn pixel_recurrence_by_hand() {
        let cost: Vec<u8> = (0..37).map(|k| ((k * 29) % 41) as u8).collect();
        let big = 16383u16;
        let mk = |seed: u16| -> Vec<u16> {
            let mut v: Vec<u16> = (0..39).map(|k| (k as u16 * seed) % 97 + 5).collect();
            (v[0], v[38]) = (big, big);
            v
        };
        let prev = [mk(3), mk(7), mk(11), mk(13)];
        let mins = prev.clone().map(|p| *p[1..38].iter().min().unwrap());
        let mut outs = [
            vec![0u16; 39],
            vec![0u16; 39],
            vec![0u16; 39],
            vec![0u16; 39],
        ];
        let mut sum = vec![0u16; 37];
        let [a, b, c, d] = &mut outs;
        let mut new_mins = [0u16; 4];
        let [m0, m1, m2, m3] = &mut new_mins;
        sgm_pixel_body(
            &cost,
            &[0u16; 37],
            [&prev[0], &prev[1], &prev[2], &prev[3]],
            mins,
            8,
            [100, 90, 80, 70],
            [a, b, c, d],
            [m0, m1, m2, m3],
            &mut sum,
            false,
        );
        // By hand for path 0, k = 0: min(L'(0), L'(1) + P1, minL' + P2) etc.
        let pr = &prev[0];
        let m = pr[1].min(pr[2] + 8).min(mins[0] + 100);
        assert_eq!(outs[0][1], cost[0] as u16 + m - mins[0]);
        assert_eq!(new_mins[0], *outs[0][1..38].iter().min().unwrap());
        assert_eq!(sum[5], (0..4).map(|p| outs[p][6]).sum::<u16>());
    }

    /// The `n` costs of pixel (x, y) of an unpadded `[y][x][k]` volume `w` wide.
    fn pixel_costs(data: &[u8], w: usize, n: usize, x: usize, y: usize) -> Vec<u16> {
        let i = (y * w + x) * n;
        data[i..i + n].iter().map(|&v| v as u16).collect()
    }

    /// Direct evaluation of one path's recurrence, for comparison.
    fn path_costs(costs: &[Vec<u16>], p1: u16, p2: u16) -> Vec<Vec<u16>> {
        path_costs_with(costs, p1, |_| p2)
    }

    /// The recurrence with P2 of the step into element t given by `p2_at(t)`.
    fn path_costs_with(costs: &[Vec<u16>], p1: u16, p2_at: impl Fn(usize) -> u16) -> Vec<Vec<u16>> {
        let mut out: Vec<Vec<u16>> = Vec::new();
        for (t, c) in costs.iter().enumerate() {
            let p2 = p2_at(t);
            let l = match out.last() {
                None => c.clone(),
                Some(prev) => {
                    let m = *prev.iter().min().unwrap();
                    (0..c.len())
                        .map(|k| {
                            let mut best = prev[k];
                            if k > 0 {
                                best = best.min(prev[k - 1] + p1);
                            }
                            if k + 1 < c.len() {
                                best = best.min(prev[k + 1] + p1);
                            }
                            c[k] + best.min(m + p2) - m
                        })
                        .collect()
                }
            };
            out.push(l);
        }
        out
    }

    #[test]
    fn four_paths_equal_the_recurrence_by_hand() {
        let (w, h, n) = (7usize, 5usize, 6usize);
        let data: Vec<u8> = (0..w * h * n)
            .map(|i| ((i * 37 + i / 5) % 23) as u8)
            .collect();
        let volume = CostVolume::unpadded(
            w,
            h,
            DisparityRange::new(0, n as i32 - 1, w).unwrap(),
            23,
            data.clone(),
        );
        let params = SgmParams {
            p1: 3,
            p2: 20,
            paths: Paths::Four,
            p2_gamma: 0.0,
        };
        let agg = aggregate(&volume, &params, None);
        let c = |x: usize, y: usize| pixel_costs(&data, w, n, x, y);
        for y in 0..h {
            for x in 0..w {
                let mut total = vec![0u16; n];
                let row: Vec<_> = (0..w).map(|xx| c(xx, y)).collect();
                let col: Vec<_> = (0..h).map(|yy| c(x, yy)).collect();
                let rev = |v: &Vec<Vec<u16>>| v.iter().rev().cloned().collect::<Vec<_>>();
                let lr = path_costs(&row, 3, 20)[x].clone();
                let rl = path_costs(&rev(&row), 3, 20)[w - 1 - x].clone();
                let tb = path_costs(&col, 3, 20)[y].clone();
                let bt = path_costs(&rev(&col), 3, 20)[h - 1 - y].clone();
                for k in 0..n {
                    total[k] = lr[k] + rl[k] + tb[k] + bt[k];
                }
                let mut got = Vec::new();
                agg.total_row(y, &mut got);
                let l = agg.lanes();
                assert_eq!(&got[x * l..x * l + n], &total[..], "pixel ({x}, {y})");
            }
        }
    }

    #[test]
    fn p2_falls_across_the_guides_edges() {
        let (w, h, n) = (6usize, 5usize, 5usize);
        let data: Vec<u8> = (0..w * h * n)
            .map(|i| ((i * 29 + i / 3) % 19) as u8)
            .collect();
        let volume = CostVolume::unpadded(
            w,
            h,
            DisparityRange::new(0, 4, w).unwrap(),
            19,
            data.clone(),
        );
        let guide = GreyImage {
            width: w,
            height: h,
            data: (0..w * h).map(|i| ((i * 53) % 97) as u8).collect(),
        };
        let params = SgmParams {
            p1: 2,
            p2: 30,
            paths: Paths::Four,
            p2_gamma: 8.0,
        };
        let p2_of = p2_table(&params, Some(&guide));
        assert!(p2_of[0] == 30 && p2_of[40] < 10 && p2_of[255] >= 3);
        let agg = aggregate(&volume, &params, Some(&guide));
        let c = |x: usize, y: usize| pixel_costs(&data, w, n, x, y);
        let g = |x: usize, y: usize| guide.at(x, y);
        let step = |a: u8, b: u8| p2_of[a.abs_diff(b) as usize];
        for y in 0..h {
            for x in 0..w {
                let row: Vec<_> = (0..w).map(|xx| c(xx, y)).collect();
                let col: Vec<_> = (0..h).map(|yy| c(x, yy)).collect();
                let rev = |v: &Vec<Vec<u16>>| v.iter().rev().cloned().collect::<Vec<_>>();
                let lr = path_costs_with(&row, 2, |t| {
                    if t > 0 {
                        step(g(t, y), g(t - 1, y))
                    } else {
                        30
                    }
                })[x]
                    .clone();
                let rl = path_costs_with(&rev(&row), 2, |t| {
                    if t > 0 {
                        step(g(w - 1 - t, y), g(w - t, y))
                    } else {
                        30
                    }
                })[w - 1 - x]
                    .clone();
                let tb = path_costs_with(&col, 2, |t| {
                    if t > 0 {
                        step(g(x, t), g(x, t - 1))
                    } else {
                        30
                    }
                })[y]
                    .clone();
                let bt = path_costs_with(&rev(&col), 2, |t| {
                    if t > 0 {
                        step(g(x, h - 1 - t), g(x, h - t))
                    } else {
                        30
                    }
                })[h - 1 - y]
                    .clone();
                let mut got = Vec::new();
                agg.total_row(y, &mut got);
                let l = agg.lanes();
                for k in 0..n {
                    assert_eq!(
                        got[x * l + k],
                        lr[k] + rl[k] + tb[k] + bt[k],
                        "pixel ({x}, {y}) k {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn padded_and_unpadded_volumes_agree() {
        let (w, h) = (40usize, 12usize);
        let img = |seed: usize| GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| ((i * 7919 + seed) % 251) as u8)
                .collect(),
        };
        let range = DisparityRange::new(0, 20, w).unwrap();
        let padded = super::super::cost::census_costs(&img(1), &img(5), range, 5, 5);
        assert_eq!(padded.lanes, 32);
        let data: Vec<u8> = (0..w * h)
            .flat_map(|i| padded.pixel(i % w, i / w).to_vec())
            .collect();
        let plain = CostVolume::unpadded(w, h, range, padded.max_cost, data);
        let params = SgmParams {
            p1: 3,
            p2: 20,
            paths: Paths::Eight,
            p2_gamma: 0.0,
        };
        assert_eq!(
            aggregate(&padded, &params, None),
            aggregate(&plain, &params, None)
        );
    }

    #[test]
    fn scalar_and_vector_builds_agree() {
        let (w, h) = (23usize, 9usize);
        let range = DisparityRange::new(0, 20, w).unwrap();
        let data: Vec<u8> = (0..w * h * 21)
            .map(|i| ((i * 40503) >> 5) as u8 % 50)
            .collect();
        let volume = CostVolume::unpadded(w, h, range, 50, data);
        let params = SgmParams {
            p1: 5,
            p2: 40,
            paths: Paths::Eight,
            p2_gamma: 0.0,
        };
        let p2_of = p2_table(&params, None);
        for plan in [
            PassPlan::two_way(Paths::Eight, 0..h, false),
            PassPlan::two_way(Paths::Eight, 0..h, true),
            PassPlan::single(0..h),
        ] {
            let scalar = pass(&volume, &params, &p2_of, None, &plan, Isa::Scalar);
            let best = pass(&volume, &params, &p2_of, None, &plan, Isa::detect());
            assert_eq!(scalar, best, "{plan:?}");
        }
    }

    #[test]
    fn meeting_in_the_middle_equals_whole_volumes() {
        let range = DisparityRange::new(-3, 20, 40).unwrap();
        for (w, h) in [(40usize, 1usize), (40, 7), (37, 30)] {
            let n = range.count;
            let data: Vec<u8> = (0..w * h * n)
                .map(|i| ((i * 2654435761) >> 7) as u8 % 40)
                .collect();
            let volume = CostVolume::unpadded(w, h, range, 40, data);
            let guide = GreyImage {
                width: w,
                height: h,
                data: (0..w * h).map(|i| (i * 37 % 256) as u8).collect(),
            };
            let select = SelectParams {
                uniqueness_pct: 5.0,
                lr_max_diff_px: Some(1.0),
                subpixel: true,
            };
            for paths in [Paths::Four, Paths::Eight] {
                let params = SgmParams {
                    p1: 4,
                    p2: 30,
                    paths,
                    p2_gamma: 8.0,
                };
                let agg = aggregate(&volume, &params, Some(&guide));
                let whole = super::super::select::select(
                    w,
                    h,
                    range,
                    agg.lanes(),
                    |y, out: &mut Vec<u16>| agg.total_row(y, out),
                    &select,
                );
                let fused = aggregate_and_select(&volume, &params, Some(&guide), &select);
                let same = whole
                    .iter()
                    .zip(&fused)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{w} x {h} {paths:?}");
            }
        }
    }

    #[test]
    fn eight_paths_include_the_diagonals() {
        let (w, h, n) = (6usize, 6usize, 4usize);
        let data: Vec<u8> = (0..w * h * n).map(|i| ((i * 13 + 7) % 17) as u8).collect();
        let volume = CostVolume::unpadded(
            w,
            h,
            DisparityRange::new(0, n as i32 - 1, w).unwrap(),
            17,
            data.clone(),
        );
        let agg = aggregate(
            &volume,
            &SgmParams {
                p1: 2,
                p2: 9,
                paths: Paths::Eight,
                p2_gamma: 0.0,
            },
            None,
        );
        let c = |x: usize, y: usize| pixel_costs(&data, w, n, x, y);
        // Pixel (3, 2): its down-right diagonal path starts at (1, 0).
        let (x, y) = (3, 2);
        let diag: Vec<_> = (0..=2).map(|t| c(1 + t, t)).collect();
        let expect_dr = path_costs(&diag, 2, 9)[2].clone();
        // The up pass's sum at (x, y) minus its straight paths leaves its diagonals;
        // check the down pass instead by recomputing its four paths.
        let row: Vec<_> = (0..=x).map(|xx| c(xx, y)).collect();
        let col: Vec<_> = (0..=y).map(|yy| c(x, yy)).collect();
        let anti: Vec<_> = (0..=2).map(|t| c(5 - t, t)).collect();
        let lr = path_costs(&row, 2, 9)[x].clone();
        let tb = path_costs(&col, 2, 9)[y].clone();
        let dl = path_costs(&anti, 2, 9)[2].clone();
        for k in 0..n {
            assert_eq!(
                agg.down[(y * w + x) * agg.lanes() + k],
                lr[k] + tb[k] + expect_dr[k] + dl[k],
                "k {k}"
            );
        }
    }

    #[test]
    fn five_paths_equal_the_recurrence_by_hand() {
        let (w, h, n) = (7usize, 6usize, 5usize);
        let data: Vec<u8> = (0..w * h * n)
            .map(|i| ((i * 31 + i / 7) % 29) as u8)
            .collect();
        let range = DisparityRange::new(0, n as i32 - 1, w).unwrap();
        let volume = CostVolume::unpadded(w, h, range, 29, data.clone());
        let params = SgmParams {
            p1: 3,
            p2: 25,
            paths: Paths::Five,
            p2_gamma: 0.0,
        };
        let agg = aggregate(&volume, &params, None);
        assert!(agg.up.iter().all(|&v| v == 0));
        let c = |x: usize, y: usize| pixel_costs(&data, w, n, x, y);
        let rec = |v: Vec<Vec<u16>>| path_costs(&v, 3, 25).pop().unwrap();
        for y in 0..h {
            for x in 0..w {
                // Each path's pixels up to (x, y), in the order the path runs.
                let lr = rec((0..=x).map(|t| c(t, y)).collect());
                let rl = rec((x..w).rev().map(|t| c(t, y)).collect());
                let tb = rec((0..=y).map(|t| c(x, t)).collect());
                let back = x.min(y);
                let dr = rec((0..=back).rev().map(|t| c(x - t, y - t)).collect());
                let fwd = (w - 1 - x).min(y);
                let dl = rec((0..=fwd).rev().map(|t| c(x + t, y - t)).collect());
                let l = agg.lanes();
                for k in 0..n {
                    assert_eq!(
                        agg.down[(y * w + x) * l + k],
                        lr[k] + rl[k] + tb[k] + dr[k] + dl[k],
                        "pixel ({x}, {y}) k {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn stripes_cover_every_row_once_with_even_work() {
        for h in [1usize, 100, 255, 256, 375, 600, 1080, 5000] {
            let bounds = stripe_bounds(h);
            assert_eq!(bounds.len(), stripe_count(h));
            assert_eq!(bounds[0].start, 0);
            assert_eq!(bounds.last().unwrap().end, h);
            for pair in bounds.windows(2) {
                assert_eq!(pair[0].end, pair[1].start, "h {h}");
            }
            // Rows aggregated per stripe, warm-up included, differ by a row
            // or two at most.
            let work: Vec<usize> = bounds
                .iter()
                .map(|r| r.end - r.start.saturating_sub(STRIPE_WARM_UP_ROWS))
                .collect();
            let (lo, hi) = (work.iter().min().unwrap(), work.iter().max().unwrap());
            assert!(hi - lo <= 2, "h {h}: {work:?}");
        }
        assert_eq!(stripe_count(255), 1);
        assert_eq!(stripe_count(600), 4);
    }
}
