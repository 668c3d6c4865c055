//! Sub-pixel refinement of disparities on slanted windows: around each valid
//! disparity, the shift that best aligns a window of the left image with the
//! right image when the window is warped by the surface's own shape, a
//! quadratic fitted to the (filled, smoothed) map over the window, as
//! PatchMatch stereo's slanted support windows do with planes (Bleyer,
//! Rhemann & Rother, BMVC 2011). A square window assumes a fronto-parallel
//! surface: on a slanted one (the dome's flanks, seen obliquely) the left
//! window's columns meet the right image at disparities that differ by the
//! slope times their offset, and the best single shift is biased where
//! texture is weak and uneven across the window; the quadratic also follows
//! the dome's bends, so weak texture can take large windows.
//!
//! A window grows (from `half_window`, by half again, up to
//! `max_half_window`, to which a last step under half a growth goes at
//! once) while its gradients predict the shift worse than
//! `target_px`, and only while the larger window fits no worse: its residual
//! per pixel after the best shift must not exceed the smaller window's (or
//! the pair's noise, whichever is larger). A window reaching across a depth
//! edge or an occlusion, where the warp is wrong, fits worse and is not
//! taken. Zero-mean sum of squared differences, Gauss-Newton on the shift,
//! the right image linearly interpolated along its rows. Written here: no
//! crate refines disparities.

use super::pair::GreyImage;
use super::simd::{Isa, kernels};
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

/// Map samples further than this from a window's first fitted shape are
/// left out of its refit (a depth edge, a filled hole), px.
const OFF_SHAPE_PX: f64 = 0.5;

/// The map samples a window's shape is fitted to: a grid of this many
/// columns and rows spanning the window.
const SHAPE_GRID: isize = 7;

/// The most samples a shape's refit leaves out by updating the fit through
/// all of them; more are refitted from scratch.
const MAX_LEFT_OUT: usize = 12;

/// A step this small ends the iterations, px.
const STEP_CONVERGED_PX: f32 = 1e-3;

/// How a window is warped to follow the surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WindowShape {
    /// Not at all: a fronto-parallel square (classic refinement).
    Square,
    /// By the plane fitted to the map over the window.
    Plane,
    /// By the quadratic fitted to the map over the window (slant and bend).
    Quadratic,
}

/// How the slanted refinement runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlantedParams {
    /// Smallest window half-size, px (side 2 * half + 1).
    pub half_window: usize,
    /// Largest window half-size, px: a window grows (by half again, from
    /// `half_window`) until its gradients predict the shift to within
    /// `target_px`, or reaches this.
    pub max_half_window: usize,
    /// The shift's predicted standard deviation a window must reach, px:
    /// sqrt(2) sigma / sqrt(sum of squared gradients), sigma the images'
    /// noise (at least 8-bit quantisation's).
    pub target_px: f32,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Largest change from the input disparity, px; beyond it the input is
    /// kept.
    pub max_change_px: f32,
    /// How windows follow the surface.
    pub shape: WindowShape,
}

impl Default for SlantedParams {
    fn default() -> Self {
        SlantedParams {
            half_window: 4,
            max_half_window: 4,
            target_px: 0.0,
            iterations: 1,
            max_change_px: 1.0,
            shape: WindowShape::Quadratic,
        }
    }
}

/// `disparity` (left rectified image, px, NaN = invalid, row-major `w x h`)
/// refined on windows slanted by its own gradient; returns the refined map
/// and how many values changed. Values whose window leaves either image,
/// whose right window has no gradient, or that would move by more than
/// `max_change_px` keep their input value.
pub fn refine_slanted(
    left: &GreyImage,
    right: &GreyImage,
    disparity: &[f32],
    p: &SlantedParams,
) -> (Vec<f32>, usize) {
    let (w, h) = (left.width, left.height);
    let map = MapView {
        data: disparity,
        width: w,
        height: h,
    };
    // Noise per image, from the pair's own residual at these disparities
    // (blind to texture, unlike a one-image estimate; that one where too few
    // pixels match), at least 8-bit quantisation's (1 / sqrt(12)).
    let sigma = super::pair_noise_dn(left, right, disparity)
        .unwrap_or_else(|| super::noise_sigma(left).max(super::noise_sigma(right)))
        .max(12f64.recip().sqrt()) as f32;
    let pair = Pair::new(left, right);
    let halves = window_halves(p);
    let fits: Vec<Option<ShapeFit>> = halves
        .iter()
        .map(|&hw| match p.shape {
            WindowShape::Square => None,
            WindowShape::Plane => Some(ShapeFit::new(hw as isize, false, w)),
            WindowShape::Quadratic => Some(ShapeFit::new(hw as isize, true, w)),
        })
        .collect();
    // Residual per pixel no larger window need beat: the pair's noise, two
    // images' worth.
    let noise_floor = 2.0 * sigma * sigma;
    let refined: Vec<(f32, bool)> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let d0 = disparity[i];
            if d0.is_nan() {
                return (d0, false);
            }
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let mut window = Window {
                x,
                y,
                shape: [0.0; 5],
            };
            // The smallest window whose gradients pin the shift well enough,
            // and its shape.
            let mut half = None;
            let mut chosen = window.shape;
            let mut first_step = None;
            let mut residual_before = 0.0f32;
            for (n, &hw) in halves.iter().enumerate() {
                if let Some(fit) = &fits[n] {
                    match fit.shape_at(&map, x, y) {
                        Some(shape) => window.shape = shape,
                        // Too little map around to grow on (the smallest
                        // window is refined unwarped).
                        None if n > 0 => break,
                        None => {}
                    }
                }
                let Some(fit) = window.step(&pair, d0, hw) else {
                    break;
                };
                if n > 0 && fit.residual > residual_before.max(noise_floor) {
                    break;
                }
                residual_before = fit.residual;
                half = Some(hw);
                chosen = window.shape;
                let pinned =
                    std::f32::consts::SQRT_2 * sigma / fit.energy.max(1e-6).sqrt() <= p.target_px;
                first_step = Some(fit);
                if pinned {
                    break;
                }
            }
            window.shape = chosen;
            let Some(half) = half else {
                return (d0, false);
            };
            let mut d = d0;
            for k in 0..p.iterations {
                // The first step is the chosen window's, at d0, taken above.
                let fit = if k == 0 {
                    first_step.take()
                } else {
                    window.step(&pair, d, half)
                };
                let Some(Fit {
                    step, energy, n, ..
                }) = fit
                else {
                    return (d0, false);
                };
                if energy < 0.1 * n {
                    // Under about a third of a grey level of gradient per
                    // pixel (quantisation's own): the window does not pin a
                    // shift.
                    return (d0, false);
                }
                d += step.clamp(-0.5, 0.5);
                if step.abs() < STEP_CONVERGED_PX {
                    break;
                }
            }
            if (d - d0).abs() > p.max_change_px {
                (d0, false)
            } else {
                (d, true)
            }
        })
        .collect();
    let changed = refined.iter().filter(|(_, c)| *c).count();
    (refined.into_iter().map(|(d, _)| d).collect(), changed)
}

/// The window half-sizes tried, smallest first: from `half_window`, each
/// half as large again, up to `max_half_window`.
fn window_halves(p: &SlantedParams) -> Vec<usize> {
    let mut halves = vec![p.half_window];
    while let Some(&last) = halves.last() {
        let largest = p.max_half_window.min(15);
        let next = (last + last.div_ceil(2)).min(largest);
        if next <= last {
            break;
        }
        // A last step under half a growth is not worth a size of its own:
        // go to the largest at once.
        let growth = next - last;
        if largest - next < growth.div_ceil(2) {
            halves.push(largest);
            break;
        }
        halves.push(next);
    }
    halves
}

/// A window around (x, y), warped by the map's local shape: the disparity
/// at offset (i, j) px differs from the centre's by
/// `gx i + gy j + gxx i^2 + gxy i j + gyy j^2` (`shape`, px per px^n).
struct Window {
    x: isize,
    y: isize,
    shape: [f32; 5],
}

/// Fits the map's local shape over windows of one size, as
/// `Window::shape`: the least-squares quadratic (or plane) through the map's
/// valid samples on a `SHAPE_GRID`-square grid spanning the window, refitted
/// once without the samples more than `OFF_SHAPE_PX` off the first fit.
pub(crate) struct ShapeFit {
    /// The samples' offsets from the window's centre, px.
    offsets: Vec<(isize, isize)>,
    /// The same in the row-major map the fit was made for.
    flat_offsets: Vec<isize>,
    /// Each sample's fitted terms (1, u, v, u^2, u v, v^2; u, v in
    /// half-windows; the bend's zero for a plane).
    terms: Vec<SVector<f64, 6>>,
    /// The same by term: `columns[c][k]` is `terms[k][c]`, so a fit is
    /// evaluated at every sample in loops that vectorise.
    columns: [[f64; (SHAPE_GRID * SHAPE_GRID) as usize]; 6],
    /// The fit when every sample is valid (the common case, and the
    /// costly part: this runs for every pixel and window size): the
    /// coefficients are `solve * samples`.
    solve: Option<SMatrix<f64, 6, { (SHAPE_GRID * SHAPE_GRID) as usize }>>,
    /// With `solve`: the hat matrix `terms[k] . solve[:, l]` (row-major),
    /// how sample l's value moves the fit at sample k; a refit without a
    /// few samples is taken from it (see [`ShapeFit::leave_out`]).
    hat: Vec<f64>,
    /// The normal equations' sum over every sample, unpinned.
    normal_all: SMatrix<f64, 6, 6>,
    quadratic: bool,
    /// Half-window, px.
    scale: f64,
    /// The instruction set the fits run with.
    isa: Isa,
}

impl ShapeFit {
    /// The fit over windows of half-size `half` px in a map `map_width` px
    /// wide.
    fn new(half: isize, quadratic: bool, map_width: usize) -> ShapeFit {
        let grid = |k: isize| {
            ((2 * half * k - half * (SHAPE_GRID - 1)) as f64 / (SHAPE_GRID - 1) as f64).round()
                as isize
        };
        let offsets: Vec<(isize, isize)> = (0..SHAPE_GRID)
            .flat_map(|a| (0..SHAPE_GRID).map(move |b| (grid(b), grid(a))))
            .collect();
        let scale = half.max(1) as f64;
        let bend = if quadratic { 1.0 } else { 0.0 };
        let terms: Vec<SVector<f64, 6>> = offsets
            .iter()
            .map(|&(i, j)| {
                let (u, v) = (i as f64 / scale, j as f64 / scale);
                SVector::<f64, 6>::from([1.0, u, v, bend * u * u, bend * u * v, bend * v * v])
            })
            .collect();
        let normal_all = terms
            .iter()
            .fold(SMatrix::<f64, 6, 6>::zeros(), |a, t| a + t * t.transpose());
        let flat_offsets = offsets
            .iter()
            .map(|&(i, j)| i + j * map_width as isize)
            .collect();
        let columns = std::array::from_fn(|c| std::array::from_fn(|k| terms[k][c]));
        let mut fit = ShapeFit {
            offsets,
            flat_offsets,
            terms,
            columns,
            solve: None,
            hat: Vec::new(),
            normal_all,
            quadratic,
            scale,
            isa: Isa::detect(),
        };
        let all = vec![true; fit.terms.len()];
        fit.solve = fit.normal_matrix(&all).try_inverse().map(|inverse| {
            SMatrix::<f64, 6, { (SHAPE_GRID * SHAPE_GRID) as usize }>::from_fn(|r, k| {
                (inverse * fit.terms[k])[r]
            })
        });
        if let Some(solve) = &fit.solve {
            fit.hat = (0..fit.terms.len())
                .flat_map(|k| {
                    let t = fit.terms[k];
                    solve.column_iter().map(move |column| t.dot(&column))
                })
                .collect();
        }
        fit
    }

    /// The least-squares coefficients through the samples `used`: on the
    /// whole grid, from the fit through every sample with the few left out
    /// taken away by [`ShapeFit::leave_out`] (most windows: a map's holes
    /// and the samples off its shape are few), else from scratch.
    #[inline(always)]
    fn fit_without(&self, samples: &[f64], used: &[bool]) -> Option<SVector<f64, 6>> {
        if let Some(solve) = &self.solve {
            let mut excluded = [0usize; (SHAPE_GRID * SHAPE_GRID) as usize];
            let mut left_out = 0;
            for k in (0..used.len()).filter(|&k| !used[k]) {
                if left_out == MAX_LEFT_OUT {
                    return self.solve_over(samples, used);
                }
                excluded[left_out] = k;
                left_out += 1;
            }
            let all = solve
                * SVector::<f64, { (SHAPE_GRID * SHAPE_GRID) as usize }>::from_column_slice(
                    samples,
                );
            if left_out == 0 {
                return Some(all);
            }
            if let Some(c) = self.leave_out(&all, samples, &excluded[..left_out]) {
                return Some(c);
            }
        }
        self.solve_over(samples, used)
    }

    /// The fit through every sample but those `excluded` (a few: at most
    /// [`MAX_LEFT_OUT`]), from the fit `all` through every sample, by the
    /// leave-out (Sherman-Morrison-Woodbury) update: with H the hat matrix
    /// and r the excluded samples' residuals, the refit is
    /// `all - solve[:, E] (I - H[E, E])^-1 r[E]`. `None` without `solve`,
    /// or where the samples left do not fix the shape.
    #[inline(always)]
    fn leave_out(
        &self,
        all: &SVector<f64, 6>,
        samples: &[f64],
        excluded: &[usize],
    ) -> Option<SVector<f64, 6>> {
        let solve = self.solve.as_ref()?;
        let k = excluded.len();
        if k > MAX_LEFT_OUT {
            return None;
        }
        let n = self.terms.len();
        let mut m = [0.0f64; MAX_LEFT_OUT * MAX_LEFT_OUT];
        let mut z = [0.0f64; MAX_LEFT_OUT];
        for (a, &ea) in excluded.iter().enumerate() {
            for (b, &eb) in excluded.iter().enumerate() {
                m[a * k + b] = f64::from(a == b) - self.hat[ea * n + eb];
            }
            z[a] = samples[ea] - self.terms[ea].dot(all);
        }
        solve_spd_in_place(&mut m[..k * k], &mut z[..k])?;
        let mut c = *all;
        for (a, &ea) in excluded.iter().enumerate() {
            c -= solve.column(ea) * z[a];
        }
        Some(c)
    }

    /// The normal equations' matrix over the samples `used`.
    #[inline(always)]
    fn normal_matrix(&self, used: &[bool]) -> SMatrix<f64, 6, 6> {
        let outer = |keep: bool| {
            self.terms
                .iter()
                .zip(used)
                .filter(move |(_, u)| **u == keep)
                .map(|(t, _)| t * t.transpose())
        };
        let left_out = used.iter().filter(|u| !**u).count();
        // Most samples used (the common case: a few off the shape): every
        // sample's sum less the few left out.
        let mut a = if left_out * 2 < used.len() {
            outer(false).fold(self.normal_all, |a, m| a - m)
        } else {
            outer(true).fold(SMatrix::zeros(), |a, m| a + m)
        };
        if !self.quadratic {
            // The bend's terms are zero: pin them.
            for k in 3..6 {
                a[(k, k)] = 1.0;
            }
        }
        a
    }

    /// The least-squares coefficients through the samples `used`.
    #[inline(always)]
    fn solve_over(&self, samples: &[f64], used: &[bool]) -> Option<SVector<f64, 6>> {
        let mut b = SVector::<f64, 6>::zeros();
        for ((t, d), _) in self
            .terms
            .iter()
            .zip(samples)
            .zip(used)
            .filter(|(_, u)| **u)
        {
            b += t * *d;
        }
        self.normal_matrix(used).cholesky().map(|c| c.solve(&b))
    }

    /// The fit `coefficients` at every sample: `terms[k].dot(coefficients)`
    /// for each k, summed in the order nalgebra's `dot` sums a 6-vector
    /// (from zero, term by term), so the same bits, but for all samples at
    /// once.
    #[inline(always)]
    fn evaluate(
        &self,
        coefficients: &SVector<f64, 6>,
    ) -> [f64; (SHAPE_GRID * SHAPE_GRID) as usize] {
        let mut fitted = [0.0f64; (SHAPE_GRID * SHAPE_GRID) as usize];
        for (column, &coefficient) in self.columns.iter().zip(coefficients.iter()) {
            for (f, &t) in fitted.iter_mut().zip(column) {
                *f += t * coefficient;
            }
        }
        fitted
    }

    /// The map's shape around (x, y); `None` with under half the samples
    /// valid. Compiled for AVX2 too (the fits are f64 arithmetic, twice
    /// as wide there), with the same bits.
    fn shape_at(&self, map: &MapView, x: isize, y: isize) -> Option<[f32; 5]> {
        self.isa.shape_at_kernel(self, map, x, y)
    }

    /// [`ShapeFit::shape_at`]'s body.
    #[inline(always)]
    fn shape_at_inline(&self, map: &MapView, x: isize, y: isize) -> Option<[f32; 5]> {
        let mut samples = [0.0f64; (SHAPE_GRID * SHAPE_GRID) as usize];
        let mut valid = [false; (SHAPE_GRID * SHAPE_GRID) as usize];
        let reach = self.scale as isize;
        if map.holds_square(x, y, reach) {
            // The common case: every sample inside the map, read directly.
            let centre = x as usize + y as usize * map.width;
            for (k, &offset) in self.flat_offsets.iter().enumerate() {
                let d = map.data[centre.wrapping_add_signed(offset)];
                (samples[k], valid[k]) = (d as f64, !d.is_nan());
            }
        } else {
            for (k, &(i, j)) in self.offsets.iter().enumerate() {
                if let Some(d) = map.at(x + i, y + j) {
                    (samples[k], valid[k]) = (d as f64, true);
                }
            }
        }
        let count = valid.iter().filter(|v| **v).count();
        if count * 2 < samples.len() {
            return None;
        }
        // A hole's sample is left out of the fit, and holds the valid ones'
        // mean meanwhile: any value gives the same fit (see
        // `fit_without`), a near one keeps the update well conditioned.
        if count < samples.len() {
            let mean = (0..samples.len())
                .filter(|&k| valid[k])
                .map(|k| samples[k])
                .sum::<f64>()
                / count as f64;
            for k in (0..samples.len()).filter(|&k| !valid[k]) {
                samples[k] = mean;
            }
        }
        let first = self.fit_without(&samples, &valid)?;
        let fitted = self.evaluate(&first);
        let inliers: [bool; (SHAPE_GRID * SHAPE_GRID) as usize] =
            std::array::from_fn(|k| valid[k] && (samples[k] - fitted[k]).abs() <= OFF_SHAPE_PX);
        let c = if inliers == valid {
            first
        } else {
            self.fit_without(&samples, &inliers).unwrap_or(first)
        };
        let (s1, s2) = (self.scale, self.scale * self.scale);
        Some([
            (c[1] / s1) as f32,
            (c[2] / s1) as f32,
            (c[3] / s2) as f32,
            (c[4] / s2) as f32,
            (c[5] / s2) as f32,
        ])
    }
}

kernels! {
    /// [`ShapeFit::shape_at`], for the baseline target and for AVX2.
    fn shape_at_kernel(fit: &ShapeFit, map: &MapView, x: isize, y: isize) -> Option<[f32; 5]> {
        fit.shape_at_inline(map, x, y)
    }
}

/// Solves `m x = z` in place (`z` becomes x) for a symmetric positive
/// definite `m` (row-major, `z.len()` square), by Cholesky; `None` where `m`
/// is not positive definite (to rounding).
#[inline(always)]
fn solve_spd_in_place(m: &mut [f64], z: &mut [f64]) -> Option<()> {
    let k = z.len();
    // Lower factor L (m = L L^T) over m's lower triangle.
    for j in 0..k {
        let mut diagonal = m[j * k + j];
        for p in 0..j {
            diagonal -= m[j * k + p] * m[j * k + p];
        }
        if diagonal <= 1e-12 {
            return None;
        }
        let root = diagonal.sqrt();
        m[j * k + j] = root;
        for i in j + 1..k {
            let mut v = m[i * k + j];
            for p in 0..j {
                v -= m[i * k + p] * m[j * k + p];
            }
            m[i * k + j] = v / root;
        }
    }
    for i in 0..k {
        for p in 0..i {
            z[i] -= m[i * k + p] * z[p];
        }
        z[i] /= m[i * k + i];
    }
    for i in (0..k).rev() {
        for p in i + 1..k {
            z[i] -= m[p * k + i] * z[p];
        }
        z[i] /= m[i * k + i];
    }
    Some(())
}

/// A disparity map as the shape fits read it: row-major, NaN = invalid.
pub(crate) struct MapView<'a> {
    data: &'a [f32],
    width: usize,
    height: usize,
}

impl MapView<'_> {
    /// The valid disparity at (x, y), px.
    #[inline(always)]
    fn at(&self, x: isize, y: isize) -> Option<f32> {
        if x < 0 || y < 0 || x >= self.width as isize || y >= self.height as isize {
            return None;
        }
        let v = self.data[x as usize + y as usize * self.width];
        (!v.is_nan()).then_some(v)
    }

    /// Whether every pixel within `reach` of (x, y) along both axes lies in
    /// the map.
    #[inline(always)]
    fn holds_square(&self, x: isize, y: isize, reach: isize) -> bool {
        x >= reach
            && y >= reach
            && x + reach < self.width as isize
            && y + reach < self.height as isize
    }
}

/// The rectified pair as the windows read it: grey levels as floats,
/// row-major.
struct Pair {
    width: usize,
    height: usize,
    left: Vec<f32>,
    right: Vec<f32>,
    /// The instruction set the window sums run with.
    isa: Isa,
}

impl Pair {
    fn new(left: &GreyImage, right: &GreyImage) -> Pair {
        let floats = |img: &GreyImage| img.data.iter().map(|&v| v as f32).collect::<Vec<f32>>();
        Pair {
            width: right.width,
            height: right.height,
            left: floats(left),
            right: floats(right),
            isa: Isa::detect(),
        }
    }
}

/// One Gauss-Newton step of a window at a disparity.
struct Fit {
    /// The step to the best shift, px.
    step: f32,
    /// The zero-mean right gradients' energy, DN^2 per px^2.
    energy: f32,
    /// The window's pixel count.
    n: f32,
    /// The zero-mean residual per pixel left after the step (linearised),
    /// DN^2.
    residual: f32,
}

impl Window {
    /// One Gauss-Newton step of the disparity `d` on the window of
    /// half-size `half`; `None` where the window leaves either image.
    fn step(&self, pair: &Pair, d: f32, half: usize) -> Option<Fit> {
        let (w, h) = (pair.width, pair.height);
        let half = half as isize;
        let (x, y) = (self.x, self.y);
        if x - half < 0 || y - half < 0 || x + half >= w as isize || y + half >= h as isize {
            return None;
        }
        let [s_lr, s_lrlr, s_g, s_lrg, s_gg] =
            pair.isa
                .slanted_window_sums(&pair.left, &pair.right, w, x, y, half, d, self.shape)?;
        let side = (2 * half + 1) as f64;
        let n = side * side;
        // Raising d moves the right samples left: r changes by -g per px.
        let num = s_lrg - s_lr * s_g / n;
        let energy = (s_gg - s_g * s_g / n).max(0.0);
        // sum(e^2) less what the step explains: num^2 / energy.
        let rss = (s_lrlr - s_lr * s_lr / n - num * num / energy.max(1e-12)).max(0.0);
        Some(Fit {
            step: (-num / energy.max(1e-12)) as f32,
            energy: energy as f32,
            n: n as f32,
            residual: (rss / n) as f32,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn a_small_positive_definite_system_is_solved_and_a_singular_one_refused() {
        // [4 2; 2 3] x = [2; 1] -> x = [0.5, 0].
        let (mut m, mut z) = ([4.0, 2.0, 2.0, 3.0], [2.0, 1.0]);
        assert!(solve_spd_in_place(&mut m, &mut z).is_some());
        assert!((z[0] - 0.5).abs() < 1e-15 && z[1].abs() < 1e-15, "{z:?}");
        let (mut m, mut z) = ([1.0, 1.0, 1.0, 1.0], [1.0, 1.0]);
        assert!(solve_spd_in_place(&mut m, &mut z).is_none());
    }

    /// The shape fits compiled for AVX2 give the baseline build's bits,
    /// on a bumpy map with holes (so fits through every sample, a few left
    /// out and refits from scratch all occur).
    #[test]
    fn shapes_have_the_same_bits_on_every_instruction_set() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
        let (w, h) = (60usize, 40usize);
        let data: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                if rng.random_range(0.0..1.0) < 0.08 {
                    f32::NAN
                } else {
                    30.0 + 0.2 * x - 0.1 * y + 0.01 * x * y + rng.random_range(-0.3..0.3)
                }
            })
            .collect();
        let map = MapView {
            data: &data,
            width: w,
            height: h,
        };
        for half in [4, 10] {
            let fit = ShapeFit::new(half, true, w);
            let mut shapes = 0;
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let base = Isa::Scalar.shape_at_kernel(&fit, &map, x, y);
                    let best = Isa::detect().shape_at_kernel(&fit, &map, x, y);
                    let bits = |s: Option<[f32; 5]>| s.map(|v| v.map(f32::to_bits));
                    assert_eq!(bits(base), bits(best), "({x}, {y}), half {half}");
                    shapes += usize::from(base.is_some());
                }
            }
            assert!(shapes > w * h / 2, "{shapes} shapes");
        }
    }

    /// The fit evaluated at every sample at once gives the bits of each
    /// sample's own dot product (the inliers, and so every refined value,
    /// depend on them): coefficients of every size and sign, some zero.
    #[test]
    fn a_fit_evaluated_at_every_sample_has_the_dot_products_bits() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        for quadratic in [false, true] {
            for half in [1, 4, 10, 15] {
                let fit = ShapeFit::new(half, quadratic, 100);
                for round in 0..200 {
                    let c = SVector::<f64, 6>::from_fn(|r, _| {
                        if round % 7 == r {
                            0.0
                        } else {
                            rng.random_range(-1.0..1.0) * 10f64.powi(rng.random_range(-6..4))
                        }
                    });
                    let fitted = fit.evaluate(&c);
                    for (k, t) in fit.terms.iter().enumerate() {
                        assert_eq!(
                            fitted[k].to_bits(),
                            t.dot(&c).to_bits(),
                            "sample {k} of {c:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn leaving_samples_out_by_update_matches_the_refit_from_scratch() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for quadratic in [false, true] {
            for half in [4, 6, 10] {
                let fit = ShapeFit::new(half, quadratic, 100);
                let n = fit.terms.len();
                for _ in 0..50 {
                    let samples: Vec<f64> = (0..n).map(|_| rng.random_range(10.0..12.0)).collect();
                    let all = fit.solve.unwrap() * SVector::<f64, 49>::from_column_slice(&samples);
                    let k = rng.random_range(1..=MAX_LEFT_OUT);
                    let mut used = vec![true; n];
                    while used.iter().filter(|u| !**u).count() < k {
                        used[rng.random_range(0..n)] = false;
                    }
                    let excluded: Vec<usize> = (0..n).filter(|&i| !used[i]).collect();
                    let updated = fit.leave_out(&all, &samples, &excluded).unwrap();
                    let scratch = fit.solve_over(&samples, &used).unwrap();
                    assert!(
                        (updated - scratch).amax() < 1e-10,
                        "half {half}, {k} left out: {updated} vs {scratch}"
                    );
                }
                let too_many: Vec<usize> = (0..=MAX_LEFT_OUT).collect();
                assert!(
                    fit.leave_out(&SVector::zeros(), &[0.0; 49], &too_many)
                        .is_none()
                );
            }
        }
    }

    /// A weakly textured surface whose true disparity depends on the column
    /// only, `truth(x)` px (at most `max_d`); the right image is the left one
    /// warped by it, each right pixel seeing the nearest surface point on
    /// its ray (smooth texture, so linear interpolation is close to exact).
    fn pair_of(
        w: usize,
        h: usize,
        truth: impl Fn(f32) -> f32,
        max_d: f32,
    ) -> (GreyImage, GreyImage, Vec<f32>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // Smooth texture: sums of random sinusoids, 12 grey levels of contrast.
        let waves: Vec<(f32, f32, f32, f32)> = (0..12)
            .map(|_| {
                (
                    rng.random_range(0.08..0.5f32),
                    rng.random_range(0.05..0.4f32),
                    rng.random_range(0.0..std::f32::consts::TAU),
                    rng.random_range(1.0..2.5f32),
                )
            })
            .collect();
        let texture = |u: f32, v: f32| {
            128.0
                + waves
                    .iter()
                    .map(|&(a, b, ph, amp)| amp * (a * u + b * v + ph).sin())
                    .sum::<f32>()
        };
        let mut left = vec![0u8; w * h];
        let mut right = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                left[x + y * w] = texture(x as f32, y as f32).round() as u8;
                // Right pixel xr sees the left point xl with xl - d(xl) = xr:
                // the fixed point from the nearest disparity down, so that
                // of two surfaces on the ray the nearer one is seen.
                let mut xl = x as f32 + max_d;
                for _ in 0..100 {
                    xl = x as f32 + truth(xl);
                }
                right[x + y * w] = texture(xl, y as f32).round() as u8;
            }
        }
        let grey = |data| GreyImage {
            width: w,
            height: h,
            data,
        };
        let truth = (0..w * h).map(|i| truth((i % w) as f32)).collect();
        (grey(left), grey(right), truth)
    }

    /// A weakly textured plane slanted along the rows: true disparity
    /// `d0 + slope * x`.
    fn slanted_pair(w: usize, h: usize, d0: f32, slope: f32) -> (GreyImage, GreyImage, Vec<f32>) {
        pair_of(w, h, |x| d0 + slope * x, d0 + slope * w as f32)
    }

    /// Mean absolute error against `truth` (row-major, `w` wide) over the
    /// pixels `margin` px inside the image, and right of x = 60 (where every
    /// right window is inside the right image).
    fn mean_error_inside(v: &[f32], truth: &[f32], w: usize, margin: usize) -> f64 {
        let h = truth.len() / w;
        let (mut sum, mut n) = (0.0, 0);
        for y in margin..h - margin {
            for x in 60..w - margin {
                sum += (v[x + y * w] - truth[x + y * w]).abs() as f64;
                n += 1;
            }
        }
        sum / n as f64
    }

    #[test]
    fn a_slanted_plane_is_refined_without_the_square_windows_bias() {
        let (w, h) = (200, 60);
        let (left, right, truth) = slanted_pair(w, h, 20.0, 0.3);
        // The input: the truth 0.4 px off (a matcher's bias), its slope right.
        let biased: Vec<f32> = truth.iter().map(|d| d + 0.4).collect();
        let mean_error = |v: &[f32]| mean_error_inside(v, &truth, w, 10);
        let (slanted, changed) = refine_slanted(&left, &right, &biased, &SlantedParams::default());
        assert!(changed > w * h / 2, "{changed} refined");
        let square = SlantedParams {
            shape: WindowShape::Square,
            ..SlantedParams::default()
        };
        let (flat, _) = refine_slanted(&left, &right, &biased, &square);
        let (before, on_slant, on_square) =
            (mean_error(&biased), mean_error(&slanted), mean_error(&flat));
        assert!(
            on_slant < 0.08 && on_slant < 0.5 * on_square,
            "mean error: {before:.3} px in, {on_slant:.3} px slanted, {on_square:.3} px square"
        );
    }

    #[test]
    fn windows_grow_on_weak_texture_until_they_pin_the_shift() {
        let (w, h) = (200, 70);
        let (left, right, truth) = slanted_pair(w, h, 20.0, 0.3);
        let biased: Vec<f32> = truth.iter().map(|d| d + 0.4).collect();
        let mean_error = |v: &[f32]| mean_error_inside(v, &truth, w, 16);
        let fixed = SlantedParams::default();
        let growing = SlantedParams {
            max_half_window: 10,
            target_px: 0.02,
            ..fixed
        };
        // Half again each time; a last step under half a growth (9 -> 10,
        // 14 -> 15) goes to the largest at once.
        assert_eq!(window_halves(&growing), vec![4, 6, 10]);
        let widest = SlantedParams {
            max_half_window: 15,
            ..growing
        };
        assert_eq!(window_halves(&widest), vec![4, 6, 9, 15]);
        let (a, _) = refine_slanted(&left, &right, &biased, &fixed);
        let (b, _) = refine_slanted(&left, &right, &biased, &growing);
        let (fixed_error, growing_error) = (mean_error(&a), mean_error(&b));
        assert!(
            growing_error < 0.7 * fixed_error,
            "mean error: fixed window {fixed_error:.4} px, growing {growing_error:.4} px"
        );
    }

    /// Mean absolute error against `truth` over the rows `margin` px inside
    /// the image and the columns `columns`.
    fn mean_error_over(
        v: &[f32],
        truth: &[f32],
        w: usize,
        margin: usize,
        columns: std::ops::Range<usize>,
    ) -> f64 {
        let h = truth.len() / w;
        let (mut sum, mut n) = (0.0, 0);
        for y in margin..h - margin {
            for x in columns.clone() {
                sum += (v[x + y * w] - truth[x + y * w]).abs() as f64;
                n += 1;
            }
        }
        sum / n as f64
    }

    /// Growing windows, on weak texture (from 9 px up to 21 px).
    fn growing() -> SlantedParams {
        SlantedParams {
            max_half_window: 10,
            target_px: 0.02,
            ..SlantedParams::default()
        }
    }

    #[test]
    fn windows_do_not_grow_across_a_depth_edge() {
        // Far surface (20 px) left of column 130, near one (28 px) right of
        // it: left pixels 122-129 are hidden from the right camera.
        let (w, h) = (230, 70);
        let (left, right, truth) = pair_of(w, h, |x| if x < 130.0 { 20.0 } else { 28.0 }, 28.0);
        // The input as a filled map has it: the edge smeared over 9 px, and
        // 0.3 px off.
        let smeared: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let span = x.saturating_sub(4)..(x + 5).min(w);
                let n = span.len() as f32;
                span.map(|xx| truth[xx + y * w]).sum::<f32>() / n + 0.3
            })
            .collect();
        let (a, _) = refine_slanted(&left, &right, &smeared, &SlantedParams::default());
        let (b, _) = refine_slanted(&left, &right, &smeared, &growing());
        let error = |v: &[f32], columns| mean_error_over(v, &truth, w, 16, columns);
        // Beside the edge, where the input is right but a grown window
        // would reach across the edge (without the test of its fit: 0.3 px
        // on the left).
        for band in [104..118, 138..152] {
            let (fixed, grown) = (error(&a, band.clone()), error(&b, band.clone()));
            assert!(
                grown <= fixed + 0.05,
                "columns {band:?}: fixed window {fixed:.3} px, growing {grown:.3} px"
            );
        }
        // Away from it, windows grow as on any weak texture (and both
        // sizes recover this noise-free pair's integer disparity to within
        // a hundredth of a pixel).
        let (fixed, grown) = (error(&a, 150..210), error(&b, 150..210));
        assert!(
            grown < (0.7 * fixed).max(0.01),
            "fixed {fixed:.3} px, growing {grown:.3} px"
        );
    }

    #[test]
    fn a_bent_surface_is_followed_by_the_quadratic_not_the_plane() {
        let (w, h) = (220, 70);
        let bend = |x: f32| 20.0 + 0.004 * (x - 110.0).powi(2);
        let (left, right, truth) = pair_of(w, h, bend, bend(0.0));
        let biased: Vec<f32> = truth.iter().map(|d| d + 0.4).collect();
        let on = |shape| {
            let params = SlantedParams { shape, ..growing() };
            let (v, _) = refine_slanted(&left, &right, &biased, &params);
            mean_error_over(&v, &truth, w, 16, 60..170)
        };
        let (quadratic, plane) = (on(WindowShape::Quadratic), on(WindowShape::Plane));
        assert!(
            quadratic < 0.7 * plane,
            "mean error: quadratic {quadratic:.4} px, plane {plane:.4} px"
        );
    }
}
