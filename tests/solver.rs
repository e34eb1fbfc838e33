//! Known-answer tests of the regularised solver.

mod common;

use faer::Mat;
use magcomp::numerics::solve::{solve, Criterion, Decomposition, LambdaChoice, Method, SolveOptions};
use proptest::prelude::*;

/// Deterministic pseudo-random values in [-1, 1) (SplitMix64).
fn values(seed: u64, count: usize) -> Vec<f64> {
    (common::splitmix64(seed, count).into_iter())
        .map(|z| 2.0 * (z >> 11) as f64 / (1u64 << 53) as f64 - 1.0)
        .collect()
}

fn random_columns(seed: u64, rows: usize, terms: usize) -> Vec<Vec<f64>> {
    (0..terms).map(|j| values(seed + j as u64 * 1000, rows)).collect()
}

fn predict(columns: &[Vec<f64>], beta: &[f64]) -> Vec<f64> {
    (0..columns[0].len())
        .map(|i| columns.iter().zip(beta).map(|(c, b)| c[i] * b).sum())
        .collect()
}

/// Ridge by the normal equations, for reference only.
fn brute_ridge(columns: &[Vec<f64>], y: &[f64], rows: &[usize], lambda: f64) -> Vec<f64> {
    let p = columns.len();
    let gram = Mat::from_fn(p, p, |a, b| {
        rows.iter().map(|&i| columns[a][i] * columns[b][i]).sum::<f64>() + if a == b { lambda } else { 0.0 }
    });
    let rhs = Mat::from_fn(p, 1, |a, _| rows.iter().map(|&i| columns[a][i] * y[i]).sum::<f64>());
    let solution = faer::linalg::solvers::Solve::solve(&gram.partial_piv_lu(), rhs.as_ref());
    (0..p).map(|a| solution[(a, 0)]).collect()
}

/// Leave-one-out PRESS of ridge at `lambda`, one refit per left-out row.
fn brute_press(columns: &[Vec<f64>], y: &[f64], lambda: f64) -> f64 {
    let rows = y.len();
    (0..rows)
        .map(|left_out| {
            let kept: Vec<usize> = (0..rows).filter(|&i| i != left_out).collect();
            let beta = brute_ridge(columns, y, &kept, lambda);
            let prediction: f64 = columns.iter().zip(&beta).map(|(c, b)| c[left_out] * b).sum();
            (y[left_out] - prediction).powi(2)
        })
        .sum()
}

/// The columns' combination by `beta` plus 0.3 × `noise`.
fn with_noise(columns: &[Vec<f64>], beta: &[f64], noise: &[f64]) -> Vec<f64> {
    predict(columns, beta)
        .iter()
        .zip(noise)
        .map(|(v, n)| v + 0.3 * n)
        .collect()
}

#[test]
fn noiseless_data_recovers_the_coefficients() {
    let columns = random_columns(3, 400, 18);
    let truth: Vec<f64> = (0..18).map(|k| (k as f64 - 8.5) * 1.7).collect();
    let y = predict(&columns, &truth);
    let options = SolveOptions {
        lambda: LambdaChoice::Fixed(0.0),
        ..SolveOptions::default()
    };
    let solution = solve(columns, &y, &[], &options).unwrap();
    // Well-conditioned random design (cond ~ 3): error ≈ eps · cond · |β|.
    for (found, expected) in solution.coefficients.iter().zip(&truth) {
        assert!((found - expected).abs() < 1e-10, "{found} vs {expected}");
    }
    assert!(solution.residual_rms < 1e-10);
}

#[test]
fn selected_fit_on_noiseless_data_also_recovers_them() {
    let columns = random_columns(5, 300, 9);
    let truth: Vec<f64> = (0..9).map(|k| 3.0 - k as f64).collect();
    let y = predict(&columns, &truth);
    let solution = solve(columns, &y, &[], &SolveOptions::default()).unwrap();
    // With no noise PRESS wants no shrinkage: the grid bottom is 1e-11 σ₁²,
    // so shrinkage biases coefficients by at most ~1e-11 · cond² relative.
    for (found, expected) in solution.coefficients.iter().zip(&truth) {
        assert!((found - expected).abs() < 1e-8, "{found} vs {expected}");
    }
}

#[test]
fn closed_form_press_equals_brute_force_leave_one_out() {
    let (rows, terms) = (40, 5);
    let columns = random_columns(11, rows, terms);
    let noise = values(99, rows);
    let y = with_noise(&columns, &[1.0, -2.0, 0.5, 3.0, 0.0], &noise);
    let solution = solve(columns.clone(), &y, &[], &SolveOptions::default()).unwrap();
    for point in solution.ridge_curve.iter().step_by(7) {
        let press = brute_press(&columns, &y, point.lambda);
        let relative = (point.press - press).abs() / press;
        assert!(
            relative < 1e-9,
            "λ={}: closed form {} vs brute force {press}",
            point.lambda,
            point.press
        );
    }
}

#[test]
fn blocked_press_equals_brute_force_leave_one_fold_out() {
    let (rows, terms) = (60, 4);
    let columns = random_columns(21, rows, terms);
    let noise = values(7, rows);
    let y: Vec<f64> = predict(&columns, &[2.0, 1.0, -1.0, 0.5])
        .iter()
        .zip(&noise)
        .map(|(v, n)| v + 0.2 * n)
        .collect();
    let folds = [0..15, 15..35, 35..60];
    let solution = solve(columns.clone(), &y, &folds, &SolveOptions::default()).unwrap();
    for point in solution.ridge_curve.iter().step_by(9) {
        let mut held_out = 0.0;
        for fold in &folds {
            let kept: Vec<usize> = (0..rows).filter(|i| !fold.contains(i)).collect();
            let beta = brute_ridge(&columns, &y, &kept, point.lambda);
            held_out += fold
                .clone()
                .map(|i| (y[i] - columns.iter().zip(&beta).map(|(c, b)| c[i] * b).sum::<f64>()).powi(2))
                .sum::<f64>();
        }
        let found = point.blocked_press.unwrap();
        assert!(
            (found - held_out).abs() / held_out < 1e-9,
            "λ={}: {found} vs {held_out}",
            point.lambda
        );
    }
}

#[test]
fn rank_deficient_design_falls_back_to_truncated_svd_and_predicts_well() {
    let rows = 200;
    let mut columns = random_columns(31, rows, 5);
    // Column 4 = column 0 + column 1 exactly: rank 4.
    columns[4] = columns[0].iter().zip(&columns[1]).map(|(a, b)| a + b).collect();
    let noise = values(8, rows);
    let clean = predict(&columns, &[1.0, 2.0, -1.0, 0.5, 0.0]);
    let y: Vec<f64> = clean.iter().zip(&noise).map(|(v, n)| v + 1e-3 * n).collect();
    let solution = solve(columns.clone(), &y, &[], &SolveOptions::default()).unwrap();
    assert_eq!(solution.method, Method::TruncatedSvd, "{}", solution.reason);
    assert!(solution.condition_number > 1e10);
    let fitted = predict(&columns, &solution.coefficients);
    let error = fitted
        .iter()
        .zip(&clean)
        .map(|(f, c)| (f - c).powi(2))
        .sum::<f64>()
        .sqrt()
        / (rows as f64).sqrt();
    // Noise is 1e-3 · U(-1,1) (RMS 5.8e-4); the fit error must stay at that level.
    assert!(error < 6e-4, "prediction error {error}");
    assert_eq!(solution.rank, Some(4));
}

#[test]
fn blocked_criterion_is_reported_and_selectable() {
    let columns = random_columns(41, 120, 6);
    let noise = values(3, 120);
    let y: Vec<f64> = predict(&columns, &[1.0; 6])
        .iter()
        .zip(&noise)
        .map(|(v, n)| v + 2.0 * n)
        .collect();
    let folds = [0..40, 40..80, 80..120];
    let options = SolveOptions {
        criterion: Criterion::BlockedPress,
        ..SolveOptions::default()
    };
    let solution = solve(columns, &y, &folds, &options).unwrap();
    assert!(solution.lambda_by_blocked_press.is_some());
    assert!(solution.ridge_curve.len() >= 50);
    assert!(solution.reason.contains("blocked PRESS"), "{}", solution.reason);
}

#[test]
fn too_few_rows_and_non_finite_values_are_errors() {
    let columns = random_columns(1, 5, 6);
    assert!(solve(columns, &[0.0; 5], &[], &SolveOptions::default()).is_err());
    let mut columns = random_columns(1, 50, 3);
    columns[1][17] = f64::NAN;
    let message = solve(columns, &[0.0; 50], &[], &SolveOptions::default())
        .unwrap_err()
        .to_string();
    assert!(message.contains("row 17"), "{message}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, rng_seed: proptest::test_runner::RngSeed::Fixed(1), ..ProptestConfig::default() })]
    /// A fixed-λ ridge solution satisfies its normal equations
    /// (AᵀA + λI)β = Aᵀy to rounding.
    #[test]
    fn ridge_solution_satisfies_its_normal_equations(seed in 0u64..10_000, lambda_exp in -6.0f64..1.0) {
        let columns = random_columns(seed, 80, 6);
        let y = values(seed + 77, 80);
        let lambda = 10f64.powf(lambda_exp);
        let options = SolveOptions { lambda: LambdaChoice::Fixed(lambda), ..SolveOptions::default() };
        let beta = solve(columns.clone(), &y, &[], &options).unwrap().coefficients;
        let rows: Vec<usize> = (0..80).collect();
        let reference = brute_ridge(&columns, &y, &rows, lambda);
        for (a, b) in beta.iter().zip(&reference) {
            prop_assert!((a - b).abs() < 1e-9 * (1.0 + b.abs()), "{} vs {}", a, b);
        }
    }
}

#[test]
fn standard_errors_match_least_squares_theory_and_the_scatter_of_refits() {
    // Least squares (λ = 0): SE_j = σ̂ √((AᵀA)⁻¹)_jj exactly, with
    // σ̂² = RSS / (n − p). Over many noise draws, the scatter of each
    // coefficient equals the true σ √((AᵀA)⁻¹)_jj.
    let (rows, terms, sigma) = (300, 4, 0.5);
    let columns = random_columns(11, rows, terms);
    let truth = [1.0, -2.0, 0.5, 3.0];
    let clean = predict(&columns, &truth);
    let options = SolveOptions {
        lambda: LambdaChoice::Fixed(0.0),
        ..SolveOptions::default()
    };
    let all: Vec<usize> = (0..rows).collect();
    let inverse_diagonal: Vec<f64> = (0..terms)
        .map(|j| {
            // ((AᵀA)⁻¹)_jj: solve (AᵀA) x = e_j (the normal equations serve
            // as the reference here, never in magcomp).
            let p = terms;
            let gram = Mat::from_fn(p, p, |a, b| {
                all.iter().map(|&i| columns[a][i] * columns[b][i]).sum::<f64>()
            });
            let unit = Mat::from_fn(p, 1, |a, _| f64::from(u8::from(a == j)));
            faer::linalg::solvers::Solve::solve(&gram.partial_piv_lu(), unit.as_ref())[(j, 0)]
        })
        .collect();
    let mut estimates: Vec<Vec<f64>> = vec![Vec::new(); terms];
    for draw in 0..400u64 {
        let noise = values(1_000_000 + draw * 7919, rows);
        // Uniform on [-1, 1) has variance 1/3: scale to standard deviation σ.
        let y: Vec<f64> = clean
            .iter()
            .zip(&noise)
            .map(|(c, e)| c + sigma * 3f64.sqrt() * e)
            .collect();
        let solution = solve(columns.clone(), &y, &[], &options).unwrap();
        let rss = solution.residual_rms.powi(2) * rows as f64;
        let noise_hat = (rss / (rows - terms) as f64).sqrt();
        for j in 0..terms {
            let exact = noise_hat * inverse_diagonal[j].sqrt();
            assert!((solution.standard_errors[j] - exact).abs() < 1e-9 * exact, "{j}");
            estimates[j].push(solution.coefficients[j]);
        }
    }
    for j in 0..terms {
        let mean = estimates[j].iter().sum::<f64>() / 400.0;
        let scatter = (estimates[j].iter().map(|b| (b - mean).powi(2)).sum::<f64>() / 399.0).sqrt();
        let theory = sigma * inverse_diagonal[j].sqrt();
        // 400 draws: the sample standard deviation is within ±3.5/√(2·400) ≈ 12 %.
        assert!((scatter / theory - 1.0).abs() < 0.12, "{j}: {scatter} vs {theory}");
    }
}

/// PRESS of the linear smoother with spectral weights `weights(σ)`, from
/// faer's own thin SVD of the whole matrix: an independent route to the
/// closed form.
fn direct_press(columns: &[Vec<f64>], y: &[f64], weights: impl Fn(usize, &[f64]) -> f64) -> f64 {
    let (rows, p) = (y.len(), columns.len());
    let a = Mat::from_fn(rows, p, |i, j| columns[j][i]);
    let svd = a.thin_svd().unwrap();
    let (u, s) = (svd.U(), svd.S());
    let sigma: Vec<f64> = (0..p).map(|k| s[k]).collect();
    let w: Vec<f64> = (0..p).map(|k| weights(k, &sigma)).collect();
    let c: Vec<f64> = (0..p).map(|k| (0..rows).map(|i| u[(i, k)] * y[i]).sum()).collect();
    (0..rows)
        .map(|i| {
            let fitted: f64 = (0..p).map(|k| u[(i, k)] * w[k] * c[k]).sum();
            let leverage: f64 = (0..p).map(|k| u[(i, k)].powi(2) * w[k]).sum();
            ((y[i] - fitted) / (1.0 - leverage)).powi(2)
        })
        .sum()
}

fn noisy_target(columns: &[Vec<f64>], seed: u64, noise: f64) -> Vec<f64> {
    let beta: Vec<f64> = (0..columns.len()).map(|k| 1.0 + 0.5 * k as f64).collect();
    predict(columns, &beta)
        .iter()
        .zip(values(seed, columns[0].len()))
        .map(|(v, n)| v + noise * n)
        .collect()
}

/// Checks every ridge and truncated-SVD PRESS value against the direct
/// formula, to `tolerance` relative.
fn check_press_curves(columns: &[Vec<f64>], y: &[f64], tolerance: f64) -> Decomposition {
    let solution = solve(columns.to_vec(), y, &[], &SolveOptions::default()).unwrap();
    for point in solution.ridge_curve.iter().step_by(5) {
        let expected = direct_press(columns, y, |k, s| s[k].powi(2) / (s[k].powi(2) + point.lambda));
        let relative = (point.press - expected).abs() / expected;
        assert!(
            relative < tolerance,
            "λ={}: {} vs {expected}",
            point.lambda,
            point.press
        );
    }
    for point in &solution.tsvd_curve {
        let expected = direct_press(columns, y, |k, _| f64::from(u8::from(k < point.rank)));
        let relative = (point.press - expected).abs() / expected;
        assert!(
            relative < tolerance,
            "rank {}: {} vs {expected}",
            point.rank,
            point.press
        );
    }
    solution.decomposition
}

#[test]
fn well_conditioned_design_takes_cholesky_qr_and_matches_the_direct_press() {
    // 5000 rows: several row blocks of the kernels, and a ragged last one.
    let columns = random_columns(51, 5003, 7);
    let y = noisy_target(&columns, 52, 0.1);
    assert_eq!(check_press_curves(&columns, &y, 1e-9), Decomposition::CholeskyQr2);
}

#[test]
fn ill_conditioned_design_takes_householder_qr_and_matches_the_direct_press() {
    let mut columns = random_columns(61, 3001, 6);
    // Column 5 is columns 0 + 1 to 1e-7: scaled condition number ~1e7,
    // beyond what the Cholesky route is trusted with.
    let wobble = values(62, 3001);
    columns[5] = (0..3001)
        .map(|i| columns[0][i] + columns[1][i] + 1e-7 * wobble[i])
        .collect();
    let y = noisy_target(&columns, 63, 0.1);
    // Both routes lose ~κ·ε in the small singular directions.
    assert_eq!(check_press_curves(&columns, &y, 1e-7), Decomposition::Householder);
}

/// A sample that alone carries a column has leverage 1 when λ is tiny: no
/// leave-one-out prediction there, so those candidates get an infinite
/// PRESS; from some λ on the leverage falls below 1 and PRESS is finite
/// again, and at the top of the grid equals brute-force leave-one-out. The
/// fine grid puts the leverage-1 candidates past the first four, which the
/// PRESS pass only checks after the smallest λ has shown leverage 1.
#[test]
fn leverage_one_sample_gives_infinite_press_at_small_lambda_only() {
    let rows = 40;
    let mut columns = random_columns(21, rows, 4);
    columns.push((0..rows).map(|i| if i == 17 { 3.0 } else { 0.0 }).collect());
    let noise = values(77, rows);
    let y = with_noise(&columns, &[1.0, -2.0, 0.5, 3.0, 4.0], &noise);
    let options = SolveOptions {
        grid_points: 200,
        ..SolveOptions::default()
    };
    let solution = solve(columns.clone(), &y, &[], &options).unwrap();
    let curve = &solution.ridge_curve;
    let infinite = curve.iter().take_while(|point| point.press.is_infinite()).count();
    assert!(
        infinite > 4 && infinite < curve.len() / 2,
        "{infinite} of {} infinite",
        curve.len()
    );
    assert!(curve[infinite..].iter().all(|point| point.press.is_finite()));
    let top = &curve[curve.len() - 1];
    let press = brute_press(&columns, &y, top.lambda);
    assert!((top.press - press).abs() < 1e-9 * press, "{} vs {press}", top.press);
}
