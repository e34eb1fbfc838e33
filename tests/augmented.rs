//! Compensating with the model a diagnosis found: on a flight whose cabin
//! sensor reads 0.15 s late, the augmented model's compensated channel is
//! closer to the Earth's field the simulator recorded as truth than plain
//! Tolles-Lawson's, a saved diagnosis gives the same outputs as one made
//! on the spot, and bad diagnoses are clear errors.

use std::path::{Path, PathBuf};

use magcomp::config::{FlightJob, Settings};
use magcomp::output::sink::{process_flight, FlightOutputs};
use magcomp::pipeline::FlightResult;

fn sample(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("sample_flights")
        .join(name)
}

fn job(input: PathBuf, diagnosis: Option<PathBuf>) -> FlightJob {
    FlightJob {
        diagnosis,
        ..FlightJob::new(input)
    }
}

fn run(job: &FlightJob, apply: bool, out: &Path) -> (FlightResult, FlightOutputs) {
    let mut options = Settings::default();
    options.diagnose.apply = match apply {
        true => magcomp::diagnose::ApplyDiagnosis::Always,
        false => magcomp::diagnose::ApplyDiagnosis::Never,
    };
    let outputs = FlightOutputs::in_directory(out, &job.input);
    let result = process_flight(job, &options, &outputs).unwrap();
    (result, outputs)
}

/// Column `name` of a CSV (`NaN` for empty cells) and the `flags` column.
fn csv_column(path: &Path, name: &str) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let index = header
        .iter()
        .position(|h| *h == name)
        .unwrap_or_else(|| panic!("no {name}"));
    lines
        .map(|l| l.split(',').nth(index).unwrap_or("").to_string())
        .collect()
}

fn numbers(cells: &[String]) -> Vec<f64> {
    cells.iter().map(|c| c.parse().unwrap_or(f64::NAN)).collect()
}

/// RMS about the mean of `compensated − earth` over the rows where both
/// are finite and `keep` holds.
fn error_rms(compensated: &[f64], earth: &[f64], keep: impl Fn(usize) -> bool) -> f64 {
    let errors: Vec<f64> = (0..compensated.len())
        .filter(|&i| keep(i) && compensated[i].is_finite() && earth[i].is_finite())
        .map(|i| compensated[i] - earth[i])
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt()
}

#[test]
fn a_diagnosed_lag_compensates_closer_to_the_truth_than_plain_tolles_lawson() {
    let folder = tempfile::tempdir().unwrap();
    let input = sample("concealed_a.csv");
    let (plain, plain_out) = run(&job(input.clone(), None), false, &folder.path().join("plain"));
    let (augmented, augmented_out) = run(&job(input.clone(), None), true, &folder.path().join("augmented"));
    assert!(plain.diagnosis.is_none() && plain.models.iter().all(|m| m.spec.is_plain()));

    // The lag is the model mag_2_uc is fitted with; the tail sensor stays plain.
    let model = augmented.models.iter().find(|m| m.channel == "mag_2_uc").unwrap();
    assert!(!model.spec.is_plain(), "mag_2_uc augmented");
    let lag = model.spec.extensions.lag_s;
    assert!((lag - 0.15).abs() < 0.03, "lag {lag}");
    let tail = augmented.models.iter().find(|m| m.channel == "mag_1_uc").unwrap();
    assert!(tail.spec.is_plain());
    assert!(augmented_out.diagnosis_json.as_ref().unwrap().exists());
    assert!(augmented
        .notes
        .iter()
        .any(|n| matches!(n, magcomp::messages::Note::DiagnosedModel { channel, .. } if channel == "mag_2_uc")));

    // Against the Earth's field at the sensor, over the calibration
    // manoeuvres (where the interference changes fastest) and the whole
    // flight (about its mean). Measured: 2.01 → 0.17 nT and 2.18 → 0.21 nT.
    let earth = truth_column(&sample("concealed_a.truth.csv"), "mag_2_uc_earth_nt");
    let time = numbers(&csv_column(&input, "tt"));
    let windows = &model.windows;
    let in_windows = |i: usize| {
        windows
            .iter()
            .any(|w| time[i] >= w.window.t_start && time[i] <= w.window.t_end)
    };
    let before = numbers(&csv_column(&plain_out.compensated, "mag_2_c"));
    let after = numbers(&csv_column(&augmented_out.compensated, "mag_2_c"));
    let (manoeuvres_before, manoeuvres_after) = (
        error_rms(&before, &earth, in_windows),
        error_rms(&after, &earth, in_windows),
    );
    assert!(
        manoeuvres_after < 0.15 * manoeuvres_before,
        "manoeuvres: {manoeuvres_before:.4} → {manoeuvres_after:.4} nT"
    );
    let (all_before, all_after) = (
        error_rms(&before, &earth, |_| true),
        error_rms(&after, &earth, |_| true),
    );
    assert!(
        all_after < 0.2 * all_before,
        "flight: {all_before:.4} → {all_after:.4} nT"
    );
    // The tail sensor's channel is the same either way.
    assert_eq!(
        csv_column(&plain_out.compensated, "mag_1_c"),
        csv_column(&augmented_out.compensated, "mag_1_c")
    );

    // Every row is written; the last rows, which a 0.15 s lag reads past
    // the end of the record, are empty and flagged.
    assert_eq!(after.len(), time.len());
    let flags = csv_column(&augmented_out.compensated, "flags");
    let missing: Vec<usize> = (0..after.len()).filter(|&i| after[i].is_nan()).collect();
    assert!(!missing.is_empty() && missing.len() <= 2, "{missing:?}");
    for i in missing {
        assert!(time.len() - i <= 2, "row {i} of {}", time.len());
        assert!(
            flags[i].contains("lag_outside_record:mag_2_uc"),
            "row {i}: {}",
            flags[i]
        );
    }

    // Accepting the saved diagnosis gives the same outputs, byte for byte.
    let saved = augmented_out.diagnosis_json.clone().unwrap();
    let (_, accepted_out) = run(&job(input, Some(saved)), false, &folder.path().join("accepted"));
    assert!(std::fs::read(&accepted_out.compensated).unwrap() == std::fs::read(&augmented_out.compensated).unwrap());
}

fn truth_column(path: &Path, name: &str) -> Vec<f64> {
    numbers(&csv_column(path, name))
}

#[test]
fn a_diagnosis_naming_a_column_the_flight_lacks_is_a_clear_error() {
    let folder = tempfile::tempdir().unwrap();
    let diagnosis = folder.path().join("DIAGNOSIS.json");
    std::fs::write(
        &diagnosis,
        r#"{"channels": [{"channel": "mag_1_uc", "model": {"sources": [
            {"kind": "aux_coupling", "column": "cur_winch", "level": 0.0}]}}], "findings": []}"#,
    )
    .unwrap();
    let options = Settings::default();
    let input = sample("clean.csv");
    let outputs = FlightOutputs::in_directory(folder.path(), &input);
    let error = process_flight(&job(input, Some(diagnosis.clone())), &options, &outputs).unwrap_err();
    let text = error.to_string();
    assert!(text.contains("cur_winch") && text.contains("mag_1_uc"), "{text}");
    assert!(!outputs.compensated.exists());

    // Not a diagnosis at all.
    std::fs::write(&diagnosis, r#"{"manoeuvres": []}"#).unwrap();
    let input = sample("clean.csv");
    let error = process_flight(&job(input, Some(diagnosis)), &options, &outputs).unwrap_err();
    assert!(error.to_string().contains("not a DIAGNOSIS.json"), "{error}");
}
