//! Sub-pixel refinement of disparities on the image intensities: around each
//! valid disparity, the shift that best aligns a window of the left image with
//! the right image along the row (zero-mean sum of squared differences,
//! minimised by Gauss-Newton as in Lucas-Kanade, linear interpolation). Cost
//! curves of census or block costs only locate the minimum to about a quarter
//! of a pixel (their parabola fit is biased towards integers, "pixel
//! locking"); matching the intensities themselves gets within a few hundredths
//! on textured surfaces, which at the phantom's 500 mm and 55 mm baseline is
//! the difference between 1 mm and 0.1 mm in depth.
//!
//! With linear interpolation every window sum that involves only the right
//! image is a mix, by the fractional shift, of sums over windows at integer
//! positions, so those come from prefix sums over the band of rows a window
//! covers (built once per row, small enough to stay in cache); only the two
//! products of the left window with the right gradient are summed per pixel.
//! All sums are of integers (grey levels and twice the gradient, a
//! difference of grey levels), so they are exact, vectorise as integer
//! code, and do not depend on the order they are added in; the prefix sums
//! are kept in f64, where integers under 2^53 are exact too.

use super::pair::GreyImage;
use super::simd::{DotWindow, Isa};
use rayon::prelude::*;

/// Largest window side the refinement supports, px.
pub const MAX_SIDE: usize = 31;

/// How the refinement runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineParams {
    /// Window half-size, px (window side 2 * half + 1, at most [`MAX_SIDE`]).
    pub half_window: usize,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Largest change from the matcher's disparity, px; beyond it the
    /// matcher's value is kept.
    pub max_change_px: f32,
}

/// The eight quantities' window sums over one band of rows, interleaved:
/// entry `x` holds, for each quantity (in [`ColumnSums`]' order), its sum over
/// columns `0 .. x` of the band's rows. Every sum is of integers well under
/// 2^53, so it is exact in f64, and a window's sum, the difference of two
/// entries, is the same number an integer sum would give; one pixel's eight
/// window sums are then four vector loads and subtractions.
struct BandSums(Vec<[f64; 8]>);

impl BandSums {
    /// From the column sums of each quantity over the band (what
    /// [`ColumnSums::windows`] gives, written plainly).
    #[cfg(test)]
    fn from_columns(columns: &[Vec<i32>; 8]) -> Self {
        let w = columns[0].len();
        let mut prefix = vec![[0.0; 8]; w + 1];
        for (q, column) in columns.iter().enumerate() {
            let mut total = 0i64;
            for (x, &c) in column.iter().enumerate() {
                total += c as i64;
                prefix[x + 1][q] = total as f64;
            }
        }
        BandSums(prefix)
    }

    /// Each quantity's sum over columns `x0 .. x0 + side` of the band.
    #[inline(always)]
    fn window(&self, x0: usize, side: usize) -> [f64; 8] {
        let (before, through) = (&self.0[x0], &self.0[x0 + side]);
        std::array::from_fn(|q| through[q] - before[q])
    }
}

/// Indices of the quantities in [`BandSums`] and [`ColumnSums`].
const L: usize = 0;
const R: usize = 1;
const G: usize = 2;
const GG: usize = 3;
const G_G1: usize = 4;
const G_R: usize = 5;
const G_R1: usize = 6;
const G1_R: usize = 7;

/// Column sums over a band of rows of the eight quantities Gauss-Newton needs
/// besides the left-gradient products: left, right, g, g^2, g x next g,
/// g x right, g x next right, next g x right, where g is twice the right
/// image's horizontal gradient (so an integer) and "next" is one column to
/// the right (0 past the edge). The band slides down a row by adding one row
/// and removing another. Each term is at most 2 * 255^2 in size, so a column
/// of up to [`MAX_SIDE`] rows fits an i32.
struct ColumnSums<'a> {
    images: [&'a [i16]; 3],
    w: usize,
    cols: [Vec<i32>; 8],
}

impl<'a> ColumnSums<'a> {
    /// The sums over rows `y0 .. y0 + rows` of the left, right and gradient images.
    fn band(images: [&'a [i16]; 3], w: usize, y0: usize, rows: usize) -> Self {
        let mut sums = ColumnSums {
            images,
            w,
            cols: [(); 8].map(|_| vec![0i32; w]),
        };
        for y in y0..y0 + rows {
            sums.add_row(y, 1);
        }
        sums
    }

    /// Adds row `y` (sign 1) or removes it (sign -1): a pass per quantity
    /// over the row, which vectorises (the last column's products with the
    /// next column are 0, so those passes stop a column short).
    fn add_row(&mut self, y: usize, sign: i32) {
        /// `col[x] += sign * terms[x]`.
        #[inline(always)]
        fn accumulate(col: &mut [i32], sign: i32, terms: impl Iterator<Item = i32>) {
            for (c, t) in col.iter_mut().zip(terms) {
                *c += sign * t;
            }
        }
        let w = self.w;
        let [lf, rf, gx] = self.images;
        let (l, r, g) = (
            &lf[y * w..(y + 1) * w],
            &rf[y * w..(y + 1) * w],
            &gx[y * w..(y + 1) * w],
        );
        let (r1, g1) = (&r[1..], &g[1..]);
        let wide = |v: &i16| *v as i32;
        let times = |(a, b): (&i16, &i16)| *a as i32 * *b as i32;
        let [c_l, c_r, c_g, c_gg, c_g_g1, c_g_r, c_g_r1, c_g1_r] = &mut self.cols;
        accumulate(c_l, sign, l.iter().map(wide));
        accumulate(c_r, sign, r.iter().map(wide));
        accumulate(c_g, sign, g.iter().map(wide));
        accumulate(c_gg, sign, g.iter().zip(g).map(times));
        accumulate(c_g_g1, sign, g.iter().zip(g1).map(times));
        accumulate(c_g_r, sign, g.iter().zip(r).map(times));
        accumulate(c_g_r1, sign, g.iter().zip(r1).map(times));
        accumulate(c_g1_r, sign, g1.iter().zip(r).map(times));
    }

    /// Window sums along the band (into `table`, reused from row to row).
    fn windows(&self, isa: Isa, table: &mut BandSums) {
        let cols: [&[i32]; 8] = std::array::from_fn(|q| &self.cols[q][..]);
        isa.prefix_sums8(cols, &mut table.0);
    }
}

/// Refines every valid (non-NaN) disparity of `disparity` in place. Pixels
/// whose window lacks horizontal texture, leaves the image, or would move by
/// more than `max_change_px` keep their value. Returns how many were refined.
pub fn refine_disparity(
    left: &GreyImage,
    right: &GreyImage,
    disparity: &mut [f32],
    params: &RefineParams,
) -> usize {
    let (w, h) = (left.width, left.height);
    let r = params.half_window.min(MAX_SIDE / 2);
    let side = 2 * r + 1;
    if w < side + 2 || h < side {
        return 0;
    }
    let li: Vec<i16> = left.data.iter().map(|&v| v as i16).collect();
    let ri: Vec<i16> = right.data.iter().map(|&v| v as i16).collect();
    // Twice the horizontal gradient of the right image (central differences).
    let mut g2 = vec![0i16; w * h];
    for y in 0..h {
        for x in 1..w - 1 {
            g2[y * w + x] = ri[y * w + x + 1] - ri[y * w + x - 1];
        }
    }
    let n = (side * side) as f64;
    let isa = Isa::detect();
    // Rows in blocks, so the band of column sums slides from row to row; each
    // block starts its band afresh (side rows of sums), so not too short.
    // The sums are exact, so the blocks do not change the result.
    const BLOCK_ROWS: usize = 48;
    let images = [&li[..], &ri[..], &g2[..]];
    disparity
        .par_chunks_mut(w * BLOCK_ROWS)
        .enumerate()
        .map(|(b, block)| {
            let mut refined = 0;
            let mut band: Option<ColumnSums> = None;
            let mut flying = Vec::new();
            let mut table = BandSums(Vec::new());
            for (k, row) in block.chunks_mut(w).enumerate() {
                let y = b * BLOCK_ROWS + k;
                if y < r || y + r >= h {
                    continue;
                }
                let y0 = y - r;
                match &mut band {
                    Some(sums) => {
                        sums.add_row(y + r, 1);
                        sums.add_row(y0 - 1, -1);
                    }
                    None => band = Some(ColumnSums::band(images, w, y0, side)),
                }
                let Some(sums) = &band else { continue };
                sums.windows(isa, &mut table);
                refined += refine_row(
                    row,
                    r..w - r,
                    y0,
                    &table,
                    &li,
                    &g2,
                    w,
                    side,
                    n,
                    isa,
                    params,
                    &mut flying,
                );
            }
            refined
        })
        .sum()
}

/// A pixel of a row in flight through the Gauss-Newton steps.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    /// Its column, px.
    x: usize,
    /// The matcher's disparity, px.
    d0: f32,
    /// The disparity so far, px.
    d: f64,
    /// The left window's sum.
    sl: f64,
    /// Where it is.
    state: State,
    /// The integer start of the right window `dots` are of (`usize::MAX`:
    /// none yet).
    at: usize,
    /// The left window's products with (twice) the right gradient over the
    /// right windows at `at` and `at + 1`.
    dots: [f64; 2],
    /// This step's numerator (the gradient's covariance with the residual,
    /// scaled as `var_g`) and the right gradient's variance it divides by
    /// (four times it, as the sums are of twice the gradient).
    num: f64,
    var_g: f64,
    /// This step's shift, px.
    delta: f64,
}

/// Where a pixel's Gauss-Newton steps have left it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Moved, and more steps may follow.
    Moving,
    /// Moved by under the step that ends the iterations: refined.
    Converged,
    /// Out of the image, without texture, or too far from the matcher's
    /// value: it keeps that value.
    Failed,
}

/// Refines the valid disparities in `columns` of one row (its windows' rows
/// start at `y0`) with the band's window sums; returns how many it refined.
/// The row's pixels take each step together, in three passes (`flying` is
/// scratch): the window sums and the step's two sides pixel by pixel, the
/// divisions for all of them without a branch, then what the step means for
/// each. Step by step, pixel after pixel waited on its division and on the
/// branches that hang on it, which the data decide.
#[allow(clippy::too_many_arguments)]
fn refine_row(
    row: &mut [f32],
    columns: std::ops::Range<usize>,
    y0: usize,
    sums: &BandSums,
    lf: &[i16],
    gx: &[i16],
    w: usize,
    side: usize,
    n: f64,
    isa: Isa,
    params: &RefineParams,
    flying: &mut Vec<InFlight>,
) -> usize {
    let r = side / 2;
    // Divisions are slow: one per step, not three.
    let inv_n = 1.0 / n;
    flying.clear();
    flying.extend(
        row.iter()
            .enumerate()
            .take(columns.end)
            .skip(columns.start)
            .filter(|(_, d0)| !d0.is_nan())
            .map(|(x, &d0)| InFlight {
                x,
                d0,
                d: d0 as f64,
                sl: sums.window(x - r, side)[L],
                state: State::Moving,
                at: usize::MAX,
                dots: [0.0; 2],
                num: 0.0,
                var_g: 0.0,
                delta: 0.0,
            }),
    );
    for _ in 0..params.iterations {
        let mut moving = 0;
        for p in flying.iter_mut().filter(|p| p.state == State::Moving) {
            // The window's right samples start at c + t (c integer).
            let xs = p.x as f64 - p.d - r as f64;
            // xs >= 0 here, so truncation is the floor (and needs no libm call).
            if xs < 0.0 || xs as usize + side + 1 >= w {
                p.state = State::Failed;
                continue;
            }
            moving += 1;
            let c = xs as usize;
            let t = xs - c as f64;
            let u = 1.0 - t;
            // The same c as the last step needs no new products, and a
            // neighbouring one only one.
            if p.at != c {
                let dots = |c: usize| {
                    let at = DotWindow {
                        x_left: p.x - r,
                        c,
                        y0,
                        side,
                    };
                    isa.window_dots(lf, gx, w, at)
                };
                p.dots = if p.at != usize::MAX && c == p.at + 1 {
                    [p.dots[1], dots(c + 1)[0] as f64]
                } else if c + 1 == p.at {
                    [dots(c)[0] as f64, p.dots[0]]
                } else {
                    dots(c).map(|v| v as f64)
                };
                p.at = c;
            }
            // The window sums at c and c + 1, mixed by this step's fraction.
            let (k0, k1, gl) = (sums.window(c, side), sums.window(c + 1, side), p.dots);
            let s_r = p.sl - u * k0[R] - t * k1[R];
            let s_g = u * k0[G] + t * k1[G];
            let s_gg = u * u * k0[GG] + 2.0 * t * u * k0[G_G1] + t * t * k1[GG];
            let s_gr = u * gl[0] + t * gl[1]
                - (u * u * k0[G_R] + t * u * (k0[G_R1] + k0[G1_R]) + t * t * k1[G_R]);
            // The sums with g are of twice the gradient: var_g is four
            // times the gradient's variance, s_gr and s_g twice theirs.
            p.var_g = s_gg - s_g * s_g * inv_n;
            p.num = s_gr - s_g * s_r * inv_n;
        }
        if moving == 0 {
            break;
        }
        // Every pixel's step (those no longer moving are not read).
        // res(d + delta) ~ res + g delta (I_R is sampled at x - d - delta).
        for p in flying.iter_mut() {
            p.delta = -2.0 * p.num / p.var_g;
        }
        for p in flying.iter_mut().filter(|p| p.state == State::Moving) {
            if p.var_g < 4e-3 * n {
                p.state = State::Failed; // no horizontal texture to align
                continue;
            }
            p.d += p.delta;
            if (p.d - p.d0 as f64).abs() > params.max_change_px as f64 {
                p.state = State::Failed;
            } else if p.delta.abs() < 0.005 {
                p.state = State::Converged;
            }
        }
    }
    let mut refined = 0;
    for p in flying.iter().filter(|p| p.state != State::Failed) {
        row[p.x] = p.d as f32;
        refined += 1;
    }
    refined
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth random texture sampled at continuous positions.
    fn texture(x: f64, y: f64) -> f64 {
        let mut v = 0.0;
        for (i, f) in [0.31, 0.53, 0.97, 1.37].iter().enumerate() {
            let phase = i as f64 * 1.7;
            v += (f * x + phase).sin() * (0.8 * f * y + 0.5 * phase).cos() / (1.0 + i as f64);
        }
        128.0 + 60.0 * v
    }

    /// Each quantity's window sums over a band; quantity q holds q times
    /// the first's values, so a mix-up of quantities shows.
    #[test]
    fn band_windows() {
        let band = |y0: usize, rows: usize| {
            let cols: Vec<i32> = (0..5)
                .map(|x| (y0..y0 + rows).map(|y| (x + 10 * y) as i32).sum())
                .collect();
            BandSums::from_columns(&std::array::from_fn(|q| {
                cols.iter().map(|&c| c * q as i32).collect()
            }))
        };
        let t = band(2, 2);
        // Columns 1..3, rows 2..4: (21 + 22) + (31 + 32).
        assert_eq!(t.window(1, 2), std::array::from_fn(|q| 106.0 * q as f64));
        let whole = band(0, 4);
        let total = (0..4)
            .flat_map(|y| (0..4).map(move |x| (x + 10 * y) as f64))
            .sum::<f64>();
        assert_eq!(
            whole.window(0, 4),
            std::array::from_fn(|q| total * q as f64)
        );
    }

    /// A band slid down row by row holds the sums of a band built afresh,
    /// each term as its definition has it (the products with the next
    /// column 0 in the last), and its window sums are each quantity's
    /// prefix sums.
    #[test]
    fn a_sliding_band_holds_each_quantitys_sums() {
        let (w, h, rows) = (13usize, 9usize, 4usize);
        let image = |seed: i32| -> Vec<i16> {
            (0..w * h)
                .map(|i| ((i as i32 * 37 + seed * 11) % 255 - seed) as i16)
                .collect()
        };
        let (l, r, g) = (image(1), image(2), image(100));
        let images = [&l[..], &r[..], &g[..]];
        let mut band = ColumnSums::band(images, w, 0, rows);
        for y0 in 1..=h - rows {
            band.add_row(y0 + rows - 1, 1);
            band.add_row(y0 - 1, -1);
            let fresh = ColumnSums::band(images, w, y0, rows);
            assert_eq!(band.cols, fresh.cols, "band from row {y0}");
            let at = |img: &[i16], x: usize, y: usize| {
                if x < w { img[y * w + x] as i32 } else { 0 }
            };
            for x in 0..w {
                let by_definition: [i32; 8] = (y0..y0 + rows).fold([0; 8], |mut s, y| {
                    let (lv, rv, gv) = (at(&l, x, y), at(&r, x, y), at(&g, x, y));
                    let (r1, g1) = (at(&r, x + 1, y), at(&g, x + 1, y));
                    let terms = [lv, rv, gv, gv * gv, gv * g1, gv * rv, gv * r1, g1 * rv];
                    for (a, t) in s.iter_mut().zip(terms) {
                        *a += t;
                    }
                    s
                });
                for (q, &expect) in by_definition.iter().enumerate() {
                    assert_eq!(band.cols[q][x], expect, "quantity {q}, column {x}");
                }
            }
            let mut table = BandSums(Vec::new());
            band.windows(Isa::detect(), &mut table);
            assert_eq!(table.0, BandSums::from_columns(&band.cols).0);
        }
    }

    #[test]
    fn recovers_a_subpixel_shift_from_a_rounded_start() {
        let (w, h) = (80, 30);
        for true_d in [5.0, 7.3, 10.75] {
            let left = GreyImage {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|i| texture((i % w) as f64, (i / w) as f64).round() as u8)
                    .collect(),
            };
            let right = GreyImage {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|i| texture((i % w) as f64 + true_d, (i / w) as f64).round() as u8)
                    .collect(),
            };
            let mut d = vec![f32::NAN; w * h];
            for y in 5..h - 5 {
                for x in 20..w - 5 {
                    d[y * w + x] = true_d.round() as f32;
                }
            }
            let p = RefineParams {
                half_window: 3,
                iterations: 6,
                max_change_px: 1.0,
            };
            let n = refine_disparity(&left, &right, &mut d, &p);
            assert!(n > 1000);
            let errors: Vec<f64> = d
                .iter()
                .filter(|v| !v.is_nan())
                .map(|&v| (v as f64 - true_d).abs())
                .collect();
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            assert!(mean < 0.03, "true {true_d}: mean error {mean}");
        }
    }

    #[test]
    fn flat_windows_keep_their_disparity() {
        let flat = GreyImage {
            width: 20,
            height: 10,
            data: vec![90; 200],
        };
        let mut d = vec![3.0f32; 200];
        let p = RefineParams {
            half_window: 2,
            iterations: 4,
            max_change_px: 1.0,
        };
        assert_eq!(refine_disparity(&flat, &flat, &mut d, &p), 0);
        assert!(d.iter().all(|&v| v == 3.0));
    }

    /// Each pixel's steps as the module describes them, every window sum
    /// taken directly from the images: the same arithmetic on the same
    /// (exact) sums, so the same bits, whatever the band, the prefix table
    /// and the reuse of window products do to get them.
    fn refined_pixel_by_pixel(
        left: &GreyImage,
        right: &GreyImage,
        disparity: &[f32],
        params: &RefineParams,
    ) -> Vec<f32> {
        let (w, h) = (left.width, left.height);
        let r = params.half_window;
        let side = 2 * r + 1;
        let n = (side * side) as f64;
        let l = |x: usize, y: usize| left.data[y * w + x] as i64;
        let rt = |x: usize, y: usize| right.data[y * w + x] as i64;
        let g = |x: usize, y: usize| {
            if x == 0 || x + 1 >= w {
                0
            } else {
                rt(x + 1, y) - rt(x - 1, y)
            }
        };
        let sum = |y: usize, f: &dyn Fn(usize, usize) -> i64| -> f64 {
            let mut total = 0;
            for yy in y - r..=y + r {
                for i in 0..side {
                    total += f(i, yy);
                }
            }
            total as f64
        };
        let mut out = disparity.to_vec();
        for y in r..h - r {
            for x in r..w - r {
                let d0 = disparity[y * w + x];
                if d0.is_nan() {
                    continue;
                }
                let sl = sum(y, &|i, yy| l(x - r + i, yy));
                let mut d = d0 as f64;
                let mut ok = true;
                for _ in 0..params.iterations {
                    let xs = x as f64 - d - r as f64;
                    if xs < 0.0 || xs.floor() as usize + side + 1 >= w {
                        ok = false;
                        break;
                    }
                    let c = xs.floor() as usize;
                    let t = xs - c as f64;
                    let u = 1.0 - t;
                    let at = |k: usize, f: &dyn Fn(usize, usize) -> i64| {
                        sum(y, &|i, yy| f(c + k + i, yy))
                    };
                    let (r0, r1) = (at(0, &rt), at(1, &rt));
                    let (g0, g1) = (at(0, &g), at(1, &g));
                    let gg = |x: usize, yy: usize| g(x, yy) * g(x, yy);
                    let gr = |x: usize, yy: usize| g(x, yy) * rt(x, yy);
                    let (gg0, gg1, gr0, gr1) = (at(0, &gg), at(1, &gg), at(0, &gr), at(1, &gr));
                    let g_g1 = at(0, &|x, yy| g(x, yy) * g(x + 1, yy));
                    let g_r1 = at(0, &|x, yy| g(x, yy) * rt(x + 1, yy));
                    let g1_r = at(0, &|x, yy| g(x + 1, yy) * rt(x, yy));
                    let dot = |k: usize| sum(y, &|i, yy| l(x - r + i, yy) * g(c + k + i, yy));
                    let s_r = sl - u * r0 - t * r1;
                    let s_g = u * g0 + t * g1;
                    let s_gg = u * u * gg0 + 2.0 * t * u * g_g1 + t * t * gg1;
                    let s_gr = u * dot(0) + t * dot(1)
                        - (u * u * gr0 + t * u * (g_r1 + g1_r) + t * t * gr1);
                    let var_g = s_gg - s_g * s_g * (1.0 / n);
                    let delta = -2.0 * (s_gr - s_g * s_r * (1.0 / n)) / var_g;
                    if var_g < 4e-3 * n {
                        ok = false;
                        break;
                    }
                    d += delta;
                    if (d - d0 as f64).abs() > params.max_change_px as f64 {
                        ok = false;
                        break;
                    }
                    if delta.abs() < 0.005 {
                        break;
                    }
                }
                if ok {
                    out[y * w + x] = d as f32;
                }
            }
        }
        out
    }

    /// The refinement gives every pixel the bits of its steps taken one
    /// pixel at a time, on a textured pair with disparities scattered over
    /// the range (windows that start at column 0, that move by one column
    /// or more between steps, or leave the image) and gaps.
    #[test]
    fn every_pixel_gets_the_bits_of_its_own_steps() {
        let (w, h) = (64, 22);
        let image = |shift: f64| GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| texture((i % w) as f64 + shift, (i / w) as f64).round() as u8)
                .collect(),
        };
        let (left, right) = (image(0.0), image(4.4));
        let mut seed = 5u64;
        let disparity: Vec<f32> = (0..w * h)
            .map(|_| {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                match (seed >> 33) % 9 {
                    0 => f32::NAN,
                    k => (seed >> 40) as f32 / (1u64 << 24) as f32 * 8.0 + k as f32 * 0.1,
                }
            })
            .collect();
        for (half_window, iterations) in [(2, 1), (3, 4), (4, 2)] {
            let params = RefineParams {
                half_window,
                iterations,
                max_change_px: 1.5,
            };
            let expect = refined_pixel_by_pixel(&left, &right, &disparity, &params);
            let mut got = disparity.clone();
            let refined = refine_disparity(&left, &right, &mut got, &params);
            let moved = got
                .iter()
                .zip(&disparity)
                .filter(|(a, b)| a.to_bits() != b.to_bits());
            assert!(
                moved.count() > 100,
                "window {half_window}: too few refined to test"
            );
            assert!(refined > 100);
            let bits = |m: &[f32]| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&got),
                bits(&expect),
                "window {half_window}, {iterations} steps"
            );
        }
    }
}
