//! Calibration data by line number (`--lines`, `[[flight]] lines`, a
//! manifest's `lines` column), as SGL-style files number their
//! calibration lines: the manoeuvres detected on the lines named are the
//! windows, and nothing of the other boxes is fitted on.

mod common;

use std::path::Path;
use std::process::Command;

use magcomp::config::FlightJob;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::{simulate, SimulatedFlight};

/// Two boxes back to back, numbered 1002.2 and 1002.21, then survey lines
/// 1001 and 1002, written to `folder`.
fn two_box_flight(folder: &Path, seed: u64) -> (std::path::PathBuf, SimulatedFlight) {
    let mut raw = RawScenario {
        seed,
        ..RawScenario::default()
    };
    raw.calibration.repeats = 2;
    raw.calibration.line_numbers = vec![1002.2, 1002.21];
    raw.calibration.pause_s = [0.0, 1.0];
    raw.survey.line_count = 2;
    raw.survey.line_length_m = 4000.0;
    raw.crust.dipole_count = 2;
    // No geomagnetic pulsations: the residual on a box is then the
    // model's error and the sensor's noise, which the truth gives.
    raw.external.pulsation_nt = 0.0;
    raw.scalar.truncate(2);
    let flight = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let csv = folder.join("two_boxes.csv");
    magcomp::formats::write_flight_log(&flight.log, &csv).unwrap();
    (csv, flight)
}

/// Each line named calibrates on its own box's twelve manoeuvres only:
/// every window lies within that box, none in the other.
#[test]
fn a_line_number_selects_its_box_and_nothing_else() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, flight) = two_box_flight(folder.path(), 41);
    let boxes = &flight.truth.boxes;
    assert_eq!(boxes.len(), 2);
    for (line, own) in [(1002.2, 0), (1002.21, 1)] {
        let job = FlightJob {
            lines: vec![line],
            ..FlightJob::new(&csv)
        };
        let run = magcomp::pipeline::run(&job, &common::plain(), &folder.path().join("out.csv")).unwrap();
        let model = &run.result.models[0];
        let margin = 5.0 + 1e-6;
        let within = |span: &magcomp::simulate::truth::TimeSpan,
                      w: &magcomp::calibration::windows::CalibrationWindow| {
            w.t_start >= span.t_start - margin && w.t_end <= span.t_end + margin
        };
        let windows: Vec<_> = model.windows.iter().map(|w| &w.window).collect();
        assert_eq!(windows.len(), 12, "line {line}: {} windows", windows.len());
        assert!(
            windows.iter().all(|w| within(&boxes[own], w)),
            "line {line}: a window outside its box"
        );
        assert!(
            run.result.notes.iter().any(|n| matches!(
                n,
                magcomp::messages::Note::ManoeuvresByLine { counts } if counts.contains(&(line, 12))
            )),
            "line {line}: notes {:?}",
            run.result.notes
        );
    }
}

/// `magcomp detect --lines` writes only the manoeuvres of the lines named:
/// twelve within the second box's span, none of the first's; and a line the
/// flight does not hold is refused.
#[test]
fn detect_keeps_the_lines_named() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, flight) = two_box_flight(folder.path(), 43);
    let out = folder.path().join("DETECT.json");
    let detect = |lines: &str| {
        let (csv, out) = (csv.to_str().unwrap(), out.to_str().unwrap());
        Command::new(env!("CARGO_BIN_EXE_magcomp"))
            .args(["detect", csv, "--out", out, "--lines", lines])
            .output()
            .unwrap()
    };
    let run = detect("1002.21");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let said = String::from_utf8_lossy(&run.stdout);
    assert!(said.contains("12 on line 1002.21"), "{said}");
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let manoeuvres = json["manoeuvres"].as_array().unwrap();
    assert_eq!(manoeuvres.len(), 12, "{said}");
    let own = &flight.truth.boxes[1];
    for m in manoeuvres {
        let (start, end) = (m["t_start"].as_f64().unwrap(), m["t_end"].as_f64().unwrap());
        assert!(start >= own.t_start - 5.0 && end <= own.t_end + 5.0, "{m}");
    }
    let absent = detect("1003.5");
    assert!(!absent.status.success());
    assert!(
        String::from_utf8_lossy(&absent.stderr).contains("calibration line 1003.5 is not in the flight"),
        "{}",
        String::from_utf8_lossy(&absent.stderr)
    );
}

/// A line the flight does not hold is an error that lists the lines it
/// does; a flight without a line column says so; lines beside windows
/// are refused.
#[test]
fn lines_that_cannot_be_used_are_errors_that_say_why() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, _) = two_box_flight(folder.path(), 42);
    let binary = env!("CARGO_BIN_EXE_magcomp");
    let out = folder.path().join("out.csv");
    let absent = Command::new(binary)
        .args(["compensate", csv.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--plain", "--lines", "1003.5"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&absent.stderr);
    assert!(!absent.status.success());
    assert!(
        said.contains("calibration line 1003.5 is not in the flight") && said.contains("1002.21"),
        "{said}"
    );
    assert!(!out.exists(), "an output was written");

    let both = Command::new(binary)
        .args(["compensate", csv.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--lines", "1002.2", "--window", "10:20"])
        .output()
        .unwrap();
    assert!(!both.status.success());

    let bad = Command::new(binary)
        .args(["compensate", csv.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--lines", "1002.2,abc"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success() && said.contains("'abc' is not a line number"),
        "{said}"
    );

    // The same flight without its line column.
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut rows = text.lines();
    let header: Vec<&str> = rows.next().unwrap().split(',').collect();
    let line = header
        .iter()
        .position(|h| *h == "line")
        .expect("the simulator writes a line column");
    let keep = |row: &str| {
        let cells: Vec<&str> = row.split(',').collect();
        let kept: Vec<&str> = (0..cells.len()).filter(|k| *k != line).map(|k| cells[k]).collect();
        kept.join(",")
    };
    let without: Vec<String> = std::iter::once(keep(&header.join(","))).chain(rows.map(keep)).collect();
    let unnumbered = folder.path().join("unnumbered.csv");
    std::fs::write(&unnumbered, without.join("\n") + "\n").unwrap();
    let job = FlightJob {
        lines: vec![1002.2],
        ..FlightJob::new(&unnumbered)
    };
    let error = magcomp::pipeline::run(&job, &common::plain(), &folder.path().join("u.csv")).unwrap_err();
    assert!(error.to_string().contains("has no line column"), "{error}");
}

/// pipeline.toml's `lines` and a manifest's `lines` column reach the job.
#[test]
fn settings_and_manifests_carry_lines() {
    let folder = tempfile::tempdir().unwrap();
    let config = folder.path().join("pipeline.toml");
    std::fs::write(&config, "[[flight]]\ninput = \"a.csv\"\nlines = [1002.2, 1002.21]\n").unwrap();
    let pipeline = magcomp::config::Pipeline::load(&config).unwrap();
    assert_eq!(pipeline.flights[0].lines, vec![1002.2, 1002.21]);

    std::fs::write(
        &config,
        "[[flight]]\ninput = \"a.csv\"\nlines = [1002.2]\nwindows = [{ t_start = 1.0, t_end = 2.0 }]\n",
    )
    .unwrap();
    let error = magcomp::config::Pipeline::load(&config).unwrap_err();
    assert!(error.to_string().contains("both lines and windows"), "{error}");

    std::fs::write(folder.path().join("a.csv"), "t,x\n0,1\n").unwrap();
    std::fs::write(
        folder.path().join("manifest.csv"),
        "input,lines\na.csv,1002.20;1002.21\n",
    )
    .unwrap();
    std::fs::write(&config, "[campaign]\nmanifest = \"manifest.csv\"\n").unwrap();
    let pipeline = magcomp::config::Pipeline::load(&config).unwrap();
    assert_eq!(pipeline.flights[0].lines, vec![1002.2, 1002.21]);
}

/// On two-box flights each box's model is measured on the other box
/// (quality JSON `box_transfer`). The figure is the residual a user sees:
/// the model's true error there (its compensation less the true Earth
/// field, the sensor's noise included) plus the Earth field's own change
/// in the band (the sensor moves through the field's gradient as the
/// aircraft pitches and rolls). Built from the truth's two parts and the
/// model's prediction over the whole flight (not the fit's held-out
/// path), their band-passed sum matches the figure within 5 % on the tail
/// sensor and 35 % on the cabin's (this test filters each window alone;
/// the fit filters the windows as it stacks them, and back-to-back
/// manoeuvres' windows overlap: the cabin's larger misfit shows the edges,
/// measured 0.99–1.00 and 1.06–1.31), and the figure never hides the
/// error: it is at least 0.9 times the error alone. Three seeds, both
/// boxes, a tail and a cabin sensor.
#[test]
fn two_boxes_give_a_box_to_box_transfer_figure_that_matches_the_truth() {
    use magcomp::numerics::filter::ZeroPhaseFilter;
    let folder = tempfile::tempdir().unwrap();
    for seed in [61, 62, 63] {
        let (csv, flight) = two_box_flight(folder.path(), seed);
        // The flight as recorded is what the fits see: no fluxgate
        // calibration stage, whose calibrated log this test does not have.
        let mut settings = common::plain();
        settings.vector_calibration.enabled = false;
        let run = magcomp::pipeline::run(&FlightJob::new(&csv), &settings, &folder.path().join("out.csv")).unwrap();
        let log = &flight.log;
        let time = log.time_s();
        let filter = settings.fit.filter;
        let band =
            ZeroPhaseFilter::butterworth(filter.band, filter.poles, 1.0 / log.median_interval_s(), filter.padding)
                .unwrap();
        for (quality, model) in run.result.channels.iter().zip(&run.result.models) {
            let pairs: Vec<(&str, &str)> = quality
                .box_transfer
                .iter()
                .map(|t| (t.fit.as_str(), t.test.as_str()))
                .collect();
            assert_eq!(
                pairs,
                [("box 1", "box 2"), ("box 2", "box 1")],
                "seed {seed} {}",
                model.channel
            );
            let truth = flight
                .truth
                .sensors
                .iter()
                .find(|s| s.channel == model.channel)
                .unwrap();
            let recorded = &log.channel(&model.channel).unwrap().values;
            for (fit_box, transfer) in [(0usize, &quality.box_transfer[0]), (1, &quality.box_transfer[1])] {
                let test_box = &flight.truth.boxes[1 - fit_box];
                let in_box = |w: &&magcomp::model::WindowFit| {
                    let middle = 0.5 * (w.window.t_start + w.window.t_end);
                    let span = &flight.truth.boxes[fit_box];
                    middle >= span.t_start && middle <= span.t_end
                };
                let windows: Vec<_> = model.windows.iter().filter(in_box).map(|w| w.window.clone()).collect();
                let sensor = log.vector_sensors().into_iter().next().unwrap();
                let fitted = magcomp::model::fit(
                    log,
                    &sensor,
                    &model.channel,
                    &windows,
                    &model.spec,
                    &settings.fit,
                    &magcomp::numerics::stacked::StorePool::new(),
                )
                .unwrap();
                let predicted = fitted.predict(log).unwrap().interference_nt;
                // The model's error on the test box's manoeuvres, band-passed
                // as the fit band-passes: compensated less the true field.
                let (mut errors, mut sums) = (Vec::new(), Vec::new());
                for w in model.windows.iter().map(|w| &w.window) {
                    let middle = 0.5 * (w.t_start + w.t_end);
                    if !(middle >= test_box.t_start && middle <= test_box.t_end) {
                        continue;
                    }
                    let rows = w.rows(time);
                    let error: Vec<f64> = rows
                        .clone()
                        .map(|k| recorded[k] - predicted[k] - truth.earth_total_nt[k])
                        .collect();
                    let filtered = band.apply(&error).unwrap();
                    let trim = filter.trim_samples.min(filtered.len() / 4);
                    errors.extend_from_slice(&filtered[trim..filtered.len() - trim]);
                    let sum: Vec<f64> = rows
                        .clone()
                        .map(|k| error[k - rows.start] + truth.earth_total_nt[k])
                        .collect();
                    let filtered = band.apply(&sum).unwrap();
                    sums.extend_from_slice(&filtered[trim..filtered.len() - trim]);
                }
                let mut earth = Vec::new();
                for w in model.windows.iter().map(|w| &w.window) {
                    let middle = 0.5 * (w.t_start + w.t_end);
                    if !(middle >= test_box.t_start && middle <= test_box.t_end) {
                        continue;
                    }
                    let rows = w.rows(time);
                    let e: Vec<f64> = rows.clone().map(|k| truth.earth_total_nt[k]).collect();
                    let filtered = band.apply(&e).unwrap();
                    let trim = filter.trim_samples.min(filtered.len() / 4);
                    earth.extend_from_slice(&filtered[trim..filtered.len() - trim]);
                }
                let earth_std = (earth.iter().map(|v| v * v).sum::<f64>() / earth.len() as f64).sqrt();
                let mean = errors.iter().sum::<f64>() / errors.len() as f64;
                let error_std = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
                let std = |values: &[f64]| {
                    let mean = values.iter().sum::<f64>() / values.len() as f64;
                    (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
                };
                let expected = std(&sums);
                let ratio = transfer.band_std_nt / expected;
                assert!(
                    transfer.band_std_nt >= 0.9 * error_std,
                    "{transfer:?}: error {error_std}"
                );
                assert!(
                    transfer.band_std_nt >= transfer.own_fit_band_std_nt * 0.9,
                    "{transfer:?}"
                );
                println!(
                    "seed {seed} {} {}→{}: transfer {:.4} nT; true error {error_std:.4} nT and the Earth field's {earth_std:.4} nT in the band; own fit {:.4} nT",
                    model.channel, transfer.fit, transfer.test, transfer.band_std_nt, transfer.own_fit_band_std_nt
                );
                let bound = if model.channel == "mag_1_uc" { 0.05 } else { 0.35 };
                assert!(
                    (ratio - 1.0).abs() <= bound,
                    "seed {seed} {}: ratio {ratio:.3}",
                    model.channel
                );
            }
        }
    }
}
