//! The estimator family on a real design: every estimator of
//! `model::compare_estimators`, held out heading by heading on the clean
//! sample flight, against the same figure reached the long way (fit on
//! three headings with `model::fit`, predict the fourth with
//! `FittedModel::held_out`).

use std::path::PathBuf;

use magcomp::formats::{read_flight_log, IngestOptions};
use magcomp::holdout::heading_splits;
use magcomp::model::{compare_estimators, fit, FitOptions, ModelSpec};
use magcomp::numerics::estimators::{Estimator, Family};
use magcomp::numerics::solve::LambdaChoice;
use magcomp::numerics::stacked::StorePool;
use magcomp::pipeline::choose_vector_sensor;
use magcomp::windows::read_detect_json;

fn sample(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("sample_flights")
        .join(name)
}

#[test]
fn least_squares_held_out_by_heading_matches_refits_through_the_model() {
    let log = read_flight_log(&sample("clean.csv"), &IngestOptions::default()).unwrap();
    let windows = read_detect_json(&sample("clean.windows.json"), 5.0).unwrap();
    let sensor = choose_vector_sensor(&log, None).unwrap();
    let spec = ModelSpec::default();
    let options = FitOptions::default();
    let stores = StorePool::new();
    let table = compare_estimators(&log, &sensor, "mag_1_uc", &windows, &spec, &options, &stores)
        .unwrap()
        .expect("four headings");
    assert_eq!(table.iter().map(|s| s.family).collect::<Vec<_>>(), Family::ALL);
    for scored in &table {
        println!(
            "{:?}: held-out RMS {:.5} nT with {:?}",
            scored.family, scored.heldout_rms, scored.estimator
        );
        assert!(scored.heldout_rms.is_finite() && scored.heldout_rms > 0.0, "{scored:?}");
        assert_eq!(scored.coefficients.len(), 18);
    }
    let ls = &table[0];
    assert_eq!(ls.estimator, Estimator::Ls);

    // The long way: plain least squares (λ fixed at 0) on three headings,
    // the fourth's band-passed residual from the fitted model.
    let mut unregularised = options;
    unregularised.solve.lambda = LambdaChoice::Fixed(0.0);
    let (mut sum, mut count) = (0.0, 0usize);
    for (held_out, training) in heading_splits(&windows).unwrap() {
        let model = fit(&log, &sensor, "mag_1_uc", &training, &spec, &unregularised, &stores).unwrap();
        for window in model.held_out(&log, &sensor, &held_out, &unregularised).unwrap() {
            sum += window.band_after_nt.iter().map(|r| r * r).sum::<f64>();
            count += window.band_after_nt.len();
        }
    }
    let long_way = (sum / count as f64).sqrt();
    assert!(
        (ls.heldout_rms - long_way).abs() < 1e-6 * long_way,
        "estimators {} vs refits {long_way}",
        ls.heldout_rms
    );
    // A family that contains least squares as a limit does at least as well.
    for family in [Family::Ridge, Family::Tsvd, Family::DampedTsvd] {
        let scored = table.iter().find(|s| s.family == family).unwrap();
        assert!(scored.heldout_rms <= ls.heldout_rms * (1.0 + 1e-6), "{scored:?}");
    }
}

#[test]
fn the_pipeline_reports_the_table_for_every_channel_it_compensates() {
    let mut settings = magcomp::config::Settings::default();
    settings.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    let mut job = magcomp::config::FlightJob::new(sample("clean.csv"));
    job.windows = read_detect_json(&sample("clean.windows.json"), 5.0).unwrap();
    let folder = tempfile::tempdir().unwrap();
    let run = magcomp::pipeline::run(&job, &settings, &folder.path().join("clean_c.csv")).unwrap();
    let log = run.log();
    let sensor = choose_vector_sensor(log, None).unwrap();
    assert!(!run.result.models.is_empty());
    for model in &run.result.models {
        let table = model
            .estimators
            .as_ref()
            .expect("a table for every compensated channel");
        // The same table as asked for directly, to the bit: one path.
        let direct = compare_estimators(
            log,
            &sensor,
            &model.channel,
            &job.windows,
            &model.spec,
            &settings.fit,
            &StorePool::new(),
        )
        .unwrap()
        .unwrap();
        assert_eq!(table, &direct, "{}", model.channel);
    }
    // The model JSON and the report carry it.
    let json = serde_json::to_value(&run.result.models[0]).unwrap();
    assert_eq!(
        json["estimators"].as_array().map(Vec::len),
        Some(6),
        "{}",
        json["estimators"]
    );
    assert_eq!(json["estimators"][4]["family"], "tls");
    let report = folder.path().join("report.html");
    magcomp::report::stage_report(&report, &run, 1.5)
        .unwrap()
        .page
        .commit()
        .unwrap();
    let html = std::fs::read_to_string(&report).unwrap();
    assert_eq!(
        html.matches("<table class=\"estimators\">").count(),
        run.result.models.len()
    );
}

#[test]
fn a_box_of_two_headings_says_it_has_no_estimator_table() {
    let mut settings = magcomp::config::Settings::default();
    settings.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    let job = clean_flight_on_two_headings();
    let folder = tempfile::tempdir().unwrap();
    let run = magcomp::pipeline::run(&job, &settings, &folder.path().join("clean_c.csv")).unwrap();
    for model in &run.result.models {
        assert_eq!(model.estimators, None);
        let said = format!("{}: no estimator table", model.channel);
        assert!(
            run.result.notes.iter().any(|n| n.starts_with(&said)),
            "{:?}",
            run.result.notes
        );
    }
}

#[test]
fn every_solver_fits_with_the_estimator_its_table_names() {
    use magcomp::numerics::estimators::Solver;
    let log = read_flight_log(&sample("clean.csv"), &IngestOptions::default()).unwrap();
    let windows = read_detect_json(&sample("clean.windows.json"), 5.0).unwrap();
    let sensor = choose_vector_sensor(&log, None).unwrap();
    let spec = ModelSpec::default();
    let stores = StorePool::new();
    let table = compare_estimators(
        &log,
        &sensor,
        "mag_1_uc",
        &windows,
        &spec,
        &FitOptions::default(),
        &stores,
    )
    .unwrap()
    .unwrap();
    let ridge = fit(
        &log,
        &sensor,
        "mag_1_uc",
        &windows,
        &spec,
        &FitOptions::default(),
        &stores,
    )
    .unwrap();
    assert_eq!(ridge.solver, None, "ridge is the PRESS path, no solver record");
    assert_eq!(
        ridge.solution.jackknife.len(),
        windows.len(),
        "ridge: one deviation a window"
    );
    for solver in [
        Solver::Ls,
        Solver::Tsvd,
        Solver::DampedTsvd,
        Solver::Tls,
        Solver::Ttls,
        Solver::Auto,
    ] {
        let options = FitOptions {
            solver,
            ..FitOptions::default()
        };
        let model = fit(&log, &sensor, "mag_1_uc", &windows, &spec, &options, &stores).unwrap();
        let used = model.solver.as_ref().expect("a solver record");
        assert!(used.applied(), "{solver:?}: {}", used.reason);
        assert!(
            model.solution.jackknife.is_empty(),
            "{solver:?}: ridge's jackknife says nothing of these coefficients"
        );
        let expected = match solver {
            Solver::Auto => table
                .iter()
                .min_by(|a, b| a.heldout_rms.total_cmp(&b.heldout_rms))
                .unwrap(),
            _ => table.iter().find(|s| Some(s.family) == used.family).unwrap(),
        };
        assert_eq!(used.family, Some(expected.family), "{solver:?}");
        assert_eq!(used.estimator, Some(expected.estimator), "{solver:?}");
        assert_eq!(used.heldout_rms, Some(expected.heldout_rms), "{solver:?}");
        assert_eq!(model.coefficients, expected.coefficients, "{solver:?}");
        // The in-sample residual is that of these coefficients, and no
        // larger than least squares' beyond rounding only for LS itself.
        let rss: f64 = model.windows.iter().flat_map(|w| &w.band_after_nt).map(|r| r * r).sum();
        let rows: usize = model.windows.iter().map(|w| w.band_after_nt.len()).sum();
        let rms = (rss / rows as f64).sqrt();
        assert!(rms.is_finite() && rms > 0.0 && rms < 1.0, "{solver:?}: {rms}");
        assert!(
            model.coefficient_uncertainty.iter().all(|s| s.is_finite() && *s > 0.0),
            "{solver:?}: {:?}",
            model.coefficient_uncertainty
        );
        assert!(
            model.solution.reason.contains(solver.name()),
            "{}",
            model.solution.reason
        );
        println!(
            "{solver:?}: {} held out {:.5} nT, in sample {rms:.5} nT",
            used.reason, expected.heldout_rms
        );
    }
    // Least squares' fitted standard errors are no smaller than ridge's
    // (ridge shrinks): a check that the uncertainty follows the estimator.
    let ls = fit(
        &log,
        &sensor,
        "mag_1_uc",
        &windows,
        &spec,
        &FitOptions {
            solver: Solver::Ls,
            ..FitOptions::default()
        },
        &stores,
    )
    .unwrap();
    let larger = ls
        .coefficient_uncertainty
        .iter()
        .zip(&ridge.coefficient_uncertainty)
        .filter(|(l, r)| l >= r)
        .count();
    assert!(
        larger >= 15,
        "{:?} vs {:?}",
        ls.coefficient_uncertainty,
        ridge.coefficient_uncertainty
    );
}

#[test]
fn a_solver_that_needs_three_headings_falls_back_to_ridge_and_warns() {
    let mut settings = magcomp::config::Settings::default();
    settings.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    settings.fit.solver = magcomp::numerics::estimators::Solver::Tls;
    let job = clean_flight_on_two_headings();
    let folder = tempfile::tempdir().unwrap();
    let run = magcomp::pipeline::run(&job, &settings, &folder.path().join("clean_c.csv")).unwrap();
    let log = run.log();
    let sensor = choose_vector_sensor(log, None).unwrap();
    for model in &run.result.models {
        let used = model.solver.as_ref().expect("a solver record");
        assert!(!used.applied());
        // The coefficients are ridge's, exactly.
        let mut ridge_options = settings.fit.clone();
        ridge_options.solver = magcomp::numerics::estimators::Solver::Ridge;
        let ridge = fit(
            log,
            &sensor,
            &model.channel,
            &job.windows,
            &model.spec,
            &ridge_options,
            &StorePool::new(),
        )
        .unwrap();
        assert_eq!(model.coefficients, ridge.coefficients, "{}", model.channel);
        let said = format!("{}: [fit] solver = \"tls\" was not used", model.channel);
        assert!(
            run.result.warnings.iter().any(|w| w.starts_with(&said)),
            "{:?}",
            run.result.warnings
        );
    }
}

/// The clean sample flight with its calibration windows cut to the first
/// two of its headings.
fn clean_flight_on_two_headings() -> magcomp::config::FlightJob {
    let mut job = magcomp::config::FlightJob::new(sample("clean.csv"));
    let windows = read_detect_json(&sample("clean.windows.json"), 5.0).unwrap();
    let headings = magcomp::holdout::distinct_headings(&windows);
    assert!(headings.len() >= 3);
    job.windows = windows
        .into_iter()
        .filter(|w| {
            w.heading_deg
                .is_some_and(|h| headings[..2].iter().any(|k| magcomp::holdout::same_heading(h, *k)))
        })
        .collect();
    job
}

/// A solver other than ridge has no jackknife, so no uncertainty figure:
/// the quality JSON has none and the run says why, where ridge on the same
/// flight states one.
#[test]
fn a_solver_without_a_jackknife_says_it_has_no_uncertainty_figure() {
    let folder = tempfile::tempdir().unwrap();
    let mut job = magcomp::config::FlightJob::new(sample("clean.csv"));
    job.windows = read_detect_json(&sample("clean.windows.json"), 5.0).unwrap();
    let mut settings = magcomp::config::Settings::default();
    settings.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    let ridge = magcomp::pipeline::run(&job, &settings, &folder.path().join("ridge.csv")).unwrap();
    settings.fit.solver = magcomp::numerics::estimators::Solver::Tls;
    let tls = magcomp::pipeline::run(&job, &settings, &folder.path().join("tls.csv")).unwrap();
    assert!(!ridge.result.channels.is_empty());
    for (stated, unstated) in ridge.result.channels.iter().zip(&tls.result.channels) {
        let sigma = stated.uncertainty.as_ref().expect("ridge states an uncertainty");
        assert!(sigma.outside_calibration_sigma_nt.is_finite() && sigma.outside_calibration_sigma_nt > 0.0);
        assert_eq!(unstated.uncertainty, None, "{}", unstated.channel);
        let said = format!(
            "{}: no uncertainty figure: the blocked jackknife is computed for ridge and truncated SVD, not for [fit] solver = \"tls\"",
            unstated.channel
        );
        assert!(tls.result.warnings.contains(&said), "{:?}", tls.result.warnings);
        assert!(!ridge
            .result
            .warnings
            .iter()
            .any(|w| w.contains("no uncertainty figure")));
    }
}
