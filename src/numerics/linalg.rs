//! Thin wrappers over `faer` with sequential parallelism.
//!
//! One fit always runs on one thread (`Par::Seq`); magcomp parallelises
//! across channels and candidate models instead, which keeps results
//! independent of the thread count.

use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::svd::ComputeSvdVectors;
use std::ops::Range;

use faer::{Accum, Mat, MatMut, MatRef, Par};

/// Rows per block of the tall-skinny QR.
pub const QR_BLOCK_ROWS: usize = 4096;

/// `dst = lhs · rhs` on one thread.
pub fn multiply(dst: MatMut<'_, f64>, lhs: MatRef<'_, f64>, rhs: MatRef<'_, f64>) {
    faer::linalg::matmul::matmul(dst, Accum::Replace, lhs, rhs, 1.0, Par::Seq);
}

/// `aᵀa` on one thread: the lower triangle computed, the upper mirrored.
pub fn gram(a: MatRef<'_, f64>) -> Mat<f64> {
    use faer::linalg::matmul::triangular::{matmul, BlockStructure};
    let p = a.ncols();
    let mut gram = Mat::zeros(p, p);
    matmul(
        gram.as_mut(),
        BlockStructure::TriangularLower,
        Accum::Replace,
        a.transpose(),
        BlockStructure::Rectangular,
        a,
        BlockStructure::Rectangular,
        1.0,
        Par::Seq,
    );
    for j in 0..p {
        for i in 0..j {
            gram[(i, j)] = gram[(j, i)];
        }
    }
    gram
}

/// Householder QR of `a` in place; returns the upper-triangular factor
/// (`min(rows, cols) × cols`).
fn qr_r_factor(mut a: Mat<f64>) -> Mat<f64> {
    use faer::linalg::qr::no_pivoting::factor;
    let (rows, cols) = a.shape();
    let size = rows.min(cols);
    let block = factor::recommended_block_size::<f64>(rows, cols);
    let mut coefficients = Mat::<f64>::zeros(block, size);
    let scratch = factor::qr_in_place_scratch::<f64>(rows, cols, block, Par::Seq, Default::default());
    let mut memory = MemBuffer::new(scratch);
    factor::qr_in_place(
        a.as_mut(),
        coefficients.as_mut(),
        Par::Seq,
        MemStack::new(&mut memory),
        Default::default(),
    );
    Mat::from_fn(size, cols, |i, j| if i <= j { a[(i, j)] } else { 0.0 })
}

/// The R factor of the QR decomposition of `columns` (all of equal length),
/// computed block by block (tall-skinny QR: Demmel et al. 2012), so the
/// whole matrix is never copied. Signs of R's rows are arbitrary.
pub fn tall_skinny_r(columns: &[&[f64]]) -> Mat<f64> {
    let rows = columns.first().map_or(0, |c| c.len());
    tall_skinny_r_of(rows, columns.len(), |range, mut block| {
        for (j, column) in columns.iter().enumerate() {
            for (i, &value) in column[range.clone()].iter().enumerate() {
                block[(i, j)] = value;
            }
        }
    })
}

/// [`tall_skinny_r`] of a `rows` × `cols` matrix that `fill(range, block)`
/// writes block by block (rows `range` into `block`, zeroed), so it never
/// exists whole. The blocks of [`QR_BLOCK_ROWS`] rows are filled and
/// factored side by side and their factors combined in order: the same
/// bits whatever the number of threads.
pub fn tall_skinny_r_of(rows: usize, cols: usize, fill: impl Fn(Range<usize>, MatMut<'_, f64>) + Sync) -> Mat<f64> {
    use rayon::prelude::*;
    let stacked_r: Vec<Mat<f64>> = (0..rows.div_ceil(QR_BLOCK_ROWS))
        .into_par_iter()
        .map(|block| {
            let range = block * QR_BLOCK_ROWS..((block + 1) * QR_BLOCK_ROWS).min(rows);
            let mut values = Mat::zeros(range.len(), cols);
            fill(range, values.as_mut());
            qr_r_factor(values)
        })
        .collect();
    combine_r(&stacked_r, cols)
}

/// The R factor of the rows of several matrices stacked, from their own R
/// factors (`parts`, each with `cols` columns): the QR of the stacked
/// factors, as the last step of a tall-skinny QR. A fit that leaves out
/// one fold of rows builds its R from the other folds' this way.
pub fn combine_r(parts: &[Mat<f64>], cols: usize) -> Mat<f64> {
    let total: usize = parts.iter().map(|r| r.nrows()).sum();
    let mut all = Mat::<f64>::zeros(total.max(cols), cols);
    let mut row = 0;
    for r in parts {
        all.as_mut().get_mut(row..row + r.nrows(), ..).copy_from(r.as_ref());
        row += r.nrows();
    }
    let r = qr_r_factor(all);
    r.as_ref().get(..cols, ..).to_owned()
}

/// The singular values of a small square matrix, non-increasing, without
/// its singular vectors.
pub fn small_singular_values(a: MatRef<'_, f64>) -> Option<Vec<f64>> {
    let n = a.nrows();
    let mut s = Diag::<f64>::zeros(n);
    let scratch = faer::linalg::svd::svd_scratch::<f64>(
        n,
        n,
        ComputeSvdVectors::No,
        ComputeSvdVectors::No,
        Par::Seq,
        Default::default(),
    );
    let mut memory = MemBuffer::new(scratch);
    let status = faer::linalg::svd::svd(
        a,
        s.as_mut(),
        None,
        None,
        Par::Seq,
        MemStack::new(&mut memory),
        Default::default(),
    );
    status.ok()?;
    Some((0..n).map(|k| s[k]).collect())
}

/// Singular value decomposition of a small square matrix: `(U, σ, V)` with
/// `a = U diag(σ) Vᵀ` and σ non-increasing.
pub fn small_svd(a: MatRef<'_, f64>) -> Option<(Mat<f64>, Vec<f64>, Mat<f64>)> {
    let n = a.nrows();
    let mut u = Mat::<f64>::zeros(n, n);
    let mut v = Mat::<f64>::zeros(n, n);
    let mut s = Diag::<f64>::zeros(n);
    let scratch = faer::linalg::svd::svd_scratch::<f64>(
        n,
        n,
        ComputeSvdVectors::Full,
        ComputeSvdVectors::Full,
        Par::Seq,
        Default::default(),
    );
    let mut memory = MemBuffer::new(scratch);
    let status = faer::linalg::svd::svd(
        a,
        s.as_mut(),
        Some(u.as_mut()),
        Some(v.as_mut()),
        Par::Seq,
        MemStack::new(&mut memory),
        Default::default(),
    );
    status.ok()?;
    let sigma = (0..n).map(|k| s[k]).collect();
    Some((u, sigma, v))
}

/// The lower Cholesky factor L of a small symmetric matrix (`a = L Lᵀ`);
/// `None` when `a` is not numerically positive definite.
pub fn cholesky_lower(a: MatRef<'_, f64>) -> Option<Mat<f64>> {
    let llt = a.llt(faer::Side::Lower).ok()?;
    let lower = llt.L().to_owned();
    let n = lower.nrows();
    let positive = (0..n).all(|i| lower[(i, i)] > 0.0 && lower[(i, i)].is_finite());
    positive.then_some(lower)
}

/// Solves the small symmetric positive semi-definite system `k x = b` by
/// Cholesky; `None` when `k` is numerically singular.
pub fn solve_spd(k: MatRef<'_, f64>, b: &[f64]) -> Option<Vec<f64>> {
    let llt = k.llt(faer::Side::Lower).ok()?;
    let rhs = Mat::from_fn(b.len(), 1, |i, _| b[i]);
    let x = faer::linalg::solvers::Solve::solve(&llt, rhs.as_ref());
    let x: Vec<f64> = (0..b.len()).map(|i| x[(i, 0)]).collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gram_is_symmetric_and_equals_the_full_product() {
        let a = Mat::from_fn(300, 7, |i, j| ((i * (j + 2)) as f64 * 0.31).sin() * (1.0 + j as f64));
        let mut full = Mat::zeros(7, 7);
        multiply(full.as_mut(), a.transpose(), a.as_ref());
        let ours = gram(a.as_ref());
        for i in 0..7 {
            for j in 0..7 {
                assert_eq!(ours[(i, j)], ours[(j, i)]);
                assert!((ours[(i, j)] - full[(i, j)]).abs() <= 1e-12 * full[(i, i)].max(full[(j, j)]));
            }
        }
    }

    /// The blocks are factored side by side: one thread and three give the
    /// same bits, and a matrix filled block by block (rows formed where
    /// they are factored, as the vector model's Gauss-Newton step forms
    /// them) gives the bits of the same matrix given as columns.
    #[test]
    fn tall_skinny_r_is_the_same_bits_on_any_threads_and_filled_by_blocks() {
        let rows = 4 * QR_BLOCK_ROWS + 5;
        let value = |i: usize, j: usize| ((i * (j + 3)) as f64 * 0.0071).cos() * (1.0 + j as f64) + 1e-3 * i as f64;
        let columns: Vec<Vec<f64>> = (0..6).map(|j| (0..rows).map(|i| value(i, j)).collect()).collect();
        let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
        let on = |threads: usize, by_blocks: bool| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let r = pool.install(|| match by_blocks {
                true => tall_skinny_r_of(rows, 6, |range, mut block| {
                    for (k, i) in range.enumerate() {
                        for j in 0..6 {
                            block[(k, j)] = value(i, j);
                        }
                    }
                }),
                false => tall_skinny_r(&views),
            });
            (0..6)
                .flat_map(|i| (0..6).map(move |j| (i, j)))
                .map(|(i, j)| r[(i, j)].to_bits())
                .collect::<Vec<u64>>()
        };
        let one = on(1, false);
        assert!(one.iter().any(|&bits| bits != 0));
        assert_eq!(on(3, false), one);
        assert_eq!(on(1, true), one);
        assert_eq!(on(3, true), one);
    }

    #[test]
    fn tall_skinny_r_matches_gram_matrix() {
        let rows = 3 * QR_BLOCK_ROWS + 17;
        let columns: Vec<Vec<f64>> = (0..4)
            .map(|j| {
                (0..rows)
                    .map(|i| ((i * (j + 2)) as f64 * 0.013).sin() + j as f64)
                    .collect()
            })
            .collect();
        let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
        let r = tall_skinny_r(&views);
        for a in 0..4 {
            for b in 0..4 {
                let gram: f64 = columns[a].iter().zip(&columns[b]).map(|(x, y)| x * y).sum();
                let rtr: f64 = (0..4).map(|k| r[(k, a)] * r[(k, b)]).sum();
                // RᵀR = AᵀA up to rounding of sums of ~12 000 terms of order 1.
                assert!(
                    (gram - rtr).abs() < 1e-9 * gram.abs().max(1.0),
                    "{a},{b}: {gram} vs {rtr}"
                );
            }
        }
    }

    #[test]
    fn small_svd_reconstructs() {
        let a = Mat::from_fn(3, 3, |i, j| (i * 3 + j) as f64 + if i == j { 2.0 } else { 0.0 });
        let (u, s, v) = small_svd(a.as_ref()).unwrap();
        let rebuilt = Mat::from_fn(3, 3, |i, j| (0..3).map(|k| u[(i, k)] * s[k] * v[(j, k)]).sum::<f64>());
        assert!((&rebuilt - &a).norm_max() < 1e-13);
        assert!(s[0] >= s[1] && s[1] >= s[2]);
    }
}
