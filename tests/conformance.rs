//! Conformance with MagNav.jl on a real flight segment.
//!
//! `../shared/reference/` holds 100 s of the SGL 2020 flight (Flux A and the
//! tail stinger, 10 Hz), MagNav.jl's design matrix A and its compensated
//! output. The test is skipped only when that folder is absent.

use std::path::{Path, PathBuf};

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::compensate::{compensate, LevelConvention};
use magcomp::formats::{read_flight_log, IngestOptions};
use magcomp::messages::{Diagnosing, Note};
use magcomp::model::terms::TermSet;
use magcomp::model::{fit, FilterSettings, FitMagnitude, FitOptions, ModelSpec};
use magcomp::numerics::estimators::Solver;
use magcomp::numerics::filter::{EdgePadding, FilterBand};
use magcomp::numerics::solve::{LambdaChoice, SolveOptions};
use magcomp::pipeline::choose_vector_sensor;
use magcomp::quality::standard_deviation;

fn reference_folder() -> Option<PathBuf> {
    let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/reference");
    if folder.join("magnav_tl_segment.csv").exists() {
        Some(folder)
    } else {
        eprintln!("skipping: {} is absent", folder.display());
        None
    }
}

fn read_matrix(path: &Path) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|line| line.split(',').map(|v| v.parse().unwrap()).collect())
        .collect()
}

#[test]
fn design_matrix_matches_magnav_to_1e_12() {
    let Some(folder) = reference_folder() else { return };
    let log = read_flight_log(&folder.join("magnav_tl_segment.csv"), &IngestOptions::default()).unwrap();
    let sensor = choose_vector_sensor(&log, Some("flux_a")).unwrap();
    let ours = TermSet::magnav().design_matrix(log.vector_components(&sensor), std::slice::from_ref(&(0..log.len())));
    let reference = read_matrix(&folder.join("magnav_tl_segment_A.csv"));
    assert_eq!(reference.len(), log.len());
    for (j, column) in ours.columns.iter().enumerate() {
        // Relative to the column's largest magnitude: the eddy terms are
        // differences of nearly equal samples, so element-wise relative error
        // is meaningless where they cross zero.
        let scale = reference.iter().map(|row| row[j].abs()).fold(0.0, f64::max);
        let worst = column
            .iter()
            .zip(&reference)
            .map(|(a, row)| (a - row[j]).abs())
            .fold(0.0, f64::max);
        assert!(
            worst <= 1e-12 * scale,
            "column {} ({}): worst {worst:e} of {scale:e}",
            j,
            ours.names[j]
        );
    }
}

fn compensated_difference_std(padding: EdgePadding) -> Option<f64> {
    let folder = reference_folder()?;
    let log = read_flight_log(&folder.join("magnav_tl_segment.csv"), &IngestOptions::default()).unwrap();
    let sensor = choose_vector_sensor(&log, Some("flux_a")).unwrap();
    let options = FitOptions {
        filter: FilterSettings {
            band: FilterBand::Bandpass {
                low_hz: 0.1,
                high_hz: 0.9,
            },
            poles: 4,
            padding,
            trim_samples: 20,
            magnitude: FitMagnitude::Measured,
        },
        solve: SolveOptions {
            lambda: LambdaChoice::Fixed(0.001),
            ..SolveOptions::default()
        },
        solver: Solver::Ridge,
    };
    let window = CalibrationWindow::new(log.time_s()[0], log.time_s()[log.len() - 1]);
    let spec = ModelSpec::plain(TermSet::magnav());
    let model = fit(
        &log,
        &sensor,
        "mag_1_uc",
        &[window],
        &spec,
        &options,
        &Default::default(),
    )
    .unwrap();
    let ours = compensate(&log, &[model], LevelConvention::Absolute).unwrap();
    let reference = &log.channel("mag_1_c").unwrap().values;
    let difference: Vec<f64> = ours.channels[0]
        .values
        .iter()
        .zip(reference)
        .map(|(a, b)| a - b)
        .collect();
    Some(standard_deviation(&difference))
}

/// MagNav.jl's own test accepts 0.1 nT; with DSP.jl's edge padding (the
/// filter MagNav.jl uses) the remaining difference is filter-edge rounding.
#[test]
fn compensation_matches_magnav_with_its_filter_convention() {
    let Some(std) = compensated_difference_std(EdgePadding::DspJl) else {
        return;
    };
    eprintln!("std(magcomp − MagNav.jl) with DSP.jl padding: {std:.4} nT");
    assert!(std < 0.1, "{std}");
}

/// With scipy's default padding (magcomp's default) the edges differ more,
/// and the result must still be within MagNav.jl's own 0.1 nT limit.
#[test]
fn compensation_matches_magnav_with_scipy_padding() {
    let Some(std) = compensated_difference_std(EdgePadding::Scipy) else {
        return;
    };
    eprintln!("std(magcomp − MagNav.jl) with scipy padding: {std:.4} nT");
    assert!(std < 0.1, "{std}");
}

/// The real segment is 100 s of straight survey flight, not a calibration
/// box: one window, held out by quarters. Diagnosis must not invent
/// physics there: with no manoeuvre to time a lag or a source by, no
/// candidate may pass the 30 % threshold, and the few attitudes flown
/// cannot pin the fluxgate calibration, which is left unchecked with a
/// note (measured figures: docs/measurements.md, section
/// tests::conformance).
#[test]
fn diagnosis_of_the_real_segment_finds_nothing_it_cannot_support() {
    let Some(folder) = reference_folder() else { return };
    let log = read_flight_log(&folder.join("magnav_tl_segment.csv"), &IngestOptions::default()).unwrap();
    let sensor = choose_vector_sensor(&log, Some("flux_a")).unwrap();
    let window = CalibrationWindow::new(log.time_s()[0], log.time_s()[log.len() - 1]);
    let options = FitOptions::default();
    let calibration = magcomp::model::Calibration {
        log: &log,
        sensor: &sensor,
        channels: &["mag_1_uc".to_string()],
        windows: &[window],
    };
    let diagnosis = magcomp::diagnose::diagnose(
        &calibration,
        &TermSet::default(),
        &options,
        &magcomp::diagnose::DiagnoseOptions::default(),
    )
    .unwrap();
    assert!(diagnosis.findings.is_empty(), "{:#?}", diagnosis.findings);
    let channel = &diagnosis.channels[0];
    assert!(
        (0.05..0.12).contains(&channel.heldout_rms_baseline_nt),
        "{}",
        channel.heldout_rms_baseline_nt
    );
    assert!(diagnosis.fluxgate.is_none());
    assert!(
        diagnosis.notes.iter().any(
            |n| matches!(n, Note::Diagnosing(Diagnosing::FluxgateNotChecked { reason })
                if reason.contains("do not pin the fluxgate calibration"))
        ),
        "{:?}",
        diagnosis.notes
    );
}
