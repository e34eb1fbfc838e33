//! The quality checks a geophysicist decides on: the transfer of the
//! calibration to manoeuvres the fit did not see.

use std::path::{Path, PathBuf};

use magcomp::config::{FlightJob, Pipeline};
use magcomp::pipeline::{process_flight, FlightOutputs, FlightResult, StageOptions};
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::transfer::TransferMethod;

fn run(input: &Path, out: &Path) -> FlightResult {
    let job = FlightJob {
        input: input.to_path_buf(),
        vector: None,
        channels: None,
        windows: Vec::new(),
    };
    let outputs = FlightOutputs::in_directory(out, input);
    process_flight(&job, &StageOptions::from(&Pipeline::default()), &outputs).unwrap()
}

fn simulated(folder: &Path, edit: impl FnOnce(&mut RawScenario)) -> PathBuf {
    let mut raw = RawScenario {
        seed: 5,
        ..RawScenario::default()
    };
    raw.survey.line_count = 1;
    edit(&mut raw);
    let flight = magcomp::simulate::simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let path = folder.join("flight.csv");
    magcomp::output::write_flight_log(&flight.log, &path).unwrap();
    path
}

#[test]
fn a_second_box_is_held_out_and_a_clean_calibration_transfers() {
    let folder = tempfile::tempdir().unwrap();
    let input = simulated(folder.path(), |raw| raw.calibration.repeats = 2);
    let result = run(&input, &folder.path().join("out"));
    for quality in &result.channels {
        let check = quality.transfer.as_ref().unwrap();
        println!("{}: {check:?}", quality.channel);
        assert_eq!(check.method, TransferMethod::SecondBox);
        assert_eq!(check.manoeuvres, 12);
        // The same aircraft, the same physics: the first box's coefficients
        // compensate the second box within 1.5× of its own fit.
        assert!(check.ratio < 1.5 && check.warning.is_none(), "{check:?}");
    }
}

#[test]
fn leave_one_heading_out_flags_a_calibration_that_does_not_transfer() {
    let folder = tempfile::tempdir().unwrap();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sample_flights");
    // The clean sample flight transfers on both sensors.
    let clean = run(&root.join("clean.csv"), &folder.path().join("clean"));
    for quality in &clean.channels {
        let check = quality.transfer.as_ref().unwrap();
        println!("clean {}: {check:?}", quality.channel);
        assert_eq!(check.method, TransferMethod::LeaveOneHeadingOut);
        assert!(check.ratio < 1.5 && check.warning.is_none(), "{check:?}");
    }
    // concealed_b: the trim tab's field (it follows the slow pitch and the
    // height) reaches the cabin sensor. Within a heading the 18 terms
    // absorb it; across headings they cannot, and the check says so.
    let coupled = run(&root.join("concealed_b.csv"), &folder.path().join("coupled"));
    let check = coupled.channels[1].transfer.as_ref().unwrap();
    println!("coupled: {check:?}");
    assert!(check.ratio > 2.0 && check.warning.is_some(), "{check:?}");
    assert!(coupled.notes.iter().any(|n| n.contains("may not transfer")));
}
