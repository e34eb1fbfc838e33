//! End-to-end behaviour: determinism, row preservation, bad input.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use magcomp::calibration::windows::read_detect_json;
use magcomp::config::{FlightJob, Settings};
use magcomp::messages::progress::{Meter, Stage};
use magcomp::output::sink::{process_flight, process_flight_listing, FlightOutputs};
use magcomp::simulate::sample_flight::{generate, write, SampleFlightSpec};

fn small_flight(folder: &Path) -> (PathBuf, PathBuf) {
    let spec = SampleFlightSpec {
        line_count: 2,
        line_duration_s: 60.0,
        ..SampleFlightSpec::default()
    };
    let csv = folder.join("flight.csv");
    let windows = folder.join("flight.windows.json");
    write(&generate(&spec, 5), &csv, &windows).unwrap();
    (csv, windows)
}

fn options() -> Settings {
    Settings::default()
}

fn run_with_threads(threads: usize, csv: &Path, windows: &Path, out: &Path) -> Vec<u8> {
    let job = FlightJob {
        windows: read_detect_json(windows, 5.0).unwrap(),
        ..FlightJob::new(csv.to_path_buf())
    };
    let outputs = FlightOutputs::in_directory(out, csv);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| process_flight(&job, &options(), &outputs)).unwrap();
    let mut bytes = std::fs::read(&outputs.compensated).unwrap();
    bytes.extend(std::fs::read(outputs.model_json.unwrap()).unwrap());
    bytes.extend(std::fs::read(outputs.quality_json.unwrap()).unwrap());
    bytes
}

/// Each stage a flight's meter heard begin, with its steps to do and the
/// steps it heard done.
#[derive(Default)]
struct Recorder(std::sync::Mutex<Vec<(Stage, u64, u64)>>);

impl Meter for Recorder {
    fn begin(&self, stage: Stage, steps: u64) {
        self.0.lock().unwrap().push((stage, steps, 0));
    }
    fn step(&self) {
        let mut stages = self.0.lock().unwrap();
        let last = stages.last_mut().expect("a step before any stage");
        last.2 += 1;
    }
}

#[test]
fn the_meter_hears_every_stage_in_order_and_every_channel_done() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    let job = FlightJob {
        windows: read_detect_json(&windows, 5.0).unwrap(),
        ..FlightJob::new(csv.clone())
    };
    let metered = FlightOutputs::in_directory(&folder.path().join("metered"), &csv);
    let recorder = Recorder::default();
    let (result, _) = process_flight_listing(&job, &options(), &metered, &recorder).unwrap();
    let stages = recorder.0.into_inner().unwrap();
    let channels = result.channels.len() as u64;
    assert_eq!(channels, 2, "the sample flight's scalar channels");
    let expected = [
        (Stage::Reading, 0),
        (Stage::Preparing, 0),
        (Stage::Diagnosing, 2 * channels),
        (Stage::Checking, 0),
        (Stage::Fitting, channels),
        (Stage::Assessing, channels),
        (Stage::Writing, 0),
    ];
    let heard: Vec<(Stage, u64)> = stages.iter().map(|&(stage, steps, _)| (stage, steps)).collect();
    assert_eq!(heard, expected);
    for (stage, steps, done) in stages {
        assert_eq!(done, steps, "{stage:?}: {done} of {steps} steps heard done");
    }
    // The meter changes nothing the flight computes.
    let silent = FlightOutputs::in_directory(&folder.path().join("silent"), &csv);
    process_flight(&job, &options(), &silent).unwrap();
    let pairs = [
        (metered.compensated, silent.compensated),
        (metered.quality_json.unwrap(), silent.quality_json.unwrap()),
    ];
    for (a, b) in pairs {
        let same = std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap();
        assert!(same, "{} differs from {}", a.display(), b.display());
    }
}

/// The vector-compensated columns of the sample flights' fluxgate (it has
/// INS attitude and a box, so they are written by default).
const VECTOR_COLUMNS: &str = "flux_a_x_c,flux_a_y_c,flux_a_z_c,flux_a_n_c,flux_a_e_c,flux_a_d_c";

#[test]
fn outputs_are_bit_identical_for_any_thread_count() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    let one = run_with_threads(1, &csv, &windows, &folder.path().join("one"));
    let four = run_with_threads(4, &csv, &windows, &folder.path().join("four"));
    assert!(one == four, "outputs differ between 1 and 4 threads");
}

#[test]
fn every_row_and_column_survives_and_missing_rows_are_flagged() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    // Blank the fluxgate on one survey row and mag_2 on another.
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let header: Vec<&str> = lines[0].split(',').collect();
    let (flux_x, mag_2) = (
        header.iter().position(|c| *c == "flux_a_x").unwrap(),
        header.iter().position(|c| *c == "mag_2_uc").unwrap(),
    );
    let blank = |line: &mut String, column: usize, marker: &str| {
        let mut cells: Vec<String> = line.split(',').map(String::from).collect();
        cells[column] = marker.into();
        *line = cells.join(",");
    };
    let rows = lines.len() - 1;
    blank(&mut lines[rows - 100], flux_x, "");
    blank(&mut lines[rows - 50], mag_2, "*");
    std::fs::write(&csv, lines.join("\n") + "\n").unwrap();
    run_with_threads(2, &csv, &windows, folder.path());
    let out = std::fs::read_to_string(folder.path().join("flight_compensated.csv")).unwrap();
    let out_lines: Vec<&str> = out.lines().collect();
    assert_eq!(out_lines.len(), lines.len(), "every input row is written");
    assert_eq!(
        out_lines[0],
        format!(
            "{},mag_1_c,mag_1_c_sigma,mag_2_c,mag_2_c_sigma,{VECTOR_COLUMNS},flags",
            lines[0]
        )
    );
    for (input, output) in lines.iter().zip(&out_lines).skip(1) {
        assert!(output.starts_with(input.as_str()), "input columns are copied unchanged");
    }
    let cells = |line: &str| line.split(',').map(String::from).collect::<Vec<_>>();
    // Without the fluxgate: no compensated scalar and no vector.
    let vector_gap = cells(out_lines[rows - 100]);
    assert_eq!(
        vector_gap[vector_gap.len() - 11..],
        ["", "", "", "", "", "", "", "", "", "", "missing_vector:flux_a"]
    );
    // Without mag_2: neither its value nor its sigma; mag_1's sigma is a
    // positive number of nT.
    let scalar_gap = cells(out_lines[rows - 50]);
    let n = scalar_gap.len();
    assert_eq!(scalar_gap[n - 9..n - 7], ["", ""]);
    let sigma_1: f64 = scalar_gap[n - 10].parse().unwrap();
    assert!(sigma_1 > 0.0 && sigma_1 < 1.0, "{sigma_1}");
    assert!(scalar_gap[n - 11].parse::<f64>().is_ok());
    assert!(scalar_gap[n - 7..n - 1].iter().all(|c| c.parse::<f64>().is_ok()));
    assert_eq!(scalar_gap[scalar_gap.len() - 1], "missing_scalar:mag_2_uc");
    assert!(!cells(out_lines[rows - 49]).last().unwrap().contains("missing"));
}

fn magcomp(args: &[&str]) -> (bool, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_magcomp")).args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "magcomp panicked: {stderr}");
    (output.status.success(), stderr)
}

fn write_file(folder: &Path, name: &str, text: &str) -> PathBuf {
    let path = folder.join(name);
    std::fs::File::create(&path)
        .unwrap()
        .write_all(text.as_bytes())
        .unwrap();
    path
}

/// A copy of the sample flight `clean.csv` in `folder`, as flight.csv.
fn sample_flight_in(folder: &Path) -> PathBuf {
    let flight = folder.join("flight.csv");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_flights/clean.csv"),
        &flight,
    )
    .unwrap();
    flight
}

/// A bad file must fail with an error whose text contains every `expected` fragment.
fn assert_fails_with(folder: &Path, name: &str, text: &str, expected: &[&str]) {
    let input = write_file(folder, name, text);
    let out = folder.join("out.csv");
    let (ok, stderr) = magcomp(&[
        "compensate",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--window",
        "0:100",
    ]);
    assert!(!ok, "{name} should fail");
    for fragment in expected {
        assert!(stderr.contains(fragment), "{name}: '{fragment}' missing from: {stderr}");
    }
    // A fix that fits another fault is a wrong cause: the ragged-row
    // advice only where the row is ragged.
    let ragged = "one field per header column";
    if !expected.iter().any(|e| e.contains(ragged)) {
        assert!(
            !stderr.contains(ragged),
            "{name}: the ragged-row fix for another fault: {stderr}"
        );
    }
    assert!(!out.exists(), "{name}: no partial output may be left");
}

#[test]
fn bad_input_gives_the_documented_error_not_a_panic() {
    let folder = tempfile::tempdir().unwrap();
    let f = folder.path();
    let header = "tt,mag_1_uc,flux_a_x,flux_a_y,flux_a_z\n";
    assert_fails_with(
        f,
        "ragged.csv",
        &format!("{header}0,50000,20000,5000,45000\n0.1,50000,20000,5000\n"),
        &["line 3", "4 fields", "header has 5", "one field per header column"],
    );
    assert_fails_with(
        f,
        "text.csv",
        &format!("{header}0,50000,20000,5000,45000\n0.1,50000,20000,abc,45000\n"),
        &["line 3", "'flux_a_y'", "'abc'"],
    );
    // A line under the header with a unit for time and a number elsewhere
    // is neither a row of units (read as such) nor data: it is named, with
    // its fix; a word in another column of that line is a bad cell, not
    // units.
    assert_fails_with(
        f,
        "units.csv",
        &format!("{header}s,nT,20000,nT,nT\n0,50000,20000,5000,45000\n0.1,50000,20000,5000,45000\n"),
        &[
            "units.csv",
            "line 2",
            "column 'flux_a_x'",
            "'20000' is a number",
            "row of units",
        ],
    );
    assert_fails_with(
        f,
        "word_on_line_2.csv",
        &format!("{header}0,50000,20000,abc,45000\n0.1,50000,20000,5000,45000\n"),
        &["line 2", "'flux_a_y'", "'abc' is not a number. Correct the cell"],
    );
    assert_fails_with(
        f,
        "backwards.csv",
        &format!("{header}0,50000,20000,5000,45000\n0.2,50000,20000,5000,45000\n0.1,50000,20000,5000,45000\n"),
        &["line 4", "'tt'", "0.2 to 0.1"],
    );
    assert_fails_with(
        f,
        "all_missing.csv",
        &format!("{header}0,,20000,5000,45000\n0.1,*,20000,5000,45000\n"),
        &["'mag_1_uc'", "no valid sample"],
    );
    assert_fails_with(
        f,
        "no_fluxgate.csv",
        "tt,mag_1_uc\n0,50000\n0.1,50001\n",
        &["vector magnetometer", "--vector"],
    );
    assert_fails_with(f, "empty.csv", "", &["empty.csv", "the file is empty (0 bytes)"]);
    assert_fails_with(
        f,
        "twice.csv",
        "tt,mag_1_uc,flux_a_x,flux_a_y,mag_1_uc\n0,50000,20000,5000,45000\n",
        &[
            "twice.csv",
            "line 1",
            "'mag_1_uc' appears twice",
            "fields 2 and 5",
            "Rename one",
        ],
    );
    assert_fails_with(
        f,
        "header_only.csv",
        header,
        &["header_only.csv", "header line but no data rows"],
    );
    assert_fails_with(
        f,
        "one_row.csv",
        &format!("{header}0,50000,20000,5000,45000\n"),
        &["one_row.csv", "1 row(s)", "two samples at distinct times"],
    );
    assert_fails_with(
        f,
        "elsewhere.csv",
        &format!("{header}500,50000,20000,5000,45000\n500.1,50000,20000,5000,45000\n"),
        &[
            "elsewhere.csv",
            "holds no row",
            "runs 500 to 500.1 s",
            "made for this flight",
        ],
    );
    assert_fails_with(
        f,
        "carriage_returns.csv",
        &format!("{header}0,50000,20000,5000,45000\n0.1,50000,20000,5000,45000\n").replace('\n', "\r"),
        &["carriage_returns.csv", "carriage return alone", "tr '\\r' '\\n'"],
    );
    assert_fails_with(
        f,
        "huge_cell.csv",
        &format!(
            "{header}0,50000,20000,5000,45000
0.1,1,2,{},4
",
            "x".repeat(2_000_000)
        ),
        &["line 3", "'flux_a_y'", "(2000000 bytes in all)"],
    );
    assert_fails_with(
        f,
        "short_window.csv",
        &format!("{header}0,50000,20000,5000,45000\n0.1,50000,20000,5000,45000\n0.2,50000,20000,5000,45000\n"),
        &[
            "calibration window",
            "longest run of valid samples has 3",
            "at least 41",
        ],
    );
}

#[test]
fn a_typo_in_pipeline_toml_is_named() {
    let folder = tempfile::tempdir().unwrap();
    let config = write_file(folder.path(), "pipeline.toml", "[fit]\nlamda = 0.1\n");
    let (ok, stderr) = magcomp(&["run", config.to_str().unwrap()]);
    assert!(!ok);
    assert!(stderr.contains("lamda") && stderr.contains("pipeline.toml"), "{stderr}");
}

#[test]
fn compensate_command_writes_all_outputs_and_honours_fixed_lambda() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    let out = folder.path().join("c.csv");
    let model = folder.path().join("m.json");
    let report = folder.path().join("q.json");
    let args = [
        "compensate",
        csv.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--windows-file",
        windows.to_str().unwrap(),
        "--lambda",
        "0.001",
        "--channels",
        "mag_1_uc",
    ];
    let (ok, stderr) = magcomp(&args);
    assert!(ok, "{stderr}");
    let model: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(model).unwrap()).unwrap();
    assert_eq!(model["models"][0]["solution"]["lambda"], 0.001);
    assert_eq!(model["models"][0]["term_names"].as_array().unwrap().len(), 16);
    let quality: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
    assert_eq!(quality["channels"][0]["fom_manoeuvres"], 12);
}

#[test]
fn awkward_csv_text_is_copied_verbatim() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    // A byte-order mark, CRLF line ends, a quoted text column holding a
    // comma and a quote, a blank line, and no terminator on the last row.
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(i, line)| match i {
            0 => format!("\u{feff}{line},note"),
            _ => format!("{line},\"leg {}, \"\"box\"\"\"", i % 7),
        })
        .collect();
    let blank_after = lines.len() / 2;
    let mut awkward = String::new();
    for (i, line) in lines.iter().enumerate() {
        awkward.push_str(line);
        if i + 1 < lines.len() {
            awkward.push_str("\r\n");
        }
        if i == blank_after {
            awkward.push_str("\r\n");
        }
    }
    std::fs::write(&csv, &awkward).unwrap();
    run_with_threads(2, &csv, &windows, folder.path());
    let out = std::fs::read_to_string(folder.path().join("flight_compensated.csv")).unwrap();
    let out_lines: Vec<&str> = out.split('\n').filter(|l| !l.is_empty()).collect();
    assert_eq!(out_lines.len(), lines.len(), "one output line per input record");
    assert_eq!(
        out_lines[0],
        format!(
            "{},mag_1_c,mag_1_c_sigma,mag_2_c,mag_2_c_sigma,{VECTOR_COLUMNS},flags",
            lines[0]
        )
    );
    for (input, output) in lines.iter().zip(&out_lines).skip(1) {
        let appended = output
            .strip_prefix(input.as_str())
            .expect("input record copied unchanged");
        let cells: Vec<&str> = appended.split(',').collect();
        // Empty first cell (after the input's last comma), then mag_1_c,
        // its sigma, mag_2_c, its sigma, six vector cells and the flags.
        assert_eq!(cells.len(), 12, "{appended}");
        assert!(cells[1..5].iter().all(|c| c.parse::<f64>().is_ok()), "{appended}");
    }
}

#[test]
fn the_vector_calibration_stage_calibrates_the_fluxgate_before_the_fit() {
    // concealed_c's fluxgate has scale factors (1.015, 0.985, 1.01) and
    // offsets of up to 120 nT.
    let folder = tempfile::tempdir().unwrap();
    let input = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sample_flights/concealed_c.csv");
    let job = FlightJob::new(input.clone());
    let plain = process_flight(
        &job,
        &options(),
        &FlightOutputs::in_directory(&folder.path().join("plain"), &input),
    )
    .unwrap();
    let mut calibrating = options();
    calibrating.vector_calibration.enabled = true;
    let outputs = FlightOutputs::in_directory(&folder.path().join("calibrated"), &input);
    let calibrated = process_flight(&job, &calibrating, &outputs).unwrap();
    assert!(plain.vector_calibration.is_none());
    let calibration = calibrated.vector_calibration.as_ref().unwrap();
    // The tail sensor is the quietest reference. The aircraft's own field
    // at the fluxgate (induced coefficients of about 2e-3) is calibrated
    // with the sensor's errors, hence 3e-3 on the scale factors.
    assert_eq!(calibration.reference, "mag_1_uc");
    for (fitted, truth) in calibration.scale.iter().zip([1.015, 0.985, 1.01]) {
        assert!((fitted - truth).abs() < 3e-3, "scale {:?}", calibration.scale);
    }
    assert!(calibration.mismatch_rms_before_nt > 100.0 && calibration.mismatch_rms_after_nt < 1.0);
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(outputs.model_json.unwrap()).unwrap()).unwrap();
    assert_eq!(model["vector_calibration"]["reference"], "mag_1_uc");
    // The recorded fluxgate columns are written back unchanged.
    let original = std::fs::read_to_string(&input).unwrap();
    let written = std::fs::read_to_string(&outputs.compensated).unwrap();
    let column = |text: &str, name: &str| -> Vec<String> {
        let mut lines = text.lines();
        let index = lines.next().unwrap().split(',').position(|h| h == name).unwrap();
        lines.map(|l| l.split(',').nth(index).unwrap().to_string()).collect()
    };
    assert_eq!(column(&original, "flux_a_x"), column(&written, "flux_a_x"));
    // Tolles-Lawson absorbs most fluxgate errors: the compensation on the
    // calibrated fluxgate is as good as on the raw one, within 10 %.
    for (a, b) in plain.channels.iter().zip(&calibrated.channels) {
        assert!(
            b.band_std_after_nt < 1.1 * a.band_std_after_nt,
            "{}: {} against {}",
            a.channel,
            b.band_std_after_nt,
            a.band_std_after_nt
        );
    }
}

#[test]
fn compensating_a_flight_without_the_models_channel_is_an_error() {
    use magcomp::compensate::{compensate, LevelConvention};
    use magcomp::ingest::flight_log::FlightLog;
    use magcomp::model::{fit, FitOptions, ModelSpec};
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    let log = magcomp::formats::read_flight_log(&csv, &Default::default()).unwrap();
    let sensor = magcomp::pipeline::choose_vector_sensor(&log, None).unwrap();
    let model = fit(
        &log,
        &sensor,
        "mag_1_uc",
        &read_detect_json(&windows, 5.0).unwrap(),
        &ModelSpec::default(),
        &FitOptions::default(),
        &Default::default(),
    )
    .unwrap();
    let models = vec![model];
    let channels = log
        .channels()
        .iter()
        .filter(|c| c.name != "mag_1_uc")
        .cloned()
        .collect();
    let other = FlightLog::new(log.source(), log.time_column(), log.time_s().to_vec(), channels).unwrap();
    let error = compensate(&other, &models, LevelConvention::Absolute)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("'mag_1_uc', which the model of 'mag_1_uc' uses"),
        "{error}"
    );
}

/// Input that is not text, or not a file, is refused with the file, the
/// place and what to do, not with a reader's inner words.
#[test]
fn a_file_that_is_not_text_or_not_a_regular_file_is_named_with_the_fix() {
    let folder = tempfile::tempdir().unwrap();
    let header = b"tt,mag_\xff1_uc,flux_a_x,flux_a_y,flux_a_z\n0,50000,20000,5000,45000\n0.1,50000,20000,5000,45000\n";
    let input = folder.path().join("latin1.csv");
    std::fs::write(&input, header).unwrap();
    let out = folder.path().join("out.csv");
    let (ok, stderr) = magcomp(&["compensate", input.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!ok);
    for fragment in [
        "latin1.csv",
        "line 1",
        "not valid text (UTF-8)",
        "Export the file again as UTF-8",
    ] {
        assert!(stderr.contains(fragment), "'{fragment}' missing from: {stderr}");
    }
    assert!(!stderr.contains("one field per header column"), "{stderr}");
    #[cfg(unix)]
    {
        let pipe = folder.path().join("pipe.csv");
        let made = Command::new("mkfifo").arg(&pipe).status();
        match made {
            Ok(status) if status.success() => {
                let (ok, stderr) = magcomp(&["compensate", pipe.to_str().unwrap(), "--out", out.to_str().unwrap()]);
                assert!(!ok);
                for fragment in ["pipe.csv", "not a regular file", "write it to a file first"] {
                    assert!(stderr.contains(fragment), "'{fragment}' missing from: {stderr}");
                }
                assert!(!stderr.contains("is empty"), "a pipe is not an empty file: {stderr}");
            }
            _ => println!("mkfifo is not available here: the named-pipe case was not run"),
        }
    }
    assert!(!out.exists());
}

/// `run` makes its output folder, and a flight whose input is missing
/// fails alone: the next flight is compensated and the table comes.
#[test]
fn run_makes_its_output_folder_and_a_missing_first_flight_fails_alone() {
    let folder = tempfile::tempdir().unwrap();
    sample_flight_in(folder.path());
    let config = write_file(
        folder.path(),
        "pipeline.toml",
        "[output]\ndirectory = \"made/here\"\n[vector]\nenabled = false\n[diagnose]\napply = \"never\"\n[[flight]]\ninput = \"missing.csv\"\n[[flight]]\ninput = \"flight.csv\"\n",
    );
    let output = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["run", config.to_str().unwrap()])
        .current_dir(folder.path())
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr),
    );
    assert!(!output.status.success(), "one flight failed: {stdout}{stderr}");
    assert!(
        (stdout.lines()).any(|l| l.starts_with("created the output folder") && l.ends_with("made/here")),
        "{stdout}"
    );
    assert!(
        stderr.contains("missing.csv") && stderr.contains("1 of 2 flights failed"),
        "{stderr}"
    );
    // The cause is the missing input, not the output folder.
    assert!(
        stderr.contains("No such file") && !stderr.contains("made/here"),
        "{stderr}"
    );
    let table = stdout.split("\nflight ").nth(1).expect("the status table");
    assert!(table.contains("missing.csv") && table.contains("FAILED"), "{table}");
    assert!(table.contains("flight.csv") && table.contains("ok,"), "{table}");
    assert!(folder.path().join("made/here/flight_compensated.csv").is_file());
}

/// The added columns are written at the stated resolution, 0.001 nT by
/// default and `[output] decimals` when given, in place of the 17 digits
/// of a double; a resolution no double holds is refused.
#[test]
fn added_columns_are_written_at_the_stated_resolution() {
    let folder = tempfile::tempdir().unwrap();
    let flight = sample_flight_in(folder.path());
    let compensate = |config: Option<&str>, out: &str| -> (bool, String, Vec<Vec<String>>) {
        let out = folder.path().join(out);
        let mut args = vec![
            "compensate".to_string(),
            flight.display().to_string(),
            "--out".into(),
            out.display().to_string(),
            "--plain".into(),
        ];
        if let Some(text) = config {
            let path = write_file(folder.path(), "settings.toml", text);
            args.extend(["--config".into(), path.display().to_string()]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (ok, stderr) = magcomp(&args);
        let text = std::fs::read_to_string(&out).unwrap_or_default();
        let rows = text.lines().map(|l| l.split(',').map(String::from).collect()).collect();
        (ok, stderr, rows)
    };
    let decimals_of = |cell: &str| cell.split_once('.').map_or(0, |(_, f)| f.len());
    let (ok, stderr, default) = compensate(None, "default.csv");
    assert!(ok, "{stderr}");
    let header = &default[0];
    let at = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (value, sigma, raw) = (at("mag_1_c"), at("mag_1_c_sigma"), at("mag_1_uc"));
    let most = |rows: &[Vec<String>], column: usize| rows[1..].iter().map(|r| decimals_of(&r[column])).max().unwrap();
    assert_eq!(most(&default, value), 3);
    assert_eq!(most(&default, sigma), 3);
    // The input's cells are copied as they are.
    let input = std::fs::read_to_string(&flight).unwrap();
    for (line, row) in input.lines().zip(&default).skip(1).take(50) {
        assert_eq!(line.split(',').nth(raw).unwrap(), row[raw]);
    }
    let (ok, stderr, coarse) = compensate(Some("[output]\ndecimals = 1\n"), "coarse.csv");
    assert!(ok, "{stderr}");
    assert_eq!(most(&coarse, value), 1);
    for (fine, coarse) in default[1..].iter().zip(&coarse[1..]) {
        let (fine, coarse): (f64, f64) = (fine[value].parse().unwrap(), coarse[value].parse().unwrap());
        assert!((fine - coarse).abs() <= 0.05 + 1e-9, "{fine} → {coarse}");
    }
    let (ok, stderr, _) = compensate(Some("[output]\ndecimals = 11\n"), "refused.csv");
    assert!(
        !ok && stderr.contains("[output] decimals = 11") && stderr.contains("0 to 10"),
        "{stderr}"
    );
}

/// `compensate` prints one line per channel, lists every file it writes,
/// and prints the fits' details and a flight's notes only with `-v` (the
/// notes' count otherwise); the warnings always.
#[test]
fn compensate_lists_what_it_writes_and_prints_notes_with_verbose() {
    let folder = tempfile::tempdir().unwrap();
    let flight = sample_flight_in(folder.path());
    let stdout_of = |verbose: bool| -> String {
        let out = folder.path().join("out.csv");
        let mut command = Command::new(env!("CARGO_BIN_EXE_magcomp"));
        command.args([
            "compensate",
            flight.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--plain",
        ]);
        if verbose {
            command.arg("-v");
        }
        let output = command.output().unwrap();
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        String::from_utf8_lossy(&output.stdout).into_owned()
    };
    let quiet = stdout_of(false);
    let notes: usize = (quiet.lines())
        .find_map(|l| l.trim().strip_suffix(" in the report (-v prints them)"))
        .and_then(|l| l.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("a count of the notes: {quiet}"));
    assert!(notes > 0 && !quiet.contains("note:"), "{quiet}");
    let written: Vec<&str> = quiet.lines().filter_map(|l| l.trim().strip_prefix("wrote ")).collect();
    for name in ["out.csv", "out_report.html", "out_report.json"] {
        assert!(written.iter().any(|w| w.ends_with(name)), "{name} not listed: {quiet}");
    }
    for path in &written {
        assert!(Path::new(path).is_file(), "{path} is listed but not there");
    }
    // One line per channel: its verdict against the limit, FOM, IR and
    // held-out FOM; the fit's details only with -v.
    for channel in ["mag_1_uc", "mag_2_uc"] {
        let lines: Vec<&str> = quiet
            .lines()
            .filter(|l| l.starts_with(&format!("  {channel}: ")))
            .collect();
        assert_eq!(lines.len(), 1, "{quiet}");
        let line = lines[0];
        assert!(
            line.contains(": PASS  FOM ")
                && line.contains("(limit 1.50; 12 of 12 manoeuvres)")
                && line.contains(", IR ")
                && line.contains(", held out "),
            "{line}"
        );
    }
    assert!(!quiet.contains("fit on flux_a"), "{quiet}");
    let loud = stdout_of(true);
    assert_eq!(loud.matches("  note: ").count(), notes, "{loud}");
    assert_eq!(loud.matches("    fit on flux_a: ").count(), 2, "{loud}");
}

/// A row of units under the header is read as units, not data: the flight
/// compensates exactly as without the row, the compensated CSV keeps the
/// row with the added columns' units, the quality JSON's notes say so, and
/// a unit other than the one magcomp reads (time in ms) is a warning. The
/// same holds for a `;`-separated input, which is written comma-separated.
#[test]
fn a_row_of_units_under_the_header_is_read_as_units_and_kept() {
    let folder = tempfile::tempdir().unwrap();
    let plain = sample_flight_in(folder.path());
    let text = std::fs::read_to_string(&plain).unwrap();
    let (header, rows) = text.split_once('\n').unwrap();
    let unit_of = |name: &str| match name {
        "tt" => "s",
        "diurnal" => "nT",
        n if n.starts_with("mag_") || n.starts_with("flux_") => "nT",
        n if n.starts_with("ins_") => "deg",
        n if n.starts_with("cur_") => "A",
        "vol_bus" => "V",
        _ => "",
    };
    let units: Vec<&str> = header.split(',').map(unit_of).collect();
    let compensate = |input: &Path, name: &str| -> (Vec<String>, serde_json::Value) {
        let out = folder.path().join(format!("{name}_out.csv"));
        let report = folder.path().join(format!("{name}_quality.json"));
        let (ok, stderr) = magcomp(&[
            "compensate",
            input.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
            "--plain",
        ]);
        assert!(ok, "{name}: {stderr}");
        let lines = std::fs::read_to_string(&out)
            .unwrap()
            .lines()
            .map(String::from)
            .collect();
        let json = serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
        (lines, json)
    };
    let sentences = |json: &serde_json::Value, key: &str| -> Vec<String> {
        (json[key].as_array().unwrap().iter())
            .map(|s| s.as_str().unwrap().to_string())
            .collect()
    };
    let (expected, plain_json) = compensate(&plain, "plain");
    let added: Vec<&str> = expected[0].split(',').skip(units.len()).collect();
    assert!(added.len() >= 3 && added.last() == Some(&"flags"), "{added:?}");
    let added_units: Vec<&str> = (added.iter())
        .map(|name| if *name == "flags" { "" } else { "nT" })
        .collect();
    assert!(sentences(&plain_json, "notes")
        .iter()
        .all(|n| !n.contains("row of units")));

    for (name, separator, time_unit) in [("units", ",", "s"), ("units_ms", ";", "ms")] {
        let mut declared = units.clone();
        declared[0] = time_unit;
        let body = format!("{header}\n{}\n{rows}", declared.join(","));
        let input = write_file(folder.path(), &format!("{name}.csv"), &body.replace(',', separator));
        let (lines, json) = compensate(&input, name);
        assert_eq!(lines.len(), expected.len() + 1, "{name}: one line more, the units");
        assert_eq!(lines[0], expected[0], "{name}: the header");
        let units_line: Vec<&str> = declared.iter().chain(&added_units).copied().collect();
        assert_eq!(
            lines[1],
            units_line.join(","),
            "{name}: the units, with the added columns'"
        );
        let differing = (lines[2..].iter().zip(&expected[1..])).filter(|(a, b)| a != b).count();
        assert_eq!(differing, 0, "{name}: every row as compensated without the units row");
        let notes = sentences(&json, "notes");
        assert!(
            notes
                .iter()
                .any(|n| n.contains("line 2 of")
                    && n.contains(&format!("is a row of units (tt {time_unit}, mag_1_uc nT"))),
            "{name}: {notes:?}"
        );
        let warnings = sentences(&json, "warnings");
        let about_time = warnings
            .iter()
            .filter(|w| w.contains("gives 'ms' for the column 'tt'"))
            .count();
        assert_eq!(about_time, usize::from(time_unit == "ms"), "{name}: {warnings:?}");
        // Amperes, volts and an empty cell say nothing.
        assert!(!warnings.iter().any(|w| w.contains("row of units gives '")) || time_unit == "ms");
    }
}

/// Each channel's line names the findings applied to it, a fluxgate
/// calibration found against a channel included (concealed_c's fluxgate
/// is miscalibrated, and its mag_2_uc has an eddy-current time constant).
#[test]
fn each_channel_line_names_the_findings_applied_to_it() {
    let folder = tempfile::tempdir().unwrap();
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("sample_flights/concealed_c.csv");
    let out = folder.path().join("out.csv");
    let output = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["compensate", flight.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let line = |channel: &str| {
        (stdout.lines())
            .find(|l| l.starts_with(&format!("  {channel}: ")))
            .unwrap_or_else(|| panic!("no line for {channel}: {stdout}"))
            .to_string()
    };
    assert!(
        line("mag_1_uc").ends_with("; findings applied: vector_calibration of flux_a"),
        "{stdout}"
    );
    assert!(
        line("mag_2_uc").contains("findings applied: eddy_time_constant"),
        "{stdout}"
    );
    let bought = stdout
        .lines()
        .skip_while(|l| !l.starts_with("  diagnosis applied"))
        .skip(1);
    assert_eq!(bought.take_while(|l| l.starts_with("    ")).count(), 2, "{stdout}");
}
