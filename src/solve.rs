//! Regularised least squares: ridge with λ chosen by PRESS, and truncated SVD.
//!
//! Given the filtered design matrix $A$ ($n \times p$) and target $y$, ridge
//! regression minimises $\lVert y - A\beta \rVert^2 + \lambda \lVert \beta \rVert^2$
//! (Hoerl & Kennard 1970), with λ on MagNav.jl's scale (unscaled
//! coefficients). With the thin SVD $A = U \Sigma V^\top$ and $c = U^\top y$,
//! every candidate is a spectral filter with weights $w_k \in [0, 1]$:
//!
//! $$ \beta = V \,\mathrm{diag}(w_k / \sigma_k)\, c, \qquad
//!    w_k^{\text{ridge}} = \frac{\sigma_k^2}{\sigma_k^2 + \lambda}, \qquad
//!    w_k^{\text{TSVD}} = [k < r]. $$
//!
//! The fitted values are $U\,\mathrm{diag}(w)\,c$ and the leverages
//! $h_{ii} = \sum_k U_{ik}^2 w_k$, so the leave-one-out PRESS statistic
//! $\sum_i \big(e_i / (1 - h_{ii})\big)^2$ (Allen 1974) for every candidate
//! comes from two matrix products per block of rows. For ridge it equals
//! brute-force leave-one-out exactly.
//!
//! Band-passed samples are autocorrelated, so plain PRESS favours small λ.
//! The blocked PRESS leaves out one fold (a calibration window) at a time.
//! For a fold $b$ the held-out residual is
//! $(I - U_b W U_b^\top)^{-1} e_b$. The Woodbury identity turns this into a
//! $p \times p$ solve that needs only $G_b = U_b^\top U_b$ and $U_b^\top y_b$.
//!
//! Numerics: the SVD comes from the R factor of a tall-skinny QR of the
//! column-scaled matrix (never the normal equations), and $U$ is rebuilt
//! block by block as $A_s D V \Sigma^{-1}$.

use std::ops::Range;

use faer::Mat;
use rayon::prelude::*;
use serde::Serialize;

use crate::linalg::{multiply, small_svd, solve_spd, tall_skinny_r};

/// Rows per block when accumulating PRESS.
const PRESS_BLOCK_ROWS: usize = 2048;

/// How λ is obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LambdaChoice {
    /// Chosen on the grid by the selection criterion.
    Select,
    /// Fixed by the user; no fallback is applied.
    Fixed(f64),
}

/// Which statistic picks λ (and the TSVD rank).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Criterion {
    /// Leave-one-sample-out PRESS.
    Press,
    /// Leave-one-fold-out (one calibration window at a time) PRESS.
    BlockedPress,
}

/// Options of the regularised solve.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveOptions {
    /// Select λ or use a fixed value.
    pub lambda: LambdaChoice,
    /// Statistic used for the selection.
    pub criterion: Criterion,
    /// Number of λ values on the log grid (at least 50).
    pub grid_points: usize,
    /// Grid spans `σ₁² · 10^low` to `σ₁² · 10^high`.
    pub grid_decades: (f64, f64),
    /// Above this condition number ridge is not trusted and TSVD is used.
    pub tsvd_condition_limit: f64,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            lambda: LambdaChoice::Select,
            // Leave-one-window-out: band-passed samples are autocorrelated,
            // so plain leave-one-out PRESS picks too little regularisation
            // (see README, Method).
            criterion: Criterion::BlockedPress,
            grid_points: 61,
            grid_decades: (-11.0, 1.0),
            tsvd_condition_limit: 1e10,
        }
    }
}

/// The regulariser finally used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Ridge regression.
    Ridge,
    /// Truncated SVD.
    TruncatedSvd,
}

/// One point of the ridge PRESS curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RidgePoint {
    /// Ridge parameter.
    pub lambda: f64,
    /// Leave-one-out PRESS, nT².
    pub press: f64,
    /// Leave-one-fold-out PRESS, nT² (`None` with fewer than two folds).
    pub blocked_press: Option<f64>,
    /// Effective degrees of freedom $\sum_k w_k$.
    pub effective_dof: f64,
}

/// One point of the TSVD PRESS curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RankPoint {
    /// Number of singular directions kept.
    pub rank: usize,
    /// Leave-one-out PRESS, nT².
    pub press: f64,
    /// Leave-one-fold-out PRESS, nT².
    pub blocked_press: Option<f64>,
}

/// A solved regularised fit with its diagnostics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Solution {
    /// Coefficients, one per design column.
    pub coefficients: Vec<f64>,
    /// Regulariser used.
    pub method: Method,
    /// Why that regulariser and parameter were used.
    pub reason: String,
    /// λ used (ridge).
    pub lambda: Option<f64>,
    /// Rank kept (TSVD).
    pub rank: Option<usize>,
    /// Effective degrees of freedom of the chosen fit.
    pub effective_dof: f64,
    /// λ at the minimum of leave-one-out PRESS.
    pub lambda_by_press: f64,
    /// λ at the minimum of the blocked PRESS, when there are folds.
    pub lambda_by_blocked_press: Option<f64>,
    /// Singular values of the design matrix, non-increasing.
    pub singular_values: Vec<f64>,
    /// σ₁/σₚ of the design matrix.
    pub condition_number: f64,
    /// σ₁/σₚ after scaling each column to unit norm.
    pub scaled_condition_number: f64,
    /// Ridge PRESS curve.
    pub ridge_curve: Vec<RidgePoint>,
    /// TSVD PRESS curve, rank 1 to the numerical rank.
    pub tsvd_curve: Vec<RankPoint>,
    /// Rows used.
    pub samples: usize,
    /// In-sample RMS residual of the chosen fit, nT.
    pub residual_rms: f64,
    /// Standard errors of the coefficients for white residuals:
    /// $\hat\sigma \sqrt{\sum_k v_{jk}^2 w_k^2/\sigma_k^2}$ with
    /// $\hat\sigma^2 = \mathrm{RSS}/(n - \mathrm{dof})$ (the ridge estimator's
    /// own variance; its bias is not included).
    pub standard_errors: Vec<f64>,
    /// Fitted values $A\beta$ on the rows given, nT.
    #[serde(skip)]
    pub fitted: Vec<f64>,
}

/// Why the solve failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// Fewer rows than columns.
    #[error("{rows} samples for {terms} terms: a fit needs more samples than terms; add calibration windows or use fewer terms")]
    TooFewSamples {
        /// Rows given.
        rows: usize,
        /// Columns.
        terms: usize,
    },
    /// A value is NaN or infinite.
    #[error("design column {column} has a non-finite value at stacked row {row}")]
    NonFinite {
        /// Column index (`terms` for the target).
        column: usize,
        /// Row in the stacked matrix.
        row: usize,
    },
    /// The design matrix is zero.
    #[error("the design matrix is all zeros: the vector magnetometer carries no signal in the fitting band")]
    ZeroMatrix,
    /// No candidate has a finite criterion.
    #[error("every candidate has an infinite PRESS (each sample has leverage 1); add calibration data")]
    NoFiniteCriterion,
    /// The singular value decomposition did not converge.
    #[error("the singular value decomposition did not converge")]
    SvdFailed,
}

/// The spectral form of the problem: everything PRESS and the coefficients need.
struct Spectrum {
    singular_values: Vec<f64>,
    v: Mat<f64>,
    /// $M = D V \Sigma^{-1}$, zero beyond the numerical rank; $U = A_s M$.
    to_u: Mat<f64>,
    uty: Vec<f64>,
    residual_ss_outside: f64,
    rank: usize,
    scaled_condition_number: f64,
}

/// Fits `y ≈ A β` with ridge/TSVD. `columns` are the (filtered) design
/// columns, consumed and scaled in place; `folds` partition the rows into
/// calibration windows for the blocked PRESS.
pub fn solve(
    mut columns: Vec<Vec<f64>>,
    y: &[f64],
    folds: &[Range<usize>],
    options: &SolveOptions,
) -> Result<Solution, SolveError> {
    check_input(&columns, y)?;
    let scales = scale_columns(&mut columns)?;
    let spectrum = decompose(&columns, y, &scales)?;
    let grid = lambda_grid(&spectrum, options);
    let weights = candidate_weights(&spectrum, &grid);
    let folds = usable_folds(folds, y.len());
    let (press, blocked) = press_statistics(&columns, y, &spectrum, &weights, &folds);
    let ridge_curve: Vec<RidgePoint> = (0..grid.len())
        .map(|l| RidgePoint {
            lambda: grid[l],
            press: press[l],
            blocked_press: blocked.as_ref().map(|b| b[l]),
            effective_dof: weights[l].iter().sum(),
        })
        .collect();
    let tsvd_curve: Vec<RankPoint> = (0..spectrum.rank)
        .map(|r| RankPoint {
            rank: r + 1,
            press: press[grid.len() + r],
            blocked_press: blocked.as_ref().map(|b| b[grid.len() + r]),
        })
        .collect();
    let mut solution = choose(spectrum, ridge_curve, tsvd_curve, options, y.len())?;
    solution.fitted = fitted_values(&columns, &scales, &solution.coefficients);
    Ok(solution)
}

/// $A\beta = A_s (D\beta)$ from the scaled columns.
fn fitted_values(scaled: &[Vec<f64>], scales: &[f64], coefficients: &[f64]) -> Vec<f64> {
    let mut fitted = vec![0.0; scaled.first().map_or(0, Vec::len)];
    for ((column, scale), beta) in scaled.iter().zip(scales).zip(coefficients) {
        let gain = scale * beta;
        fitted.iter_mut().zip(column).for_each(|(f, a)| *f += a * gain);
    }
    fitted
}

fn check_input(columns: &[Vec<f64>], y: &[f64]) -> Result<(), SolveError> {
    let terms = columns.len();
    if y.len() <= terms {
        return Err(SolveError::TooFewSamples { rows: y.len(), terms });
    }
    let values = columns.iter().map(Vec::as_slice).chain(std::iter::once(y));
    for (column, values) in values.enumerate() {
        if let Some(row) = values.iter().position(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite { column, row });
        }
    }
    Ok(())
}

/// Scales each column to unit Euclidean norm; returns the norms $D$.
fn scale_columns(columns: &mut [Vec<f64>]) -> Result<Vec<f64>, SolveError> {
    let scales: Vec<f64> = columns
        .iter_mut()
        .map(|column| {
            let norm = column.iter().map(|v| v * v).sum::<f64>().sqrt();
            let scale = if norm > 0.0 { norm } else { 1.0 };
            column.iter_mut().for_each(|v| *v /= scale);
            scale
        })
        .collect();
    if columns.iter().all(|c| c.iter().all(|&v| v == 0.0)) {
        return Err(SolveError::ZeroMatrix);
    }
    Ok(scales)
}

fn decompose(scaled: &[Vec<f64>], y: &[f64], scales: &[f64]) -> Result<Spectrum, SolveError> {
    let p = scaled.len();
    let mut views: Vec<&[f64]> = scaled.iter().map(Vec::as_slice).collect();
    views.push(y);
    let r_aug = tall_skinny_r(&views);
    let r_scaled = r_aug.as_ref().get(..p, ..p);
    let r = Mat::from_fn(p, p, |i, j| r_scaled[(i, j)] * scales[j]);
    let (u_r, singular_values, v) = small_svd(r.as_ref()).ok_or(SolveError::SvdFailed)?;
    let q_y: Vec<f64> = (0..p).map(|i| r_aug[(i, p)]).collect();
    let uty: Vec<f64> = (0..p).map(|k| (0..p).map(|i| u_r[(i, k)] * q_y[i]).sum()).collect();
    let tolerance = singular_values[0] * (y.len().max(p) as f64) * f64::EPSILON;
    let rank = singular_values.iter().take_while(|&&s| s > tolerance).count();
    let to_u = Mat::from_fn(p, p, |j, k| {
        if k < rank {
            scales[j] * v[(j, k)] / singular_values[k]
        } else {
            0.0
        }
    });
    let scaled_sigma = small_svd(r_scaled).ok_or(SolveError::SvdFailed)?.1;
    Ok(Spectrum {
        residual_ss_outside: r_aug[(p, p)].powi(2),
        scaled_condition_number: scaled_sigma[0] / scaled_sigma[p - 1],
        singular_values,
        v,
        to_u,
        uty,
        rank,
    })
}

/// Log-spaced λ grid relative to σ₁².
fn lambda_grid(spectrum: &Spectrum, options: &SolveOptions) -> Vec<f64> {
    let top = spectrum.singular_values[0].powi(2);
    let (low, high) = options.grid_decades;
    let points = options.grid_points.max(2);
    let mut grid: Vec<f64> = (0..points)
        .map(|l| top * 10f64.powf(low + (high - low) * l as f64 / (points - 1) as f64))
        .collect();
    if let LambdaChoice::Fixed(lambda) = options.lambda {
        grid.push(lambda);
        grid.sort_by(f64::total_cmp);
        grid.dedup();
    }
    grid
}

/// Spectral weights of every candidate: ridge λs, then TSVD ranks 1..=rank.
fn candidate_weights(spectrum: &Spectrum, grid: &[f64]) -> Vec<Vec<f64>> {
    let p = spectrum.singular_values.len();
    let ridge = grid.iter().map(|&lambda| {
        (0..p)
            .map(|k| match k < spectrum.rank {
                true => spectrum.singular_values[k].powi(2) / (spectrum.singular_values[k].powi(2) + lambda),
                false => 0.0,
            })
            .collect()
    });
    let tsvd = (1..=spectrum.rank).map(|r| (0..p).map(|k| if k < r { 1.0 } else { 0.0 }).collect());
    ridge.chain(tsvd).collect()
}

/// Folds used for the blocked PRESS: only when there are at least two and
/// they partition the rows.
fn usable_folds(folds: &[Range<usize>], rows: usize) -> Vec<Range<usize>> {
    let contiguous = folds.windows(2).all(|w| w[0].end == w[1].start);
    let covers = folds.first().is_some_and(|f| f.start == 0) && folds.last().is_some_and(|f| f.end == rows);
    match folds.len() >= 2 && contiguous && covers {
        true => folds.to_vec(),
        false => Vec::new(),
    }
}

/// Per-fold sufficient statistics for the blocked PRESS.
struct FoldStatistics {
    gram: Mat<f64>,
    uty: Vec<f64>,
    yy: f64,
}

/// PRESS for every candidate, and the blocked PRESS when there are folds.
///
/// Row blocks are processed in parallel; their partial sums are added in
/// block order, so the result does not depend on the number of threads.
fn press_statistics(
    scaled: &[Vec<f64>],
    y: &[f64],
    spectrum: &Spectrum,
    weights: &[Vec<f64>],
    folds: &[Range<usize>],
) -> (Vec<f64>, Option<Vec<f64>>) {
    let p = scaled.len();
    let m = weights.len();
    let weight_matrix = Mat::from_fn(p, m, |k, l| weights[l][k]);
    let fitted_weights = Mat::from_fn(p, m, |k, l| weights[l][k] * spectrum.uty[k]);
    let whole = std::slice::from_ref(&(0..y.len())).to_vec();
    let ranges: &[Range<usize>] = if folds.is_empty() { &whole } else { folds };
    let blocks: Vec<(usize, Range<usize>)> = ranges
        .iter()
        .enumerate()
        .flat_map(|(f, fold)| {
            fold.clone()
                .step_by(PRESS_BLOCK_ROWS)
                .map(move |start| (f, start..(start + PRESS_BLOCK_ROWS).min(fold.end)))
        })
        .collect();
    let partials: Vec<BlockPress> = blocks
        .par_iter()
        .map(|(fold, rows)| {
            let u = basis_block(scaled, &spectrum.to_u, rows.clone());
            let y = &y[rows.clone()];
            let (press, worst_leverage) = block_press(&u, y, &weight_matrix, &fitted_weights);
            let statistics = (!folds.is_empty()).then(|| FoldStatistics::of_block(&u, y));
            BlockPress {
                fold: *fold,
                press,
                worst_leverage,
                statistics,
            }
        })
        .collect();
    let mut press = vec![0.0; m];
    let mut worst_leverage = vec![0.0f64; m];
    let mut fold_statistics: Vec<FoldStatistics> = (0..ranges.len()).map(|_| FoldStatistics::zeros(p)).collect();
    for partial in partials {
        for l in 0..m {
            press[l] += partial.press[l];
            worst_leverage[l] = worst_leverage[l].max(partial.worst_leverage[l]);
        }
        if let Some(statistics) = partial.statistics {
            fold_statistics[partial.fold].add(&statistics);
        }
    }
    // A sample with leverage 1 has no leave-one-out prediction.
    for (total, worst) in press.iter_mut().zip(&worst_leverage) {
        if *worst >= 1.0 - 1e-10 || worst.is_nan() {
            *total = f64::INFINITY;
        }
    }
    let blocked = (!folds.is_empty()).then(|| blocked_press(&fold_statistics, spectrum, weights));
    (press, blocked)
}

/// One row block's share of the PRESS statistics.
struct BlockPress {
    fold: usize,
    press: Vec<f64>,
    worst_leverage: Vec<f64>,
    statistics: Option<FoldStatistics>,
}

/// Rows `rows` of $U = A_s M$.
fn basis_block(scaled: &[Vec<f64>], to_u: &Mat<f64>, rows: Range<usize>) -> Mat<f64> {
    let mut block = Mat::zeros(rows.len(), scaled.len());
    for (j, column) in scaled.iter().enumerate() {
        block.col_as_slice_mut(j).copy_from_slice(&column[rows.clone()]);
    }
    let mut u = Mat::zeros(rows.len(), scaled.len());
    multiply(u.as_mut(), block.as_ref(), to_u.as_ref());
    u
}

/// Sum of squared leave-one-out residuals of every candidate over one row
/// block, and the largest leverage met.
fn block_press(u: &Mat<f64>, y: &[f64], weight_matrix: &Mat<f64>, fitted_weights: &Mat<f64>) -> (Vec<f64>, Vec<f64>) {
    let (rows, m) = (u.nrows(), weight_matrix.ncols());
    let mut squared = Mat::zeros(rows, u.ncols());
    for k in 0..u.ncols() {
        for (s, v) in squared.col_as_slice_mut(k).iter_mut().zip(u.col_as_slice(k)) {
            *s = v * v;
        }
    }
    let mut fitted = Mat::zeros(rows, m);
    let mut leverage = Mat::zeros(rows, m);
    multiply(fitted.as_mut(), u.as_ref(), fitted_weights.as_ref());
    multiply(leverage.as_mut(), squared.as_ref(), weight_matrix.as_ref());
    (0..m)
        .map(|l| loo_sum_of_squares(y, fitted.col_as_slice(l), leverage.col_as_slice(l)))
        .unzip()
}

/// $\sum_i ((y_i - f_i)/(1 - h_i))^2$ and $\max_i h_i$, branch-free so it
/// vectorises; AVX2 when the processor has it (no fused multiply-add, so
/// both paths give the same bits).
fn loo_sum_of_squares(y: &[f64], fitted: &[f64], leverage: &[f64]) -> (f64, f64) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor supports AVX2, checked just above.
        return unsafe { loo_sum_of_squares_avx2(y, fitted, leverage) };
    }
    loo_sum_of_squares_portable(y, fitted, leverage)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn loo_sum_of_squares_avx2(y: &[f64], fitted: &[f64], leverage: &[f64]) -> (f64, f64) {
    loo_sum_of_squares_portable(y, fitted, leverage)
}

#[inline(always)]
fn loo_sum_of_squares_portable(y: &[f64], fitted: &[f64], leverage: &[f64]) -> (f64, f64) {
    const WIDTH: usize = 8;
    let mut sums = [0.0; WIDTH];
    let mut worst = [0.0f64; WIDTH];
    let chunks = y.len() / WIDTH;
    for c in 0..chunks {
        let range = c * WIDTH..(c + 1) * WIDTH;
        let (y, f, h) = (&y[range.clone()], &fitted[range.clone()], &leverage[range]);
        for k in 0..WIDTH {
            let e = (y[k] - f[k]) / (1.0 - h[k]);
            sums[k] += e * e;
            worst[k] = if h[k] > worst[k] { h[k] } else { worst[k] };
        }
    }
    for i in chunks * WIDTH..y.len() {
        let e = (y[i] - fitted[i]) / (1.0 - leverage[i]);
        sums[0] += e * e;
        worst[0] = worst[0].max(leverage[i]);
    }
    let sum = sums.iter().sum();
    let worst = worst.iter().fold(0.0f64, |a, &b| a.max(b));
    (sum, worst)
}

impl FoldStatistics {
    fn zeros(p: usize) -> Self {
        FoldStatistics {
            gram: Mat::zeros(p, p),
            uty: vec![0.0; p],
            yy: 0.0,
        }
    }

    fn of_block(u: &Mat<f64>, y: &[f64]) -> Self {
        let p = u.ncols();
        let mut gram = Mat::zeros(p, p);
        multiply(gram.as_mut(), u.transpose(), u.as_ref());
        let uty = (0..p)
            .map(|k| u.col_as_slice(k).iter().zip(y).map(|(a, b)| a * b).sum())
            .collect();
        FoldStatistics {
            gram,
            uty,
            yy: y.iter().map(|v| v * v).sum(),
        }
    }

    fn add(&mut self, other: &FoldStatistics) {
        self.gram += &other.gram;
        self.uty.iter_mut().zip(&other.uty).for_each(|(a, b)| *a += b);
        self.yy += other.yy;
    }
}

/// Held-out sum of squares over folds for every candidate, by the Woodbury
/// form $x = e_b + U_b S (I - S G_b S)^{-1} S U_b^\top e_b$ with $S = W^{1/2}$.
fn blocked_press(folds: &[FoldStatistics], spectrum: &Spectrum, weights: &[Vec<f64>]) -> Vec<f64> {
    weights
        .iter()
        .map(|w| {
            folds
                .iter()
                .map(|fold| held_out_sum_of_squares(fold, &spectrum.uty, w))
                .sum()
        })
        .collect()
}

fn held_out_sum_of_squares(fold: &FoldStatistics, uty: &[f64], w: &[f64]) -> f64 {
    let p = w.len();
    let shrunk: Vec<f64> = (0..p).map(|k| w[k] * uty[k]).collect();
    let gram_shrunk: Vec<f64> = (0..p)
        .map(|i| (0..p).map(|k| fold.gram[(i, k)] * shrunk[k]).sum())
        .collect();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let residual_ss = fold.yy - 2.0 * dot(&fold.uty, &shrunk) + dot(&shrunk, &gram_shrunk);
    let projected: Vec<f64> = (0..p).map(|k| fold.uty[k] - gram_shrunk[k]).collect();
    let root: Vec<f64> = w.iter().map(|v| v.sqrt()).collect();
    let k_matrix = Mat::from_fn(p, p, |i, j| f64::from(i == j) - root[i] * fold.gram[(i, j)] * root[j]);
    let rhs: Vec<f64> = (0..p).map(|k| root[k] * projected[k]).collect();
    let Some(z) = solve_spd(k_matrix.as_ref(), &rhs) else {
        return f64::INFINITY;
    };
    let correction: Vec<f64> = (0..p).map(|k| root[k] * z[k]).collect();
    let gram_correction: Vec<f64> = (0..p)
        .map(|i| (0..p).map(|k| fold.gram[(i, k)] * correction[k]).sum())
        .collect();
    residual_ss + 2.0 * dot(&projected, &correction) + dot(&correction, &gram_correction)
}

/// Index of the smallest finite value.
fn argmin(values: impl Iterator<Item = f64>) -> Option<usize> {
    values
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

fn criterion_value(press: f64, blocked: Option<f64>, criterion: Criterion) -> f64 {
    match criterion {
        Criterion::BlockedPress => blocked.unwrap_or(press),
        Criterion::Press => press,
    }
}

fn choose(
    spectrum: Spectrum,
    ridge: Vec<RidgePoint>,
    tsvd: Vec<RankPoint>,
    options: &SolveOptions,
    samples: usize,
) -> Result<Solution, SolveError> {
    let p = spectrum.singular_values.len();
    let condition_number = spectrum.singular_values[0] / spectrum.singular_values[p - 1];
    let lambda_by_press = argmin(ridge.iter().map(|r| r.press))
        .map(|i| ridge[i].lambda)
        .ok_or(SolveError::NoFiniteCriterion)?;
    let lambda_by_blocked_press = argmin(ridge.iter().filter_map(|r| r.blocked_press)).map(|i| ridge[i].lambda);
    let criterion = match (options.criterion, lambda_by_blocked_press) {
        (Criterion::BlockedPress, None) => Criterion::Press,
        (chosen, _) => chosen,
    };
    let ridge_best = argmin(
        ridge
            .iter()
            .map(|r| criterion_value(r.press, r.blocked_press, criterion)),
    )
    .ok_or(SolveError::NoFiniteCriterion)?;
    let rank_best = argmin(
        tsvd.iter()
            .map(|r| criterion_value(r.press, r.blocked_press, criterion)),
    )
    .unwrap_or(spectrum.rank.saturating_sub(1));
    let name = match criterion {
        Criterion::Press => "PRESS",
        Criterion::BlockedPress => "blocked PRESS",
    };
    let (method, lambda, rank, reason) = match options.lambda {
        LambdaChoice::Fixed(lambda) => (
            Method::Ridge,
            Some(lambda),
            None,
            format!("λ = {lambda:e} fixed by the user"),
        ),
        LambdaChoice::Select if condition_number > options.tsvd_condition_limit => {
            let reason = format!("condition number {condition_number:.3e} exceeds the limit {:.1e} that ridge is trusted with; truncated SVD rank chosen by {name}", options.tsvd_condition_limit);
            (Method::TruncatedSvd, None, Some(rank_best + 1), reason)
        }
        LambdaChoice::Select if ridge_best == 0 || ridge_best == ridge.len() - 1 => {
            let edge = if ridge_best == 0 { "lower" } else { "upper" };
            let reason = format!("{name} minimum lies at the {edge} edge of the λ grid, so ridge cannot locate an optimum; truncated SVD rank chosen by {name}");
            (Method::TruncatedSvd, None, Some(rank_best + 1), reason)
        }
        LambdaChoice::Select => {
            let lambda = ridge[ridge_best].lambda;
            (
                Method::Ridge,
                Some(lambda),
                None,
                format!("{name} minimum at λ = {lambda:.3e} inside the grid"),
            )
        }
    };
    let weights: Vec<f64> = match (lambda, rank) {
        (Some(lambda), _) => candidate_weights(&spectrum, &[lambda]).remove(0),
        (None, Some(rank)) => (0..p).map(|k| f64::from(u8::from(k < rank))).collect(),
        (None, None) => unreachable!("a method always sets λ or rank"),
    };
    let residual_ss = spectrum.residual_ss_outside
        + (0..p)
            .map(|k| ((1.0 - weights[k]) * spectrum.uty[k]).powi(2))
            .sum::<f64>();
    let effective_dof: f64 = weights.iter().sum();
    let noise = (residual_ss / (samples as f64 - effective_dof).max(1.0)).sqrt();
    Ok(Solution {
        coefficients: coefficients(&spectrum, &weights),
        residual_rms: (residual_ss / samples as f64).sqrt(),
        standard_errors: standard_errors(&spectrum, &weights, noise),
        effective_dof,
        method,
        reason,
        lambda,
        rank,
        lambda_by_press,
        lambda_by_blocked_press,
        condition_number,
        scaled_condition_number: spectrum.scaled_condition_number,
        singular_values: spectrum.singular_values,
        ridge_curve: ridge,
        tsvd_curve: tsvd,
        samples,
        fitted: Vec::new(),
    })
}

/// $\hat\sigma \sqrt{\sum_k v_{jk}^2 (w_k/\sigma_k)^2}$ per coefficient.
fn standard_errors(spectrum: &Spectrum, weights: &[f64], noise: f64) -> Vec<f64> {
    let p = weights.len();
    let gains: Vec<f64> = (0..p)
        .map(|k| match weights[k] > 0.0 {
            true => (weights[k] / spectrum.singular_values[k]).powi(2),
            false => 0.0,
        })
        .collect();
    (0..p)
        .map(|j| {
            noise
                * (0..p)
                    .map(|k| spectrum.v[(j, k)].powi(2) * gains[k])
                    .sum::<f64>()
                    .sqrt()
        })
        .collect()
}

/// $\beta = V \,\mathrm{diag}(w_k/\sigma_k)\, c$.
fn coefficients(spectrum: &Spectrum, weights: &[f64]) -> Vec<f64> {
    let p = weights.len();
    let gains: Vec<f64> = (0..p)
        .map(|k| match weights[k] > 0.0 {
            true => weights[k] * spectrum.uty[k] / spectrum.singular_values[k],
            false => 0.0,
        })
        .collect();
    (0..p)
        .map(|j| (0..p).map(|k| spectrum.v[(j, k)] * gains[k]).sum())
        .collect()
}
