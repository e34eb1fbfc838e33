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
//!    w_k^{\text{TSVD}} = \mathbb{1}(k < r). $$
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
//! Numerics: the SVD comes from an R factor of $A$ (never from solving the
//! normal equations). R is obtained by CholeskyQR2 (Fukaya et al. 2014;
//! Yamamoto et al. 2015): Cholesky of the column-scaled Gram matrix gives a
//! first basis $U_1$, whose own Gram matrix, accumulated row block by row
//! block, refines it to working precision. Ill-conditioned (scaled
//! condition number above 10⁶) or rank-deficient designs use a Householder
//! tall-skinny QR instead. $U$ is rebuilt block by block as $A V \Sigma^{-1}$,
//! and the leave-one-out residuals of all candidates are formed in
//! registers from it, never stored.

use std::ops::Range;

use faer::{Mat, MatRef};
use rayon::prelude::*;
use serde::Serialize;

use crate::numerics::linalg::{cholesky_lower, gram, multiply, small_singular_values, small_svd, tall_skinny_r};
use crate::numerics::stacked::{Block, Stacked, BLOCK_ROWS};

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

impl Criterion {
    /// Its name in reports.
    pub fn describe(self) -> &'static str {
        match self {
            Criterion::Press => "PRESS",
            Criterion::BlockedPress => "blocked PRESS",
        }
    }

    /// The other criterion.
    pub fn other(self) -> Self {
        match self {
            Criterion::Press => Criterion::BlockedPress,
            Criterion::BlockedPress => Criterion::Press,
        }
    }
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
    /// What the solve computes beyond the coefficients.
    pub figures: Figures,
}

/// What a solve computes beyond its coefficients and the curve that
/// chooses them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Figures {
    /// Both PRESS curves, the standard errors and the blocked jackknife:
    /// what a fit reports.
    #[default]
    All,
    /// Only the curve of the criterion that picks λ (both when λ is
    /// fixed): what a held-out score needs, which keeps the coefficients
    /// and nothing else. The other curve reads NaN, and the standard
    /// errors and the jackknife are empty. Leave-one-out PRESS reads
    /// infinity at the λs its partial sums show cannot be its minimum.
    Choice,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            lambda: LambdaChoice::Select,
            // Leave-one-window-out: band-passed samples are autocorrelated,
            // so plain leave-one-out PRESS picks too little regularisation
            // (docs/guide/src/method.md, step 3).
            criterion: Criterion::BlockedPress,
            grid_points: 50,
            grid_decades: (-11.0, 1.0),
            tsvd_condition_limit: 1e10,
            figures: Figures::All,
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
    /// How the R factor behind the SVD was computed.
    pub decomposition: Decomposition,
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
    /// The blocked jackknife of the coefficients with its bias reduced:
    /// the cluster-robust covariance with Bell & McCaffrey's (2002)
    /// correction (CR2), one cluster per fold (window). For each fold f,
    /// $d_f = (X^\top X + \lambda I)^{-1} X_f^\top (I - H_{ff})^{-1/2} e_f$,
    /// with $e_f$ the full fit's residuals on the fold and $H_{ff}$ the
    /// fold's block of the hat matrix; a prediction $a\beta$ has variance
    /// $\sum_f (a \cdot d_f)^2$. Whole windows are the clusters, so the
    /// band-passed residuals' autocorrelation within a window (which
    /// makes the white-noise [`Self::standard_errors`] too small) is kept,
    /// and so is what differs between windows: the Earth's field in the
    /// band, which coefficients along directions the manoeuvres barely
    /// excite fit differently each time.
    ///
    /// The plain blocked jackknife (refit without each fold; Künsch 1989)
    /// is the same with $(I - H_{ff})^{-1}$, and by the Efron-Stein
    /// inequality it overstates the variance: a calibration window carries
    /// much of what the box says about some direction (one manoeuvre on
    /// one heading), so leaving it out moves the fit far more than its
    /// noise does. On the survey lines of 80 random plans
    /// (`tests/uncertainty.rs`, seeds 81-160, which the rule was not chosen
    /// on) the plain jackknife's column held 0.80 of the true errors
    /// within one sigma and 0.98 within two, and warned 20 of 214 right
    /// channels; this one 0.64 and 0.91, and 1 of 214. Empty with fewer
    /// than three folds. In the model JSON, one row per fold.
    pub jackknife: Vec<Vec<f64>>,
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
#[derive(Clone)]
struct Spectrum {
    singular_values: Vec<f64>,
    v: Mat<f64>,
    /// $M = V \Sigma^{-1}$, zero beyond the numerical rank; $U = A M$.
    to_u: Mat<f64>,
    uty: Vec<f64>,
    rank: usize,
    scaled_condition_number: f64,
    decomposition: Decomposition,
}

/// How the R factor of the design matrix was computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Decomposition {
    /// Cholesky of the column-scaled Gram matrix, refined once (CholeskyQR2).
    CholeskyQr2,
    /// Householder tall-skinny QR, for ill-conditioned or rank-deficient data.
    Householder,
}

/// Above this condition number of the column-scaled matrix the Cholesky
/// route is not taken: its first pass loses κ²·ε, and one refinement
/// restores full accuracy only while κ²·ε ≪ 1 (Yamamoto et al. 2015).
const CHOLESKY_CONDITION_LIMIT: f64 = 1e6;

/// Fits `y ≈ A β` with ridge/TSVD. `columns` are the (filtered) design
/// columns; `folds` partition the rows into calibration windows for the
/// blocked PRESS.
pub fn solve(
    columns: Vec<Vec<f64>>,
    y: &[f64],
    folds: &[Range<usize>],
    options: &SolveOptions,
) -> Result<Solution, SolveError> {
    if y.len() <= columns.len() {
        return Err(SolveError::TooFewSamples {
            rows: y.len(),
            terms: columns.len(),
        });
    }
    let lengths: Vec<usize> = match usable_folds(folds, y.len()) {
        folds if folds.is_empty() => vec![y.len()],
        folds => folds.iter().map(Range::len).collect(),
    };
    solve_stacked(&Stacked::from_columns(&columns, y, &lengths), options)
}

/// [`solve`] for a design already stacked with its target; its folds
/// (when there are at least two) are those of the blocked PRESS.
pub fn solve_stacked(design: &Stacked, options: &SolveOptions) -> Result<Solution, SolveError> {
    solve_keeping(design, options).map(|(solution, _)| solution)
}

/// [`solve_stacked`], keeping the design's decomposition for
/// [`solve_again`] on the same design with another target.
pub fn solve_keeping(design: &Stacked, options: &SolveOptions) -> Result<(Solution, DesignFactor), SolveError> {
    check_shape(design)?;
    let factor = decompose(design, design.folds().len())?;
    let solution = solve_factored(design, (&factor.spectrum, &factor.statistics), options)?;
    Ok((solution, factor))
}

/// [`solve_stacked`] on `design`, whose design columns are those `factor`
/// was made from (only the target differs): bit for bit the same solution,
/// without decomposing the design again. The second-order passes fit the
/// same columns to a target less the term of the fit before.
pub fn solve_again(design: &Stacked, factor: &DesignFactor, options: &SolveOptions) -> Result<Solution, SolveError> {
    check_shape(design)?;
    let (spectrum, statistics) = factor.with_target(design);
    solve_factored(design, (&spectrum, &statistics), options)
}

/// The solve on a decomposed design: the λ grid, the PRESS curves, the
/// choice and its figures.
fn solve_factored(
    design: &Stacked,
    (spectrum, fold_statistics): (&Spectrum, &[FoldStatistics]),
    options: &SolveOptions,
) -> Result<Solution, SolveError> {
    let rows = design.rows();
    let fold_count = design.folds().len();
    let grid = lambda_grid(spectrum, options);
    let weights = candidate_weights(spectrum, &grid);
    let (press_needed, blocked_needed) = curves_needed(options, fold_count);
    let blocked = blocked_needed.then(|| blocked_press(fold_statistics, spectrum, &grid));
    // Blocked PRESS with no finite value on the ridge grid gives way to
    // leave-one-out PRESS ([`choose`]), which is then needed.
    let no_blocked_choice = blocked
        .as_ref()
        .is_some_and(|b| !b[..grid.len()].iter().any(|v| v.is_finite()));
    let press_needed = press_needed || no_blocked_choice;
    let press = match (press_needed, options.figures) {
        (true, Figures::Choice) => press_to_minimum(design, spectrum, &weights)
            .unwrap_or_else(|| leave_one_out_press(design, spectrum, &weights)),
        (true, _) => leave_one_out_press(design, spectrum, &weights),
        (false, _) => vec![f64::NAN; weights.len()],
    };
    let curves = curves((&grid, &weights, spectrum.rank), &press, blocked.as_deref());
    let (mut solution, chosen_weights) = choose(spectrum, curves, (options, press_needed), rows)?;
    solution.fitted = design.predict(&solution.coefficients);
    let residual_ss: f64 = (design.target_pieces().flatten().zip(&solution.fitted))
        .map(|(y, f)| (y - f) * (y - f))
        .sum();
    let samples = rows as f64;
    let noise = (residual_ss / (samples - solution.effective_dof).max(1.0)).sqrt();
    solution.residual_rms = (residual_ss / samples).sqrt();
    if options.figures == Figures::Choice {
        return Ok(solution);
    }
    solution.standard_errors = standard_errors(spectrum, &chosen_weights, noise);
    if fold_count >= 3 {
        solution.jackknife = jackknife(spectrum, fold_statistics, solution.lambda, solution.rank);
    }
    Ok(solution)
}

/// The ridge curve (one point per λ of `grid`, with its `weights`) and
/// the truncated-SVD curve (ranks 1..=`rank`) from the criteria of every
/// candidate, ridge then ranks.
fn curves(
    (grid, weights, rank): (&[f64], &[Vec<f64>], usize),
    press: &[f64],
    blocked: Option<&[f64]>,
) -> (Vec<RidgePoint>, Vec<RankPoint>) {
    let ridge = (0..grid.len())
        .map(|l| RidgePoint {
            lambda: grid[l],
            press: press[l],
            blocked_press: blocked.map(|b| b[l]),
            effective_dof: weights[l].iter().sum(),
        })
        .collect();
    let tsvd = (0..rank)
        .map(|r| RankPoint {
            rank: r + 1,
            press: press[grid.len() + r],
            blocked_press: blocked.map(|b| b[grid.len() + r]),
        })
        .collect();
    (ridge, tsvd)
}

/// Which PRESS curves a solve computes: (leave-one-out, blocked). Both
/// for [`Figures::All`] (blocked only with two folds or more); for
/// [`Figures::Choice`] only the one whose minimum picks λ (blocked PRESS
/// falls back to leave-one-out with fewer than two folds), and
/// leave-one-out for a fixed λ, which picks nothing but still reports
/// where PRESS would have put it.
fn curves_needed(options: &SolveOptions, fold_count: usize) -> (bool, bool) {
    let blocked_possible = fold_count >= 2;
    match options.figures {
        Figures::All => (true, blocked_possible),
        Figures::Choice => {
            let by_blocked = options.lambda == LambdaChoice::Select
                && options.criterion == Criterion::BlockedPress
                && blocked_possible;
            (!by_blocked, by_blocked)
        }
    }
}

/// The deviations of [`Solution::jackknife`], in the spectral basis
/// (design $X = U\Sigma V^\top$ over the first `rank` components for
/// truncated SVD, λ = 0, and every active one for ridge): with
/// $D = (\Sigma^2 + \lambda I)^{-1/2}$, the fold's share of the Gram
/// matrix $G_f = U_f^\top U_f$ and $S_f = D \Sigma G_f \Sigma D$ (the
/// fold's leverage, eigenvalues in [0, 1)),
/// $d_f = V D (I - S_f)^{-1/2} D\,\Sigma\,(U_f^\top y_f - G_f \Sigma z)$,
/// $z$ the full fit. With the power −1 in place of −1/2 this is exactly
/// the refit without the fold (the plain blocked jackknife). Empty when a
/// fold carries all of a component's information ($S_f$ reaches 1).
fn jackknife(spectrum: &Spectrum, folds: &[FoldStatistics], lambda: Option<f64>, rank: Option<usize>) -> Vec<Vec<f64>> {
    let n = rank.unwrap_or(spectrum.rank).min(spectrum.rank);
    let lambda = lambda.unwrap_or(0.0);
    let sigma = &spectrum.singular_values[..n];
    let p = spectrum.singular_values.len();
    let d: Vec<f64> = sigma.iter().map(|s| 1.0 / (s * s + lambda).sqrt()).collect();
    let z: Vec<f64> = (0..n)
        .map(|k| sigma[k] * spectrum.uty[k] / (sigma[k] * sigma[k] + lambda))
        .collect();
    let mut deviations = Vec::with_capacity(folds.len());
    for fold in folds {
        // D Σ (U_f' y_f − G_f Σ z): the fold's residual seen by each
        // component, scaled.
        let scaled: Vec<f64> = (0..n)
            .map(|k| {
                let fitted: f64 = (0..n).map(|j| fold.gram[(k, j)] * sigma[j] * z[j]).sum();
                d[k] * sigma[k] * (fold.uty[k] - fitted)
            })
            .collect();
        let leverage = Mat::from_fn(n, n, |i, j| d[i] * sigma[i] * fold.gram[(i, j)] * sigma[j] * d[j]);
        let Ok(eigen) = leverage.self_adjoint_eigen(faer::Side::Lower) else {
            return Vec::new();
        };
        let (q, values) = (eigen.U(), eigen.S());
        // A NaN eigenvalue fails as one at or above 1 does.
        if (0..n).any(|m| values[m] >= 1.0 - 1e-12 || values[m].is_nan()) {
            return Vec::new();
        }
        let along: Vec<f64> = (0..n)
            .map(|m| (0..n).map(|k| q[(k, m)] * scaled[k]).sum::<f64>() / (1.0 - values[m].max(0.0)).sqrt())
            .collect();
        let w: Vec<f64> = (0..n)
            .map(|k| d[k] * (0..n).map(|m| q[(k, m)] * along[m]).sum::<f64>())
            .collect();
        let beta: Vec<f64> = (0..p)
            .map(|j| (0..n).map(|k| spectrum.v[(j, k)] * w[k]).sum())
            .collect();
        if !beta.iter().all(|b| b.is_finite()) {
            return Vec::new();
        }
        deviations.push(beta);
    }
    deviations
}

fn check_shape(design: &Stacked) -> Result<(), SolveError> {
    let terms = design.columns();
    if design.rows() <= terms {
        return Err(SolveError::TooFewSamples {
            rows: design.rows(),
            terms,
        });
    }
    if let Some(row) = design.target_pieces().flatten().position(|v| !v.is_finite()) {
        return Err(SolveError::NonFinite { column: terms, row });
    }
    Ok(())
}

/// The first non-finite design value, searched only once the Gram matrix
/// has shown there is one.
fn first_non_finite(design: &Stacked) -> SolveError {
    (0..design.columns())
        .find_map(|column| {
            let row = design.column(column).iter().position(|v| !v.is_finite())?;
            Some(SolveError::NonFinite { column, row })
        })
        // Finite values whose squares overflow.
        .unwrap_or(SolveError::NonFinite { column: 0, row: 0 })
}

/// A reusable block of the basis $U = A M$, column-major, and of the
/// target, their row count rounded up to [`LANES`] with zeros below the data
/// (zero rows add nothing to any sum).
struct BlockBuffer {
    basis: Mat<f64>,
    /// The loaded basis in groups of [`LANES`] rows, group by group: entry
    /// `g·p + k` holds column k's values in group g and their squares
    /// (filled by [`Self::group`]), so the PRESS kernel reads one stream.
    groups: Vec<Group>,
}

/// [`LANES`] values of a basis column and their squares.
type Group = [[f64; LANES]; 2];

impl BlockBuffer {
    fn new(p: usize) -> Self {
        BlockBuffer {
            basis: Mat::zeros(BLOCK_ROWS, p),
            groups: Vec::new(),
        }
    }

    /// Regroups the first `rows` rows (a whole number of groups) of the
    /// loaded basis into `groups`.
    fn group(&mut self, rows: usize) {
        let p = self.basis.ncols();
        self.groups.clear();
        self.groups.resize(rows / LANES * p, [[0.0; LANES]; 2]);
        for k in 0..p {
            let (column, _) = self.basis.col_as_slice(k)[..rows].as_chunks::<LANES>();
            for (g, values) in column.iter().enumerate() {
                self.groups[g * p + k] = [*values, values.map(|u| u * u)];
            }
        }
    }

    /// $U_b = A_b M$ for `block`, padding rows included (zero, as the
    /// block's are); returns the block's target with its padding.
    fn load<'d>(&mut self, design: &'d Stacked, block: &Block, to_u: &Mat<f64>) -> &'d [f64] {
        let p = design.columns();
        let view = design.block_view(block);
        let basis = self.basis.as_mut().get_mut(..view.nrows(), ..);
        multiply(basis, view.get(.., ..p), to_u.as_ref());
        design.block_target(block)
    }
}

/// Singular values and vectors of $A$ from an R factor ($A = QR$).
struct Factor {
    u_r: Mat<f64>,
    singular_values: Vec<f64>,
    v: Mat<f64>,
    rank: usize,
    /// $V\Sigma^{-1}$, zero beyond the rank.
    to_u: Mat<f64>,
}

impl Factor {
    /// The spectrum this factor gives, with the condition number of the
    /// unscaled design's R (`r` with its columns divided by `scales`).
    fn spectrum(
        self,
        r: MatRef<'_, f64>,
        scales: &[f64],
        uty: Vec<f64>,
        decomposition: Decomposition,
    ) -> Result<Spectrum, SolveError> {
        let p = r.ncols();
        let scaled_r = Mat::from_fn(p, p, |i, j| r[(i, j)] / scales[j]);
        Ok(Spectrum {
            scaled_condition_number: condition_number(scaled_r.as_ref())?,
            singular_values: self.singular_values,
            v: self.v,
            to_u: self.to_u,
            uty,
            rank: self.rank,
            decomposition,
        })
    }

    fn of_r(r: MatRef<'_, f64>, rows: usize) -> Result<Self, SolveError> {
        let p = r.ncols();
        let (u_r, singular_values, v) = small_svd(r).ok_or(SolveError::SvdFailed)?;
        let tolerance = singular_values[0] * (rows.max(p) as f64) * f64::EPSILON;
        let rank = singular_values.iter().take_while(|&&s| s > tolerance).count();
        let to_u = Mat::from_fn(p, p, |j, k| match k < rank {
            true => v[(j, k)] / singular_values[k],
            false => 0.0,
        });
        Ok(Factor {
            u_r,
            singular_values,
            v,
            rank,
            to_u,
        })
    }
}

/// The SVD of the design matrix and the per-fold statistics of its left
/// singular vectors, in three passes over the rows: the Gram matrix, then
/// $U_1 = A M_1$ with its Gram matrix and $U_1^\top y$ per fold, from which
/// a small refinement gives the final basis (CholeskyQR2: the second
/// Cholesky factor of $U_1^\top U_1$ corrects the first to working
/// precision). Ill-conditioned or rank-deficient designs take the
/// Householder tall-skinny QR instead.
fn decompose(design: &Stacked, fold_count: usize) -> Result<DesignFactor, SolveError> {
    let p = design.columns();
    let gram = design.gram();
    if !(0..p).all(|j| (0..p).all(|i| gram[(i, j)].is_finite())) {
        return Err(first_non_finite(design));
    }
    if (0..p).all(|j| gram[(j, j)] == 0.0) {
        return Err(SolveError::ZeroMatrix);
    }
    let scales: Vec<f64> = (0..p)
        .map(|j| match gram[(j, j)] > 0.0 {
            true => gram[(j, j)].sqrt(),
            false => 1.0,
        })
        .collect();
    let scaled_gram = Mat::from_fn(p, p, |i, j| gram[(i, j)] / (scales[i] * scales[j]));
    if let Some(refined) = cholesky_route(design, fold_count, scaled_gram.as_ref(), &scales)? {
        return Ok(refined);
    }
    let columns: Vec<Vec<f64>> = (0..p).map(|j| design.column(j)).collect();
    let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
    let r = tall_skinny_r(&views);
    drop(columns);
    let factor = Factor::of_r(r.as_ref(), design.rows())?;
    let statistics = basis_statistics(design, &factor.to_u, fold_count);
    let total = FoldStatistics::total(&statistics, p);
    let spectrum = factor.spectrum(r.as_ref(), &scales, total.uty, Decomposition::Householder)?;
    Ok(DesignFactor {
        spectrum,
        statistics,
        to_final: None,
    })
}

/// CholeskyQR2 when the scaled Gram matrix is safely positive definite;
/// `None` sends the caller to Householder QR.
fn cholesky_route(
    design: &Stacked,
    fold_count: usize,
    scaled_gram: MatRef<'_, f64>,
    scales: &[f64],
) -> Result<Option<DesignFactor>, SolveError> {
    let p = scales.len();
    let Some(first_lower) = cholesky_lower(scaled_gram) else {
        return Ok(None);
    };
    // R₁ of the scaled matrix, then of A itself.
    let first_r = Mat::from_fn(p, p, |i, j| first_lower[(j, i)] * scales[j]);
    let first = Factor::of_r(first_r.as_ref(), design.rows())?;
    let scaled_first_r = Mat::from_fn(p, p, |i, j| first_lower[(j, i)]);
    if first.rank < p || condition_number(scaled_first_r.as_ref())? > CHOLESKY_CONDITION_LIMIT {
        return Ok(None);
    }
    let first_statistics = basis_statistics(design, &first.to_u, fold_count);
    let first_total = FoldStatistics::total(&first_statistics, p);
    // U₁ = Q L₂ᵀ with L₂ L₂ᵀ = U₁ᵀU₁, so A = U₁ Σ₁ V₁ᵀ = Q (L₂ᵀ Σ₁ V₁ᵀ).
    let Some(second_lower) = cholesky_lower(first_total.gram.as_ref()) else {
        return Ok(None);
    };
    let r = Mat::from_fn(p, p, |i, j| {
        (i..p)
            .map(|k| second_lower[(k, i)] * first.singular_values[k] * first.v[(j, k)])
            .sum::<f64>()
    });
    let factor = Factor::of_r(r.as_ref(), design.rows())?;
    if factor.rank < p {
        return Ok(None);
    }
    // U = Q U_R = U₁ T with T = L₂⁻ᵀ U_R.
    let mut t = factor.u_r.clone();
    faer::linalg::triangular_solve::solve_upper_triangular_in_place(
        second_lower.as_ref().transpose(),
        t.as_mut(),
        faer::Par::Seq,
    );
    let statistics: Vec<FoldStatistics> = first_statistics.iter().map(|s| s.in_basis(&t)).collect();
    let uty = first_total.in_basis(&t).uty;
    let spectrum = factor.spectrum(r.as_ref(), scales, uty, Decomposition::CholeskyQr2)?;
    Ok(Some(DesignFactor {
        spectrum,
        statistics,
        to_final: Some((first.to_u, t)),
    }))
}

/// A design's decomposition ([`solve_keeping`]): its spectrum and per-fold
/// statistics, with what a new target needs to be seen in the same basis.
pub struct DesignFactor {
    spectrum: Spectrum,
    statistics: Vec<FoldStatistics>,
    /// CholeskyQR2's first basis $M_1$ ($U_1 = A M_1$), in which the
    /// statistics were summed, and $T$ taking it to the final one
    /// ($U = U_1 T$); `None` where they were summed in the final basis
    /// (Householder).
    to_final: Option<(Mat<f64>, Mat<f64>)>,
}

impl DesignFactor {
    /// The spectrum and per-fold statistics of the same design with the
    /// target `design` holds: $U^\top y$ and $y^\top y$ summed as
    /// [`decompose`] sums them, so they are the same bits.
    fn with_target(&self, design: &Stacked) -> (Spectrum, Vec<FoldStatistics>) {
        let p = design.columns();
        let basis = match &self.to_final {
            Some((first, _)) => first,
            None => &self.spectrum.to_u,
        };
        let sums = target_statistics(design, basis, self.statistics.len());
        let mut total = vec![0.0; p];
        for (uty, _) in &sums {
            total.iter_mut().zip(uty).for_each(|(a, b)| *a += b);
        }
        let in_final = |uty: &[f64]| match &self.to_final {
            Some((_, t)) => uty_in_basis(t, uty),
            None => uty.to_vec(),
        };
        let statistics = (self.statistics.iter().zip(&sums))
            .map(|(fold, (uty, yy))| FoldStatistics {
                gram: fold.gram.clone(),
                uty: in_final(uty),
                yy: *yy,
            })
            .collect();
        let spectrum = Spectrum {
            uty: in_final(&total),
            ..self.spectrum.clone()
        };
        (spectrum, statistics)
    }
}

/// Per fold, $U^\top y$ and $y^\top y$ with $U = A M$ ([`basis_statistics`]
/// without the Gram matrices), summed in block order.
fn target_statistics(design: &Stacked, to_u: &Mat<f64>, fold_count: usize) -> Vec<(Vec<f64>, f64)> {
    let p = design.columns();
    let partials = per_block_in_basis(design, to_u, |u, y| {
        (basis_times(u, y), y.iter().map(|v| v * v).sum::<f64>())
    });
    let mut folds: Vec<(Vec<f64>, f64)> = (0..fold_count).map(|_| (vec![0.0; p], 0.0)).collect();
    for (fold, (uty, yy)) in partials {
        folds[fold].0.iter_mut().zip(&uty).for_each(|(a, b)| *a += b);
        folds[fold].1 += yy;
    }
    folds
}

/// `each(U_b, y_b)` of every row block, with $U = A M$ (`to_u` is M), the
/// blocks side by side: each result with its block's fold, in block order.
fn per_block_in_basis<T: Send>(
    design: &Stacked,
    to_u: &Mat<f64>,
    each: impl Fn(MatRef<'_, f64>, &[f64]) -> T + Sync + Send,
) -> Vec<(usize, T)> {
    let p = design.columns();
    (design.blocks().par_iter())
        .map_init(
            || BlockBuffer::new(p),
            |buffer, block| {
                let y = buffer.load(design, block, to_u);
                let u = buffer.basis.as_ref().get(..y.len(), ..);
                (block.fold, each(u, y))
            },
        )
        .collect()
}

/// $U^\top y$.
fn basis_times(u: MatRef<'_, f64>, y: &[f64]) -> Vec<f64> {
    let p = u.ncols();
    let mut uty = Mat::zeros(p, 1);
    let y_column = MatRef::from_column_major_slice(y, y.len(), 1);
    multiply(uty.as_mut(), u.transpose(), y_column);
    (0..p).map(|k| uty[(k, 0)]).collect()
}

/// $T^\top (U^\top y)$: $U^\top y$ for the basis $U T$.
fn uty_in_basis(t: &Mat<f64>, uty: &[f64]) -> Vec<f64> {
    let p = t.ncols();
    (0..p).map(|k| (0..p).map(|i| t[(i, k)] * uty[i]).sum()).collect()
}

/// σ₁/σₚ of a small matrix.
fn condition_number(a: MatRef<'_, f64>) -> Result<f64, SolveError> {
    let sigma = small_singular_values(a).ok_or(SolveError::SvdFailed)?;
    Ok(sigma[0] / sigma[sigma.len() - 1])
}

/// Per-fold $U_b^\top U_b$, $U_b^\top y_b$ and $y_b^\top y_b$ with
/// $U = A M$, summed in block order.
fn basis_statistics(design: &Stacked, to_u: &Mat<f64>, fold_count: usize) -> Vec<FoldStatistics> {
    let p = design.columns();
    let partials = per_block_in_basis(design, to_u, FoldStatistics::of_block);
    let mut folds: Vec<FoldStatistics> = (0..fold_count).map(|_| FoldStatistics::zeros(p)).collect();
    for (fold, partial) in partials {
        folds[fold].add(&partial);
    }
    folds
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

/// Rows in one AVX-512 register of the PRESS kernel.
const LANES: usize = 8;

/// Candidates handled together by the PRESS kernel.
const CANDIDATES: usize = 4;

/// `value(l, k)` of the first `ridge` candidates l and `p` components k,
/// candidate-major in chunks of [`CANDIDATES`], zero-padded:
/// `[chunk * p + k][c]`.
fn packed((ridge, p): (usize, usize), value: impl Fn(usize, usize) -> f64) -> Vec<[f64; CANDIDATES]> {
    (0..ridge.div_ceil(CANDIDATES) * p)
        .map(|index| {
            let (chunk, k) = (index / p, index % p);
            std::array::from_fn(|c| {
                let l = chunk * CANDIDATES + c;
                if l < ridge {
                    value(l, k)
                } else {
                    0.0
                }
            })
        })
        .collect()
}

/// Leave-one-out PRESS of every candidate. Row blocks run in parallel and
/// their sums are added in block order, so the result does not depend on
/// the number of threads.
fn leave_one_out_press(design: &Stacked, spectrum: &Spectrum, weights: &[Vec<f64>]) -> Vec<f64> {
    let p = design.columns();
    let m = weights.len();
    // Truncated-SVD candidates (the last `rank`) are cumulative sums, done apart.
    let ridge = m - spectrum.rank;
    let leverage_weights = packed((ridge, p), |l, k| weights[l][k]);
    let fitted_weights = packed((ridge, p), |l, k| weights[l][k] * spectrum.uty[k]);
    let run = |track_all: bool| {
        let partials: Vec<Vec<(f64, f64)>> = design
            .blocks()
            .par_iter()
            .map_init(
                || BlockBuffer::new(p),
                |buffer, block| {
                    let y = buffer.load(design, block, &spectrum.to_u);
                    buffer.group(y.len());
                    let kernel = Kernel {
                        leverage_weights: &leverage_weights,
                        fitted_weights: &fitted_weights,
                        ridge,
                        track_all,
                        uty: &spectrum.uty[..spectrum.rank],
                    };
                    kernel.block(&buffer.groups, p, y)
                },
            )
            .collect();
        let mut press = vec![0.0; m];
        let mut worst = vec![0.0f64; m];
        for partial in partials {
            for (l, (sum, high)) in partial.into_iter().enumerate() {
                press[l] += sum;
                worst[l] = nan_max(worst[l], high);
            }
        }
        (press, worst)
    };
    let (mut press, mut worst) = run(false);
    if ridge > 0 && too_high(worst[0]) {
        // Some leverage reaches 1 at the smallest λ: find at which others.
        (press, worst) = run(true);
    }
    // A sample with leverage 1 has no leave-one-out prediction.
    for (total, worst) in press.iter_mut().zip(&worst) {
        if too_high(*worst) {
            *total = f64::INFINITY;
        }
    }
    press
}

/// A largest leverage at which a sample has no leave-one-out prediction.
fn too_high(leverage: f64) -> bool {
    leverage >= 1.0 - 1e-10 || leverage.is_nan()
}

/// Most rows [`press_to_minimum`] keeps the basis of between its two
/// passes: a score's box has a few thousand, in as many blocks as it has
/// pieces (a manoeuvre each).
const KEPT_ROWS: usize = 16_384;

/// Groups of rows a chunk of candidates adds between the checks of
/// [`press_to_minimum`] (256 rows).
const CHECK_GROUPS: usize = 32;

/// [`leave_one_out_press`] where only its minimum matters (the fit of a
/// score, [`Figures::Choice`]): every candidate that can be the minimum
/// gets its value bit for bit, the others infinity. The smallest λs (whose
/// largest leverage says whether any sample has leverage 1) and those
/// around the minimum of generalised cross-validation (from the spectrum
/// alone; it tracks PRESS closely) are summed first over every row,
/// blocks in parallel: their least PRESS bounds the minimum. The other
/// ridge candidates are then summed block by block in order, 256 rows at
/// a time, a chunk of them dropped as soon as each of its sums passes the
/// bound (a sum of squares only grows, so a dropped λ cannot be the
/// minimum). Truncated-SVD ranks are summed whole. The second pass reads
/// the basis the first made of each block. `None` where a leverage
/// reaches 1, the bound is not finite or the design has more than
/// [`KEPT_ROWS`] rows: the caller sums every candidate.
fn press_to_minimum(design: &Stacked, spectrum: &Spectrum, weights: &[Vec<f64>]) -> Option<Vec<f64>> {
    let p = design.columns();
    let m = weights.len();
    let ridge = m - spectrum.rank;
    // The first pass keeps each block's basis for the second: a few
    // thousand rows, as a score's box has (more are summed whole).
    if design.rows() > KEPT_ROWS {
        return None;
    }
    let guess = gcv_minimum(design, spectrum, &weights[..ridge])? / CANDIDATES;
    let leverage_weights = packed((ridge, p), |l, k| weights[l][k]);
    let fitted_weights = packed((ridge, p), |l, k| weights[l][k] * spectrum.uty[k]);
    let kernel = Kernel {
        leverage_weights: &leverage_weights,
        fitted_weights: &fitted_weights,
        ridge,
        track_all: false,
        uty: &spectrum.uty[..spectrum.rank],
    };
    let first: Vec<usize> = if guess == 0 { vec![0] } else { vec![0, guess] };
    let (totals, groups) = sums_whole(design, spectrum, &kernel, &first);
    let summed = first.len() * CANDIDATES;
    if ridge == 0 || too_high(totals[0].1) {
        return None;
    }
    // A sample with leverage 1 has no leave-one-out prediction.
    let value = |(sum, high): (f64, f64)| if too_high(high) { f64::INFINITY } else { sum };
    let mut press = vec![f64::INFINITY; m];
    for (index, &total) in totals[..summed].iter().enumerate() {
        let l = first[index / CANDIDATES] * CANDIDATES + index % CANDIDATES;
        if l < ridge {
            press[l] = value(total);
        }
    }
    for (rank, &total) in totals[summed..].iter().enumerate() {
        press[ridge + rank] = value(total);
    }
    let bound = press[..ridge]
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(f64::INFINITY, f64::min);
    if !bound.is_finite() {
        return None;
    }
    let rest: Vec<usize> = (0..ridge.div_ceil(CANDIDATES)).filter(|c| !first.contains(c)).collect();
    for (chunk, sums) in rest.iter().zip(sums_below(design, (&groups, &kernel), (&rest, bound))) {
        for (c, sum) in sums.into_iter().enumerate() {
            let l = chunk * CANDIDATES + c;
            if l < ridge {
                press[l] = sum;
            }
        }
    }
    Some(press)
}

/// The leave-one-out sums and largest leverages of the ridge `chunks` of
/// `kernel` (candidate by candidate), then of every truncated-SVD rank:
/// blocks in parallel, summed in block order.
fn sums_whole(
    design: &Stacked,
    spectrum: &Spectrum,
    kernel: &Kernel,
    chunks: &[usize],
) -> (Vec<(f64, f64)>, Vec<Vec<Group>>) {
    let p = design.columns();
    let ranks_only = Kernel {
        leverage_weights: &[],
        fitted_weights: &[],
        ridge: 0,
        ..*kernel
    };
    let (partials, groups): (Vec<Vec<(f64, f64)>>, Vec<_>) = (design.blocks().par_iter())
        .map_init(
            || BlockBuffer::new(p),
            |buffer, block| {
                let y = buffer.load(design, block, &spectrum.to_u);
                buffer.group(y.len());
                let (targets, _) = y.as_chunks::<LANES>();
                let mut out = Vec::new();
                for &chunk in chunks {
                    let mut state = ChunkSums::default();
                    kernel.chunk_rows((&buffer.groups, p, targets), chunk, &mut state);
                    out.extend(state.totals());
                }
                out.extend(ranks_only.block(&buffer.groups, p, y));
                (out, std::mem::take(&mut buffer.groups))
            },
        )
        .unzip();
    let mut totals = vec![(0.0, 0.0f64); chunks.len() * CANDIDATES + spectrum.rank];
    for partial in partials {
        for ((sum, high), (s, h)) in totals.iter_mut().zip(partial) {
            *sum += s;
            *high = nan_max(*high, h);
        }
    }
    (totals, groups)
}

/// The leave-one-out sums of the ridge `chunks` of `kernel` over the
/// blocks in order, each chunk dropped (its sums infinite) once every one
/// of its sums passes `bound`.
fn sums_below(
    design: &Stacked,
    (grouped, kernel): (&[Vec<Group>], &Kernel),
    (chunks, bound): (&[usize], f64),
) -> Vec<[f64; CANDIDATES]> {
    let p = design.columns();
    let mut totals = vec![[0.0; CANDIDATES]; chunks.len()];
    let mut live = vec![true; chunks.len()];
    for (block, block_groups) in design.blocks().iter().zip(grouped) {
        if !live.contains(&true) {
            break;
        }
        let (targets, _) = design.block_target(block).as_chunks::<LANES>();
        let groups = block_groups.chunks(CHECK_GROUPS * p).zip(targets.chunks(CHECK_GROUPS));
        let mut states = vec![ChunkSums::default(); chunks.len()];
        for (rows, y) in groups {
            for ((state, total), (alive, &chunk)) in states.iter_mut().zip(&totals).zip(live.iter_mut().zip(chunks)) {
                if !*alive {
                    continue;
                }
                kernel.chunk_rows((rows, p, y), chunk, state);
                let so_far = |c: usize| total[c] + state.sums[c].iter().sum::<f64>();
                *alive = !(0..CANDIDATES).all(|c| so_far(c) > bound);
            }
        }
        for ((total, state), alive) in totals.iter_mut().zip(&states).zip(&live) {
            if *alive {
                for (sum, (s, _)) in total.iter_mut().zip(state.totals()) {
                    *sum += s;
                }
            }
        }
    }
    (totals.into_iter().zip(live))
        .map(|(total, alive)| if alive { total } else { [f64::INFINITY; CANDIDATES] })
        .collect()
}

/// The ridge candidate (index into `weights`) with the least generalised
/// cross-validation, $n\,\mathrm{RSS}(λ)/(n - \mathrm{tr}\,H(λ))^2$ with
/// $\mathrm{RSS} = y^\top y - \sum_k (2 w_k - w_k^2) c_k^2$, $c = U^\top y$;
/// `None` where no candidate has a finite one.
fn gcv_minimum(design: &Stacked, spectrum: &Spectrum, weights: &[Vec<f64>]) -> Option<usize> {
    let rows = design.rows() as f64;
    let yy: f64 = design.target_pieces().flatten().map(|y| y * y).sum();
    let gcv = weights.iter().map(|w| {
        let explained: f64 = (w.iter().zip(&spectrum.uty))
            .map(|(w, c)| (2.0 * w - w * w) * c * c)
            .sum();
        let dof: f64 = w.iter().sum();
        let left = rows - dof;
        match left > 0.0 {
            true => rows * (yy - explained).max(0.0) / (left * left),
            false => f64::NAN,
        }
    });
    argmin(gcv)
}

/// The leave-one-out sums of every candidate over row blocks.
struct Kernel<'a> {
    /// Ridge weights $W$, packed by [`leave_one_out_press`].
    leverage_weights: &'a [[f64; CANDIDATES]],
    /// Ridge weights times $U^\top y$.
    fitted_weights: &'a [[f64; CANDIDATES]],
    /// Number of ridge candidates.
    ridge: usize,
    /// Track the largest leverage of every ridge candidate, not only of
    /// the smallest λs (see [`loo_kernel`]).
    track_all: bool,
    /// $U^\top y$ up to the rank: truncated SVD of rank r fits
    /// $\sum_{k<r} u_k c_k$ with leverage $\sum_{k<r} u_k^2$.
    uty: &'a [f64],
}

impl Kernel<'_> {
    /// Per candidate (ridge, then every rank), $\sum_i ((y_i - f_i)/(1 - h_i))^2$
    /// and $\max_i h_i$ over the rows of `groups` ([`BlockBuffer::group`],
    /// `p` columns) and `y`, with $f = U F$ and $h = (U \circ U) W$ formed on
    /// the fly: the fitted values and leverages never reach memory. AVX-512
    /// or AVX2 when the processor has them; every path uses fused
    /// multiply-adds in the same order, so they give the same bits.
    fn block(&self, groups: &[Group], p: usize, y: &[f64]) -> Vec<(f64, f64)> {
        let (targets, _) = y.as_chunks::<LANES>();
        let mut out = Vec::with_capacity(self.ridge.next_multiple_of(CANDIDATES) + self.uty.len());
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the processor supports AVX-512F and FMA, checked just above.
                unsafe { self.run_avx512(groups, p, targets, &mut out) };
                return out;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the processor supports AVX2 and FMA, checked just above.
                unsafe { self.run_avx2(groups, p, targets, &mut out) };
                return out;
            }
        }
        self.run(groups, p, targets, &mut out);
        out
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,fma")]
    unsafe fn run_avx512(&self, groups: &[Group], p: usize, y: &[[f64; LANES]], out: &mut Vec<(f64, f64)>) {
        self.run(groups, p, y, out);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(&self, groups: &[Group], p: usize, y: &[[f64; LANES]], out: &mut Vec<(f64, f64)>) {
        self.run(groups, p, y, out);
    }

    /// Adds the rows of `groups` and `y` to the sums `state` of ridge
    /// chunk `chunk` ([`loo_chunk`]), with the processor's widest vectors.
    fn chunk_rows(&self, (groups, p, y): (&[Group], usize, &[[f64; LANES]]), chunk: usize, state: &mut ChunkSums) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the processor supports AVX-512F and FMA, checked just above.
                unsafe { self.chunk_rows_avx512((groups, p, y), chunk, state) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the processor supports AVX2 and FMA, checked just above.
                unsafe { self.chunk_rows_avx2((groups, p, y), chunk, state) };
                return;
            }
        }
        self.chunk_rows_of((groups, p, y), chunk, state);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,fma")]
    unsafe fn chunk_rows_avx512(&self, rows: (&[Group], usize, &[[f64; LANES]]), chunk: usize, state: &mut ChunkSums) {
        self.chunk_rows_of(rows, chunk, state);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn chunk_rows_avx2(&self, rows: (&[Group], usize, &[[f64; LANES]]), chunk: usize, state: &mut ChunkSums) {
        self.chunk_rows_of(rows, chunk, state);
    }

    #[inline(always)]
    fn chunk_rows_of(&self, (groups, p, y): (&[Group], usize, &[[f64; LANES]]), chunk: usize, state: &mut ChunkSums) {
        let weights = chunk * p..(chunk + 1) * p;
        let pair = (&self.leverage_weights[weights.clone()], &self.fitted_weights[weights]);
        loo_chunk_tracking(self.track_all || chunk == 0, (groups, p, y), pair, state);
    }

    #[inline(always)]
    fn run(&self, groups: &[Group], p: usize, y: &[[f64; LANES]], out: &mut Vec<(f64, f64)>) {
        match self.track_all {
            true => loo_kernel::<true>(groups, p, y, [self.leverage_weights, self.fitted_weights], out),
            false => loo_kernel::<false>(groups, p, y, [self.leverage_weights, self.fitted_weights], out),
        }
        out.truncate(self.ridge);
        rank_kernel(groups, p, y, self.uty, out);
    }
}

/// Leave-one-out sums of the truncated SVDs of every rank up to `uty.len()`.
#[inline(always)]
fn rank_kernel(groups: &[Group], p: usize, y: &[[f64; LANES]], uty: &[f64], out: &mut Vec<(f64, f64)>) {
    let ranks = uty.len();
    let mut sums = vec![[0.0; LANES]; ranks];
    let mut worst = vec![[0.0f64; LANES]; ranks];
    for (group, target) in groups.chunks_exact(p).zip(y) {
        let mut leverage = [0.0; LANES];
        let mut fitted = [0.0; LANES];
        for ((([u, _], c), sum), high) in group.iter().zip(uty).zip(&mut sums).zip(&mut worst) {
            // Whole-register copies of the rank's sums, so the lanes vectorise.
            let (mut s, mut h) = (*sum, *high);
            for lane in 0..LANES {
                leverage[lane] = u[lane].mul_add(u[lane], leverage[lane]);
                fitted[lane] = u[lane].mul_add(*c, fitted[lane]);
                let e = (target[lane] - fitted[lane]) / (1.0 - leverage[lane]);
                s[lane] = e.mul_add(e, s[lane]);
                h[lane] = nan_max(h[lane], leverage[lane]);
            }
            (*sum, *high) = (s, h);
        }
    }
    out.extend(sums.iter().zip(&worst).map(|(s, w)| lane_totals(s, w)));
}

/// The ridge candidates' sums. The largest leverage is tracked only for
/// the first chunk of candidates, the smallest λ, unless `TRACK_ALL`: a
/// leverage $\sum_k u_k^2 \sigma_k^2/(\sigma_k^2 + \lambda)$ only falls as λ
/// grows, so when no leverage reaches 1 at the smallest λ none does at any.
#[inline(always)]
fn loo_kernel<const TRACK_ALL: bool>(
    groups: &[Group],
    p: usize,
    y: &[[f64; LANES]],
    [leverage_weights, fitted_weights]: [&[[f64; CANDIDATES]]; 2],
    out: &mut Vec<(f64, f64)>,
) {
    let chunks = leverage_weights.chunks_exact(p).zip(fitted_weights.chunks_exact(p));
    for (chunk, weights) in chunks.enumerate() {
        let mut state = ChunkSums::default();
        loo_chunk_tracking(TRACK_ALL || chunk == 0, (groups, p, y), weights, &mut state);
        out.extend(state.totals());
    }
}

/// One chunk of candidates' running leave-one-out sums and largest
/// leverages, lane by lane.
#[derive(Clone, Copy, Default)]
struct ChunkSums {
    sums: [[f64; LANES]; CANDIDATES],
    worst: [[f64; LANES]; CANDIDATES],
}

impl ChunkSums {
    /// Each candidate's sum and largest leverage.
    fn totals(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.sums.iter().zip(&self.worst).map(|(s, w)| lane_totals(s, w))
    }
}

/// [`loo_chunk`], tracking the largest leverage where `track`. The
/// tracking is a constant of each loop, so that the loop vectorises: with
/// it a value at run time, a release build sent the chunk's sums through
/// the stack one lane at a time.
#[inline(always)]
fn loo_chunk_tracking(
    track: bool,
    (groups, p, y): (&[Group], usize, &[[f64; LANES]]),
    weights: (&[[f64; CANDIDATES]], &[[f64; CANDIDATES]]),
    state: &mut ChunkSums,
) {
    match track {
        true => loo_chunk::<true>(groups, p, y, weights, state),
        false => loo_chunk::<false>(groups, p, y, weights, state),
    }
}

/// Adds the rows of `groups` and `y` to one chunk's sums in `state`
/// (its leverage weights and fitted weights), tracking the largest
/// leverage where `TRACK`. Rows added in pieces give the same bits as
/// rows added at once.
#[inline(always)]
fn loo_chunk<const TRACK: bool>(
    groups: &[Group],
    p: usize,
    y: &[[f64; LANES]],
    (w_chunk, f_chunk): (&[[f64; CANDIDATES]], &[[f64; CANDIDATES]]),
    state: &mut ChunkSums,
) {
    let ChunkSums { mut sums, mut worst } = *state;
    for (group, target) in groups.chunks_exact(p).zip(y) {
        let mut leverage = [[0.0; LANES]; CANDIDATES];
        let mut fitted = [[0.0; LANES]; CANDIDATES];
        for (([u, squared], w), f) in group.iter().zip(w_chunk).zip(f_chunk) {
            for c in 0..CANDIDATES {
                for lane in 0..LANES {
                    leverage[c][lane] = squared[lane].mul_add(w[c], leverage[c][lane]);
                    fitted[c][lane] = u[lane].mul_add(f[c], fitted[c][lane]);
                }
            }
        }
        for c in 0..CANDIDATES {
            for lane in 0..LANES {
                let h = leverage[c][lane];
                let e = (target[lane] - fitted[c][lane]) / (1.0 - h);
                sums[c][lane] = e.mul_add(e, sums[c][lane]);
                if TRACK {
                    worst[c][lane] = nan_max(worst[c][lane], h);
                }
            }
        }
    }
    *state = ChunkSums { sums, worst };
}

/// The larger of the two, NaN winning: a NaN leverage marks its candidate.
#[inline(always)]
fn nan_max(a: f64, b: f64) -> f64 {
    if b > a || b.is_nan() {
        b
    } else {
        a
    }
}

/// Sum of the lane sums and the largest lane leverage.
#[inline(always)]
fn lane_totals(sums: &[f64; LANES], worst: &[f64; LANES]) -> (f64, f64) {
    (sums.iter().sum(), worst.iter().fold(0.0, |a, &b| nan_max(a, b)))
}

impl FoldStatistics {
    fn zeros(p: usize) -> Self {
        FoldStatistics {
            gram: Mat::zeros(p, p),
            uty: vec![0.0; p],
            yy: 0.0,
        }
    }

    fn of_block(u: MatRef<'_, f64>, y: &[f64]) -> Self {
        FoldStatistics {
            gram: gram(u),
            uty: basis_times(u, y),
            yy: y.iter().map(|v| v * v).sum(),
        }
    }

    fn add(&mut self, other: &FoldStatistics) {
        self.gram += &other.gram;
        self.uty.iter_mut().zip(&other.uty).for_each(|(a, b)| *a += b);
        self.yy += other.yy;
    }

    /// The sum over folds, in fold order.
    fn total(folds: &[FoldStatistics], p: usize) -> FoldStatistics {
        let mut total = FoldStatistics::zeros(p);
        for fold in folds {
            total.add(fold);
        }
        total
    }

    /// The same statistics for the basis $U T$.
    fn in_basis(&self, t: &Mat<f64>) -> FoldStatistics {
        let p = t.ncols();
        let mut half = Mat::zeros(p, p);
        multiply(half.as_mut(), self.gram.as_ref(), t.as_ref());
        let mut gram = Mat::zeros(p, p);
        multiply(gram.as_mut(), t.transpose(), half.as_ref());
        FoldStatistics {
            gram,
            uty: uty_in_basis(t, &self.uty),
            yy: self.yy,
        }
    }
}

/// Held-out sum of squares over folds for every candidate (the ridge
/// grid's λs, then TSVD ranks 1..=rank), summed in fold order.
fn blocked_press(folds: &[FoldStatistics], spectrum: &Spectrum, grid: &[f64]) -> Vec<f64> {
    let mut total = vec![0.0; grid.len() + spectrum.rank];
    for fold in folds {
        for (sum, value) in total.iter_mut().zip(fold_held_out(fold, spectrum, grid)) {
            *sum += value;
        }
    }
    total
}

/// Held-out sum of squares of one fold for every candidate, by the Woodbury
/// form of the fit without the fold's rows, in the spectral basis:
/// $x = e_b + U_b S (I - S G_b S)^{-1} S U_b^\top e_b$ with $S = W^{1/2}$,
/// $W$ the candidate's spectral weights and $G_b = U_b^\top U_b$.
///
/// Only the components with a weight take part. With $c = S (I - S G_b S)^{-1} S p$,
/// $p = U_b^\top y_b - G_b W U^\top y$, the sum is
/// $\lVert y_b - U_b W U^\top y\rVert^2 + 2 p^\top c + c^\top G_b c$, and:
/// - for ridge, $W^{-1} = I + \lambda \Sigma^{-2}$, so
///   $c = (W^{-1} - G_b)^{-1} p = \Sigma (M + \lambda I)^{-1} \Sigma p$ with
///   $M = \Sigma (I - G_b) \Sigma$: one eigendecomposition of $M$ serves
///   every λ of the grid;
/// - for TSVD of rank r, $W = I$ on the first r components, and
///   $c = (I - G_b)_{rr}^{-1} p_r$: the Cholesky factor of a leading block is
///   the leading block of the whole factor, so one factorisation serves
///   every rank.
///
/// A candidate whose system is not positive definite (the fold carries all
/// of a component's information) scores infinity.
fn fold_held_out(fold: &FoldStatistics, spectrum: &Spectrum, grid: &[f64]) -> Vec<f64> {
    let active = spectrum.rank;
    let sigma = &spectrum.singular_values[..active];
    // Row-major copies: every product below is a run of slice dot products.
    let gram: Vec<f64> = (0..active * active)
        .map(|index| fold.gram[(index / active, index % active)])
        .collect();
    // The fit's residual on the fold, and the projection p, for the
    // shrunk coefficients of the first `shrunk.len()` components.
    let parts = |shrunk: &[f64]| -> (f64, Vec<f64>) {
        let n = shrunk.len();
        let gram_shrunk = times(&gram, active, shrunk);
        let residual_ss = fold.yy - 2.0 * dot(&fold.uty[..n], shrunk) + dot(shrunk, &gram_shrunk);
        let projected = (0..n).map(|k| fold.uty[k] - gram_shrunk[k]).collect();
        (residual_ss, projected)
    };
    let held_out = |residual_ss: f64, projected: &[f64], correction: &[f64]| -> f64 {
        finite_or_infinite(
            residual_ss + 2.0 * dot(projected, correction) + dot(correction, &times(&gram, active, correction)),
        )
    };

    let m = Mat::from_fn(active, active, |i, j| {
        sigma[i] * (f64::from(i == j) - gram[i * active + j]) * sigma[j]
    });
    let eigen = row_major_eigen(&m, active);
    let decomposed = eigen.is_some();
    let (vectors, vectors_t, values) = eigen.unwrap_or_default();
    let ridge = grid.iter().map(|&lambda| {
        let shrunk: Vec<f64> = (0..active)
            .map(|k| sigma[k].powi(2) / (sigma[k].powi(2) + lambda) * spectrum.uty[k])
            .collect();
        let (residual_ss, projected) = parts(&shrunk);
        if active == 0 {
            return held_out(residual_ss, &projected, &[]);
        }
        if !decomposed || values.iter().any(|v: &f64| v + lambda <= 0.0) {
            return f64::INFINITY;
        }
        let scaled: Vec<f64> = (0..active).map(|k| sigma[k] * projected[k]).collect();
        let rotated: Vec<f64> = times(&vectors_t, active, &scaled)
            .iter()
            .zip(&values)
            .map(|(r, v)| r / (v + lambda))
            .collect();
        let correction: Vec<f64> = times(&vectors, active, &rotated)
            .iter()
            .zip(sigma)
            .map(|(c, s)| s * c)
            .collect();
        held_out(residual_ss, &projected, &correction)
    });
    let mut scores: Vec<f64> = ridge.collect();

    let complement = Mat::from_fn(active, active, |i, j| f64::from(i == j) - gram[i * active + j]);
    let (lower, positive) = leading_cholesky(complement.as_ref());
    scores.extend((1..=active).map(|rank| {
        let (residual_ss, projected) = parts(&spectrum.uty[..rank]);
        if rank > positive {
            return f64::INFINITY;
        }
        let correction = cholesky_solve(lower.as_ref().get(..rank, ..rank), &projected);
        held_out(residual_ss, &projected, &correction)
    }));
    scores
}

/// $x$ with $L L^\top x = b$, `factor` the lower Cholesky factor $L$.
fn cholesky_solve(factor: MatRef<'_, f64>, b: &[f64]) -> Vec<f64> {
    let mut x = Mat::from_fn(b.len(), 1, |k, _| b[k]);
    faer::linalg::triangular_solve::solve_lower_triangular_in_place(factor, x.as_mut(), faer::Par::Seq);
    faer::linalg::triangular_solve::solve_upper_triangular_in_place(factor.transpose(), x.as_mut(), faer::Par::Seq);
    (0..b.len()).map(|k| x[(k, 0)]).collect()
}

/// `value`, or infinity where it is not finite (a score that cannot win).
fn finite_or_infinite(value: f64) -> f64 {
    if value.is_finite() {
        value
    } else {
        f64::INFINITY
    }
}

/// $a \cdot b$ over the shorter of the two.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>()
}

/// `matrix` (row-major, `columns` wide) times `v`, over its first
/// `v.len()` rows and columns.
fn times(matrix: &[f64], columns: usize, v: &[f64]) -> Vec<f64> {
    matrix
        .chunks_exact(columns)
        .take(v.len())
        .map(|row| dot(&row[..v.len()], v))
        .collect()
}

/// The eigendecomposition of the symmetric `active`×`active` matrix `m`:
/// its eigenvectors row-major (`vectors[k * active + i]` = Q[k, i]) and as
/// rows of Qᵀ, and its eigenvalues; `None` for an empty matrix or when the
/// decomposition fails.
fn row_major_eigen(m: &Mat<f64>, active: usize) -> Option<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let eigen = (active > 0)
        .then(|| m.self_adjoint_eigen(faer::Side::Lower).ok())
        .flatten()?;
    let (q, s) = (eigen.U(), eigen.S());
    let vectors: Vec<f64> = (0..active * active)
        .map(|index| q[(index / active, index % active)])
        .collect();
    let vectors_t = (0..active * active)
        .map(|index| q[(index % active, index / active)])
        .collect();
    Some((vectors, vectors_t, (0..active).map(|i| s[i]).collect()))
}

/// The lower Cholesky factor of the largest leading block of `a` that is
/// positive definite, and that block's size.
fn leading_cholesky(a: MatRef<'_, f64>) -> (Mat<f64>, usize) {
    let n = a.nrows();
    let size = match a.llt(faer::Side::Lower) {
        Ok(llt) => return (llt.L().to_owned(), n),
        Err(faer::linalg::solvers::LltError::NonPositivePivot { index }) => index,
    };
    match a.get(..size, ..size).llt(faer::Side::Lower) {
        Ok(llt) if size > 0 => (llt.L().to_owned(), size),
        _ => (Mat::zeros(0, 0), 0),
    }
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

/// Picks the regulariser; returns the solution (residual figures still to
/// fill in) and the spectral weights of the choice.
/// `press_computed` says whether the leave-one-out curve was computed
/// ([`curves_needed`]).
fn choose(
    spectrum: &Spectrum,
    (ridge, tsvd): (Vec<RidgePoint>, Vec<RankPoint>),
    (options, press_computed): (&SolveOptions, bool),
    samples: usize,
) -> Result<(Solution, Vec<f64>), SolveError> {
    let p = spectrum.singular_values.len();
    let condition_number = spectrum.singular_values[0] / spectrum.singular_values[p - 1];
    let lambda_by_press = match argmin(ridge.iter().map(|r| r.press)) {
        Some(i) => ridge[i].lambda,
        None if !press_computed => f64::NAN,
        None => return Err(SolveError::NoFiniteCriterion),
    };
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
    let (method, lambda, rank, reason) = regulariser(
        options,
        (condition_number, p),
        (&ridge, ridge_best, rank_best),
        criterion.describe(),
    );
    let weights: Vec<f64> = match (lambda, rank) {
        (Some(lambda), _) => candidate_weights(spectrum, &[lambda]).remove(0),
        (None, Some(rank)) => (0..p).map(|k| f64::from(u8::from(k < rank))).collect(),
        (None, None) => unreachable!("a method always sets λ or rank"),
    };
    let effective_dof: f64 = weights.iter().sum();
    let solution = Solution {
        coefficients: coefficients(spectrum, &weights),
        residual_rms: f64::NAN,
        standard_errors: Vec::new(),
        effective_dof,
        method,
        reason,
        lambda,
        rank,
        lambda_by_press,
        lambda_by_blocked_press,
        condition_number,
        decomposition: spectrum.decomposition,
        scaled_condition_number: spectrum.scaled_condition_number,
        singular_values: spectrum.singular_values.clone(),
        ridge_curve: ridge,
        tsvd_curve: tsvd,
        samples,
        fitted: Vec::new(),
        jackknife: Vec::new(),
    };
    Ok((solution, weights))
}

/// The regulariser `options` ask for, or the one the curves call for:
/// ridge at the minimum of the criterion `name` inside the λ grid,
/// truncated SVD when the design is too ill-conditioned for ridge
/// (`condition_number` of `p` columns) or the minimum lies at the grid's
/// edge. Gives the method, λ or rank, and why, in words.
fn regulariser(
    options: &SolveOptions,
    (condition_number, p): (f64, usize),
    (ridge, ridge_best, rank_best): (&[RidgePoint], usize, usize),
    name: &str,
) -> (Method, Option<f64>, Option<usize>, String) {
    match options.lambda {
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
            let reason = if ridge_best == 0 {
                format!("{name} minimum lies at the lower edge of the λ grid: the calibration pins every direction and needs no regularisation; truncated SVD by {name} keeps {} of {p} components", rank_best + 1)
            } else {
                format!("{name} minimum lies at the upper edge of the λ grid, so ridge cannot locate an optimum; truncated SVD rank chosen by {name}")
            };
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
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The processor-specific kernels and the portable one agree to the bit
    /// (on a processor without AVX2 both calls take the portable path).
    #[test]
    fn press_kernel_paths_give_the_same_bits() {
        let (rows, p) = (48, 5);
        let basis = Mat::from_fn(rows, p, |i, k| ((i * 7 + k * 3) as f64 * 0.37).sin() * 0.1);
        let y: Vec<f64> = (0..rows).map(|i| (i as f64 * 0.21).cos()).collect();
        let weights: Vec<[f64; CANDIDATES]> = (0..2 * p)
            .map(|i| std::array::from_fn(|c| 1.0 / (1.0 + (i + c) as f64)))
            .collect();
        let fitted: Vec<[f64; CANDIDATES]> = weights.iter().map(|w| w.map(|v| v * 0.7)).collect();
        let uty = [0.3, -0.2, 0.9, 0.1];
        let kernel = Kernel {
            leverage_weights: &weights,
            fitted_weights: &fitted,
            ridge: 7,
            track_all: true,
            uty: &uty,
        };
        let mut buffer = BlockBuffer {
            basis,
            groups: Vec::new(),
        };
        buffer.group(rows);
        let dispatched = kernel.block(&buffer.groups, p, &y);
        let mut portable = Vec::new();
        kernel.run(&buffer.groups, p, y.as_chunks::<LANES>().0, &mut portable);
        assert_eq!(dispatched.len(), 7 + uty.len());
        let bits = |v: &[(f64, f64)]| v.iter().map(|(a, b)| (a.to_bits(), b.to_bits())).collect::<Vec<_>>();
        assert_eq!(bits(&dispatched), bits(&portable));
    }

    /// Where only the minimum of leave-one-out PRESS matters (a score's
    /// fit), the candidates that can be the minimum are summed bit for bit
    /// as the whole curve sums them and the others are dropped; the
    /// solution is the same to the bit. Over designs several blocks long
    /// (clean and noisy targets, a full-rank and a rank-deficient design),
    /// some λs are dropped and every dropped one lies above the minimum.
    #[test]
    fn press_summed_to_its_minimum_chooses_what_the_whole_curve_chooses() {
        let rows = 3 * crate::numerics::stacked::BLOCK_ROWS + 700;
        let mut dropped = 0;
        for deficient in [false, true] {
            let columns = sine_columns(rows, deficient);
            for noise in [0.001, 0.3, 3.0] {
                let target: Vec<f64> = (0..rows)
                    .map(|i| {
                        (columns.iter().enumerate())
                            .map(|(k, c)| (k as f64 - 2.5) * c[i])
                            .sum::<f64>()
                            + noise * ((i * i) as f64 * 0.61).sin()
                    })
                    .collect();
                let design = Stacked::from_columns(
                    &columns,
                    &target,
                    &[rows / 4, rows / 4, rows / 4, rows - 3 * (rows / 4)],
                );
                let factor = decompose(&design, 4).unwrap();
                let spectrum = &factor.spectrum;
                let grid = lambda_grid(spectrum, &SolveOptions::default());
                let weights = candidate_weights(spectrum, &grid);
                let whole = leave_one_out_press(&design, spectrum, &weights);
                let least = whole
                    .iter()
                    .copied()
                    .filter(|v| v.is_finite())
                    .fold(f64::INFINITY, f64::min);
                let to_minimum = press_to_minimum(&design, spectrum, &weights).unwrap();
                for (l, (all, some)) in whole.iter().zip(&to_minimum).enumerate() {
                    match some.is_finite() {
                        true => assert_eq!(all.to_bits(), some.to_bits(), "candidate {l}"),
                        false => {
                            assert!(*all > least, "candidate {l}: {all} dropped, the minimum {least}");
                            dropped += 1;
                        }
                    }
                }
                let solve = |figures| SolveOptions {
                    criterion: Criterion::Press,
                    figures,
                    ..SolveOptions::default()
                };
                let (choice, all) = (
                    solve_stacked(&design, &solve(Figures::Choice)).unwrap(),
                    solve_stacked(&design, &solve(Figures::All)).unwrap(),
                );
                let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(choice.lambda.map(f64::to_bits), all.lambda.map(f64::to_bits));
                assert_eq!(choice.rank, all.rank);
                assert_eq!(bits(&choice.coefficients), bits(&all.coefficients));
                assert_eq!(bits(&choice.fitted), bits(&all.fitted));
            }
        }
        assert!(dropped > 50, "{dropped} candidates dropped");
    }

    /// The per-candidate Woodbury solve the eigen and leading-Cholesky forms
    /// replace: $x = e_b + U_b S (I - S G_b S)^{-1} S U_b^\top e_b$, one
    /// Cholesky per candidate and fold.
    fn held_out_by_candidate(fold: &FoldStatistics, uty: &[f64], w: &[f64]) -> f64 {
        let p = w.len();
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let times_gram =
            |v: &[f64]| -> Vec<f64> { (0..p).map(|i| (0..p).map(|k| fold.gram[(i, k)] * v[k]).sum()).collect() };
        let shrunk: Vec<f64> = (0..p).map(|k| w[k] * uty[k]).collect();
        let gram_shrunk = times_gram(&shrunk);
        let residual_ss = fold.yy - 2.0 * dot(&fold.uty, &shrunk) + dot(&shrunk, &gram_shrunk);
        let projected: Vec<f64> = (0..p).map(|k| fold.uty[k] - gram_shrunk[k]).collect();
        let root: Vec<f64> = w.iter().map(|v| v.sqrt()).collect();
        let k_matrix = Mat::from_fn(p, p, |i, j| f64::from(i == j) - root[i] * fold.gram[(i, j)] * root[j]);
        let rhs: Vec<f64> = (0..p).map(|k| root[k] * projected[k]).collect();
        let Some(z) = crate::numerics::linalg::solve_spd(k_matrix.as_ref(), &rhs) else {
            return f64::INFINITY;
        };
        let correction: Vec<f64> = (0..p).map(|k| root[k] * z[k]).collect();
        residual_ss + 2.0 * dot(&projected, &correction) + dot(&correction, &times_gram(&correction))
    }

    /// Six sine columns of `rows` rows, the last a combination of two
    /// others when `deficient`.
    fn sine_columns(rows: usize, deficient: bool) -> Vec<Vec<f64>> {
        let mut columns: Vec<Vec<f64>> = (0..6)
            .map(|k| {
                (0..rows)
                    .map(|i| ((i * (2 * k + 3)) as f64 * 0.173 + k as f64).sin())
                    .collect()
            })
            .collect();
        if deficient {
            columns[5] = columns[0].iter().zip(&columns[2]).map(|(a, b)| a - 2.0 * b).collect();
        }
        columns
    }

    #[test]
    fn a_kept_decomposition_solves_another_target_bit_for_bit() {
        let rows = 300;
        // Well conditioned (CholeskyQR2) and rank-deficient (Householder).
        for deficient in [false, true] {
            let columns = sine_columns(rows, deficient);
            let target = |shift: f64| -> Vec<f64> {
                (0..rows)
                    .map(|i| {
                        (columns.iter().enumerate())
                            .map(|(k, c)| (k as f64 - shift) * c[i])
                            .sum::<f64>()
                            + 0.05 * (i as f64 * 1.7).cos()
                    })
                    .collect()
            };
            let folds = [70, 80, 90, 60];
            let first = Stacked::from_columns(&columns, &target(2.0), &folds);
            let second = Stacked::from_columns(&columns, &target(-1.0), &folds);
            for options in [
                SolveOptions::default(),
                SolveOptions {
                    criterion: Criterion::BlockedPress,
                    figures: Figures::All,
                    ..SolveOptions::default()
                },
            ] {
                let (_, factor) = solve_keeping(&first, &options).unwrap();
                assert_eq!(factor.to_final.is_none(), deficient);
                let again = solve_again(&second, &factor, &options).unwrap();
                let afresh = solve_stacked(&second, &options).unwrap();
                let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&again.coefficients), bits(&afresh.coefficients));
                assert_eq!(bits(&again.fitted), bits(&afresh.fitted));
                assert_eq!(again.lambda.map(f64::to_bits), afresh.lambda.map(f64::to_bits));
                assert_eq!(bits(&again.standard_errors), bits(&afresh.standard_errors));
                assert_eq!(again.jackknife.len(), afresh.jackknife.len());
                // Another target: another fit.
                let (kept, _) = solve_keeping(&first, &options).unwrap();
                assert!((kept.coefficients[1] - again.coefficients[1]).abs() > 1.0);
            }
        }
    }

    /// Every ridge λ and TSVD rank of the blocked PRESS equals the
    /// per-candidate solve, on a full-rank design and on one with a column
    /// that repeats a combination of two others.
    #[test]
    fn blocked_press_forms_equal_the_per_candidate_solve() {
        let (rows, p) = (90, 6);
        for deficient in [false, true] {
            let columns = sine_columns(rows, deficient);
            let y: Vec<f64> = (0..rows)
                .map(|i| {
                    columns
                        .iter()
                        .enumerate()
                        .map(|(k, c)| (k as f64 - 2.0) * c[i])
                        .sum::<f64>()
                        + 0.05 * (i as f64 * 1.7).cos()
                })
                .collect();
            let design = Stacked::from_columns(&columns, &y, &[20, 25, 30, 15]);
            let DesignFactor {
                spectrum,
                statistics: folds,
                ..
            } = decompose(&design, 4).unwrap();
            assert_eq!(spectrum.rank, if deficient { p - 1 } else { p });
            let grid = lambda_grid(&spectrum, &SolveOptions::default());
            let weights = candidate_weights(&spectrum, &grid);
            let fast = blocked_press(&folds, &spectrum, &grid);
            assert_eq!(fast.len(), weights.len());
            for (candidate, w) in weights.iter().enumerate() {
                let reference: f64 = folds.iter().map(|f| held_out_by_candidate(f, &spectrum.uty, w)).sum();
                let relative = (fast[candidate] - reference).abs() / reference;
                assert!(
                    relative < 1e-8,
                    "deficient {deficient}, candidate {candidate}: {} against {reference}",
                    fast[candidate]
                );
            }
        }
    }

    /// The deviations equal the cluster-robust CR2 formula computed densely,
    /// $(X^\top X)^{-1} X_f^\top (I - H_{ff})^{-1/2} e_f$, on a least-squares
    /// fit (λ negligible), to 1e-7 of the coefficients; and each fold's
    /// deviation is smaller than its refit difference (the plain jackknife)
    /// wherever the fold has leverage.
    /// A solve for a held-out score ([`Figures::Choice`]) picks the same λ
    /// or rank and the same coefficients, to the bit, as the full solve,
    /// by either criterion and with λ fixed; it leaves out the other
    /// curve, the standard errors, the jackknife and the leave-one-out
    /// values of λs that cannot be the minimum.
    #[test]
    fn a_choice_only_solve_keeps_the_choice_to_the_bit() {
        let (p, lengths) = (5, [40usize, 35, 50, 45]);
        let rows: usize = lengths.iter().sum();
        let columns: Vec<Vec<f64>> = (0..p)
            .map(|k| {
                (0..rows)
                    .map(|i| ((i * (k + 2)) as f64 * 0.29 + k as f64).sin() + 0.3 * (i as f64 * 0.011).cos())
                    .collect()
            })
            .collect();
        let y: Vec<f64> = (0..rows)
            .map(|i| (0..p).map(|k| (k as f64 - 2.0) * columns[k][i]).sum::<f64>() + 0.4 * (i as f64 * 1.3).sin())
            .collect();
        let design = Stacked::from_columns(&columns, &y, &lengths);
        for (criterion, lambda) in [
            (Criterion::BlockedPress, LambdaChoice::Select),
            (Criterion::Press, LambdaChoice::Select),
            (Criterion::BlockedPress, LambdaChoice::Fixed(1e-3)),
        ] {
            let all = SolveOptions {
                criterion,
                lambda,
                ..SolveOptions::default()
            };
            let full = solve_stacked(&design, &all).unwrap();
            let lean = solve_stacked(
                &design,
                &SolveOptions {
                    figures: Figures::Choice,
                    ..all.clone()
                },
            )
            .unwrap();
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&lean.coefficients),
                bits(&full.coefficients),
                "{criterion:?} {lambda:?}"
            );
            assert_eq!(
                (lean.lambda, lean.rank),
                (full.lambda, full.rank),
                "{criterion:?} {lambda:?}"
            );
            assert_eq!(lean.residual_rms.to_bits(), full.residual_rms.to_bits());
            assert_eq!(full.standard_errors.len(), p);
            assert_eq!(full.jackknife.len(), lengths.len());
            assert!(lean.standard_errors.is_empty() && lean.jackknife.is_empty());
            let blocked = lean.ridge_curve.iter().all(|r| r.blocked_press.is_some());
            // Leave-one-out PRESS where it is the criterion: the value of
            // every λ that can be its minimum, as the full curve has it;
            // infinity, above that minimum, for the others.
            let least = (full.ridge_curve.iter().map(|r| r.press)).fold(f64::INFINITY, f64::min);
            let press =
                (lean.ridge_curve.iter().zip(&full.ridge_curve)).all(|(lean, full)| match lean.press.is_finite() {
                    true => lean.press.to_bits() == full.press.to_bits(),
                    false => lean.press == f64::INFINITY && full.press > least,
                });
            match (criterion, lambda) {
                (Criterion::BlockedPress, LambdaChoice::Select) => {
                    assert!(blocked && lean.ridge_curve.iter().all(|r| r.press.is_nan()));
                    assert!(lean.lambda_by_press.is_nan());
                }
                _ => {
                    assert!(press && lean.ridge_curve.iter().all(|r| r.blocked_press.is_none()));
                    assert_eq!(lean.lambda_by_press.to_bits(), full.lambda_by_press.to_bits());
                }
            }
        }
    }

    #[test]
    fn the_jackknife_is_the_bias_reduced_cluster_formula() {
        let (p, lengths) = (4, [20usize, 25, 30, 15]);
        let rows: usize = lengths.iter().sum();
        let columns: Vec<Vec<f64>> = (0..p)
            .map(|k| {
                (0..rows)
                    .map(|i| ((i * (k + 2)) as f64 * 0.31 + k as f64).sin())
                    .collect()
            })
            .collect();
        let y: Vec<f64> = (0..rows)
            .map(|i| (0..p).map(|k| (k as f64 + 1.0) * columns[k][i]).sum::<f64>() + 0.05 * (i as f64 * 1.7).cos())
            .collect();
        let options = SolveOptions {
            lambda: LambdaChoice::Fixed(1e-14),
            ..SolveOptions::default()
        };
        let design = Stacked::from_columns(&columns, &y, &lengths);
        let solution = solve_stacked(&design, &options).unwrap();
        assert_eq!(solution.jackknife.len(), lengths.len());
        let x = Mat::from_fn(rows, p, |i, k| columns[k][i]);
        use faer::linalg::solvers::Solve;
        let inverse = (x.transpose() * &x)
            .llt(faer::Side::Lower)
            .unwrap()
            .solve(Mat::<f64>::identity(p, p));
        let beta = &inverse * x.transpose() * Mat::from_fn(rows, 1, |i, _| y[i]);
        let mut start = 0;
        for (fold, &length) in lengths.iter().enumerate() {
            let xf = x.subrows(start, length);
            let residual = Mat::from_fn(length, 1, |i, _| {
                y[start + i] - (0..p).map(|k| xf[(i, k)] * beta[(k, 0)]).sum::<f64>()
            });
            let kept = Mat::<f64>::identity(length, length) - xf * &inverse * xf.transpose();
            let eigen = kept.self_adjoint_eigen(faer::Side::Lower).unwrap();
            let (q, values) = (eigen.U(), eigen.S());
            let root = Mat::from_fn(length, length, |i, j| {
                (0..length)
                    .map(|m| q[(i, m)] * q[(j, m)] / values[m].sqrt())
                    .sum::<f64>()
            });
            let expected = &inverse * xf.transpose() * &root * &residual;
            let refit = &inverse * xf.transpose() * kept.llt(faer::Side::Lower).unwrap().solve(&residual);
            for j in 0..p {
                let got = solution.jackknife[fold][j];
                assert!(
                    (got - expected[(j, 0)]).abs() < 1e-7 * (1.0 + beta[(j, 0)].abs()),
                    "fold {fold}, coefficient {j}: {got} against {}",
                    expected[(j, 0)]
                );
            }
            let norm = |v: &dyn Fn(usize) -> f64| (0..p).map(|j| v(j) * v(j)).sum::<f64>();
            assert!(
                norm(&|j| solution.jackknife[fold][j]) < norm(&|j| refit[(j, 0)]),
                "fold {fold}"
            );
            start += length;
        }
    }
}
