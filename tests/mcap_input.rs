//! MCAP input: multi-rate alignment, JSON messages, every way of laying out
//! the file, and damaged files.

use std::collections::BTreeMap;
use std::path::Path;

use magcomp::formats::mcap::messages::{descriptor_set, timestamp, Attitude, Sample, ScalarMag, VectorMag};
use magcomp::formats::{read_flight_log, IngestOptions};
use magcomp::messages::{ReadNote, Reading, Warning};
use prost::Message;

/// Which encoding and layout a test file uses.
#[derive(Clone, Copy)]
struct Layout {
    json: bool,
    compression: Option<mcap::Compression>,
    chunks: bool,
    summary: bool,
}

const INDEXED: Layout = Layout {
    json: false,
    compression: Some(mcap::Compression::Zstd),
    chunks: true,
    summary: true,
};

/// True signals of the multi-rate flight.
fn scalar(t: f64) -> f64 {
    50_000.0 + 30.0 * (0.5 * t).sin()
}
fn flux_x(t: f64) -> f64 {
    20_000.0 * (0.3 * t).cos()
}
fn current(t: f64) -> f64 {
    3.0 + (0.2 * t).sin()
}
fn line_number(t: f64) -> f64 {
    1000.0 + (t / 7.0).floor()
}

/// One message: topic, time (s), and its fields.
type Record = (&'static str, f64, Vec<(&'static str, f64)>);

/// Scalar 10 Hz from t = 100 s; fluxgate 50 Hz on its own clock (offset
/// 7.3 ms) from 99 s; INS 50 Hz; current 2 Hz from 101 s with a gap
/// 110–113 s; line number 1 Hz.
fn records() -> Vec<Record> {
    let mut records = Vec::new();
    for k in 0..300 {
        let t = 100.0 + k as f64 / 10.0;
        records.push(("/mag/1/scalar", t, vec![("total_nt", scalar(t))]));
    }
    for k in 0..1600 {
        let t = 99.0 + k as f64 / 50.0 + 0.0073;
        let v = vec![("x_nt", flux_x(t)), ("y_nt", 1000.0), ("z_nt", 45_000.0)];
        records.push(("/mag/a/vector", t, v));
        let a = vec![("roll_deg", 2.0), ("pitch_deg", 1.0), ("yaw_deg", 90.0)];
        records.push(("/ins/attitude", t, a));
    }
    for k in 0..60 {
        let t = 101.0 + k as f64 / 2.0;
        if !(110.0..113.0).contains(&t) {
            records.push(("/aux/cur_a", t, vec![("value", current(t))]));
        }
    }
    for k in 0..35 {
        let t = 99.5 + k as f64;
        records.push(("/aux/line", t, vec![("value", line_number(t))]));
    }
    records.sort_by(|a, b| a.1.total_cmp(&b.1));
    records
}

fn encode(topic: &str, time_ns: u64, fields: &[(&str, f64)], json: bool) -> Vec<u8> {
    if json {
        let object: serde_json::Map<String, serde_json::Value> = fields
            .iter()
            .map(|(k, v)| (k.to_string(), serde_json::json!(v)))
            .collect();
        return serde_json::to_vec(&object).unwrap();
    }
    let get = |name: &str| fields.iter().find(|(k, _)| *k == name).map_or(0.0, |(_, v)| *v);
    let stamp = Some(timestamp(time_ns));
    match topic {
        "/mag/1/scalar" => ScalarMag {
            timestamp: stamp,
            frame_id: "mag_1".into(),
            total_nt: get("total_nt"),
        }
        .encode_to_vec(),
        "/mag/a/vector" => VectorMag {
            timestamp: stamp,
            frame_id: "flux_a".into(),
            x_nt: get("x_nt"),
            y_nt: get("y_nt"),
            z_nt: get("z_nt"),
        }
        .encode_to_vec(),
        "/ins/attitude" => Attitude {
            timestamp: stamp,
            roll_deg: get("roll_deg"),
            pitch_deg: get("pitch_deg"),
            yaw_deg: get("yaw_deg"),
        }
        .encode_to_vec(),
        _ => Sample {
            timestamp: stamp,
            value: get("value"),
            unit: String::new(),
        }
        .encode_to_vec(),
    }
}

fn schema_of(topic: &str) -> &'static str {
    match topic {
        "/mag/1/scalar" => "magcomp.ScalarMag",
        "/mag/a/vector" => "magcomp.VectorMag",
        "/ins/attitude" => "magcomp.Attitude",
        _ => "magcomp.Sample",
    }
}

fn write_file(path: &Path, layout: Layout) {
    write_records(path, layout, records());
}

fn write_records(path: &Path, layout: Layout, records: Vec<Record>) {
    write_records_restarting(path, layout, records, None);
}

/// [`write_records`], with the messages of topic `restart.0` from time
/// `restart.1` on written on a second channel record of the same topic
/// (a logger that restarted).
fn write_records_restarting(path: &Path, layout: Layout, records: Vec<Record>, restart: Option<(&str, f64)>) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut writer = mcap::WriteOptions::new()
        .compression(layout.compression)
        .use_chunks(layout.chunks)
        .chunk_size(Some(16 * 1024))
        .emit_summary_records(layout.summary)
        .emit_summary_offsets(layout.summary)
        .emit_chunk_indexes(layout.summary)
        .emit_message_indexes(layout.summary)
        .emit_statistics(layout.summary)
        .create(file)
        .unwrap();
    let mut channels: BTreeMap<(&str, bool), u16> = BTreeMap::new();
    for (sequence, (topic, t, fields)) in records.into_iter().enumerate() {
        let restarted = restart.is_some_and(|(name, from)| name == topic && t >= from);
        let channel = *channels.entry((topic, restarted)).or_insert_with(|| {
            // A topic in an encoding magcomp does not decode, or a logger
            // that restarted writing the current in one.
            if topic.starts_with("/msgpack/") || (restarted && topic == "/aux/cur_a") {
                return writer.add_channel(0, topic, "msgpack", &BTreeMap::new()).unwrap();
            }
            // Protobuf messages whose schema is in another encoding.
            if topic == MISMATCHED_SCHEMA_TOPIC {
                let schema = writer.add_schema("Total", "foo", b"total").unwrap();
                return writer.add_channel(schema, topic, "protobuf", &BTreeMap::new()).unwrap();
            }
            // A magnetometer recorded in a ROS 2 type magcomp does not read.
            if topic == UNREAD_ROS_MAGNETOMETER {
                let schema = writer
                    .add_schema("vendor_msgs/msg/Total", "ros2msg", b"float64 total")
                    .unwrap();
                return writer.add_channel(schema, topic, "cdr", &BTreeMap::new()).unwrap();
            }
            let schema = match layout.json {
                true => writer
                    .add_schema(schema_of(topic), "jsonschema", b"{\"type\":\"object\"}")
                    .unwrap(),
                false => writer
                    .add_schema(schema_of(topic), "protobuf", &descriptor_set(schema_of(topic)))
                    .unwrap(),
            };
            let encoding = if layout.json { "json" } else { "protobuf" };
            // The restarted logger's channel record differs in its
            // metadata, so it is a record of its own.
            let metadata = match restarted {
                true => BTreeMap::from([("session".to_string(), "2".to_string())]),
                false => BTreeMap::new(),
            };
            writer.add_channel(schema, topic, encoding, &metadata).unwrap()
        });
        let time_ns = (t * 1e9).round() as u64;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: sequence as u32,
            log_time: time_ns,
            publish_time: time_ns,
        };
        writer
            .write_to_known_channel(&header, &encode(topic, time_ns, &fields, layout.json))
            .unwrap();
    }
    writer.finish().unwrap();
}

/// A magnetometer topic written in a ROS 2 type magcomp does not read.
const UNREAD_ROS_MAGNETOMETER: &str = "/mag/2/scalar";

/// A topic of protobuf messages whose schema is in encoding "foo".
const MISMATCHED_SCHEMA_TOPIC: &str = "/mag/3/scalar";

/// A topic magcomp cannot read is not dropped silently: the flight carries
/// a reading warning (which `compensate` prints and the report shows) that
/// names the topic, says it is not in the output, and why. So is a
/// magnetometer recorded in a ROS 2 type magcomp does not read: a sensor
/// lost, not a topic of no interest (other unread ROS types, such as
/// diagnostics, are notes).
#[test]
fn a_topic_magcomp_cannot_read_is_a_warning() {
    let folder = tempfile::tempdir().unwrap();
    let cases = [
        ("/msgpack/mag_9", "'msgpack'"),
        (UNREAD_ROS_MAGNETOMETER, "vendor_msgs/msg/Total"),
        // Named for its schema's encoding, not as protobuf unread.
        (
            MISMATCHED_SCHEMA_TOPIC,
            "schema 'Total' is in encoding 'foo', not a protobuf descriptor set",
        ),
    ];
    for (topic, why) in cases {
        let path = folder.path().join("unread.mcap");
        let mut records = records();
        records.extend((0..30).map(|k| (topic, 100.0 + k as f64, vec![("value", 1.0)])));
        write_records(&path, INDEXED, records);
        if topic.starts_with("/msgpack/") {
            keep_in_corpus("topic_in_an_unknown_encoding", &std::fs::read(&path).unwrap());
        }
        let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
        assert_eq!(log.len(), 300);
        assert!(
            log.reading_warnings().iter().any(|w| matches!(
                w,
                Warning::Reading(Reading::McapTopicLost { topic: lost, why: said })
                    if lost == topic && said.contains(why)
            )),
            "{topic}: {:?}",
            log.reading_warnings()
        );
    }
}

#[test]
fn multi_rate_channels_align_within_the_interpolation_error() {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("multirate.mcap");
    write_file(&path, INDEXED);
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    assert_eq!(log.len(), 300, "the scalar magnetometer's timestamps are the time base");
    let time = log.time_s();
    for (t, v) in time.iter().zip(&log.channel("mag_1_uc").unwrap().values) {
        assert_eq!(*v, scalar(*t), "the time-base channel is taken as recorded");
    }
    // Linear interpolation over a step h errs by at most h²/8·max|f''|:
    // fluxgate h = 0.02 s, |f''| ≤ 20 000·0.3² → 0.09 nT; current h = 0.5 s,
    // |f''| ≤ 0.2² → 0.00125 A.
    let flux_bound = 0.02f64.powi(2) / 8.0 * 20_000.0 * 0.09;
    let current_bound = 0.5f64.powi(2) / 8.0 * 0.04;
    let flux = &log.channel("flux_a_x").unwrap().values;
    let cur = &log.channel("cur_a").unwrap().values;
    let line = &log.channel("line").unwrap().values;
    let (mut flux_worst, mut current_worst) = (0.0f64, 0.0f64);
    for (row, &t) in time.iter().enumerate() {
        flux_worst = flux_worst.max((flux[row] - flux_x(t)).abs());
        let before_first = t < 101.0;
        let in_gap = t > 109.5 && t < 113.0;
        match (before_first, in_gap) {
            (true, _) => assert!(cur[row].is_nan(), "no extrapolation before the first sample, t = {t}"),
            (_, true) => {
                assert!(cur[row].is_nan(), "a 3.5 s gap stays missing, t = {t}");
                assert!(log.row_flags()[row].to_string().contains("gap:cur_a"), "t = {t}");
            }
            _ => current_worst = current_worst.max((cur[row] - current(t)).abs()),
        }
        assert_eq!(
            line[row],
            line_number(t - 0.5).max(line_number(99.5)),
            "line held, t = {t}"
        );
    }
    assert!(flux_worst <= flux_bound, "fluxgate error {flux_worst} > {flux_bound}");
    assert!(
        current_worst <= current_bound,
        "current error {current_worst} > {current_bound}"
    );
    let report = log.alignment().unwrap();
    let method = |name: &str| report.channels.iter().find(|c| c.channel == name).unwrap().method;
    assert_eq!(method("flux_a_x"), "linear");
    assert_eq!(method("line"), "previous value");
    assert_eq!(method("mag_1_uc"), "time base");
}

#[test]
fn every_layout_and_encoding_reads_to_the_same_log() {
    let folder = tempfile::tempdir().unwrap();
    let reference = folder.path().join("reference.mcap");
    write_file(&reference, INDEXED);
    let expected = read_flight_log(&reference, &IngestOptions::default()).unwrap();
    let scanned =
        |log: &magcomp::ingest::flight_log::FlightLog| log.alignment().unwrap().notes.iter().any(|n| n.scanned());
    assert!(!scanned(&expected), "an indexed file is read through its chunk index");
    let layouts = [
        (
            "lz4",
            Layout {
                compression: Some(mcap::Compression::Lz4),
                ..INDEXED
            },
        ),
        (
            "uncompressed",
            Layout {
                compression: None,
                ..INDEXED
            },
        ),
        (
            "unchunked",
            Layout {
                chunks: false,
                ..INDEXED
            },
        ),
        (
            "no summary",
            Layout {
                summary: false,
                ..INDEXED
            },
        ),
        ("json", Layout { json: true, ..INDEXED }),
    ];
    for (name, layout) in layouts {
        let path = folder.path().join(format!("{}.mcap", name.replace(' ', "_")));
        write_file(&path, layout);
        let log = read_flight_log(&path, &IngestOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        if name == "no summary" {
            assert!(scanned(&log), "a file without a summary is scanned");
        }
        assert_same_log(&expected, &log, name);
    }
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
fn damaged_files_give_errors_not_panics() {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("good.mcap");
    write_file(&path, INDEXED);
    let good = std::fs::read(&path).unwrap();
    let damaged = folder.path().join("damaged.mcap");
    let options = IngestOptions::default();
    let read = |bytes: &[u8]| {
        std::fs::write(&damaged, bytes).unwrap();
        std::panic::catch_unwind(|| read_flight_log(&damaged, &options)).expect("reading a damaged MCAP panicked")
    };
    // Nothing to read: errors naming the file.
    for bytes in [&[][..], &good[..4], &good[..40]] {
        let error = read(bytes).unwrap_err().to_string();
        assert!(error.contains("damaged.mcap"), "the error names the file: {error}");
    }
    // A recording cut short (a logger that died) is read up to the damage,
    // and says so.
    let mut partial = 0;
    for k in 1..40 {
        match read(&good[..good.len() * k / 40]) {
            // A cut inside the summary loses no message.
            Ok(log) if log.len() == 300 => {}
            Ok(log) => {
                assert!(log.len() < 300);
                let warnings = &log.alignment().unwrap().warnings;
                assert!(
                    (warnings.iter()).any(|w| matches!(w, Warning::Reading(Reading::McapCutShort { .. }))),
                    "cut at {k}/40: {warnings:?}"
                );
                partial += 1;
            }
            Err(error) => assert!(error.to_string().contains("damaged.mcap"), "{error}"),
        }
    }
    assert!(
        partial >= 20,
        "most truncated recordings give their first part ({partial} of 39)"
    );
    let mut state = 7;
    for _ in 0..150 {
        let mut bytes = good.clone();
        for _ in 0..1 + next(&mut state) % 8 {
            let at = (next(&mut state) % bytes.len() as u64) as usize;
            bytes[at] ^= 1 << (next(&mut state) % 8);
        }
        if let Ok(log) = read(&bytes) {
            assert!(log.len() <= 300);
        }
    }
}

/// A turn through north: the heading at `t` s, 0–360°.
fn heading_through_north(t: f64) -> f64 {
    (350.0 + 2.0 * (t - 100.0)).rem_euclid(360.0)
}

#[test]
fn heading_across_north_is_interpolated_on_the_circle() {
    // Attitude 30 ms off the magnetometer, turning 2°/s through north.
    let mut records: Vec<Record> = Vec::new();
    for k in 0..100 {
        let t = 100.0 + k as f64 / 10.0;
        records.push(("/mag/1/scalar", t, vec![("total_nt", scalar(t))]));
        let t = t + 0.03;
        let a = vec![
            ("roll_deg", 0.0),
            ("pitch_deg", 0.0),
            ("yaw_deg", heading_through_north(t)),
        ];
        records.push(("/ins/attitude", t, a));
    }
    records.sort_by(|a, b| a.1.total_cmp(&b.1));
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("north.mcap");
    write_records(&path, INDEXED, records);
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    let yaw = &log.channel("ins_yaw").unwrap().values;
    let mut compared = 0;
    for (t, value) in log.time_s().iter().zip(yaw).filter(|(_, v)| v.is_finite()) {
        let truth = heading_through_north(*t);
        let error = (value - truth + 180.0).rem_euclid(360.0) - 180.0;
        assert!(error.abs() < 1e-6, "t = {t}: yaw {value}°, truth {truth}°");
        assert!((0.0..360.0).contains(value), "t = {t}: yaw {value}° leaves 0–360°");
        compared += 1;
    }
    assert!(compared >= 98, "{compared} rows compared");
}

#[test]
fn repeated_log_times_are_dropped_flagged_or_refused() {
    let base: Vec<Record> = (0..50)
        .map(|k| {
            let t = 100.0 + k as f64 / 10.0;
            ("/mag/1/scalar", t, vec![("total_nt", scalar(t))])
        })
        .collect();
    let folder = tempfile::tempdir().unwrap();

    // A current logged twice at one time with one value, then with two.
    let mut records = base.clone();
    for (t, value) in [(101.0, 3.0), (101.0, 3.0), (102.0, 4.0), (102.0, 7.0), (103.0, 5.0)] {
        records.push(("/aux/cur_a", t, vec![("value", value)]));
    }
    records.sort_by(|a, b| a.1.total_cmp(&b.1));
    let path = folder.path().join("current.mcap");
    write_records(&path, INDEXED, records);
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    assert_eq!(log.len(), 50, "no magnetometer row is merged");
    let current = &log.channel("cur_a").unwrap().values;
    let row = |t: f64| log.time_s().iter().position(|&s| (s - t).abs() < 1e-6).unwrap();
    assert_eq!(current[row(101.0)], 3.0, "an exact repeat is one sample");
    assert!(
        current[row(102.0)].is_nan() && current[row(101.5)].is_nan(),
        "disagreeing samples are not used"
    );
    assert_eq!(log.row_flags()[row(102.0)].to_string(), "duplicate_time:cur_a");
    let warnings = &log.alignment().unwrap().warnings;
    assert!(
        warnings.iter().any(|w| matches!(
            w,
            Warning::Reading(Reading::RepeatsDisagree { times: 1, column, .. }) if column == "cur_a"
        )),
        "{warnings:?}"
    );

    // The magnetometer itself twice at one time with two values: an error.
    let mut records = base;
    records.push(("/mag/1/scalar", 101.0, vec![("total_nt", 51_000.0)]));
    records.sort_by(|a, b| a.1.total_cmp(&b.1));
    let path = folder.path().join("scalar.mcap");
    write_records(&path, INDEXED, records);
    let error = read_flight_log(&path, &IngestOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("scalar.mcap") && error.contains("/mag/1/scalar") && error.contains("101 s"),
        "{error}"
    );
}

#[test]
fn log_times_are_absolute_and_read_back_as_times_of_day() {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("multirate.mcap");
    write_file(&path, INDEXED);
    let date = magcomp::ingest::flight_date::FlightDate::parse("2020-06-20").unwrap();
    let options = IngestOptions {
        date: Some(date),
        ..IngestOptions::default()
    };
    let log = read_flight_log(&path, &options).unwrap();
    assert_eq!(log.date(), Some(date));
    let written = folder.path().join("dated.mcap");
    magcomp::formats::write_flight_log(&log, &written).unwrap();
    let bytes = std::fs::read(&written).unwrap();
    let first = mcap::MessageStream::new(&bytes).unwrap().next().unwrap().unwrap();
    let midnight_ns = 1_592_611_200_000_000_000u64;
    assert_eq!(first.log_time, midnight_ns + 100_000_000_000, "2020-06-20 00:01:40 UTC");
    assert_eq!(
        first.channel.metadata.get("magcomp.date").map(String::as_str),
        Some("2020-06-20")
    );
    let back = read_flight_log(&written, &IngestOptions::default()).unwrap();
    assert_eq!(back.date(), Some(date));
    assert_eq!(
        back.time_s(),
        log.time_s(),
        "the time column is seconds of the day again"
    );
    assert_eq!(
        back.channel("mag_1_uc").unwrap().values,
        log.channel("mag_1_uc").unwrap().values
    );
    // Another day given over the recorded one is used, and said.
    let other = IngestOptions {
        date: magcomp::ingest::flight_date::FlightDate::parse("2021-01-01"),
        ..IngestOptions::default()
    };
    let overridden = read_flight_log(&written, &other).unwrap();
    assert_eq!(overridden.date(), other.date);
    let warnings = overridden.reading_warnings();
    assert!(
        warnings.iter().any(|w| matches!(
            w,
            Warning::Reading(Reading::DayGivenOverRecorded { given, recorded, .. })
                if given == "2021-01-01" && recorded == "2020-06-20"
        )),
        "{warnings:?}"
    );
}

/// The flight written in `layout` to `whole.mcap` in `folder`: its bytes
/// and the log read from it.
fn whole_file(folder: &Path, layout: Layout) -> (Vec<u8>, magcomp::ingest::flight_log::FlightLog) {
    let path = folder.join("whole.mcap");
    write_file(&path, layout);
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    (std::fs::read(&path).unwrap(), log)
}

/// Asserts that `log` has `expected`'s rows and channels, bit for bit.
fn assert_same_log(
    expected: &magcomp::ingest::flight_log::FlightLog,
    log: &magcomp::ingest::flight_log::FlightLog,
    name: &str,
) {
    assert_eq!(log.time_s(), expected.time_s(), "{name}");
    for channel in expected.channels() {
        let other = log
            .channel(&channel.name)
            .unwrap_or_else(|| panic!("{name}: no {}", channel.name));
        let same = channel
            .values
            .iter()
            .zip(&other.values)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "{name}: {} differs", channel.name);
    }
}

/// The records laid end to end in `bytes` from the magic to the data-end
/// record: (opcode, start, end) of each.
fn records_of(bytes: &[u8]) -> Vec<(u8, usize, usize)> {
    let mut at = 8;
    let mut found = Vec::new();
    while at + 9 <= bytes.len() {
        let opcode = bytes[at];
        let length = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        found.push((opcode, at, at + 9 + length));
        at += 9 + length;
        if opcode == 0x0F {
            break;
        }
    }
    found
}

/// A recording that stops between two records (no data-end record, no
/// summary, no footer: a logger that died between writes) is read up to
/// there, and a warning says it was cut short, with the rows and the time
/// span read; the recording whole has no such warning.
#[test]
fn a_file_cut_at_a_record_boundary_says_so_with_what_was_read() {
    let folder = tempfile::tempdir().unwrap();
    let (good, whole) = whole_file(folder.path(), INDEXED);
    assert!(!(whole.alignment().unwrap().warnings.iter())
        .any(|w| matches!(w, Warning::Reading(Reading::McapCutShort { .. }))));
    let chunk_ends: Vec<usize> = records_of(&good)
        .into_iter()
        .filter(|(opcode, _, _)| *opcode == 0x06)
        .map(|(_, _, end)| end)
        .collect();
    assert!(chunk_ends.len() >= 3, "{} chunks", chunk_ends.len());
    let cut = folder.path().join("cut.mcap");
    std::fs::write(&cut, &good[..chunk_ends[1]]).unwrap();
    keep_in_corpus("cut_at_a_record_boundary", &good[..chunk_ends[1]]);
    let log = read_flight_log(&cut, &IngestOptions::default()).unwrap();
    assert!(
        log.len() < whole.len() && !log.is_empty(),
        "{} of {} rows",
        log.len(),
        whole.len()
    );
    let warnings = &log.alignment().unwrap().warnings;
    let said = (warnings.iter())
        .find_map(|w| match w {
            Warning::Reading(cut @ Reading::McapCutShort { .. }) => Some(cut),
            _ => None,
        })
        .unwrap_or_else(|| panic!("{warnings:?}"));
    let Reading::McapCutShort {
        at_byte,
        inside_record_of,
        read: Some((rows, first_s, last_s)),
    } = said
    else {
        panic!("{said:?}")
    };
    assert_eq!(
        (*at_byte, *inside_record_of, *rows),
        (chunk_ends[1] as u64, None, log.len()),
        "{said}"
    );
    assert_eq!((*first_s, *last_s), (log.time_s()[0], log.time_s()[log.len() - 1]));
    assert!(said.to_string().contains("between two records"), "{said}");
}

/// A summary whose chunk index lost an entry is not trusted: the file is
/// read by a scan of its data section, every row is there, and a note says
/// how many chunks the index listed.
#[test]
fn a_chunk_index_that_lost_an_entry_is_not_trusted() {
    let folder = tempfile::tempdir().unwrap();
    let (mut bytes, whole) = whole_file(folder.path(), INDEXED);
    let chunks = records_of(&bytes)
        .iter()
        .filter(|(opcode, _, _)| *opcode == 0x06)
        .count();
    // The summary starts where the footer says; its first chunk index
    // record (opcode 0x08) is turned into a record of an unknown kind,
    // which readers skip.
    let footer = bytes.len() - 8 - 29;
    assert_eq!(bytes[footer], 0x02, "the footer");
    let summary = u64::from_le_bytes(bytes[footer + 9..footer + 17].try_into().unwrap()) as usize;
    let mut at = summary;
    while bytes[at] != 0x08 {
        at += 9 + u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
    }
    bytes[at] = 0x7F;
    let damaged = folder.path().join("lost_entry.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    keep_in_corpus("chunk_index_lost_an_entry", &bytes);
    let log = read_flight_log(&damaged, &IngestOptions::default()).unwrap();
    assert_same_log(&whole, &log, "lost index entry");
    let notes = &log.alignment().unwrap().notes;
    assert!(
        notes.contains(&ReadNote::ChunkIndexIncomplete {
            listed: chunks - 1,
            chunks
        }),
        "{notes:?}"
    );
}

/// A value edited inside an uncompressed chunk is caught by the chunk's
/// CRC: the chunk is left out with a warning that names the CRC, the
/// data section's own CRC is said not to match, and the other chunks are
/// read as they are.
#[test]
fn an_edited_chunk_fails_its_crc_and_is_left_out_with_a_warning() {
    let folder = tempfile::tempdir().unwrap();
    let layout = Layout {
        compression: None,
        ..INDEXED
    };
    let (mut bytes, whole) = whole_file(folder.path(), layout);
    assert!(whole.alignment().unwrap().warnings.is_empty());
    let chunks: Vec<(usize, usize)> = records_of(&bytes)
        .into_iter()
        .filter(|(opcode, _, _)| *opcode == 0x06)
        .map(|(_, start, end)| (start, end))
        .collect();
    let (start, end) = chunks[1];
    // Past the chunk's header, inside its records: a message's data.
    bytes[end - (end - start) / 3] ^= 0x10;
    let edited = folder.path().join("edited.mcap");
    std::fs::write(&edited, &bytes).unwrap();
    keep_in_corpus("chunk_fails_its_crc", &bytes);
    let log = read_flight_log(&edited, &IngestOptions::default()).unwrap();
    let warnings = &log.alignment().unwrap().warnings;
    assert!(
        warnings.iter().any(|w| matches!(
            w,
            Warning::Reading(Reading::McapChunkDamaged { why }) if why.contains("do not match their CRC")
        )),
        "{warnings:?}"
    );
    assert!(
        warnings.iter().any(|w| matches!(
            w,
            Warning::Reading(Reading::McapChunksLeftOut { damaged: 1, of }) if *of == chunks.len()
        )),
        "{warnings:?}"
    );
    assert!(
        (warnings.iter()).any(|w| matches!(w, Warning::Reading(Reading::McapCrcFails))),
        "{warnings:?}"
    );
}

/// A topic recorded on two channel records (a logger that restarted
/// halfway: the second half of the scalar's messages on a new channel of
/// the same topic) is read whole, and a note says so.
#[test]
fn a_topic_on_two_channel_records_is_read_whole() {
    let folder = tempfile::tempdir().unwrap();
    let (_, whole) = whole_file(folder.path(), INDEXED);
    let path = folder.path().join("restarted.mcap");
    write_records_restarting(&path, INDEXED, records(), Some(("/mag/1/scalar", 115.0)));
    keep_in_corpus("topic_on_two_channel_records", &std::fs::read(&path).unwrap());
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    assert_same_log(&whole, &log, "restarted");
    let notes = &log.alignment().unwrap().notes;
    assert!(
        notes.contains(&ReadNote::TopicJoined {
            source: "/mag/1/scalar:total_nt".into(),
            parts: 2,
            messages: 300
        }),
        "{notes:?}"
    );
}

/// A topic whose logger restarted in an encoding magcomp does not decode
/// is read where its first channel record covers it, and the warning says
/// that only the second record's messages are lost, not the topic.
#[test]
fn a_topic_half_in_an_unknown_encoding_is_read_where_it_can_be() {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("half.mcap");
    write_records_restarting(&path, INDEXED, records(), Some(("/aux/cur_a", 120.0)));
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    let lost: Vec<&Reading> = (log.reading_warnings().iter())
        .filter_map(|w| match w {
            Warning::Reading(r) => Some(r),
            _ => None,
        })
        .collect();
    assert!(
        lost.iter()
            .any(|r| matches!(r, Reading::McapChannelLost { topic, why, .. }
            if topic == "/aux/cur_a" && why.contains("'msgpack'"))),
        "{lost:?}"
    );
    assert!(
        !lost
            .iter()
            .any(|r| matches!(r, Reading::McapTopicLost { topic, .. } if topic == "/aux/cur_a")),
        "{lost:?}"
    );
    // Read on its first record (101–119.5 s, but for the gap), missing after.
    let values = &log.channel("cur_a").expect("cur_a read from its first record").values;
    let (time, read) = (log.time_s(), |t: f64| {
        values[log.time_s().iter().position(|&x| x >= t).unwrap()]
    });
    assert!((read(105.0) - current(105.0)).abs() < 1e-6, "{} at 105 s", read(105.0));
    assert!(read(125.0).is_nan() && time.len() == 300, "{} at 125 s", read(125.0));
}

/// A recording whose only fluxgate topic is in an encoding magcomp does not
/// decode is refused for want of a fluxgate, and the refusal names the
/// topic it could not read and why, not only the columns it did.
#[test]
fn a_missing_fluxgate_names_the_topic_that_could_not_be_read() {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("unread_vector.mcap");
    let records = (records().into_iter())
        .map(|(topic, t, fields)| match topic {
            "/mag/a/vector" => ("/msgpack/mag/a/vector", t, fields),
            _ => (topic, t, fields),
        })
        .collect();
    write_records(&path, INDEXED, records);
    let log = read_flight_log(&path, &IngestOptions::default()).unwrap();
    let error = magcomp::pipeline::choose_vector_sensor(&log, None)
        .unwrap_err()
        .to_string();
    for needed in [
        "no vector magnetometer",
        "'/msgpack/mag/a/vector'",
        "'msgpack'",
        "could not be read",
    ] {
        assert!(error.contains(needed), "'{needed}' not in: {error}");
    }
}

/// `compensate` says what it could not read (issue: nothing lost): a
/// second scalar magnetometer recorded in an encoding magcomp does not
/// decode is named on stdout and in the quality JSON's warnings, and the
/// magnetometers it reads are compensated on every row.
#[test]
fn compensate_names_a_magnetometer_it_cannot_read() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let bytes = std::fs::read(root.join("sample_flights/clean_mcap.mcap")).unwrap();
    let messages: Vec<mcap::Message<'_>> = mcap::MessageStream::new(&bytes).unwrap().map(Result::unwrap).collect();
    let times: Vec<u64> = (messages.iter())
        .filter(|m| m.channel.topic == "/mag/1/scalar")
        .map(|m| m.log_time)
        .collect();
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("unread_magnetometer.mcap");
    let mut writer = mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(&path).unwrap())).unwrap();
    for message in &messages {
        writer.write(message).unwrap();
    }
    let unread = writer
        .add_channel(0, "/mag/7/scalar", "msgpack", &BTreeMap::new())
        .unwrap();
    for (sequence, &time_ns) in times.iter().enumerate() {
        let header = mcap::records::MessageHeader {
            channel_id: unread,
            sequence: sequence as u32,
            log_time: time_ns,
            publish_time: time_ns,
        };
        writer
            .write_to_known_channel(&header, &[0x81, 0xa1, 0x74, 0x01])
            .unwrap();
    }
    writer.finish().unwrap();
    drop(writer);
    let out = folder.path().join("out.csv");
    let quality = folder.path().join("quality.json");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .arg("compensate")
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .arg("--report")
        .arg(&quality)
        .arg("--plain")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let said = "topic '/mag/7/scalar' is not in the output";
    assert!(
        stdout
            .lines()
            .any(|l| l.contains("warning:") && l.contains(said) && l.contains("'msgpack'")),
        "{stdout}"
    );
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&quality).unwrap()).unwrap();
    let warnings: Vec<&str> = (json["warnings"].as_array().unwrap().iter())
        .filter_map(|w| w.as_str())
        .collect();
    assert!(warnings.iter().any(|w| w.contains(said)), "{warnings:?}");
    // Every time-base row is written, compensated.
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(text.lines().count() - 1, times.len());
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    assert!(header.contains(&"mag_1_c"), "{header:?}");
}

/// With `MAGCOMP_WRITE_CORPUS` set, writes a damaged recording a test built
/// into the MCAP fuzz target's kept corpus as `kept_<name>.mcap`, where
/// `tests/fuzz_corpus.rs` replays it through every stage.
fn keep_in_corpus(name: &str, bytes: &[u8]) {
    if std::env::var_os("MAGCOMP_WRITE_CORPUS").is_none() {
        return;
    }
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("fuzz/corpus/ingest_mcap/kept_{name}.mcap"));
    std::fs::write(&path, bytes).unwrap();
    println!("wrote {}", path.display());
}
