//! A singular value decomposition that always ends. nalgebra's `svd()` iterates until it
//! converges, without a limit: a CapBall dataset with an angle of 10¹⁶⁰° made it loop forever.
//! Every SVD of data from outside the process goes through [`svd`]: the matrix must be finite,
//! and the iterations are capped; past either the caller gets `None` and says why.

use nalgebra::{DMatrix, linalg::SVD};

/// The most QR iterations of one decomposition: a well-posed matrix of the sizes here
/// (up to a few thousand rows, tens of columns) converges in a few hundred.
pub const MAX_ITERATIONS: usize = 100_000;

/// The SVD of `m`, or `None` when `m` holds a non-finite entry or the iteration does not
/// converge within [`MAX_ITERATIONS`].
pub fn svd(
    m: DMatrix<f64>,
    compute_u: bool,
    compute_v: bool,
) -> Option<SVD<f64, nalgebra::Dyn, nalgebra::Dyn>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    // nalgebra's own `svd()` stops at 5·ε: the same tolerance, so the results are those of
    // `svd()` whenever it ends.
    m.try_svd(compute_u, compute_v, 5.0 * f64::EPSILON, MAX_ITERATIONS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_finite_matrix_decomposes_and_a_non_finite_one_is_refused() {
        let m = DMatrix::from_row_slice(3, 2, &[3.0, 0.0, 0.0, 4.0, 0.0, 0.0]);
        let s = svd(m.clone(), true, true).expect("converges");
        let mut sv: Vec<f64> = s.singular_values.iter().copied().collect();
        sv.sort_by(f64::total_cmp);
        assert!(
            (sv[0] - 3.0).abs() < 1e-12 && (sv[1] - 4.0).abs() < 1e-12,
            "{sv:?}"
        );
        let mut bad = m;
        bad[(0, 1)] = f64::NAN;
        assert!(svd(bad.clone(), true, true).is_none());
        bad[(0, 1)] = f64::INFINITY;
        assert!(svd(bad, false, false).is_none());
    }

    /// Entries spread over 300 decades (what an angle of 10¹⁶⁰° produced): the decomposition
    /// ends, with a result or `None`, instead of iterating forever.
    #[test]
    fn an_ill_scaled_matrix_ends() {
        let m = DMatrix::from_fn(20, 14, |r, c| {
            let e = ((r * 14 + c) as i32 % 61 - 30) * 10;
            (1.0 + (r * 7 + c * 3) as f64).sin() * 10f64.powi(e)
        });
        let _ = svd(m, true, true);
    }
}
