//! Writing flight logs and compensated flights as MCAP (CONTRACT §4).
//!
//! Every message is protobuf with its `FileDescriptorSet` as the schema, in
//! zstd-compressed, indexed chunks, so Foxglove and Lichtblick open the file
//! and any MCAP reader can decode it from the file alone. `log_time` is the
//! sample time in nanoseconds and each message repeats it in `timestamp`.
//! A missing sample is written as NaN, so every row survives a round trip.
//!
//! | channels | topic | message |
//! |---|---|---|
//! | `mag_<n>_uc` (any scalar) | `/mag/<n>/scalar` | `magcomp.ScalarMag` |
//! | `flux_<s>_x/y/z` | `/mag/<s>/vector` | `magcomp.VectorMag` |
//! | `ins_roll/pitch/yaw` | `/ins/attitude` | `magcomp.Attitude` |
//! | `lat`, `lon` and a height | `/gps/fix` | `foxglove.LocationFix` |
//! | every other channel | `/aux/<name>` | `magcomp.Sample` |
//! | compensated `mag_<n>` | `/mag/<n>/compensated` | `magcomp.ScalarMag` |
//! | its one-sigma uncertainty `mag_<n>_c_sigma` | `/mag/<n>/compensated_sigma` | `magcomp.Sample` (unit `nT`) |
//! | vector-compensated `flux_<s>`, body axes | `/mag/<s>/vector_compensated` | `magcomp.VectorMag` (frame `body`) |
//! | the same in north-east-down | `/mag/<s>/vector_compensated_ned` | `magcomp.VectorMag` (x, y, z = n, e, d; frame `ned`) |
//! | compensated gradient `grad_<a>_<b>_c` | `/grad/<a>_<b>/compensated` | `magcomp.Sample` (unit `nT/m`) |
//! | on request, `mag_<n>_dc` and `mag_<n>_igrf` | `/mag/<n>/dc`, `/mag/<n>/igrf` | `magcomp.Sample` (unit `nT`) |
//! | the row flags (`flags`) | `/magcomp/flags` | `magcomp.RowFlags` (empty when the row is fine) |
//!
//! Reading a compensated file back gives the CSV's column names:
//! `mag_<n>_c`, `mag_<n>_c_sigma`, `flux_<s>_<x|y|z|n|e|d>_c`,
//! `grad_<a>_<b>_c`, `mag_<n>_dc`, `mag_<n>_igrf` ([`super::channel_name`]).
//!
//! The fitted model and quality figures go in as metadata records and JSON
//! attachments.

use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::path::Path;

use prost::Message;

use super::messages::{descriptor_set, timestamp, Attitude, LocationFix, RowFlags, Sample, ScalarMag, VectorMag};
use super::{ALTITUDE_COLUMN_KEY, DATE_KEY};
use crate::compensate::Compensation;
use crate::error::{Error, Result};
use crate::formats::destination::{stage, Staged};
use crate::ingest::flight_date::SECONDS_PER_DAY;
use crate::ingest::flight_log::{AttitudeAngle, ChannelRole, FlightLog};

/// JSON documents stored with the data.
#[derive(Debug, Clone, Default)]
pub struct McapExtras {
    /// `(name, JSON text)` pairs, e.g. `("model", …)`.
    pub documents: Vec<(String, String)>,
}

/// One topic to write: its message per row (or `None` for a missing sample).
struct Topic<'a> {
    topic: String,
    schema: &'static str,
    metadata: BTreeMap<String, String>,
    encode: Box<dyn Fn(usize, u64) -> Option<Vec<u8>> + 'a>,
}

/// Stages `log` (and the compensated channels, if any) as MCAP for `output`.
pub fn stage_mcap(
    log: &FlightLog,
    output: &Path,
    compensation: Option<&Compensation>,
    extras: &McapExtras,
) -> Result<Staged> {
    let midnight_ns = midnight_of_flight_ns(log);
    let times = log_times_ns(log, midnight_ns.unwrap_or(0))?;
    let mut topics = plan_topics(log, compensation);
    if let (Some(date), Some(_)) = (log.date(), midnight_ns) {
        for topic in &mut topics {
            topic.metadata.insert(DATE_KEY.to_string(), date.to_string());
        }
    }
    let mut failure: Option<mcap::McapError> = None;
    let staged = stage(output, |file| {
        let result = write_records(file, &times, &topics, extras);
        result.map_err(|e| {
            let text = e.to_string();
            failure = Some(e);
            std::io::Error::other(text)
        })
    });
    match failure {
        Some(e) => Err(Error::io(output, "writing MCAP", std::io::Error::other(e.to_string()))),
        None => staged,
    }
}

/// Nanoseconds from 1970-01-01 to the midnight the time column counts
/// from: the flight's day when it is known and the times are seconds of a
/// day (under two days, for flights past midnight); otherwise `None`, and
/// the time column is written as it is.
pub fn midnight_of_flight_ns(log: &FlightLog) -> Option<u64> {
    let date = log.date()?;
    let time = log.time_s();
    let time_of_day =
        time.first().is_some_and(|&t| t >= 0.0) && time.last().is_some_and(|&t| t < 2.0 * SECONDS_PER_DAY);
    time_of_day
        .then(|| u64::try_from(date.midnight_unix_ns()).ok())
        .flatten()
}

/// The warning for an MCAP `output` of `log` whose log times cannot be
/// absolute (the flight's day is unknown); `None` for other outputs.
pub fn undated_warning(log: &FlightLog, output: &Path) -> Option<crate::messages::Warning> {
    let mcap = crate::formats::detect_output_format(output) == crate::formats::Format::Mcap;
    let absolute = log.time_s().first().is_some_and(|&t| t >= 2.0 * SECONDS_PER_DAY);
    (mcap && !absolute && midnight_of_flight_ns(log).is_none()).then(|| crate::messages::Warning::McapUndated {
        output: output.to_path_buf(),
        time_column: log.time_column().to_string(),
    })
}

fn log_times_ns(log: &FlightLog, midnight_ns: u64) -> Result<Vec<u64>> {
    log.time_s()
        .iter()
        .enumerate()
        .map(
            |(row, &t)| match t >= 0.0 && t * 1e9 + (midnight_ns as f64) < u64::MAX as f64 {
                true => Ok((t * 1e9).round() as u64 + midnight_ns),
                false => Err(Error::BadTime {
                    path: log.source().to_path_buf(),
                    location: format!("sample {row}"),
                    column: log.time_column().to_string(),
                    problem: match t < 0.0 || t.is_nan() {
                        true => format!(
                            "is {} s; MCAP log times are nanoseconds from 0, so negative times cannot be written",
                            crate::error::Number(t)
                        ),
                        false => format!(
                            "is {} s, beyond the about 584 years after 1970 that MCAP's nanosecond log times reach: the column is probably not in seconds (milliseconds or microseconds?); convert it to seconds before writing MCAP",
                            crate::error::Number(t)
                        ),
                    },
                    fix: "write the flight as CSV, XYZ or HDF5, which hold any time in seconds, or shift its times to start at zero".into(),
                }),
            },
        )
        .collect()
}

fn write_records<W: Write + Seek>(
    file: W,
    times: &[u64],
    topics: &[Topic],
    extras: &McapExtras,
) -> std::result::Result<(), mcap::McapError> {
    let options = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("")
        .library(concat!("magcomp ", env!("CARGO_PKG_VERSION")));
    let mut writer = options.create(file)?;
    let mut channels = Vec::with_capacity(topics.len());
    for topic in topics {
        let schema = writer.add_schema(topic.schema, "protobuf", &descriptor_set(topic.schema))?;
        channels.push(writer.add_channel(schema, &topic.topic, "protobuf", &topic.metadata)?);
    }
    let mut sequence = vec![0u32; topics.len()];
    for (row, &time) in times.iter().enumerate() {
        for (k, topic) in topics.iter().enumerate() {
            let Some(data) = (topic.encode)(row, time) else {
                continue;
            };
            sequence[k] += 1;
            let header = mcap::records::MessageHeader {
                channel_id: channels[k],
                sequence: sequence[k],
                log_time: time,
                publish_time: time,
            };
            writer.write_to_known_channel(&header, &data)?;
        }
    }
    let created = times.first().copied().unwrap_or(0);
    write_documents(&mut writer, &extras.documents, created)?;
    writer.finish()?;
    Ok(())
}

/// Stores each JSON document twice, as a metadata record
/// (`magcomp.<name>`) and as an attachment (`<name>.json`) made at
/// `created`, ns.
fn write_documents<W: Write + Seek>(
    writer: &mut mcap::Writer<W>,
    documents: &[(String, String)],
    created: u64,
) -> std::result::Result<(), mcap::McapError> {
    for (name, json) in documents {
        writer.write_metadata(&mcap::records::Metadata {
            name: format!("magcomp.{name}"),
            metadata: BTreeMap::from([("json".to_string(), json.clone())]),
        })?;
        writer.attach(&mcap::Attachment {
            log_time: created,
            create_time: created,
            name: format!("{name}.json"),
            media_type: "application/json".into(),
            data: std::borrow::Cow::Borrowed(json.as_bytes()),
        })?;
    }
    Ok(())
}

/// The `<n>` of `mag_<n>_uc`, or the whole name.
fn scalar_label(name: &str) -> &str {
    name.strip_prefix("mag_")
        .and_then(|rest| rest.strip_suffix("_uc"))
        .unwrap_or(name)
}

fn unit_of(name: &str, role: &ChannelRole) -> &'static str {
    match role {
        ChannelRole::BaseStation | ChannelRole::VectorTotal { .. } => "nT",
        _ if name.starts_with("cur_") => "A",
        _ if name.starts_with("vol_") => "V",
        _ => "",
    }
}

/// A `magcomp.Sample` topic of `values`, one message a row, in `unit`.
fn sample_topic<'a>(topic: String, values: &'a [f64], unit: &'static str) -> Topic<'a> {
    Topic {
        topic,
        schema: "magcomp.Sample",
        metadata: BTreeMap::new(),
        encode: Box::new(move |row, time| {
            Some(
                Sample {
                    timestamp: Some(timestamp(time)),
                    value: values[row],
                    unit: unit.into(),
                }
                .encode_to_vec(),
            )
        }),
    }
}

/// Every topic of the output: the recorded channels', then the
/// compensation's.
fn plan_topics<'a>(log: &'a FlightLog, compensation: Option<&'a Compensation>) -> Vec<Topic<'a>> {
    let mut topics = recorded_topics(log);
    if let Some(compensation) = compensation {
        topics.extend(compensated_topics(compensation));
    }
    topics
}

/// The recorded channels' topics: each scalar and vector magnetometer,
/// the attitude and the position where the log holds them, and every
/// other channel as a sample topic.
fn recorded_topics(log: &FlightLog) -> Vec<Topic<'_>> {
    let mut topics: Vec<Topic<'_>> = Vec::new();
    let mut covered = vec![false; log.channels().len()];
    let channel = |i: usize| &log.channels()[i].values;
    for (i, c) in log.channels().iter().enumerate() {
        if c.role == ChannelRole::ScalarMagnetometer {
            covered[i] = true;
            let frame = c.name.clone();
            topics.push(Topic {
                topic: format!("/mag/{}/scalar", scalar_label(&c.name)),
                schema: "magcomp.ScalarMag",
                metadata: BTreeMap::new(),
                encode: Box::new(move |row, time| {
                    let total = channel(i)[row];
                    Some({
                        ScalarMag {
                            timestamp: Some(timestamp(time)),
                            frame_id: frame.clone(),
                            total_nt: total,
                        }
                        .encode_to_vec()
                    })
                }),
            });
        }
    }
    for sensor in log.vector_sensors() {
        sensor.axes.iter().for_each(|&i| covered[i] = true);
        topics.push(recorded_vector_topic(log, &sensor));
    }
    topics.extend(navigation_topics(log, &mut covered));
    for (i, c) in log.channels().iter().enumerate().filter(|(i, _)| !covered[*i]) {
        topics.push(sample_topic(
            format!("/aux/{}", c.name),
            channel(i),
            unit_of(&c.name, &c.role),
        ));
    }
    topics
}

/// A fluxgate's recorded vector topic.
fn recorded_vector_topic<'a>(log: &'a FlightLog, sensor: &crate::ingest::flight_log::VectorSensor) -> Topic<'a> {
    let channel = |i: usize| &log.channels()[i].values;
    let [x, y, z] = sensor.axes;
    let label = sensor
        .prefix
        .strip_prefix("flux_")
        .unwrap_or(&sensor.prefix)
        .to_string();
    let frame = sensor.prefix.clone();
    Topic {
        topic: format!("/mag/{label}/vector"),
        schema: "magcomp.VectorMag",
        metadata: BTreeMap::new(),
        encode: Box::new(move |row, time| {
            let v = [channel(x)[row], channel(y)[row], channel(z)[row]];
            Some({
                VectorMag {
                    timestamp: Some(timestamp(time)),
                    frame_id: frame.clone(),
                    x_nt: v[0],
                    y_nt: v[1],
                    z_nt: v[2],
                }
                .encode_to_vec()
            })
        }),
    }
}

/// The INS attitude topic of the channels `[roll, pitch, yaw]`.
fn attitude_topic(log: &FlightLog, [roll, pitch, yaw]: [usize; 3]) -> Topic<'_> {
    let channel = |i: usize| &log.channels()[i].values;
    Topic {
        topic: "/ins/attitude".into(),
        schema: "magcomp.Attitude",
        metadata: BTreeMap::new(),
        encode: Box::new(move |row, time| {
            let a = [channel(roll)[row], channel(pitch)[row], channel(yaw)[row]];
            Some({
                Attitude {
                    timestamp: Some(timestamp(time)),
                    roll_deg: a[0],
                    pitch_deg: a[1],
                    yaw_deg: a[2],
                }
                .encode_to_vec()
            })
        }),
    }
}

/// The attitude and position topics, where the log holds their channels
/// (marked `covered`).
fn navigation_topics<'a>(log: &'a FlightLog, covered: &mut [bool]) -> Vec<Topic<'a>> {
    let mut topics: Vec<Topic<'a>> = Vec::new();
    let channel = |i: usize| &log.channels()[i].values;
    let find = |role: ChannelRole, name: &str| {
        log.channels()
            .iter()
            .position(|c| c.role == role && (name.is_empty() || c.name == name))
    };
    let attitude = [AttitudeAngle::Roll, AttitudeAngle::Pitch, AttitudeAngle::Yaw]
        .map(|angle| find(ChannelRole::Attitude(angle), ""));
    let attitude_names = ["ins_roll", "ins_pitch", "ins_yaw"];
    if let [Some(roll), Some(pitch), Some(yaw)] = attitude {
        if [roll, pitch, yaw]
            .iter()
            .zip(attitude_names)
            .all(|(&i, n)| log.channels()[i].name == n)
        {
            [roll, pitch, yaw].iter().for_each(|&i| covered[i] = true);
            topics.push(attitude_topic(log, [roll, pitch, yaw]));
        }
    }
    let lat = find(ChannelRole::Position, "lat");
    let lon = find(ChannelRole::Position, "lon");
    let height = ["alt", "msl", "utm_z"]
        .iter()
        .find_map(|h| find(ChannelRole::Position, h));
    if let (Some(lat), Some(lon), Some(height)) = (lat, lon, height) {
        [lat, lon, height].iter().for_each(|&i| covered[i] = true);
        let metadata = BTreeMap::from([(ALTITUDE_COLUMN_KEY.to_string(), log.channels()[height].name.clone())]);
        topics.push(Topic {
            topic: "/gps/fix".into(),
            schema: "foxglove.LocationFix",
            metadata,
            encode: Box::new(move |row, time| {
                let p = [channel(lat)[row], channel(lon)[row], channel(height)[row]];
                Some({
                    LocationFix {
                        latitude: p[0],
                        longitude: p[1],
                        altitude: p[2],
                        timestamp: Some(timestamp(time)),
                        frame_id: "wgs84".into(),
                    }
                    .encode_to_vec()
                })
            }),
        });
    }
    topics
}

/// A compensated vector's two topics: in body axes and north-east-down.
fn vector_topics(vector: &crate::vector::CompensatedVector) -> Vec<Topic<'_>> {
    let mut topics: Vec<Topic<'_>> = Vec::new();
    let label = vector.sensor.strip_prefix("flux_").unwrap_or(&vector.sensor);
    for (suffix, frame, values) in [("", "body", &vector.body_nt), ("_ned", "ned", &vector.ned_nt)] {
        topics.push(Topic {
            topic: format!("/mag/{label}/vector_compensated{suffix}"),
            schema: "magcomp.VectorMag",
            metadata: BTreeMap::new(),
            encode: Box::new(move |row, time| {
                Some(
                    VectorMag {
                        timestamp: Some(timestamp(time)),
                        frame_id: frame.into(),
                        x_nt: values[0][row],
                        y_nt: values[1][row],
                        z_nt: values[2][row],
                    }
                    .encode_to_vec(),
                )
            }),
        });
    }
    topics
}

/// The compensation's topics: each compensated channel and its sigma,
/// each compensated vector and gradient, the reduced channels and the row
/// flags.
fn compensated_topics(compensation: &Compensation) -> Vec<Topic<'_>> {
    let mut topics: Vec<Topic<'_>> = Vec::new();
    for compensated in &compensation.channels {
        let frame = compensated.channel.clone();
        let label = scalar_label(&compensated.channel);
        topics.push(Topic {
            topic: format!("/mag/{label}/compensated"),
            schema: "magcomp.ScalarMag",
            metadata: BTreeMap::new(),
            encode: Box::new(move |row, time| {
                let total = compensated.values[row];
                Some({
                    ScalarMag {
                        timestamp: Some(timestamp(time)),
                        frame_id: frame.clone(),
                        total_nt: total,
                    }
                    .encode_to_vec()
                })
            }),
        });
        if let Some(sigma) = compensated.sigma_nt.as_deref() {
            topics.push(sample_topic(format!("/mag/{label}/compensated_sigma"), sigma, "nT"));
        }
    }
    topics.extend(compensation.vectors.iter().flat_map(vector_topics));
    for gradient in &compensation.gradients {
        let label = gradient.column.strip_prefix("grad_").unwrap_or(&gradient.column);
        let label = label.strip_suffix("_c").unwrap_or(label);
        topics.push(sample_topic(
            format!("/grad/{label}/compensated"),
            &gradient.values,
            "nT/m",
        ));
    }
    for reduced in &compensation.reduced {
        // `mag_1_dc` → /mag/1/dc, as the compensated channel's topic.
        let (channel, kind) = reduced.column.rsplit_once('_').unwrap_or((&reduced.column, "reduced"));
        let name = format!("{channel}_uc");
        topics.push(sample_topic(
            format!("/mag/{}/{kind}", scalar_label(&name)),
            &reduced.values,
            "nT",
        ));
    }
    let flags = &compensation.flags;
    topics.push(Topic {
        topic: "/magcomp/flags".into(),
        schema: "magcomp.RowFlags",
        metadata: BTreeMap::new(),
        encode: Box::new(move |row, time| {
            Some(
                RowFlags {
                    timestamp: Some(timestamp(time)),
                    flags: flags.get(row).map(|f| f.to_string()).unwrap_or_default(),
                }
                .encode_to_vec(),
            )
        }),
    });
    topics
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A time before 0 and a time beyond what nanoseconds reach are each
    /// refused with their own cause: the second is a column in another
    /// unit, not a negative time.
    #[test]
    fn times_mcap_cannot_hold_are_refused_with_their_cause() {
        let log = |time: Vec<f64>| FlightLog::new("t.csv", "tt", time, Vec::new()).unwrap();
        let early = log_times_ns(&log(vec![-1.0, 0.0]), 0).unwrap_err().to_string();
        assert!(
            early.contains("sample 0") && early.contains("negative times"),
            "{early}"
        );
        let microseconds = log_times_ns(&log(vec![1.7e15, 1.7e15 + 1e5]), 0)
            .unwrap_err()
            .to_string();
        assert!(
            microseconds.contains("not in seconds") && !microseconds.contains("negative"),
            "{microseconds}"
        );
        assert_eq!(
            log_times_ns(&log(vec![1.5, 2.0]), 10).unwrap(),
            vec![1_500_000_010, 2_000_000_010]
        );
    }
}
