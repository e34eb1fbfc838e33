//! Speed and memory figures: `cargo bench --bench fit`.
//!
//! 1. Fit of one channel (design matrix, band-pass, PRESS over the λ grid
//!    and the TSVD check) at 1e5 and 1e6 calibration rows, median of several
//!    runs, with the peak resident set size after each size; then the same
//!    fits in numpy and scipy (`anchors/ridge_numpy.py`, fixed λ and PRESS)
//!    on this machine, when a `python3` with them is there.
//! 2. A whole-file run: 200 000 rows × 100 columns with 5 scalar channels
//!    and a fluxgate with INS attitude (vector compensation on; `-- file
//!    novector` turns it off) and two gradients (`-- file nogradient`
//!    turns them off), CSV in and CSV out, against the bare time the csv
//!    crate needs to read and write the same file. Its windows carry no
//!    heading, so nothing is held out by heading (no estimator table, no
//!    held-out comparison of the gradient methods).
//!    The same job in Python (`anchors/whole_file_python.py`: pandas and
//!    pyarrow, numpy fits with a fixed λ) runs on the same file when a
//!    `python3` with them is there, and the speed-up over the faster is
//!    printed.
//! 3. Screening (`-- screen`): the whole sample screen of a two-hour
//!    flight at 25 Hz, and the INS-fluxgate agreement check within it.
//! 4. Format ingest: 1e6 protobuf messages from MCAP against the bare mcap +
//!    prost decode, and CSV / XYZ against the bare csv crate parse.

use std::path::Path;
use std::time::Instant;

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::config::{FlightJob, Pipeline, Settings};
use magcomp::ingest::flight_log::{Channel, ChannelRole, FlightLog, VectorAxis};
use magcomp::model::{fit, FitOptions, ModelSpec};
use magcomp::output::sink::{process_flight, FlightOutputs};
use magcomp::pipeline::choose_vector_sensor;

/// The diagnosis tests' flight helpers (the unrelated columns).
#[path = "../tests/common/mod.rs"]
mod common;

/// Peak resident set size so far, MB (Linux `VmHWM`).
fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let line = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .unwrap_or("VmHWM: 0 kB");
    line.split_whitespace()
        .nth(1)
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0)
        / 1024.0
}

/// A field that rotates like an aircraft manoeuvring, and a scalar reading
/// with a Tolles-Lawson-like interference.
fn synthetic_field(rows: usize) -> ([Vec<f64>; 3], Vec<f64>) {
    let mut field = [
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
        Vec::with_capacity(rows),
    ];
    let mut scalar = Vec::with_capacity(rows);
    for k in 0..rows {
        let t = k as f64 / 10.0;
        let (roll, pitch, yaw) = (0.17 * (t * 0.9).sin(), 0.09 * (t * 1.1).cos(), t * 0.01);
        let b = [
            20_000.0 * yaw.cos() + 900.0 * roll,
            20_000.0 * yaw.sin() + 700.0 * pitch,
            47_000.0 - 300.0 * roll * pitch,
        ];
        let total = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        let interference = 2.0 * b[0] / total - 1.5 * b[1] / total + 3e-4 * b[0] * b[2] / total;
        scalar.push(total + interference + 0.01 * ((k * 7919 % 1000) as f64 / 500.0 - 1.0));
        for axis in 0..3 {
            field[axis].push(b[axis]);
        }
    }
    (field, scalar)
}

fn synthetic_log(rows: usize) -> FlightLog {
    let (field, scalar) = synthetic_field(rows);
    let time: Vec<f64> = (0..rows).map(|k| k as f64 / 10.0).collect();
    let mut channels = vec![Channel {
        name: "mag_1_uc".into(),
        role: ChannelRole::ScalarMagnetometer,
        values: scalar,
    }];
    for (axis, values) in [VectorAxis::X, VectorAxis::Y, VectorAxis::Z].into_iter().zip(field) {
        channels.push(Channel {
            name: format!("flux_a_{}", format!("{axis:?}").to_lowercase()),
            role: ChannelRole::VectorMagnetometer {
                sensor: "flux_a".into(),
                axis,
            },
            values,
        });
    }
    FlightLog::new("synthetic", "tt", time, channels).unwrap()
}

fn median_seconds(repeats: usize, run: impl FnMut()) -> f64 {
    let times = sorted_seconds(repeats, run);
    times[repeats / 2]
}

/// Wall times of `repeats` runs, fastest first.
fn sorted_seconds(repeats: usize, mut run: impl FnMut()) -> Vec<f64> {
    let mut times: Vec<f64> = (0..repeats)
        .map(|_| {
            let start = Instant::now();
            run();
            start.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times
}

fn bench_fit(rows: usize, repeats: usize) {
    let log = synthetic_log(rows);
    let sensor = choose_vector_sensor(&log, None).unwrap();
    let window = CalibrationWindow::new(0.0, log.time_s()[rows - 1]);
    let options = FitOptions::default();
    // The repeats share one pool of stores, as the fits of a flight do.
    let stores = magcomp::numerics::stacked::StorePool::new();
    let fit = || {
        let model = fit(
            &log,
            &sensor,
            "mag_1_uc",
            std::slice::from_ref(&window),
            &ModelSpec::default(),
            &options,
            &stores,
        )
        .unwrap();
        std::hint::black_box(model);
    };
    // The first fit finds no store in the pool and takes fresh memory; the
    // repeats show a fit in a run of fits (channels, diagnosis candidates).
    let first = sorted_seconds(1, fit)[0];
    let times = sorted_seconds(repeats, fit);
    // The fastest run shows the cost with the least interference from
    // other work on the machine; the median is the usual figure.
    println!(
        "fit, {rows} rows, 18 terms, {} λ: first {:.1} ms; then median {:.1} ms, fastest {:.1} ms over {repeats} runs; peak RSS so far {:.0} MB",
        options.solve.grid_points,
        first * 1e3,
        times[repeats / 2] * 1e3,
        times[0] * 1e3,
        peak_rss_mb()
    );
}

/// A 200 000-row file of 5 scalar channels, a fluxgate, the INS attitude
/// and 88 auxiliary columns (100 in all). The fluxgate reads the Earth's
/// field rotated by the attitude, through a twelve-constant error, so the
/// vector stage fits what it would on a flight.
fn write_wide_csv(path: &Path, rows: usize) {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut header = vec!["tt".to_string()];
    header.extend((1..=5).map(|n| format!("mag_{n}_uc")));
    header.extend(["flux_a_x", "flux_a_y", "flux_a_z"].map(String::from));
    header.extend(["ins_roll", "ins_pitch", "ins_yaw"].map(String::from));
    header.extend((0..88).map(|k| format!("aux_{k}")));
    writeln!(out, "{}", header.join(",")).unwrap();
    let earth = nalgebra::Vector3::new(17_500.0, -3_900.0, 49_200.0);
    let k_error = nalgebra::Matrix3::new(1.03, 0.012, -0.008, 0.004, 0.97, 0.015, -0.011, 0.009, 1.02);
    let h_error = nalgebra::Vector3::new(950.0, -1_200.0, 640.0);
    for k in 0..rows {
        let t = k as f64 / 10.0;
        // Manoeuvres of ±10° roll and ±5° pitch, every heading in turn.
        let (roll, pitch, yaw) = (
            10.0 * (t * 0.9).sin(),
            5.0 * (t * 1.1).cos(),
            (t * 0.6).rem_euclid(360.0),
        );
        let body = magcomp::vector::body_to_ned(roll, pitch, yaw).inverse() * earth;
        let total = body.norm();
        let interference = 2.0 * body[0] / total - 1.5 * body[1] / total + 3e-4 * body[0] * body[2] / total;
        let noise = 0.01 * ((k * 7919 % 1000) as f64 / 500.0 - 1.0);
        write!(out, "{t:.1}").unwrap();
        for n in 0..5 {
            write!(out, ",{:.3}", total + (1.0 + n as f64) * interference + noise).unwrap();
        }
        let reading = k_error * body + h_error;
        for axis in 0..3 {
            write!(out, ",{:.3}", reading[axis]).unwrap();
        }
        write!(out, ",{roll:.4},{pitch:.4},{yaw:.4}").unwrap();
        for a in 0..88 {
            write!(out, ",{:.4}", ((k * (a + 3)) % 997) as f64 * 0.01).unwrap();
        }
        writeln!(out).unwrap();
    }
}

fn bare_csv_copy(input: &Path, output: &Path) {
    let mut reader = csv::Reader::from_path(input).unwrap();
    let mut writer = csv::Writer::from_path(output).unwrap();
    writer.write_byte_record(reader.byte_headers().unwrap()).unwrap();
    let mut record = csv::ByteRecord::new();
    while reader.read_byte_record(&mut record).unwrap() {
        writer.write_byte_record(&record).unwrap();
    }
    writer.flush().unwrap();
}

fn bench_whole_file(rows: usize) {
    let folder = tempfile::tempdir().unwrap();
    let input = folder.path().join("wide.csv");
    write_wide_csv(&input, rows);
    let bare = median_seconds(3, || bare_csv_copy(&input, &folder.path().join("bare.csv")));
    // Plain Tolles-Lawson: the reading, fitting and writing this figure has
    // always measured (`run` below times the default, which diagnoses).
    let mut options = Settings::default();
    options.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    // `-- file novector` times it with the vector stage off.
    options.vector.enabled = !std::env::args().any(|a| a == "novector");
    // Two gradients, fitted directly and compared with the difference
    // (`-- file nogradient` times it without).
    if !std::env::args().any(|a| a == "nogradient") {
        options.gradients = [("mag_1_uc", "mag_2_uc"), ("mag_3_uc", "mag_5_uc")]
            .map(|(a, b)| magcomp::compensate::gradient::GradientPair {
                a: a.into(),
                b: b.into(),
                separation_m: 1.5,
                axis_body: None,
                method: magcomp::compensate::gradient::GradientMethod::Auto,
            })
            .to_vec();
    }
    let windows: Vec<CalibrationWindow> = (0..8)
        .map(|w| CalibrationWindow::new(w as f64 * 300.0, w as f64 * 300.0 + 120.0))
        .collect();
    let job = FlightJob {
        windows,
        ..FlightJob::new(input.clone())
    };
    let outputs = FlightOutputs::in_directory(folder.path(), &input);
    let clock = StageClock::default();
    let full = median_seconds(3, || {
        // A new modification time: the process hashes the input again, as
        // a run on a flight does once.
        let file = std::fs::File::options().write(true).open(&input).unwrap();
        file.set_modified(std::time::SystemTime::now()).unwrap();
        drop(file);
        clock.restart();
        magcomp::output::sink::process_flight_listing(&job, &options, &outputs, &clock).unwrap();
        clock.stop();
    });
    let megabytes = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
    println!(
        "whole file, {rows} rows × 100 columns ({megabytes:.0} MB), 5 channels, vector {}, {} gradients, {} threads: magcomp {:.0} ms, bare csv read+write {:.0} ms, ratio {:.2}; peak RSS so far {:.0} MB",
        if options.vector.enabled { "on" } else { "off" },
        options.gradients.len(),
        rayon::current_num_threads(),
        full * 1e3,
        bare * 1e3,
        full / bare,
        peak_rss_mb()
    );
    println!("  where the time goes (the last run): {}", clock.shares());
    python_whole_file_anchor(&input, folder.path(), full);
}

/// The whole job in Python (`anchors/whole_file_python.py`: pandas and
/// pyarrow readers and writers, numpy fits) on the same file, and magcomp's
/// speed-up over the faster, when a `python3` with them is there.
fn python_whole_file_anchor(input: &Path, folder: &Path, magcomp_s: f64) {
    let python = std::env::var("MAGCOMP_BENCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/anchors/whole_file_python.py");
    let output = match std::process::Command::new(&python)
        .arg(script)
        .arg(input)
        .arg(folder)
        .output()
    {
        Ok(output) if output.status.success() => String::from_utf8_lossy(&output.stdout).into_owned(),
        Ok(output) => {
            let why = String::from_utf8_lossy(&output.stderr);
            println!(
                "  Python anchor not run: {python} {script} failed (numpy, scipy and pandas or pyarrow installed?): {}",
                why.lines().last().unwrap_or("")
            );
            return;
        }
        Err(e) => {
            println!("  Python anchor not run: {python}: {e}");
            return;
        }
    };
    for line in output.lines().filter(|l| !l.starts_with("fastest")) {
        println!("  Python anchor, {line}");
    }
    let fastest = output
        .lines()
        .find_map(|l| l.strip_prefix("fastest ")?.trim().parse::<f64>().ok());
    if let Some(ms) = fastest {
        println!(
            "  magcomp is {:.1}× the fastest Python anchor ({ms:.0} ms)",
            ms / (magcomp_s * 1e3)
        );
    }
}

/// A meter that keeps when each stage of a flight began: the wall time of
/// every stage of the last run.
#[derive(Default)]
struct StageClock(std::sync::Mutex<Vec<(&'static str, Instant)>>);

impl StageClock {
    fn restart(&self) {
        self.0.lock().unwrap().clear();
    }

    fn stop(&self) {
        self.0.lock().unwrap().push(("end", Instant::now()));
    }

    /// "reading 310 ms, finding the box 40 ms, …".
    fn shares(&self) -> String {
        let stages = self.0.lock().unwrap();
        (stages.windows(2))
            .map(|pair| format!("{} {:.0} ms", pair[0].0, (pair[1].1 - pair[0].1).as_secs_f64() * 1e3))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl magcomp::messages::progress::Meter for StageClock {
    fn begin(&self, stage: magcomp::messages::progress::Stage, _: u64) {
        self.0.lock().unwrap().push((stage.words(), Instant::now()));
    }
    fn step(&self) {}
}

/// A log of `rows` rows whose MCAP form holds 4 messages a row: scalar,
/// vector, two auxiliary channels.
fn format_log(rows: usize) -> FlightLog {
    let (field, scalar) = synthetic_field(rows);
    let time: Vec<f64> = (0..rows).map(|k| 1000.0 + k as f64 / 10.0).collect();
    let mut channels = vec![Channel {
        name: "mag_1_uc".into(),
        role: ChannelRole::ScalarMagnetometer,
        values: scalar,
    }];
    for (axis, values) in [VectorAxis::X, VectorAxis::Y, VectorAxis::Z].into_iter().zip(field) {
        channels.push(Channel {
            name: format!("flux_a_{}", format!("{axis:?}").to_lowercase()),
            role: ChannelRole::VectorMagnetometer {
                sensor: "flux_a".into(),
                axis,
            },
            values,
        });
    }
    for name in ["cur_a", "vol_b"] {
        channels.push(Channel {
            name: name.into(),
            role: ChannelRole::Auxiliary,
            values: (0..rows).map(|k| ((k * 7) % 101) as f64 * 0.01).collect(),
        });
    }
    FlightLog::new("bench", "tt", time, channels).unwrap()
}

/// The mcap crate's message stream plus a prost decode of every message.
fn bare_mcap_decode(path: &Path) -> usize {
    use prost::Message;
    let bytes = std::fs::read(path).unwrap();
    let mut decoded = 0;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let ok = match message.channel.topic.as_str() {
            "/mag/1/scalar" => magcomp::formats::mcap::messages::ScalarMag::decode(&message.data[..]).is_ok(),
            "/mag/a/vector" => magcomp::formats::mcap::messages::VectorMag::decode(&message.data[..]).is_ok(),
            _ => magcomp::formats::mcap::messages::Sample::decode(&message.data[..]).is_ok(),
        };
        decoded += usize::from(ok);
    }
    decoded
}

fn bare_csv_parse(path: &Path, delimiter: u8) -> usize {
    let mut reader = csv::ReaderBuilder::new().delimiter(delimiter).from_path(path).unwrap();
    let mut record = csv::ByteRecord::new();
    let mut fields = 0;
    while reader.read_byte_record(&mut record).unwrap() {
        fields += record.len();
    }
    fields
}

fn bench_formats(rows: usize) {
    use magcomp::formats::{read_flight_log, IngestOptions};
    let folder = tempfile::tempdir().unwrap();
    let log = format_log(rows);
    let options = IngestOptions::default();
    let mcap = folder.path().join("flight.mcap");
    magcomp::formats::write_flight_log(&log, &mcap).unwrap();
    let messages = rows * 4;
    let ours = median_seconds(3, || {
        std::hint::black_box(read_flight_log(&mcap, &options).unwrap());
    });
    let bare = median_seconds(3, || {
        assert_eq!(bare_mcap_decode(&mcap), messages);
    });
    println!(
        "MCAP ingest, {messages} protobuf messages ({:.0} MB): magcomp {:.0} ms = {:.2} M messages/s (decode + align); bare mcap + prost decode {:.0} ms = {:.2} M/s; peak RSS so far {:.0} MB",
        std::fs::metadata(&mcap).unwrap().len() as f64 / 1e6,
        ours * 1e3,
        messages as f64 / ours / 1e6,
        bare * 1e3,
        messages as f64 / bare / 1e6,
        peak_rss_mb()
    );
    for (extension, delimiter) in [("csv", b','), ("xyz", b' ')] {
        let path = folder.path().join(format!("flight.{extension}"));
        magcomp::formats::write_flight_log(&log, &path).unwrap();
        let ours = median_seconds(7, || {
            std::hint::black_box(read_flight_log(&path, &options).unwrap());
        });
        let bare = match extension {
            // The XYZ form has comment lines before its header; the bare
            // parse reads the same bytes after them.
            "xyz" => {
                let text = std::fs::read_to_string(&path).unwrap();
                let body: String = text
                    .lines()
                    .filter(|l| !l.starts_with("/ magcomp"))
                    .map(|l| format!("{}\n", l.trim_start_matches("/ ")))
                    .collect();
                let plain = folder.path().join("plain.txt");
                std::fs::write(&plain, body).unwrap();
                median_seconds(7, || {
                    std::hint::black_box(bare_csv_parse(&plain, delimiter));
                })
            }
            _ => median_seconds(7, || {
                std::hint::black_box(bare_csv_parse(&path, delimiter));
            }),
        };
        println!(
            "{extension} ingest, {rows} rows × 7 columns: magcomp {:.0} ms, bare csv parse {:.0} ms, ratio {:.2}",
            ours * 1e3,
            bare * 1e3,
            ours / bare
        );
    }
}

/// The same fits as a Python user writes them with numpy and scipy
/// (`benches/anchors/ridge_numpy.py`), on this machine; says so when no
/// `python3` with numpy and scipy is there (`MAGCOMP_BENCH_PYTHON` names
/// another interpreter).
fn numpy_anchor() {
    let python = std::env::var("MAGCOMP_BENCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/anchors/ridge_numpy.py");
    match std::process::Command::new(&python).arg(script).output() {
        Ok(output) if output.status.success() => print!("{}", String::from_utf8_lossy(&output.stdout)),
        Ok(output) => println!(
            "numpy anchor not run: {python} {script} failed (numpy and scipy installed?): {}",
            String::from_utf8_lossy(&output.stderr).lines().last().unwrap_or("")
        ),
        Err(e) => println!("numpy anchor not run: {python}: {e}"),
    }
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    println!(
        "machine: {} logical CPUs",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    // `cargo bench --bench fit -- fit` (or `-- file`) runs one part only.
    let only: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).collect();
    let wanted = |part: &str| only.is_empty() || only.iter().any(|o| o == part);
    if wanted("fit") {
        bench_fit(100_000, 9);
        bench_fit(1_000_000, 3);
        numpy_anchor();
    }
    // Many repeats of the small fit alone, for a profiler.
    if only.iter().any(|o| o == "profile") {
        bench_fit(100_000, 201);
    }
    if only.iter().any(|o| o == "profile-large") {
        bench_fit(1_000_000, 21);
    }
    if wanted("file") {
        bench_whole_file(200_000);
    }
    if wanted("formats") {
        bench_formats(250_000);
    }
    if wanted("simulate") {
        bench_simulate();
    }
    if wanted("diagnose") {
        bench_diagnose();
    }
    if wanted("run") {
        bench_run_default();
    }
    if wanted("run-window") {
        bench_run_one_window();
    }
    if wanted("screen") {
        bench_screen();
    }
}

/// Screening the two-hour, five-magnetometer flight at 25 Hz (about
/// 200,000 rows, one fluxgate and the INS attitude): the whole screen, and
/// the agreement check between the INS and the fluxgate within it.
fn bench_screen() {
    use magcomp::ingest::agreement::{disagreements, Masks};
    let mut scenario = two_hour_scenario();
    scenario.raw.sample_rate_hz = 25.0;
    let log = magcomp::simulate::simulate(&scenario).unwrap().log;
    let mut masked = 0;
    let screen_s = median_seconds(5, || {
        let screened = magcomp::ingest::screen::screen_samples(&log).unwrap();
        masked = usize::from(!screened.screening.is_clean());
    });
    let mut found = 0;
    let agreement_s = median_seconds(5, || {
        found = disagreements(&log, &Masks::new()).values().map(Vec::len).sum();
    });
    println!(
        "screen: {} rows, {} channels: whole screen {:.0} ms, of which the INS-fluxgate agreement {:.0} ms ({:.0} %) (medians of 5); rows masked by agreement {found}, anything masked {masked}; peak RSS {:.0} MB",
        log.len(),
        log.channels().len(),
        screen_s * 1e3,
        agreement_s * 1e3,
        100.0 * agreement_s / screen_s,
        peak_rss_mb()
    );
}

/// `compensate` with the default settings against `--plain` on a whole
/// calibration flight given as one window: the two-hour, five-magnetometer
/// flight at 25 Hz (about 200,000 rows, 30 auxiliary columns), fitted over
/// one window spanning it (held out by quarters).
fn bench_run_one_window() {
    let mut scenario = two_hour_scenario();
    scenario.raw.sample_rate_hz = 25.0;
    let flight = magcomp::simulate::simulate(&scenario).unwrap();
    let log = common::with_unrelated_columns(&flight.log, 22);
    let folder = tempfile::tempdir().unwrap();
    let input = folder.path().join("one_window.csv");
    magcomp::formats::write_flight_log(&log, &input).unwrap();
    let mut job = FlightJob::new(&input);
    let time = log.time_s();
    job.windows = vec![CalibrationWindow::new(time[0], time[log.len() - 1])];
    default_against_plain(&job, folder.path(), (log.len(), " over one window spanning the flight"));
}

/// `compensate` with the default settings (diagnose, then fit with what
/// holds out) on the two-hour, five-magnetometer, 30-column flight written
/// as CSV, against `--plain`.
fn bench_run_default() {
    let flight = two_hour_flight();
    let log = common::with_unrelated_columns(&flight.log, 22);
    let folder = tempfile::tempdir().unwrap();
    let input = folder.path().join("two_hours.csv");
    magcomp::formats::write_flight_log(&log, &input).unwrap();
    let job = FlightJob::new(&input);
    default_against_plain(&job, folder.path(), (log.len(), ""));
}

/// `compensate` of `job` with no finding applied (as `--plain`), then the
/// default,
/// outputs under `folder`: the time, the findings applied and the peak RSS
/// of each, for a flight of `rows` rows (`how` says how it was fitted).
fn default_against_plain(job: &FlightJob, folder: &Path, (rows, how): (usize, &str)) {
    for apply in [
        magcomp::diagnose::ApplyDiagnosis::Never,
        magcomp::diagnose::ApplyDiagnosis::Auto,
    ] {
        let mut options = Settings::default();
        options.diagnose.apply = apply;
        let outputs = FlightOutputs::in_directory(&folder.join(format!("{apply:?}")), &job.input);
        std::fs::create_dir_all(outputs.compensated.parent().unwrap()).unwrap();
        let start = Instant::now();
        let result = process_flight(job, &options, &outputs).unwrap();
        println!(
            "compensate{how}, apply = {apply:?}: {rows} rows, 5 scalar channels, 30 auxiliary columns, CSV in and out with report: {:.2} s, {} findings applied; peak RSS {:.0} MB",
            start.elapsed().as_secs_f64(),
            result.applied_findings.len(),
            peak_rss_mb()
        );
    }
}

/// The two-hour, five-magnetometer flight of `bench_simulate`, with 22
/// more auxiliary columns (30 in all), diagnosed on its detected box.
fn bench_diagnose() {
    let flight = two_hour_flight();
    // Slow, smooth channels (temperatures, pressures, settings).
    let log = common::with_unrelated_columns(&flight.log, 22);
    let pipeline = Pipeline::default();
    let job = magcomp::config::FlightJob::new("bench");
    let options = pipeline.settings.clone();
    let start = std::time::Instant::now();
    let diagnosis = magcomp::pipeline::diagnose_flight(&log, &job, &options, &pipeline.settings.diagnose).unwrap();
    println!(
        "diagnose: {} rows, 5 scalar channels, 30 auxiliary columns: {:.2} s, {} findings; peak RSS {:.0} MB",
        log.len(),
        start.elapsed().as_secs_f64(),
        diagnosis.findings.len(),
        peak_rss_mb()
    );
    for finding in &diagnosis.findings {
        println!(
            "  finding on a flight with no concealed effect: {} on {} from {:?}, {:.4} → {:.4} nT",
            finding.effect,
            finding.channel,
            finding.source,
            finding.heldout_rms_before_nt,
            finding.heldout_rms_after_nt
        );
    }
}

/// A two-hour flight at 10 Hz (box, then 19 lines of 18 km) with five
/// scalar magnetometers.
fn two_hour_flight() -> magcomp::simulate::SimulatedFlight {
    magcomp::simulate::simulate(&two_hour_scenario()).unwrap()
}

/// Its scenario.
fn two_hour_scenario() -> magcomp::simulate::scenario::Scenario {
    use magcomp::simulate::scenario::{RawScenario, Scenario};
    let text = r#"
        [survey]
        line_count = 19
        line_length_m = 18000.0
        [[scalar]]
        name = "mag_1_uc"
        location = "tail"
        [[scalar]]
        name = "mag_2_uc"
        location = "cabin"
        [[scalar]]
        name = "mag_3_uc"
        location = "cabin"
        [[scalar]]
        name = "mag_4_uc"
        location = "wing"
        [[scalar]]
        name = "mag_5_uc"
        location = "wing"
    "#;
    let raw: RawScenario = toml::from_str(text).unwrap();
    Scenario::try_from(raw).unwrap()
}

/// A two-hour flight at 10 Hz (box, then 19 lines of 18 km) with five
/// scalar magnetometers, simulated at the 100 Hz internal rate.
fn bench_simulate() {
    let scenario = two_hour_scenario();
    let mut rows = 0;
    let seconds = median_seconds(3, || {
        let flight = magcomp::simulate::simulate(&scenario).unwrap();
        rows = flight.log.len();
    });
    println!(
        "simulate: {rows} rows ({:.2} h at 10 Hz), 5 scalar magnetometers: {seconds:.2} s (median of 3); peak RSS {:.0} MB",
        rows as f64 / 36_000.0,
        peak_rss_mb()
    );
}
