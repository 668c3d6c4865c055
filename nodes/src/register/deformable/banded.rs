//! The Cholesky factor of a symmetric positive definite band matrix, and
//! solves with it: the multigrid's coarsest level (a lattice of up to 160
//! nodes, whose matrix couples nodes at most two planes apart).
//!
//! nalgebra's `Cholesky` factors the whole dense matrix, though outside its
//! band every product it adds is zero: on the phantom's coarsest level (360
//! unknowns, half-bandwidth 146) four fifths of its work, and the factor
//! was the one serial step of the multigrid's set-up. Here each entry is
//! computed by the same operations, in the same order, as nalgebra's
//! left-looking factor, forward substitution and backward dot products (its
//! eight partial sums), the zero terms left out: the same bits, but for the
//! sign of an exact zero (a test compares them).

use nalgebra::DMatrix;

/// A band matrix's Cholesky factor L (A = L L^T), lower triangle, column
/// major.
pub(super) struct BandedCholesky {
    n: usize,
    /// Largest distance below the diagonal of a nonzero entry of A (and so
    /// of L).
    band: usize,
    l: Vec<f64>,
}

impl BandedCholesky {
    /// The factor of `a` (symmetric; its lower triangle is read), or `None`
    /// where it is not positive definite (as nalgebra's `Cholesky::new`).
    pub(super) fn new(a: &DMatrix<f64>) -> Option<Self> {
        let n = a.nrows();
        assert_eq!(n, a.ncols(), "a square matrix");
        let band = (0..n)
            .filter_map(|j| (j..n).rev().find(|&i| a[(i, j)] != 0.0).map(|i| i - j))
            .max()
            .unwrap_or(0);
        let mut l = vec![0.0; n * n];
        for j in 0..n {
            let end = (j + band + 1).min(n);
            l[j * n + j..j * n + end].copy_from_slice(&a.as_slice()[j * n + j..j * n + end]);
        }
        for j in 0..n {
            let end = (j + band + 1).min(n);
            // Column j less each earlier column k times L[j, k] (nalgebra's
            // axpy: factor * x + y, the same sum as y + factor * x), k
            // ascending; columns more than the band before j have L[j, k] = 0.
            for k in j.saturating_sub(band)..j {
                let factor = -l[k * n + j];
                let rows = j..(k + band + 1).min(end);
                let (before, from_j) = l.split_at_mut(j * n);
                let col_k = &before[k * n..k * n + n];
                for (y, x) in from_j[rows.clone()].iter_mut().zip(&col_k[rows]) {
                    *y += factor * x;
                }
            }
            let diag = l[j * n + j];
            // nalgebra refuses a zero diagonal and one whose square root
            // fails (negative or NaN).
            if diag.is_nan() || diag <= 0.0 {
                return None;
            }
            let denom = diag.sqrt();
            l[j * n + j] = denom;
            for v in &mut l[j * n + j + 1..j * n + end] {
                *v /= denom;
            }
        }
        Some(BandedCholesky { n, band, l })
    }

    fn at(&self, i: usize, j: usize) -> f64 {
        self.l[j * self.n + i]
    }

    /// Solves A x = b in place (nalgebra's `solve_mut`: L y = b, then
    /// L^T x = y).
    pub(super) fn solve_mut(&self, b: &mut [f64]) {
        let (n, band) = (self.n, self.band);
        assert_eq!(b.len(), n, "one right-hand side entry per unknown");
        for i in 0..n {
            let coeff = b[i] / self.at(i, i);
            b[i] = coeff;
            let end = (i + band + 1).min(n);
            let below = &self.l[i * n + i + 1..i * n + end];
            for (y, x) in b[i + 1..end].iter_mut().zip(below) {
                *y += -coeff * x;
            }
        }
        for i in (0..n).rev() {
            let below = &self.l[i * n + i + 1..i * n + n];
            let dot = banded_dot(below, &b[i + 1..], band);
            b[i] = (b[i] - dot) / self.at(i, i);
        }
    }
}

/// x . y as nalgebra's `dot` sums it (eight partial sums over whole groups
/// of eight, paired, then the rest), where only the first `band` entries of
/// `x` can be nonzero: the groups wholly past them add zeros, and are left
/// out.
fn banded_dot(x: &[f64], y: &[f64], band: usize) -> f64 {
    let len = x.len();
    let whole = band.div_ceil(8) * 8;
    // Past `whole` nalgebra adds only zeros, to its partial sums or the rest.
    let (m, groups) = if whole < len {
        (whole, whole)
    } else {
        (len, len / 8 * 8)
    };
    let mut acc = [0.0f64; 8];
    for g in (0..groups).step_by(8) {
        for (k, a) in acc.iter_mut().enumerate() {
            *a += x[g + k] * y[g + k];
        }
    }
    let mut res = 0.0;
    res += acc[0] + acc[4];
    res += acc[1] + acc[5];
    res += acc[2] + acc[6];
    res += acc[3] + acc[7];
    for k in groups..m {
        res += x[k] * y[k];
    }
    res
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A random symmetric positive definite matrix of half-bandwidth `band`.
    fn band_matrix(rng: &mut ChaCha8Rng, n: usize, band: usize) -> DMatrix<f64> {
        let mut a = DMatrix::zeros(n, n);
        for j in 0..n {
            for i in j + 1..(j + band + 1).min(n) {
                // Some entries inside the band exactly zero, as a lattice's.
                let v = if rng.random_range(0..5) == 0 {
                    0.0
                } else {
                    rng.random_range(-1.0..1.0)
                };
                a[(i, j)] = v;
                a[(j, i)] = v;
            }
            a[(j, j)] = 2.0 * band as f64 + rng.random_range(0.0..1.0);
        }
        a
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        // The sign of an exact zero may differ (see the module's notes).
        v.iter()
            .map(|x| if *x == 0.0 { 0 } else { x.to_bits() })
            .collect()
    }

    #[test]
    fn factor_and_solve_have_nalgebras_bits() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // Bands narrower and wider than the matrix, bands of whole groups of
        // eight and not, and the coarsest level's shape (360, 146).
        for (n, band) in [(360, 146), (50, 7), (50, 8), (50, 17), (30, 40), (9, 0)] {
            let a = band_matrix(&mut rng, n, band);
            let ours = BandedCholesky::new(&a).expect("positive definite");
            let theirs = nalgebra::Cholesky::new(a.clone()).expect("positive definite");
            let l = theirs.l();
            let lower: Vec<f64> = (0..n)
                .flat_map(|j| (0..n).map(move |i| (i, j)))
                .map(|(i, j)| if i >= j { l[(i, j)] } else { 0.0 })
                .collect();
            assert_eq!(bits(&ours.l), bits(&lower), "factor, n {n}, band {band}");
            let b: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut x = b.clone();
            ours.solve_mut(&mut x);
            let expected = theirs.solve(&DVector::from_vec(b));
            assert_eq!(
                bits(&x),
                bits(expected.as_slice()),
                "solve, n {n}, band {band}"
            );
        }
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_has_no_factor() {
        let mut a = DMatrix::identity(4, 4);
        a[(2, 2)] = -1.0;
        assert!(BandedCholesky::new(&a).is_none());
        a[(2, 2)] = 0.0;
        assert!(BandedCholesky::new(&a).is_none());
        a[(2, 2)] = f64::NAN;
        assert!(BandedCholesky::new(&a).is_none());
    }
}
