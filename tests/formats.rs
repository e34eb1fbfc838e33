//! Every format ingests to the same flight log, and the pipeline gives the
//! same compensated values on each.

use std::path::{Path, PathBuf};

use magcomp::calibration::windows::read_detect_json;
use magcomp::config::{FlightJob, Settings};
use magcomp::formats::write_flight_log;
use magcomp::formats::{read_flight_log, IngestOptions};
use magcomp::ingest::flight_log::FlightLog;
use magcomp::messages::{Reading, Warning};
use magcomp::output::sink::{process_flight, FlightOutputs};
use magcomp::simulate::sample_flight::{generate, write, SampleFlightSpec};

fn small_flight(folder: &Path) -> (PathBuf, PathBuf) {
    let spec = SampleFlightSpec {
        line_count: 2,
        line_duration_s: 60.0,
        ..SampleFlightSpec::default()
    };
    let csv = folder.join("flight.csv");
    let windows = folder.join("flight.windows.json");
    write(&generate(&spec, 11), &csv, &windows).unwrap();
    (csv, windows)
}

/// Asserts two logs hold the same samples; `tolerance` is relative.
fn assert_same_log(a: &FlightLog, b: &FlightLog, tolerance: f64) {
    assert_eq!(a.len(), b.len(), "row count");
    let close = |x: f64, y: f64| (x.is_nan() && y.is_nan()) || (x - y).abs() <= tolerance * x.abs().max(1.0);
    assert!(a.time_s().iter().zip(b.time_s()).all(|(x, y)| close(*x, *y)), "time");
    assert_eq!(a.channels().len(), b.channels().len(), "channel count");
    for channel in a.channels() {
        let other = b
            .channel(&channel.name)
            .unwrap_or_else(|| panic!("{} missing", channel.name));
        assert_eq!(channel.role, other.role, "{}", channel.name);
        let worst = channel
            .values
            .iter()
            .zip(&other.values)
            .position(|(x, y)| !close(*x, *y));
        assert!(worst.is_none(), "{} differs at row {worst:?}", channel.name);
    }
}

fn options() -> Settings {
    Settings::default()
}

/// Compensated values of `column` from a CSV or XYZ output.
fn output_column(path: &Path, column: &str) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let xyz = path.extension().is_some_and(|e| e == "xyz");
    let split = |line: &str| -> Vec<String> {
        match xyz {
            true => line.split_ascii_whitespace().map(String::from).collect(),
            false => line.split(',').map(String::from).collect(),
        }
    };
    let mut lines = text.lines().filter(|l| !l.starts_with("Line "));
    let header = loop {
        let line = lines.next().unwrap();
        if xyz && line.starts_with('/') && line.contains(column) {
            break split(line.trim_start_matches('/'));
        }
        if !xyz {
            break split(line);
        }
    };
    let index = header.iter().position(|h| h == column).unwrap();
    lines
        .filter(|l| !l.starts_with('/'))
        .map(|l| {
            let cells = split(l);
            match cells[index].as_str() {
                "*" => String::new(),
                v => v.to_string(),
            }
        })
        .collect()
}

#[test]
fn every_format_ingests_to_the_same_log_and_compensates_identically() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    let ingest = IngestOptions::default();
    let from_csv = read_flight_log(&csv, &ingest).unwrap();
    let xyz = folder.path().join("flight.xyz");
    write_flight_log(&from_csv, &xyz).unwrap();
    let from_xyz = read_flight_log(&xyz, &ingest).unwrap();
    // Shortest round-trip number text: exact.
    assert_same_log(&from_csv, &from_xyz, 0.0);
    let mcap = folder.path().join("flight.mcap");
    write_flight_log(&from_csv, &mcap).unwrap();
    let from_mcap = read_flight_log(&mcap, &ingest).unwrap();
    // Doubles are stored as they are and times as integer nanoseconds, which
    // give back the same doubles for times of 0.1 s resolution.
    assert_same_log(&from_csv, &from_mcap, 0.0);
    let report = from_mcap.alignment().expect("an MCAP log records its alignment");
    assert_eq!(report.time_base, "mag_1_uc");
    assert!(report
        .channels
        .iter()
        .all(|c| c.rows_in_gaps == 0 && c.rows_outside == 0));

    let hdf5 = folder.path().join("flight.h5");
    write_flight_log(&from_csv, &hdf5).unwrap();
    assert_same_log(&from_csv, &read_flight_log(&hdf5, &ingest).unwrap(), 0.0);

    let mut compensated = Vec::new();
    for input in [&csv, &xyz, &mcap, &hdf5] {
        let job = FlightJob {
            windows: read_detect_json(&windows, 5.0).unwrap(),
            ..FlightJob::new(input.clone())
        };
        let outputs = FlightOutputs::in_directory(&folder.path().join("out"), input);
        process_flight(&job, &options(), &outputs).unwrap();
        let bits = |v: f64| if v.is_nan() { u64::MAX } else { v.to_bits() };
        let column = |name: &str| -> Vec<u64> {
            match outputs.compensated.extension().is_some_and(|e| e == "mcap") {
                // MCAP in, MCAP out: /mag/1/compensated reads back as
                // mag_1_c and /mag/1/compensated_sigma as mag_1_c_sigma.
                true => read_flight_log(&outputs.compensated, &ingest)
                    .unwrap()
                    .channel(name)
                    .unwrap_or_else(|| panic!("{name} is written to MCAP"))
                    .values
                    .iter()
                    .map(|&v| bits(v))
                    .collect(),
                false => output_column(&outputs.compensated, name)
                    .iter()
                    .map(|v| v.parse::<f64>().map_or(u64::MAX, bits))
                    .collect(),
            }
        };
        let (values, sigma) = (column("mag_1_c"), column("mag_1_c_sigma"));
        assert!(sigma.iter().any(|&s| s != u64::MAX), "{input:?}: a sigma column");
        compensated.push([values, sigma].concat());
    }
    assert_eq!(compensated[0].len(), 2 * from_csv.len());
    assert!(
        compensated[0] == compensated[1],
        "CSV and XYZ inputs compensate differently"
    );
    assert!(
        compensated[0] == compensated[2],
        "CSV and MCAP inputs compensate differently"
    );
    assert!(
        compensated[0] == compensated[3],
        "CSV and HDF5 inputs compensate differently"
    );
}

/// Asserts `log` (read from the fixture `name`) holds exactly the first
/// `rows` rows of `sample`: times, channels, roles and values bit for bit.
fn assert_first_rows(log: &FlightLog, sample: &FlightLog, rows: usize, name: &str) {
    assert_eq!(log.len(), rows, "{name}");
    assert_eq!(log.time_s(), &sample.time_s()[..rows], "{name}");
    assert_eq!(log.channels().len(), sample.channels().len(), "{name}");
    for channel in sample.channels() {
        let stored = log
            .channel(&channel.name)
            .unwrap_or_else(|| panic!("{name}: no {}", channel.name));
        assert_eq!(stored.role, channel.role, "{name} {}", channel.name);
        assert_eq!(stored.values, channel.values[..rows], "{name} {}", channel.name);
    }
}

/// The shipped MagNav-layout fixture holds the first 2000 rows of the
/// sample flight (made with `magcomp convert` from those rows).
#[test]
fn magnav_layout_fixture_reads_to_the_sample_flight_rows() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ingest = IngestOptions::default();
    let fixture = read_flight_log(&root.join("tests/fixtures/Flt_sample_train.h5"), &ingest).unwrap();
    let sample = read_flight_log(&root.join("sample_flights/box_and_lines.csv"), &ingest).unwrap();
    assert_first_rows(&fixture, &sample, 2000, "Flt_sample_train.h5");
    assert_eq!(fixture.vector_sensors()[0].prefix, "flux_a");
}

/// Files written by h5py itself (`tests/fixtures/h5py_layouts.py`, h5py
/// 3.16 with HDF5 2.0 and hdf5plugin) read to the sample flight's first 600
/// rows exactly: chunked with gzip, shuffle and fletcher32, one dataset in
/// szip and one in bitshuffle with LZ4; and with `libver="latest"`, whose
/// layout version 5 and chunk indexes the first decoder refuses.
#[test]
fn h5py_chunked_and_filtered_files_read_to_the_sample_flight_rows() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ingest = IngestOptions::default();
    let sample = read_flight_log(&root.join("sample_flights/box_and_lines.csv"), &ingest).unwrap();
    for name in ["h5py_gzip_shuffle.h5", "h5py_latest_gzip.h5"] {
        let log =
            read_flight_log(&root.join("tests/fixtures").join(name), &ingest).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_first_rows(&log, &sample, 600, name);
    }
}

/// A dataset compressed with a filter neither decoder has (Zstandard, from
/// hdf5plugin) is an error that names the dataset and the filter and says
/// how to rewrite the file, not a missing column or a damaged file.
#[test]
fn an_hdf5_filter_magcomp_does_not_decode_is_named_with_its_fix() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("tests/fixtures/h5py_zstd.h5");
    let error = read_flight_log(&path, &IngestOptions::default())
        .unwrap_err()
        .to_string();
    for needed in [
        "h5py_zstd.h5",
        "dataset 'ins_pitch'",
        "32015",
        "filter magcomp does not decode",
        "h5repack",
    ] {
        assert!(error.contains(needed), "'{needed}' not in: {error}");
    }
    for wrong in ["no time column", "damaged"] {
        assert!(!error.contains(wrong), "'{wrong}' in: {error}");
    }
}

#[test]
fn sgl_xyz_with_line_records_runs_through_the_cli() {
    let folder = tempfile::tempdir().unwrap();
    let (csv, windows) = small_flight(folder.path());
    let log = read_flight_log(&csv, &IngestOptions::default()).unwrap();
    // Rewrite as an SGL-style delivery: uppercase names, line records, no
    // line column.
    let rename = |name: &str| match name {
        "tt" => "TIME".to_string(),
        "ins_pitch" => "PITCH".into(),
        "ins_roll" => "ROLL".into(),
        "ins_yaw" => "AZIMUTH".into(),
        n if n.starts_with("mag_") => format!("UNCOMPMAG{}", &n[4..5]),
        n if n.starts_with("flux_") => format!("FLUX{}_{}", n[5..6].to_uppercase(), n[7..].to_uppercase()),
        n => n.to_uppercase(),
    };
    let keep: Vec<usize> = (0..log.channels().len())
        .filter(|&i| log.channels()[i].name != "line")
        .collect();
    let line = &log.channel("line").unwrap().values;
    let mut text = String::from("/ SGL 2020 delivery\n/ ");
    let names: Vec<String> = std::iter::once("tt")
        .chain(keep.iter().map(|&i| log.channels()[i].name.as_str()))
        .map(rename)
        .collect();
    text += &names.join("  ");
    text += "\n";
    let mut current = f64::NAN;
    for (row, &line_number) in line.iter().enumerate() {
        if line_number != current {
            current = line_number;
            text += &format!("Line {current}\n");
        }
        text += &format!("{}", log.time_s()[row]);
        for &i in &keep {
            let v = log.channels()[i].values[row];
            text += &if v.is_finite() { format!("  {v}") } else { "  *".into() };
        }
        text += "\n";
    }
    let xyz = folder.path().join("Flt1002.xyz");
    std::fs::write(&xyz, &text).unwrap();
    let from_xyz = read_flight_log(&xyz, &IngestOptions::default()).unwrap();
    assert_same_log(&log, &from_xyz, 0.0);

    let windows_arg: Vec<String> = read_detect_json(&windows, 5.0)
        .unwrap()
        .iter()
        .map(|w| format!("{}:{}", w.t_start, w.t_end))
        .collect();
    let out = folder.path().join("Flt1002_c.xyz");
    let mut args = vec![
        "compensate".to_string(),
        xyz.display().to_string(),
        "--out".into(),
        out.display().to_string(),
    ];
    for w in &windows_arg {
        args.push("--window".into());
        args.push(w.clone());
    }
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(&args)
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let written = std::fs::read_to_string(&out).unwrap();
    let input_lines: Vec<&str> = text.lines().collect();
    let output_lines: Vec<&str> = written.lines().collect();
    assert_eq!(input_lines.len(), output_lines.len(), "every line is kept");
    // The compensated scalars, then (the file has a fluxgate and INS
    // attitude) the vector in body axes and north-east-down, then flags.
    assert_eq!(
        output_lines[1],
        format!(
            "{} mag_1_c mag_1_c_sigma mag_2_c mag_2_c_sigma flux_a_x_c flux_a_y_c flux_a_z_c flux_a_n_c flux_a_e_c flux_a_d_c flags",
            input_lines[1]
        )
    );
    for (i, o) in input_lines.iter().zip(&output_lines).skip(2) {
        assert!(o.starts_with(i), "line copied unchanged: {i}");
    }
    let values = output_column(&out, "mag_1_c");
    assert_eq!(values.len(), log.len());
    assert!(values.iter().filter(|v| v.parse::<f64>().is_ok()).count() > log.len() * 99 / 100);
}

/// Small deterministic generator for damage positions.
fn next(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[test]
fn damaged_xyz_and_hdf5_files_give_errors_not_panics() {
    let folder = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ingest = IngestOptions::default();
    let log = read_flight_log(&root.join("tests/fixtures/Flt_sample_train.h5"), &ingest).unwrap();
    for extension in ["xyz", "h5"] {
        let good_path = folder.path().join(format!("good.{extension}"));
        write_flight_log(&log, &good_path).unwrap();
        let good = std::fs::read(&good_path).unwrap();
        let damaged = folder.path().join(format!("damaged.{extension}"));
        let mut state = 11;
        let mut cases: Vec<Vec<u8>> = vec![Vec::new()];
        cases.extend((1..25).map(|k| good[..good.len() * k / 25].to_vec()));
        for _ in 0..60 {
            let mut bytes = good.clone();
            for _ in 0..1 + next(&mut state) % 6 {
                let at = (next(&mut state) % bytes.len() as u64) as usize;
                bytes[at] ^= 1 << (next(&mut state) % 8);
            }
            cases.push(bytes);
        }
        let mut errors = 0;
        for bytes in &cases {
            std::fs::write(&damaged, bytes).unwrap();
            match std::panic::catch_unwind(|| read_flight_log(&damaged, &ingest)) {
                Ok(Err(error)) => {
                    errors += 1;
                    assert!(
                        error.to_string().contains("damaged"),
                        "the error names the file: {error}"
                    );
                }
                Ok(Ok(read)) => assert!(read.len() <= log.len()),
                Err(_) => panic!("reading a damaged .{extension} panicked"),
            }
        }
        assert!(errors >= 1, ".{extension}: the empty file is an error");
    }
}

/// A time column that jumps by 10⁹ s (31.7 years) between two rows is
/// read with every row kept and a warning that names the jump, its place
/// and what to check; steps of an ordinary flight give none.
#[test]
fn a_time_column_that_jumps_by_years_is_warned_of() {
    let folder = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("sample_flights/clean.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let header: Vec<&str> = lines[0].split(',').collect();
    let time = header.iter().position(|c| *c == "tt").unwrap();
    let rows = lines.len() - 1;
    for line in lines.iter_mut().skip(1001) {
        let mut cells: Vec<String> = line.split(',').map(String::from).collect();
        cells[time] = format!("{}", cells[time].parse::<f64>().unwrap() + 1e9);
        *line = cells.join(",");
    }
    let jumped = folder.path().join("jumped.csv");
    std::fs::write(&jumped, lines.join("\n") + "\n").unwrap();
    let clean = read_flight_log(&root.join("sample_flights/clean.csv"), &IngestOptions::default()).unwrap();
    assert!(clean.reading_warnings().is_empty(), "{:?}", clean.reading_warnings());
    let log = read_flight_log(&jumped, &IngestOptions::default()).unwrap();
    assert_eq!(log.len(), rows);
    let jumps: Vec<&Reading> = (log.reading_warnings().iter())
        .filter_map(|w| match w {
            Warning::Reading(jump @ (Reading::TimeJump { .. } | Reading::TimeJumps { .. })) => Some(jump),
            _ => None,
        })
        .collect();
    assert_eq!(jumps.len(), 1, "{:?}", log.reading_warnings());
    let Reading::TimeJump {
        column,
        from_s,
        to_s,
        row,
        ..
    } = jumps[0]
    else {
        panic!("{:?}", jumps[0])
    };
    assert_eq!((column.as_str(), *row), ("tt", 1001));
    assert!(((to_s - from_s) - (1e9 + 0.1)).abs() < 1e-3, "{from_s} → {to_s}");
    assert!(jumps[0].to_string().contains("(11574.1 days)"), "{}", jumps[0]);
}
