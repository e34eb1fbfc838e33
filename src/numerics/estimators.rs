//! The estimator family set side by side: least squares, ridge, truncated
//! SVD, damped TSVD, total least squares and truncated TLS, each scored
//! held out on the same folds.
//!
//! Every estimator works from the R factor of the augmented design
//! $Z = [A \mid y]$ ($n \times q$, $q = p + 1$), never from normal
//! equations. With $R = \begin{pmatrix} R_{11} & r_{12} \\ 0 & r_{22}
//! \end{pmatrix}$, $R_{11}$ is the R factor of A and $r_{12} = Q_1^\top y$,
//! so with $R_{11} = U \Sigma V^\top$ and $c = U^\top r_{12}$ the
//! estimators of y on A are spectral filters,
//! $\beta = V\,\mathrm{diag}(w_k/\sigma_k)\,c$ (Hansen 1998, ch. 4):
//! - least squares, $w_k = 1$;
//! - ridge (Tikhonov), $w_k = \sigma_k^2/(\sigma_k^2 + \lambda)$;
//! - truncated SVD of rank r, $w_k = \mathbb{1}(k < r)$;
//! - damped TSVD, $w_k = \mathbb{1}(k < r)\,\sigma_k^2/(\sigma_k^2 + \lambda)$
//!   (Hansen 1998, §4.2: the truncation removes the directions the data do
//!   not pin, the damping shrinks the weakly pinned ones kept).
//!
//! Total least squares (Golub & Van Loan 1980) allows errors in A as well
//! as in y: with $Z = \tilde U \tilde\Sigma \tilde V^\top$ it takes the
//! right singular vector of Z's smallest singular value,
//! $\beta = -\tilde v_{1:p,q} / \tilde v_{q,q}$. Truncated TLS of rank r
//! (Fierro, Golub, Hansen & O'Leary 1997) keeps the r largest:
//! $\beta = -\tilde V_{12} \tilde V_{22}^\top / \lVert \tilde V_{22}
//! \rVert^2$ with $\tilde V_{12} = \tilde V_{1:p,\,r+1:q}$,
//! $\tilde V_{22} = \tilde V_{q,\,r+1:q}$; rank p is plain TLS.
//!
//! TLS assumes the errors of every column of Z have one variance, so the
//! family works on Z with each column scaled to unit norm over the
//! training rows, and maps the coefficients back: a column's noise must be
//! comparable to its spread for TLS to apply as stated. Least squares and
//! the truncation are unchanged by the scaling; ridge's λ and the damped
//! TSVD's λ act on the scaled columns.
//!
//! Held out: each fold (a heading's calibration windows) is predicted by
//! an estimator fitted on the other folds, its squared residual
//! $\lVert R_b\,[\beta; -1] \rVert^2$ from the fold's own R factor $R_b$;
//! the training R comes from the other folds' R factors stacked
//! ([`crate::numerics::linalg::combine_r`]). A rank, a λ, or both are
//! chosen by that held-out figure.

use faer::Mat;
use serde::Serialize;

use crate::numerics::linalg::{combine_r, small_svd, tall_skinny_r};

/// One estimator with its setting.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "estimator", rename_all = "snake_case")]
pub enum Estimator {
    /// Ordinary least squares.
    Ls,
    /// Ridge with λ on the column-scaled design.
    Ridge {
        /// λ.
        lambda: f64,
    },
    /// Truncated SVD.
    Tsvd {
        /// Singular values kept.
        rank: usize,
    },
    /// Damped (Tikhonov-regularised) truncated SVD.
    DampedTsvd {
        /// Singular values kept.
        rank: usize,
        /// λ on the kept ones.
        lambda: f64,
    },
    /// Total least squares.
    Tls,
    /// Truncated total least squares.
    Ttls {
        /// Singular values of Z kept.
        rank: usize,
    },
}

impl Estimator {
    /// The estimator and its setting, for people.
    pub fn describe(&self) -> String {
        match *self {
            Estimator::Ls => "least squares".into(),
            Estimator::Ridge { lambda } => format!("ridge, λ {lambda:.2e} on unit-norm columns"),
            Estimator::Tsvd { rank } => format!("truncated SVD, rank {rank}"),
            Estimator::DampedTsvd { rank, lambda } => {
                format!("damped truncated SVD, rank {rank}, λ {lambda:.2e} on unit-norm columns")
            }
            Estimator::Tls => "total least squares".into(),
            Estimator::Ttls { rank } => format!("truncated total least squares, rank {rank}"),
        }
    }
}

/// The R factor of the augmented design of some rows: what a fit or a
/// held-out score needs of them.
#[derive(Debug, Clone)]
pub struct Factor {
    /// Upper-triangular, q × q.
    r: Mat<f64>,
    /// Rows it stands for.
    rows: usize,
}

impl Factor {
    /// The factor of regressor `columns` and target `y` (equal lengths).
    pub fn of_columns(columns: &[&[f64]], y: &[f64]) -> Factor {
        let mut all: Vec<&[f64]> = columns.to_vec();
        all.push(y);
        Factor {
            r: tall_skinny_r(&all),
            rows: y.len(),
        }
    }

    /// The factor of every row of `parts` together.
    pub fn combine<'a>(parts: impl IntoIterator<Item = &'a Factor>) -> Option<Factor> {
        let parts: Vec<&Factor> = parts.into_iter().collect();
        let q = parts.first()?.r.ncols();
        let rs: Vec<Mat<f64>> = parts.iter().map(|f| f.r.clone()).collect();
        Some(Factor {
            r: combine_r(&rs, q),
            rows: parts.iter().map(|f| f.rows).sum(),
        })
    }

    /// Regressors.
    pub fn regressors(&self) -> usize {
        self.r.ncols() - 1
    }

    /// $\lVert y - A\beta \rVert^2$ over this factor's rows.
    pub fn sum_of_squares(&self, beta: &[f64]) -> f64 {
        let q = self.r.ncols();
        let x: Vec<f64> = beta.iter().copied().chain([-1.0]).collect();
        (0..q)
            .map(|i| (i..q).map(|j| self.r[(i, j)] * x[j]).sum::<f64>().powi(2))
            .sum()
    }
}

/// The decompositions every estimator of one training set reads.
#[derive(Debug, Clone)]
pub struct Decomposed {
    /// Column norms of A, then of y.
    scale: Vec<f64>,
    /// Singular values of the scaled A, non-increasing.
    sigma: Vec<f64>,
    /// Right singular vectors of the scaled A.
    v: Mat<f64>,
    /// $U^\top r_{12}$ of the scaled problem.
    c: Vec<f64>,
    /// Right singular vectors of the scaled Z.
    v_z: Mat<f64>,
    /// Smallest singular value of the scaled Z.
    sigma_z_last: f64,
}

impl Decomposed {
    /// Scales `training`'s columns to unit norm and takes the SVDs of A and
    /// of Z; `None` when a column is all zero or an SVD fails.
    pub fn new(training: &Factor) -> Option<Decomposed> {
        let q = training.r.ncols();
        let p = q - 1;
        let scale: Vec<f64> = (0..q)
            .map(|j| (0..=j).map(|i| training.r[(i, j)].powi(2)).sum::<f64>().sqrt())
            .collect();
        if scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return None;
        }
        let scaled = Mat::from_fn(q, q, |i, j| training.r[(i, j)] / scale[j]);
        let r11 = Mat::from_fn(p, p, |i, j| scaled[(i, j)]);
        let (u, sigma, v) = small_svd(r11.as_ref())?;
        let c = (0..p)
            .map(|k| (0..p).map(|i| u[(i, k)] * scaled[(i, p)]).sum())
            .collect();
        let (_, sigma_z, v_z) = small_svd(scaled.as_ref())?;
        Some(Decomposed {
            sigma_z_last: sigma_z.last().copied().unwrap_or(0.0),
            scale,
            sigma,
            v,
            c,
            v_z,
        })
    }

    /// Regressors.
    pub fn regressors(&self) -> usize {
        self.sigma.len()
    }

    /// Singular values of the column-scaled A, non-increasing.
    pub fn singular_values(&self) -> &[f64] {
        &self.sigma
    }

    /// The coefficients of `estimator` on the unscaled regressors; `None`
    /// for a rank out of range, a negative λ, or TLS whose last singular
    /// vector has no y component (y uncorrelated with the rest).
    pub fn coefficients(&self, estimator: Estimator) -> Option<Vec<f64>> {
        let p = self.regressors();
        let filter = |weight: &dyn Fn(usize, f64) -> f64| -> Vec<f64> {
            let mut scaled = vec![0.0; p];
            for k in 0..p {
                let w = weight(k, self.sigma[k]);
                if w == 0.0 || self.sigma[k] <= 0.0 {
                    continue;
                }
                let factor = w * self.c[k] / self.sigma[k];
                for (j, b) in scaled.iter_mut().enumerate() {
                    *b += self.v[(j, k)] * factor;
                }
            }
            scaled
        };
        let scaled = match estimator {
            Estimator::Ls => filter(&|_, _| 1.0),
            Estimator::Ridge { lambda } if lambda >= 0.0 => filter(&|_, s| s * s / (s * s + lambda)),
            Estimator::Tsvd { rank } if (1..=p).contains(&rank) => filter(&|k, _| f64::from(k < rank)),
            Estimator::DampedTsvd { rank, lambda } if (1..=p).contains(&rank) && lambda >= 0.0 => {
                filter(&|k, s| if k < rank { s * s / (s * s + lambda) } else { 0.0 })
            }
            Estimator::Tls => self.truncated_tls(p)?,
            Estimator::Ttls { rank } if (1..=p).contains(&rank) => self.truncated_tls(rank)?,
            _ => return None,
        };
        // A_s β_s ≈ y_s with A_s = A S_A and y_s = y / s_y: β = S_A β_s s_y.
        let y_scale = self.scale[p];
        Some(scaled.iter().zip(&self.scale).map(|(b, s)| b * y_scale / s).collect())
    }

    /// One-sigma standard error of each coefficient of `estimator` when
    /// y carries white noise of standard deviation `noise`, to first order:
    /// a spectral filter $\beta_s = V\,\mathrm{diag}(w_k/\sigma_k)\,c$ has
    /// $\mathrm{se}_j = (\text{noise}/s_j)\sqrt{\sum_k v_{jk}^2 w_k^2/\sigma_k^2}$
    /// with $s_j$ column j's scale. TLS is the filter
    /// $w_k = \sigma_k^2/(\sigma_k^2 - \tilde\sigma_q^2)$ (Fierro et al.
    /// 1997), its noise inflated by $\sqrt{1 + \lVert\beta_s\rVert^2}$ for
    /// the errors it allows in A (Van Huffel & Vandewalle 1991, §8); truncated
    /// TLS of rank r is taken as the TSVD filter of rank r, its first-order
    /// equivalent when the dropped singular values are well separated.
    /// `None` where [`Self::coefficients`] is.
    pub fn standard_errors(&self, estimator: Estimator, noise: f64) -> Option<Vec<f64>> {
        let p = self.regressors();
        let beta = self.coefficients(estimator)?;
        let smallest_z = self.sigma_z_last;
        let (weight, inflation): (Box<dyn Fn(usize, f64) -> f64>, f64) = match estimator {
            Estimator::Ls => (Box::new(|_, _| 1.0), 1.0),
            Estimator::Ridge { lambda } => (Box::new(move |_, s| s * s / (s * s + lambda)), 1.0),
            Estimator::Tsvd { rank } | Estimator::Ttls { rank } => (Box::new(move |k, _| f64::from(k < rank)), 1.0),
            Estimator::DampedTsvd { rank, lambda } => (
                Box::new(move |k, s| if k < rank { s * s / (s * s + lambda) } else { 0.0 }),
                1.0,
            ),
            Estimator::Tls => {
                let scaled_norm: f64 = (beta.iter().zip(&self.scale))
                    .map(|(b, s)| (b * s / self.scale[p]).powi(2))
                    .sum();
                (
                    Box::new(move |_, s| s * s / (s * s - smallest_z * smallest_z)),
                    (1.0 + scaled_norm).sqrt(),
                )
            }
        };
        Some(
            (0..p)
                .map(|j| {
                    let gain: f64 = (0..p)
                        .filter(|&k| self.sigma[k] > 0.0)
                        .map(|k| (self.v[(j, k)] * weight(k, self.sigma[k]) / self.sigma[k]).powi(2))
                        .sum();
                    noise * inflation * gain.sqrt() / self.scale[j]
                })
                .collect(),
        )
    }

    /// $-\tilde V_{12} \tilde V_{22}^\top / \lVert \tilde V_{22} \rVert^2$
    /// of the scaled Z, keeping `rank` singular values.
    fn truncated_tls(&self, rank: usize) -> Option<Vec<f64>> {
        let p = self.regressors();
        let q = p + 1;
        let v22_norm: f64 = (rank..q).map(|k| self.v_z[(p, k)].powi(2)).sum();
        if v22_norm.is_nan() || v22_norm <= f64::EPSILON {
            return None;
        }
        Some(
            (0..p)
                .map(|j| -(rank..q).map(|k| self.v_z[(j, k)] * self.v_z[(p, k)]).sum::<f64>() / v22_norm)
                .collect(),
        )
    }
}

/// A family of estimators, whose setting (rank, λ) is chosen held out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Family {
    /// Least squares.
    Ls,
    /// Ridge, λ on a grid.
    Ridge,
    /// Truncated SVD, every rank.
    Tsvd,
    /// Damped TSVD, every rank and λ on a grid.
    DampedTsvd,
    /// Total least squares.
    Tls,
    /// Truncated TLS, every rank.
    Ttls,
}

impl Family {
    /// The family's name as a reader knows it.
    pub fn name(self) -> &'static str {
        match self {
            Family::Ls => "least squares",
            Family::Ridge => "ridge",
            Family::Tsvd => "truncated SVD",
            Family::DampedTsvd => "damped truncated SVD",
            Family::Tls => "total least squares",
            Family::Ttls => "truncated total least squares",
        }
    }

    /// Every family, in the order a table lists them.
    pub const ALL: [Family; 6] = [
        Family::Ls,
        Family::Ridge,
        Family::Tsvd,
        Family::DampedTsvd,
        Family::Tls,
        Family::Ttls,
    ];

    /// The candidates of this family for `p` regressors with scaled
    /// singular values `sigma`: λ spans 1e-12 to 1 of σ₁², 4 per decade.
    fn candidates(self, sigma: &[f64]) -> Vec<Estimator> {
        let p = sigma.len();
        let top = sigma.first().map_or(1.0, |s| s * s);
        let lambdas: Vec<f64> = (0..=48).map(|k| top * 10f64.powf(-12.0 + k as f64 / 4.0)).collect();
        match self {
            Family::Ls => vec![Estimator::Ls],
            Family::Tls => vec![Estimator::Tls],
            Family::Ridge => lambdas.iter().map(|&lambda| Estimator::Ridge { lambda }).collect(),
            Family::Tsvd => (1..=p).map(|rank| Estimator::Tsvd { rank }).collect(),
            Family::Ttls => (1..=p).map(|rank| Estimator::Ttls { rank }).collect(),
            Family::DampedTsvd => (1..=p)
                .flat_map(|rank| {
                    lambdas
                        .iter()
                        .map(move |&lambda| Estimator::DampedTsvd { rank, lambda })
                })
                .collect(),
        }
    }
}

/// The best of one family, held out.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Scored {
    /// The family.
    pub family: Family,
    /// Its best setting.
    pub estimator: Estimator,
    /// Held-out RMS of the residual over every fold, in y's units.
    pub heldout_rms: f64,
    /// Coefficients of that setting fitted on every fold.
    pub coefficients: Vec<f64>,
}

/// The estimator a model is fitted with (`[fit] solver`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Solver {
    /// Ridge with λ by PRESS over the windows, truncated SVD when the
    /// design is too ill-conditioned ([`crate::numerics::solve`]).
    #[default]
    Ridge,
    /// Truncated SVD, rank chosen leaving one heading out.
    Tsvd,
    /// Ordinary least squares.
    Ls,
    /// Total least squares.
    Tls,
    /// Truncated TLS, rank chosen leaving one heading out.
    Ttls,
    /// Damped TSVD, rank and λ chosen leaving one heading out.
    DampedTsvd,
    /// The family with the least held-out RMS, leaving one heading out.
    Auto,
}

impl Solver {
    /// Every solver, as `[fit] solver` names them.
    pub const ALL: [Solver; 7] = [
        Solver::Ridge,
        Solver::Tsvd,
        Solver::Ls,
        Solver::Tls,
        Solver::Ttls,
        Solver::DampedTsvd,
        Solver::Auto,
    ];

    /// The name `[fit] solver` takes.
    pub fn name(self) -> &'static str {
        match self {
            Solver::Ridge => "ridge",
            Solver::Tsvd => "tsvd",
            Solver::Ls => "ls",
            Solver::Tls => "tls",
            Solver::Ttls => "ttls",
            Solver::DampedTsvd => "damped_tsvd",
            Solver::Auto => "auto",
        }
    }

    /// The solver named `name`.
    pub fn from_name(name: &str) -> Option<Solver> {
        Solver::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The families this solver chooses among on heading folds; empty for
    /// ridge, which selects λ by PRESS over the windows instead.
    pub fn families(self) -> &'static [Family] {
        match self {
            Solver::Ridge => &[],
            Solver::Tsvd => &[Family::Tsvd],
            Solver::Ls => &[Family::Ls],
            Solver::Tls => &[Family::Tls],
            Solver::Ttls => &[Family::Ttls],
            Solver::DampedTsvd => &[Family::DampedTsvd],
            Solver::Auto => &Family::ALL,
        }
    }
}

/// Scores every family on `folds`, each fold predicted by a fit on the
/// others; at least two folds. A family none of whose candidates can be
/// fitted on every split is left out.
pub fn compare(folds: &[Factor]) -> Vec<Scored> {
    compare_families(folds, &Family::ALL)
}

/// [`compare`] restricted to `families`, in their order.
pub fn compare_families(folds: &[Factor], families: &[Family]) -> Vec<Scored> {
    if folds.len() < 2 {
        return Vec::new();
    }
    let splits: Vec<(Decomposed, &Factor)> = (0..folds.len())
        .filter_map(|b| {
            let training = Factor::combine(folds.iter().enumerate().filter(|(i, _)| *i != b).map(|(_, f)| f))?;
            Some((Decomposed::new(&training)?, &folds[b]))
        })
        .collect();
    let Some(all) = Factor::combine(folds).and_then(|f| Decomposed::new(&f)) else {
        return Vec::new();
    };
    if splits.len() != folds.len() {
        return Vec::new();
    }
    let rows: usize = folds.iter().map(|f| f.rows).sum();
    families
        .iter()
        .filter_map(|&family| {
            let mut best: Option<(f64, Estimator)> = None;
            for estimator in family.candidates(all.singular_values()) {
                let total: Option<f64> = splits
                    .iter()
                    .map(|(fit, fold)| Some(fold.sum_of_squares(&fit.coefficients(estimator)?)))
                    .sum();
                let Some(total) = total.filter(|t| t.is_finite()) else {
                    continue;
                };
                let rms = (total / rows.max(1) as f64).sqrt();
                // Ties keep the earlier, more regularised or lower-rank, setting.
                if best.is_none_or(|(b, _)| rms < b) {
                    best = Some((rms, estimator));
                }
            }
            let (heldout_rms, estimator) = best?;
            Some(Scored {
                family,
                estimator,
                heldout_rms,
                coefficients: all.coefficients(estimator)?,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reproducible pseudo-random sequence in [-1, 1).
    fn noise(seed: u64, count: usize) -> Vec<f64> {
        let mut state = seed;
        (0..count)
            .map(|_| {
                state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                z ^= z >> 31;
                (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
            })
            .collect()
    }

    /// The thin SVD of a full n × q matrix by faer, the brute-force answer.
    fn right_vectors(z: &Mat<f64>) -> (Vec<f64>, Mat<f64>) {
        let svd = z.thin_svd().expect("svd");
        let q = z.ncols();
        ((0..q).map(|k| svd.S()[k]).collect(), svd.V().to_owned())
    }

    /// The rows of `a` and `y` in four consecutive folds of equal size.
    fn quarter_folds(a: &[Vec<f64>], y: &[f64]) -> Vec<Factor> {
        let n = y.len();
        (0..4)
            .map(|b| {
                let rows = b * n / 4..(b + 1) * n / 4;
                let views: Vec<&[f64]> = a.iter().map(|c| &c[rows.clone()]).collect();
                Factor::of_columns(&views, &y[rows])
            })
            .collect()
    }

    fn columns(n: usize, p: usize, seed: u64) -> Vec<Vec<f64>> {
        (0..p).map(|j| noise(seed + j as u64, n)).collect()
    }

    #[test]
    fn total_least_squares_matches_the_svd_of_the_whole_scaled_matrix() {
        let (n, p) = (60, 3);
        let truth = [2.0, -1.0, 0.5];
        let clean = columns(n, p, 11);
        let errors = columns(n, p, 31);
        let a: Vec<Vec<f64>> = clean
            .iter()
            .zip(&errors)
            .map(|(c, e)| c.iter().zip(e).map(|(x, d)| x + 0.05 * d).collect())
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|i| (0..p).map(|j| truth[j] * clean[j][i]).sum::<f64>() + 0.05 * noise(77, n)[i])
            .collect();
        let views: Vec<&[f64]> = a.iter().map(Vec::as_slice).collect();
        let factor = Factor::of_columns(&views, &y);
        let beta = Decomposed::new(&factor).unwrap().coefficients(Estimator::Tls).unwrap();
        // Brute force: scale every column of [A y] to unit norm, take the
        // last right singular vector.
        let all: Vec<&Vec<f64>> = a.iter().chain([&y]).collect();
        let norms: Vec<f64> = all
            .iter()
            .map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt())
            .collect();
        let z = Mat::from_fn(n, p + 1, |i, j| all[j][i] / norms[j]);
        let (_, v) = right_vectors(&z);
        let brute: Vec<f64> = (0..p).map(|j| -v[(j, p)] / v[(p, p)] * norms[p] / norms[j]).collect();
        for j in 0..p {
            assert!(
                (beta[j] - brute[j]).abs() < 1e-9 * brute[j].abs().max(1.0),
                "{beta:?} vs {brute:?}"
            );
        }
        // And TLS is not least squares here: noise in A biases LS toward zero.
        let ls = Decomposed::new(&factor).unwrap().coefficients(Estimator::Ls).unwrap();
        assert!(
            ls.iter().zip(&beta).any(|(l, t)| (l - t).abs() > 1e-3),
            "{ls:?} vs {beta:?}"
        );
    }

    #[test]
    fn truncated_tls_on_a_rank_deficient_design_gives_the_minimum_norm_solution() {
        // Column 3 = column 1 + column 2: rank 2. Exact data y = A β has a
        // line of solutions; TTLS of rank 2 must give the minimum-norm one
        // (in the scaled coordinates), the pseudo-inverse's.
        let n = 40;
        let c = columns(n, 2, 5);
        let third: Vec<f64> = (0..n).map(|i| c[0][i] + c[1][i]).collect();
        let a = [c[0].clone(), c[1].clone(), third];
        let y: Vec<f64> = (0..n).map(|i| 1.5 * a[0][i] - 0.5 * a[1][i] + 0.25 * a[2][i]).collect();
        let views: Vec<&[f64]> = a.iter().map(Vec::as_slice).collect();
        let decomposed = Decomposed::new(&Factor::of_columns(&views, &y)).unwrap();
        let beta = decomposed.coefficients(Estimator::Ttls { rank: 2 }).unwrap();
        // Brute force: pseudo-inverse of the scaled A at rank 2.
        let norms: Vec<f64> = a.iter().map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt()).collect();
        let y_norm = y.iter().map(|v| v * v).sum::<f64>().sqrt();
        let scaled = Mat::from_fn(n, 3, |i, j| a[j][i] / norms[j]);
        let svd = scaled.thin_svd().unwrap();
        let mut brute = [0.0; 3];
        for k in 0..2 {
            let uty: f64 = (0..n).map(|i| svd.U()[(i, k)] * y[i] / y_norm).sum();
            for (j, b) in brute.iter_mut().enumerate() {
                *b += svd.V()[(j, k)] * uty / svd.S()[k];
            }
        }
        for j in 0..3 {
            let expected = brute[j] * y_norm / norms[j];
            assert!((beta[j] - expected).abs() < 1e-9, "{beta:?} vs {expected} at {j}");
        }
        // It reproduces y exactly.
        let fitted: Vec<f64> = (0..n).map(|i| (0..3).map(|j| beta[j] * a[j][i]).sum()).collect();
        assert!(fitted.iter().zip(&y).all(|(f, y)| (f - y).abs() < 1e-9));
        // Plain TLS has no unique answer here (two zero singular values) and
        // TSVD of rank 2 agrees with TTLS on exact data.
        let tsvd = decomposed.coefficients(Estimator::Tsvd { rank: 2 }).unwrap();
        assert!(
            tsvd.iter().zip(&beta).all(|(s, t)| (s - t).abs() < 1e-9),
            "{tsvd:?} vs {beta:?}"
        );
    }

    #[test]
    fn the_spectral_estimators_reduce_to_least_squares_at_their_limits() {
        let (n, p) = (80, 4);
        let a = columns(n, p, 101);
        let y: Vec<f64> = (0..n).map(|i| a[0][i] - 2.0 * a[3][i] + 0.1 * noise(9, n)[i]).collect();
        let views: Vec<&[f64]> = a.iter().map(Vec::as_slice).collect();
        let d = Decomposed::new(&Factor::of_columns(&views, &y)).unwrap();
        let ls = d.coefficients(Estimator::Ls).unwrap();
        for other in [
            Estimator::Ridge { lambda: 0.0 },
            Estimator::Tsvd { rank: p },
            Estimator::DampedTsvd { rank: p, lambda: 0.0 },
        ] {
            let beta = d.coefficients(other).unwrap();
            assert!(beta.iter().zip(&ls).all(|(b, l)| (b - l).abs() < 1e-12), "{other:?}");
        }
        // Least squares against the normal equations, solved directly.
        let g = Mat::from_fn(p, p, |i, j| (0..n).map(|k| a[i][k] * a[j][k]).sum::<f64>());
        let b: Vec<f64> = (0..p).map(|i| (0..n).map(|k| a[i][k] * y[k]).sum()).collect();
        let direct = crate::numerics::linalg::solve_spd(g.as_ref(), &b).unwrap();
        assert!(
            direct.iter().zip(&ls).all(|(d, l)| (d - l).abs() < 1e-10),
            "{direct:?} vs {ls:?}"
        );
        assert!((ls[0] - 1.0).abs() < 0.05 && (ls[3] + 2.0).abs() < 0.05);
        assert_eq!(d.coefficients(Estimator::Tsvd { rank: 0 }), None);
        assert_eq!(d.coefficients(Estimator::Ridge { lambda: -1.0 }), None);
    }

    #[test]
    fn held_out_scores_equal_refits_on_the_other_folds() {
        let (n, p) = (90, 3);
        let a = columns(n, p, 201);
        let y: Vec<f64> = (0..n).map(|i| 3.0 * a[1][i] + 0.2 * noise(3, n)[i]).collect();
        let fold_rows = [0..30, 30..60, 60..90];
        let folds: Vec<Factor> = fold_rows
            .iter()
            .map(|r| {
                let views: Vec<&[f64]> = a.iter().map(|c| &c[r.clone()]).collect();
                Factor::of_columns(&views, &y[r.clone()])
            })
            .collect();
        let table = compare(&folds);
        assert_eq!(table.iter().map(|s| s.family).collect::<Vec<_>>(), Family::ALL);
        let ls = &table[0];
        // By hand: least squares on the other two folds' rows, residual on
        // the third.
        let mut total = 0.0;
        for held in &fold_rows {
            let train: Vec<usize> = (0..n).filter(|i| !held.contains(i)).collect();
            let cols: Vec<Vec<f64>> = a.iter().map(|c| train.iter().map(|&i| c[i]).collect()).collect();
            let ty: Vec<f64> = train.iter().map(|&i| y[i]).collect();
            let views: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
            let beta = Decomposed::new(&Factor::of_columns(&views, &ty))
                .unwrap()
                .coefficients(Estimator::Ls)
                .unwrap();
            total += held
                .clone()
                .map(|i| (y[i] - (0..p).map(|j| beta[j] * a[j][i]).sum::<f64>()).powi(2))
                .sum::<f64>();
        }
        let by_hand = (total / n as f64).sqrt();
        assert!(
            (ls.heldout_rms - by_hand).abs() < 1e-12 * by_hand,
            "{} vs {by_hand}",
            ls.heldout_rms
        );
        // Every family's best is at least as good as least squares when it
        // contains it (ridge at λ → 0, TSVD at full rank).
        for scored in &table[1..4] {
            assert!(scored.heldout_rms <= ls.heldout_rms * (1.0 + 1e-3), "{scored:?}");
        }
        // The noise: 0.2 × uniform on [-1, 1), RMS 0.2/√3 = 0.115.
        assert!(ls.heldout_rms > 0.09 && ls.heldout_rms < 0.15, "{}", ls.heldout_rms);
    }

    #[test]
    fn least_squares_standard_errors_are_the_inverse_normal_matrix_diagonal() {
        let (n, p) = (120, 3);
        let a = columns(n, p, 401);
        let y: Vec<f64> = (0..n).map(|i| a[0][i] + 0.3 * a[2][i] + 0.1 * noise(5, n)[i]).collect();
        let views: Vec<&[f64]> = a.iter().map(Vec::as_slice).collect();
        let d = Decomposed::new(&Factor::of_columns(&views, &y)).unwrap();
        let sigma = 0.7;
        let se = d.standard_errors(Estimator::Ls, sigma).unwrap();
        // Brute force: σ² (AᵀA)⁻¹, column by column through solve_spd.
        let g = Mat::from_fn(p, p, |i, j| (0..n).map(|k| a[i][k] * a[j][k]).sum::<f64>());
        for j in 0..p {
            let e: Vec<f64> = (0..p).map(|i| f64::from(i == j)).collect();
            let column = crate::numerics::linalg::solve_spd(g.as_ref(), &e).unwrap();
            let expected = sigma * column[j].sqrt();
            assert!(
                (se[j] - expected).abs() < 1e-10 * expected,
                "{se:?} vs {expected} at {j}"
            );
        }
        // Truncation and damping only shrink them.
        for other in [Estimator::Tsvd { rank: 2 }, Estimator::Ridge { lambda: 0.1 }] {
            let shrunk = d.standard_errors(other, sigma).unwrap();
            assert!(
                shrunk.iter().zip(&se).all(|(s, l)| *s <= l * (1.0 + 1e-12)),
                "{other:?}"
            );
        }
    }

    #[test]
    fn total_least_squares_is_the_filter_of_the_smallest_singular_value_of_z() {
        // β_TLS = (AᵀA − σ̃²I)⁻¹Aᵀy on the scaled columns: the spectral
        // filter w_k = σ_k²/(σ_k² − σ̃²), which standard_errors uses.
        let (n, p) = (200, 3);
        let clean = columns(n, p, 501);
        let a: Vec<Vec<f64>> = (0..p)
            .map(|j| {
                (0..n)
                    .map(|i| clean[j][i] + 0.1 * noise(600 + j as u64, n)[i])
                    .collect()
            })
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|i| 2.0 * clean[0][i] - clean[1][i] + 0.5 * clean[2][i] + 0.1 * noise(700, n)[i])
            .collect();
        let views: Vec<&[f64]> = a.iter().map(Vec::as_slice).collect();
        let d = Decomposed::new(&Factor::of_columns(&views, &y)).unwrap();
        let tls = d.coefficients(Estimator::Tls).unwrap();
        let smallest = d.sigma_z_last;
        let mut scaled = vec![0.0; p];
        for k in 0..p {
            let w = d.sigma[k].powi(2) / (d.sigma[k].powi(2) - smallest * smallest);
            for (j, b) in scaled.iter_mut().enumerate() {
                *b += d.v[(j, k)] * w * d.c[k] / d.sigma[k];
            }
        }
        for j in 0..p {
            let filtered = scaled[j] * d.scale[p] / d.scale[j];
            assert!(
                (filtered - tls[j]).abs() < 1e-9 * tls[j].abs().max(1.0),
                "{filtered} vs {}",
                tls[j]
            );
        }
    }

    #[test]
    fn with_noise_in_the_regressors_tls_recovers_the_coefficients_and_least_squares_predicts_better() {
        // Errors in variables: a regressor read with noise (a noisy
        // fluxgate) attenuates least squares toward zero by
        // var(clean)/(var(clean) + var(noise)); TLS, whose assumption of
        // one noise level on every scaled column holds here, does not.
        // Held out, least squares still predicts the noisy scalar better:
        // it is the best linear predictor from the regressors as recorded.
        // So the held-out table favours LS or ridge, while the physical
        // coefficients (the aircraft's permanent and induced moments) are
        // TLS's when the fluxgate is the noisier instrument.
        let (n, p) = (6000, 2);
        let truth = [1.0, -1.0];
        let clean = columns(n, p, 801);
        // Uniform on [-1, 1): variance 1/3; noise 0.4 × uniform: variance
        // 0.16/3. Attenuation 1/(1 + 0.16) = 0.862.
        let a: Vec<Vec<f64>> = (0..p)
            .map(|j| {
                (0..n)
                    .map(|i| clean[j][i] + 0.4 * noise(900 + j as u64, n)[i])
                    .collect()
            })
            .collect();
        // y's noise scaled by |β| so that every scaled column carries the
        // same noise, as TLS assumes.
        let y: Vec<f64> = (0..n)
            .map(|i| truth[0] * clean[0][i] + truth[1] * clean[1][i] + 0.4 * 2f64.sqrt() * noise(990, n)[i])
            .collect();
        let folds = quarter_folds(&a, &y);
        let all = Decomposed::new(&Factor::combine(&folds).unwrap()).unwrap();
        let ls = all.coefficients(Estimator::Ls).unwrap();
        let tls = all.coefficients(Estimator::Tls).unwrap();
        for j in 0..p {
            assert!((tls[j] - truth[j]).abs() < 0.04, "TLS {tls:?}");
            assert!((ls[j] / truth[j] - 1.0 / 1.16).abs() < 0.04, "LS {ls:?}");
        }
        let table = compare(&folds);
        let rms = |family| table.iter().find(|s| s.family == family).unwrap().heldout_rms;
        assert!(rms(Family::Ls) < rms(Family::Tls), "{table:?}");
    }

    #[test]
    fn tls_wins_held_out_when_a_heading_swings_wider_than_the_others_under_regressor_noise() {
        // The same errors in variables, but one fold (a heading whose
        // manoeuvres swing the regressors four times wider) unlike the
        // others; every variance below in units of 1/3 (uniform noise).
        // Narrow folds: clean 0.25, regressor noise 0.16, y's noise 0.32.
        // Fitted on the three narrow folds, least squares is attenuated to
        // 0.25/0.41 = 0.61 and misses 39 % of the wide fold's swing (clean
        // 4 per column): residual variance 0.39²·8 + 0.61²·0.32 + 0.32 =
        // 1.66; TLS is not attenuated and leaves the noise only, 0.64.
        // Each narrow fold, held out, is predicted from a fit that includes
        // the wide fold (clean 1.5, attenuation 0.90): 0.58 for least
        // squares, 0.64 for TLS. Over the four folds: least squares
        // √((1.66 + 3·0.58)/12) = 0.53, TLS √(0.64/3) = 0.46. So the
        // heading table favours TLS: the regressors' noise is comparable to
        // the narrow headings' swings, and the heading held out swings
        // wider than the ones fitted, where the best linear predictor of
        // the fitted data is no longer the best one.
        let (n, p) = (8000, 2);
        let truth = [1.0, -1.0];
        let clean = columns(n, p, 1801);
        let wide = |i: usize| if i >= 3 * n / 4 { 4.0 } else { 1.0 };
        // Narrow folds: clean variance 0.25 × 1/3, noise variance 0.16/3.
        let a: Vec<Vec<f64>> = (0..p)
            .map(|j| {
                (0..n)
                    .map(|i| 0.5 * wide(i) * clean[j][i] + 0.4 * noise(1900 + j as u64, n)[i])
                    .collect()
            })
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|i| {
                0.5 * wide(i) * (truth[0] * clean[0][i] + truth[1] * clean[1][i])
                    + 0.4 * 2f64.sqrt() * noise(1990, n)[i]
            })
            .collect();
        let folds = quarter_folds(&a, &y);
        // Fitted on the narrow folds alone: least squares attenuated to
        // 0.61 of the truth, TLS within 0.06 of it.
        let narrow = Decomposed::new(&Factor::combine(&folds[..3]).unwrap()).unwrap();
        let (ls, tls) = (
            narrow.coefficients(Estimator::Ls).unwrap(),
            narrow.coefficients(Estimator::Tls).unwrap(),
        );
        for j in 0..p {
            assert!((ls[j] / truth[j] - 0.61).abs() < 0.05, "LS {ls:?}");
            assert!((tls[j] - truth[j]).abs() < 0.06, "TLS {tls:?}");
        }
        let table = compare(&folds);
        let rms = |family| table.iter().find(|s| s.family == family).unwrap().heldout_rms;
        assert!((rms(Family::Ls) - 0.533).abs() < 0.02, "{table:?}");
        assert!((rms(Family::Tls) - 0.462).abs() < 0.02, "{table:?}");
        for family in [Family::Ls, Family::Ridge, Family::Tsvd, Family::DampedTsvd] {
            assert!(
                rms(Family::Tls) < 0.9 * rms(family),
                "TLS against {family:?}: {table:?}"
            );
        }
        let best = table
            .iter()
            .min_by(|x, y| x.heldout_rms.total_cmp(&y.heldout_rms))
            .unwrap();
        assert!(matches!(best.family, Family::Tls | Family::Ttls), "{table:?}");
    }
}
