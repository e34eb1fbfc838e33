//! Speed and memory figures: `cargo bench --bench fit`.
//!
//! 1. Fit of one channel (design matrix + band-pass + PRESS over the λ grid
//!    + TSVD check) at 1e5 and 1e6 calibration rows, median of several runs,
//!    with the peak resident set size after each size.
//! 2. A whole-file run: 200 000 rows × 100 columns with 5 scalar channels,
//!    CSV in and CSV out, against the bare time the csv crate needs to read
//!    and write the same file.

use std::path::Path;
use std::time::Instant;

use magcomp::config::{FlightJob, Pipeline};
use magcomp::fit::{fit_channel, FitOptions};
use magcomp::flight_log::{Channel, ChannelRole, FlightLog, VectorAxis};
use magcomp::pipeline::{choose_vector_sensor, process_flight, FlightOutputs, StageOptions};
use magcomp::windows::CalibrationWindow;

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

fn median_seconds(repeats: usize, mut run: impl FnMut()) -> f64 {
    let mut times: Vec<f64> = (0..repeats)
        .map(|_| {
            let start = Instant::now();
            run();
            start.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[repeats / 2]
}

fn bench_fit(rows: usize, repeats: usize) {
    let log = synthetic_log(rows);
    let sensor = choose_vector_sensor(&log, None).unwrap();
    let window = CalibrationWindow::new(0.0, log.time_s()[rows - 1]);
    let options = FitOptions::default();
    let seconds = median_seconds(repeats, || {
        let model = fit_channel(&log, &sensor, "mag_1_uc", std::slice::from_ref(&window), &options).unwrap();
        std::hint::black_box(model);
    });
    println!(
        "fit, {rows} rows, 18 terms, {} λ: median {:.1} ms over {repeats} runs; peak RSS so far {:.0} MB",
        options.solve.grid_points,
        seconds * 1e3,
        peak_rss_mb()
    );
}

fn write_wide_csv(path: &Path, rows: usize) {
    use std::io::Write;
    let (field, scalar) = synthetic_field(rows);
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut header = vec!["tt".to_string()];
    header.extend((1..=5).map(|n| format!("mag_{n}_uc")));
    header.extend(["flux_a_x", "flux_a_y", "flux_a_z"].map(String::from));
    header.extend((0..91).map(|k| format!("aux_{k}")));
    writeln!(out, "{}", header.join(",")).unwrap();
    for k in 0..rows {
        write!(out, "{:.1}", k as f64 / 10.0).unwrap();
        for n in 0..5 {
            write!(out, ",{:.3}", scalar[k] + n as f64 * 10.0).unwrap();
        }
        for axis in &field {
            write!(out, ",{:.3}", axis[k]).unwrap();
        }
        for a in 0..91 {
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
    let pipeline = Pipeline::default();
    let options = StageOptions {
        ingest: pipeline.ingest,
        fit: pipeline.fit,
        level: pipeline.level,
    };
    let windows: Vec<CalibrationWindow> = (0..8)
        .map(|w| CalibrationWindow::new(w as f64 * 300.0, w as f64 * 300.0 + 120.0))
        .collect();
    let job = FlightJob {
        input: input.clone(),
        vector: None,
        channels: None,
        windows,
    };
    let outputs = FlightOutputs::in_directory(folder.path(), &input);
    let full = median_seconds(3, || {
        process_flight(&job, &options, &outputs).unwrap();
    });
    let megabytes = std::fs::metadata(&input).unwrap().len() as f64 / 1e6;
    println!(
        "whole file, {rows} rows × 100 columns ({megabytes:.0} MB), 5 channels, {} threads: magcomp {:.0} ms, bare csv read+write {:.0} ms, ratio {:.2}; peak RSS so far {:.0} MB",
        rayon::current_num_threads(),
        full * 1e3,
        bare * 1e3,
        full / bare,
        peak_rss_mb()
    );
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
    }
    if wanted("file") {
        bench_whole_file(200_000);
    }
}
