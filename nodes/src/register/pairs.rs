//! What every ICP variant shares: the pairs of source and target points,
//! the robust kernels that weigh them, sums over them in a fixed order (the
//! same bits on any number of threads), and the small-motion Jacobian the
//! linearised fits (and the frame's adjustment) are taken in.

use nalgebra::{Matrix3, Matrix3x6, Matrix6, Point3, Vector6};
use rayon::prelude::*;

/// How a point at `p` moves under a small turn w and shift t applied
/// after (`p -> p + w x p + t`), in (w, t) at zero: `[-[p]x | I]`.
pub(crate) fn motion_jacobian(p: &Point3<f64>) -> Matrix3x6<f64> {
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-p.coords.cross_matrix()));
    j.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    j
}

/// Pairs of (source index, target index, distance mm).
pub(crate) type Pairs = Vec<(usize, usize, f64)>;

/// Down-weighting of large residuals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kernel {
    /// Plain least squares.
    None,
    /// Huber with threshold k (mm).
    Huber(f64),
    /// Tukey's biweight with cut-off c (mm).
    Tukey(f64),
}

impl Kernel {
    /// The weight of a residual of `r` mm.
    pub(crate) fn weight(self, r: f64) -> f64 {
        let r = r.abs();
        match self {
            Kernel::None => 1.0,
            Kernel::Huber(k) => {
                if r <= k {
                    1.0
                } else {
                    k / r
                }
            }
            Kernel::Tukey(c) => {
                if r >= c {
                    0.0
                } else {
                    (1.0 - (r / c).powi(2)).powi(2)
                }
            }
        }
    }
}

/// Pairs per partial sum: each chunk is summed on its own, then the chunks
/// in order, whatever the thread count (rayon's own reduce splits by it).
pub(crate) const REDUCTION_CHUNK: usize = 4096;

/// Linearised normal equations `(sum J^T W J, sum J^T W r, sum w)` over
/// `pairs`, `term` giving each pair's part (`None` to leave it out): over
/// fixed chunks in parallel, then the chunks in order.
pub(crate) fn normal_equations_over<F>(pairs: &Pairs, term: F) -> (Matrix6<f64>, Vector6<f64>, f64)
where
    F: Fn(usize, usize, f64) -> Option<(Matrix6<f64>, Vector6<f64>, f64)> + Sync,
{
    let partials: Vec<(Matrix6<f64>, Vector6<f64>, f64)> = pairs
        .par_chunks(REDUCTION_CHUNK)
        .map(|chunk| {
            chunk.iter().fold(
                (Matrix6::zeros(), Vector6::zeros(), 0.0),
                |(a, b, t), &(i, j, distance)| match term(i, j, distance) {
                    Some((pa, pb, pt)) => (a + pa, b + pb, t + pt),
                    None => (a, b, t),
                },
            )
        })
        .collect();
    partials.iter().fold(
        (Matrix6::zeros(), Vector6::zeros(), 0.0),
        |(a, b, t), (pa, pb, pt)| (a + pa, b + pb, t + pt),
    )
}
