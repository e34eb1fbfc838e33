//! MCAP flight logs (CONTRACT §4).
//!
//! Protobuf messages are decoded through the `FileDescriptorSet` embedded in
//! the file's schemas, by field name, so any producer's numbering works.
//! JSON messages (with a `jsonschema` or no schema) are read by the same
//! field names. Topics map to channels as CONTRACT §4 lays out:
//! `/mag/<n>/scalar` → `mag_<n>_uc`, `/mag/<s>/vector` → `flux_<s>_x|y|z`,
//! `/ins/attitude` → `ins_roll|pitch|yaw`, `/gps/fix` → `lat`, `lon`, `alt`
//! (or the column named by the channel's `magcomp.altitude_column`
//! metadata), `/aux/<column>` → `<column>`. Numeric fields of any other
//! topic become auxiliary channels named `<topic>_<field>`.
//!
//! ROS 2 recordings (rosbag2 MCAP, CDR messages) are read too:
//! `sensor_msgs/msg/MagneticField` becomes a vector magnetometer (tesla →
//! nT) or, mapped with `[[topic]] scalar = "mag_1_uc"`, a scalar one (its
//! magnitude); `Imu` becomes `ins_roll|pitch|yaw` in the SGL convention;
//! `NavSatFix` becomes `lat`, `lon`, `alt` (see [`ros`]).
//!
//! The file is read through its summary and chunk index when it has them,
//! chunks decoded in parallel and merged in file order; a file without a
//! summary is scanned linearly. Channels then go onto one time base (see
//! [`align`](super::align)). A truncated or corrupt file is an error, never
//! a panic.

use std::collections::BTreeMap;
use std::path::Path;

use std::borrow::Cow;

use rayon::prelude::*;

pub mod messages;
mod records;
pub mod write;

pub use write::{midnight_of_flight_ns, stage_mcap, undated_warning, McapExtras};

use self::records::{ChannelRecord, Definitions, SchemaRecord};
use super::align::{align, Stream};
use super::columns::ColumnNames;
use super::ros::{self, RosType};
use super::{IngestOptions, TopicMapping};
use crate::error::{Error, Result};
use crate::ingest::flight_date::FlightDate;
use crate::ingest::flight_log::{AttitudeAngle, Channel, ChannelRole, FlightLog, VectorAxis};
use crate::messages::{ReadNote, Reading, Warning};
use messages::MessageLayout;

/// Metadata key on a `/gps/fix` channel naming the height column.
pub const ALTITUDE_COLUMN_KEY: &str = "magcomp.altitude_column";

/// Channel metadata key of the flight's day (`YYYY-MM-DD`, UTC): the
/// log times are that day's midnight plus the time column, which the
/// reader restores as seconds of the day.
pub const DATE_KEY: &str = "magcomp.date";

/// How one MCAP channel's messages are decoded.
#[derive(Debug, Clone)]
enum Decoder {
    Protobuf(MessageLayout),
    Json,
    Ros(RosType),
    /// Not read: why, and whether numbers it may hold are lost with it (an
    /// encoding or schema magcomp cannot decode) or it holds none magcomp
    /// reads (text, a ROS 2 type other than the three read).
    Skip {
        why: String,
        lost: bool,
    },
}

/// Per MCAP channel: its topic, decoder and the height column of a fix.
#[derive(Debug, Clone)]
struct TopicPlan {
    topic: String,
    decoder: Decoder,
    altitude_column: String,
    /// The flight's day, when the channel's metadata gives it.
    date: Option<FlightDate>,
}

/// Decoded samples of one MCAP channel in one part of the file.
#[derive(Debug, Default, Clone)]
struct Decoded {
    times_ns: Vec<u64>,
    /// Field name of each column: from the schema for protobuf, by first
    /// appearance for JSON.
    fields: Vec<String>,
    /// One column per field, one value per message (NaN where a JSON
    /// message lacks the field).
    values: Vec<Vec<f64>>,
    errors: usize,
    first_error: Option<String>,
}

impl Decoded {
    /// The column of `field`, created (missing so far) when new.
    fn column(&mut self, field: &str) -> usize {
        match self.fields.iter().position(|f| f == field) {
            Some(index) => index,
            None => {
                self.fields.push(field.to_string());
                self.values.push(vec![f64::NAN; self.times_ns.len()]);
                self.fields.len() - 1
            }
        }
    }

    /// Appends `other` (a later part of the same channel), matching fields by name.
    fn append(&mut self, other: Decoded) {
        let before = self.times_ns.len();
        let added = other.times_ns.len();
        self.times_ns.extend(other.times_ns);
        for (field, values) in other.fields.iter().zip(other.values) {
            let index = match self.fields.iter().position(|f| f == field) {
                Some(index) => index,
                None => {
                    self.fields.push(field.clone());
                    self.values.push(vec![f64::NAN; before]);
                    self.fields.len() - 1
                }
            };
            self.values[index].extend(values);
        }
        for column in &mut self.values {
            column.resize(before + added, f64::NAN);
        }
        self.errors += other.errors;
        self.first_error = self.first_error.take().or(other.first_error);
    }
}

/// Reads an MCAP flight log.
pub fn read_mcap(path: &Path, options: &IngestOptions) -> Result<FlightLog> {
    let names = &options.columns;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, "reading", e))?;
    let corrupt = |message: String| Error::UnsupportedFormat {
        path: path.to_path_buf(),
        message,
    };
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(corrupt(
            "the file does not start with the MCAP magic bytes; it is not an MCAP file or it is damaged".into(),
        ));
    }
    // The mcap crate is trusted to return errors, but a damaged file must
    // never take the whole run down: a panic inside it becomes an error.
    let decoded = std::panic::catch_unwind(|| decode_file(&bytes, names))
        .map_err(|_| corrupt("the MCAP file is corrupt (its records could not be parsed)".into()))?
        .map_err(|e| corrupt(format!("the MCAP file is truncated or corrupt: {e}")))?;
    build_log(path, options, decoded)
}

/// The topics' plans, their decoded messages, remarks on how the file was
/// read, what was lost reading it (damaged chunks, undecodable messages)
/// and where the file was cut short.
type FileContents = (
    BTreeMap<u16, TopicPlan>,
    BTreeMap<u16, Decoded>,
    Vec<ReadNote>,
    Vec<Warning>,
    Option<records::CutShort>,
);

/// Every message of the decompressed `chunks` (in parallel) and those
/// outside chunks, decoded by their topic's plan, by channel id: each
/// channel's messages in chunk order, then those outside chunks.
fn decode_messages(
    plans: &BTreeMap<u16, TopicPlan>,
    chunks: &[Cow<'_, [u8]>],
    loose_messages: &[records::MessageRef<'_>],
) -> BTreeMap<u16, Decoded> {
    let parts: Vec<BTreeMap<u16, Decoded>> = chunks
        .par_iter()
        .map(|records| {
            let mut part = BTreeMap::new();
            let mut ignored = Definitions::default();
            // Already walked once without error, so this cannot fail.
            let _ = records::chunk_messages(records, &mut ignored, |m| {
                add_message(plans, &mut part, m.channel_id, m.log_time, m.data);
            });
            part
        })
        .collect();
    let mut merged: BTreeMap<u16, Decoded> = BTreeMap::new();
    for part in parts {
        for (id, decoded) in part {
            merged.entry(id).or_default().append(decoded);
        }
    }
    let mut loose = BTreeMap::new();
    for m in loose_messages {
        add_message(plans, &mut loose, m.channel_id, m.log_time, m.data);
    }
    for (id, decoded) in loose {
        merged.entry(id).or_default().append(decoded);
    }
    merged
}

/// A decompressed chunk and the schemas and channels it defines.
type OpenedChunk<'a> = (Cow<'a, [u8]>, Definitions);

fn decode_file(bytes: &[u8], names: &ColumnNames) -> std::result::Result<FileContents, String> {
    let section = records::data_section(bytes)?;
    let (notes, cut_short) = (section.notes, section.cut_short);
    let mut losses: Vec<Warning> = Vec::new();
    if records::data_section_crc_holds(bytes) == Some(false) {
        losses.push(Reading::McapCrcFails.into());
    }
    // Decompress every chunk (in parallel) and learn the schemas and
    // channels they define; messages are decoded once all are known.
    let opened: Vec<std::result::Result<OpenedChunk, String>> = section
        .chunks
        .par_iter()
        .map(|body| {
            let records = records::chunk_records(body)?;
            let mut definitions = Definitions::default();
            records::chunk_messages(&records, &mut definitions, |_| {})?;
            Ok((records, definitions))
        })
        .collect();
    let mut definitions = section.definitions;
    let (chunks, damaged) = whole_chunks(opened, &mut definitions, &mut losses);
    if damaged > 0 && chunks.is_empty() && section.messages.is_empty() {
        return Err(format!("every chunk is damaged ({} of them)", damaged));
    }
    let plans: BTreeMap<u16, TopicPlan> = definitions
        .channels
        .iter()
        .map(|(id, channel)| {
            (
                *id,
                plan_topic(channel, definitions.schemas.get(&channel.schema_id), names),
            )
        })
        .collect();
    let merged = decode_messages(&plans, &chunks, &section.messages);
    Ok((plans, merged, notes, losses, cut_short))
}

/// The chunks that opened, their definitions merged into `definitions`,
/// and how many were damaged; the first damage and the count left out are
/// told in `losses`.
fn whole_chunks<'a>(
    opened: Vec<std::result::Result<OpenedChunk<'a>, String>>,
    definitions: &mut Definitions,
    losses: &mut Vec<Warning>,
) -> (Vec<Cow<'a, [u8]>>, usize) {
    let mut chunks = Vec::with_capacity(opened.len());
    let mut damaged = 0;
    for chunk in opened {
        match chunk {
            Ok((records, found)) => {
                definitions.merge(found);
                chunks.push(records);
            }
            Err(e) => {
                if damaged == 0 {
                    losses.push(Reading::McapChunkDamaged { why: e }.into());
                }
                damaged += 1;
            }
        }
    }
    if damaged > 0 {
        losses.push(
            Reading::McapChunksLeftOut {
                damaged,
                of: damaged + chunks.len(),
            }
            .into(),
        );
    }
    (chunks, damaged)
}

/// Whether `topic` is one of the contract's sensor topics:
/// `/mag/<n>/scalar`, `/mag/<s>/vector`, `/ins/attitude`, `/gps/fix`.
fn is_sensor_topic(topic: &str) -> bool {
    let parts: Vec<&str> = topic.trim_matches('/').split('/').collect();
    matches!(
        parts.as_slice(),
        ["mag", _, "scalar"] | ["mag", _, "vector"] | ["ins", "attitude"] | ["gps", "fix"]
    )
}

/// Decides how to decode a channel and what its fields become.
fn plan_topic(channel: &ChannelRecord, schema: Option<&SchemaRecord>, names: &ColumnNames) -> TopicPlan {
    let topic = channel.topic.clone();
    let decoder = decoder_for(channel, schema);
    // A sensor topic of the contract (a magnetometer, the INS, the GPS)
    // that cannot be read loses a sensor the run would use: a warning,
    // whatever the reason.
    let decoder = match decoder {
        Decoder::Skip { why, lost: false } if is_sensor_topic(&topic) => Decoder::Skip { why, lost: true },
        other => other,
    };
    let altitude_column = channel
        .metadata
        .get(ALTITUDE_COLUMN_KEY)
        .cloned()
        .unwrap_or_else(|| "alt".into());
    let _ = names;
    TopicPlan {
        topic,
        decoder,
        altitude_column,
        date: channel.metadata.get(DATE_KEY).and_then(|d| FlightDate::parse(d)),
    }
}

/// How to decode a channel's messages, by their encoding and schema: the
/// protobuf layout, JSON, a ROS 2 type, or skipped with why.
fn decoder_for(channel: &ChannelRecord, schema: Option<&SchemaRecord>) -> Decoder {
    match (channel.message_encoding.as_str(), schema) {
        ("protobuf", Some(schema)) if schema.encoding == "protobuf" => {
            match MessageLayout::from_descriptor_set(&schema.data, &schema.name) {
                Ok(layout) if layout.names.is_empty() => Decoder::Skip {
                    why: format!(
                        "message type '{}' has no number field (text, such as magcomp's row flags, is not read)",
                        schema.name
                    ),
                    lost: false,
                },
                Ok(layout) => Decoder::Protobuf(layout),
                Err(why) => Decoder::Skip { why, lost: true },
            }
        }
        ("json", _) => Decoder::Json,
        ("cdr", Some(schema)) => match RosType::from_schema_name(&schema.name) {
            Some(kind) => Decoder::Ros(kind),
            None => Decoder::Skip {
                why: format!(
                    "ROS 2 type '{}' is not read (magcomp reads sensor_msgs MagneticField, Imu and NavSatFix)",
                    schema.name
                ),
                lost: false,
            },
        },
        ("protobuf", Some(schema)) => Decoder::Skip {
            why: format!(
                "its messages are protobuf but their schema '{}' is in encoding '{}', not a protobuf descriptor set, so they cannot be decoded: rewrite the schema record, or record the topic again",
                schema.name, schema.encoding
            ),
            lost: true,
        },
        (encoding @ ("protobuf" | "cdr"), None) => Decoder::Skip {
            why: format!("its messages are {encoding} but the channel names no schema, without which they cannot be decoded: record the topic with its schema"),
            lost: true,
        },
        (encoding, _) => Decoder::Skip {
            why: format!("message encoding '{encoding}' is not read (magcomp reads protobuf, JSON and ROS 2 CDR)"),
            lost: true,
        },
    }
}

/// The flight-log channel name of `field` on `topic` (CONTRACT §4).
pub fn channel_name(topic: &str, field: &str, altitude_column: &str) -> String {
    let parts: Vec<&str> = topic.trim_matches('/').split('/').collect();
    let known = match (parts.as_slice(), field) {
        (["mag", n, "scalar"], "total_nt") => Some(format!("mag_{n}_uc")),
        (["mag", n, "compensated"], "total_nt") => Some(format!("mag_{n}_c")),
        (["mag", n, "compensated_sigma"], "value") => Some(format!("mag_{n}_c_sigma")),
        (["mag", n, kind @ ("dc" | "igrf")], "value") => Some(format!("mag_{n}_{kind}")),
        (["mag", s, "vector_compensated"], "x_nt" | "y_nt" | "z_nt") => Some(format!("flux_{s}_{}_c", &field[..1])),
        (["mag", s, "vector_compensated_ned"], "x_nt" | "y_nt" | "z_nt") => {
            let axis = match &field[..1] {
                "x" => "n",
                "y" => "e",
                _ => "d",
            };
            Some(format!("flux_{s}_{axis}_c"))
        }
        (["grad", pair, "compensated"], "value") => Some(format!("grad_{pair}_c")),
        (["mag", s, "vector"], "x_nt" | "y_nt" | "z_nt") => Some(format!("flux_{s}_{}", &field[..1])),
        (["ins", "attitude"], "roll_deg" | "pitch_deg" | "yaw_deg") => {
            Some(format!("ins_{}", field.trim_end_matches("_deg")))
        }
        (["gps", "fix"], "latitude") => Some("lat".into()),
        (["gps", "fix"], "longitude") => Some("lon".into()),
        (["gps", "fix"], "altitude") => Some(altitude_column.into()),
        (["aux", column @ ..], "value") if !column.is_empty() => Some(column.join("_")),
        _ => None,
    };
    known.unwrap_or_else(|| {
        let stem: String = parts
            .join("_")
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        format!("{stem}_{field}")
    })
}

fn add_message(
    plans: &BTreeMap<u16, TopicPlan>,
    part: &mut BTreeMap<u16, Decoded>,
    id: u16,
    log_time: u64,
    data: &[u8],
) {
    let Some(plan) = plans.get(&id) else { return };
    let decoded = part.entry(id).or_default();
    let result = match &plan.decoder {
        Decoder::Skip { .. } => return,
        Decoder::Protobuf(layout) => decode_protobuf(layout, data, decoded),
        Decoder::Json => decode_json(data, decoded),
        Decoder::Ros(kind) => decode_ros(*kind, data, decoded),
    };
    match result {
        Ok(()) => decoded.times_ns.push(log_time),
        Err(e) => {
            decoded.errors += 1;
            decoded.first_error.get_or_insert(e);
        }
    }
}

fn decode_protobuf(layout: &MessageLayout, data: &[u8], decoded: &mut Decoded) -> std::result::Result<(), String> {
    let slots = layout.names.len();
    if decoded.fields.is_empty() && slots > 0 {
        decoded.fields = layout.names.clone();
        decoded.values = vec![Vec::new(); slots];
    }
    let mut stack = [0.0; 32];
    let mut heap = Vec::new();
    let buffer: &mut [f64] = if slots <= stack.len() {
        &mut stack[..slots]
    } else {
        heap.resize(slots, 0.0);
        &mut heap
    };
    layout.decode(data, buffer)?;
    for (column, value) in decoded.values.iter_mut().zip(buffer.iter()) {
        column.push(*value);
    }
    Ok(())
}

fn decode_ros(kind: RosType, data: &[u8], decoded: &mut Decoded) -> std::result::Result<(), String> {
    if decoded.fields.is_empty() {
        decoded.fields = kind.fields().iter().map(|f| f.to_string()).collect();
        decoded.values = vec![Vec::new(); decoded.fields.len()];
    }
    let mut values = [0.0; 3];
    ros::decode(kind, data, &mut values)?;
    for (column, value) in decoded.values.iter_mut().zip(values) {
        column.push(value);
    }
    Ok(())
}

/// JSON messages: the numeric (and boolean) top-level fields, by name.
fn decode_json(data: &[u8], decoded: &mut Decoded) -> std::result::Result<(), String> {
    let object: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(data).map_err(|e| format!("not a JSON object: {e}"))?;
    let row = decoded.times_ns.len();
    for (field, value) in &object {
        let number = match value {
            serde_json::Value::Number(n) => n.as_f64(),
            serde_json::Value::Bool(b) => Some(f64::from(u8::from(*b))),
            _ => None,
        };
        if let Some(number) = number {
            let column = decoded.column(field);
            decoded.values[column].push(number);
        }
    }
    for column in &mut decoded.values {
        column.resize(row + 1, f64::NAN);
    }
    Ok(())
}

/// `[topic]` with its path parts made into a name: `/imu/mag` → `imu_mag`.
fn topic_stem(topic: &str) -> String {
    topic
        .trim_matches('/')
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

/// The magnitude of a vector given by its three components' series.
fn magnitude([x, y, z]: [&[f64]; 3]) -> Vec<f64> {
    (0..x.len())
        .map(|i| (x[i] * x[i] + y[i] * y[i] + z[i] * z[i]).sqrt())
        .collect()
}

/// The streams of a ROS 2 topic, with their roles.
fn ros_streams(
    kind: RosType,
    topic: &str,
    data: Decoded,
    mapping: Option<&TopicMapping>,
    attitude_taken: &mut bool,
) -> Vec<Stream> {
    let stream = |name: String, field: &str, role: Option<ChannelRole>, values: Vec<f64>| Stream {
        name,
        source: format!("{topic}:{field}"),
        hold: false,
        angle: false,
        role,
        times_ns: data.times_ns.clone(),
        values,
    };
    let mut columns = data.values.clone().into_iter();
    let mut next = || columns.next().unwrap_or_default();
    match kind {
        RosType::MagneticField => {
            let [x, y, z] = [next(), next(), next()];
            if let Some(scalar) = mapping.and_then(|m| m.scalar.clone()) {
                let role = Some(ChannelRole::ScalarMagnetometer);
                return vec![stream(scalar, "|magnetic_field|", role, magnitude([&x, &y, &z]))];
            }
            let prefix = mapping
                .and_then(|m| m.vector.clone())
                .unwrap_or_else(|| format!("flux_{}", topic_stem(topic)));
            [
                (VectorAxis::X, "x", x),
                (VectorAxis::Y, "y", y),
                (VectorAxis::Z, "z", z),
            ]
            .into_iter()
            .map(|(axis, letter, values)| {
                let role = ChannelRole::VectorMagnetometer {
                    sensor: prefix.clone(),
                    axis,
                };
                stream(format!("{prefix}_{letter}"), letter, Some(role), values)
            })
            .collect()
        }
        RosType::Imu => {
            let first = !std::mem::replace(attitude_taken, true);
            let angles = [
                (AttitudeAngle::Roll, "roll", next()),
                (AttitudeAngle::Pitch, "pitch", next()),
                (AttitudeAngle::Yaw, "yaw", next()),
            ];
            angles
                .into_iter()
                .map(|(angle, word, values)| match first {
                    true => stream(format!("ins_{word}"), word, Some(ChannelRole::Attitude(angle)), values),
                    false => stream(format!("{}_{word}", topic_stem(topic)), word, None, values),
                })
                .collect()
        }
        RosType::NavSatFix => ["lat", "lon", "alt"]
            .into_iter()
            .zip(["latitude", "longitude", "altitude"])
            .map(|(name, field)| stream(name.into(), field, None, next()))
            .collect(),
    }
}

fn build_log(
    path: &Path,
    options: &IngestOptions,
    (plans, decoded, mut notes, mut losses, cut_short): FileContents,
) -> Result<FlightLog> {
    let (names, alignment) = (&options.columns, &options.alignment);
    let streams = decoded_streams(path, options, (&plans, decoded), (&mut notes, &mut losses))?;
    let mut streams = joined_streams(streams, &mut notes, &mut losses);
    let base = time_base(path, options, &streams)?;
    if streams[base].times_ns.is_empty() {
        return Err(Error::AllMissing {
            path: path.to_path_buf(),
            column: streams[base].name.clone(),
        });
    }
    let date = time_of_day(&plans, &mut streams, &mut losses);
    let roles: Vec<Option<ChannelRole>> = streams.iter().map(|s| s.role.clone()).collect();
    for (stream, role) in streams.iter_mut().zip(&roles) {
        let role = role.clone().or_else(|| names.role_of(&stream.name));
        stream.angle = matches!(role, Some(ChannelRole::Attitude(_)));
    }
    let mut aligned = align(streams, base, alignment).map_err(|conflict| Error::BadTime {
        path: path.to_path_buf(),
        location: format!("topic {}", conflict.source),
        column: conflict.channel.clone(),
        problem: format!(
            "has {} time(s) at which messages disagree, the first at {} s, so which row the time stands for cannot be decided",
            conflict.times,
            crate::error::Number(conflict.first_time_s)
        ),
        fix: "the recording holds two copies of the topic that disagree (two recorders, or a logger that restarted): keep one, or map the other to its own column with [columns]".into(),
    })?;
    aligned.report.notes = notes;
    aligned.report.warnings.splice(0..0, losses);
    if let Some(cut) = cut_short {
        aligned
            .report
            .warnings
            .insert(0, cut_short_warning(&cut, &aligned.time_s));
    }
    let channels: Vec<Channel> = aligned
        .channels
        .into_iter()
        .zip(roles)
        .filter_map(|((name, values), role)| {
            let role = role.or_else(|| names.role_of(&name))?;
            Some(Channel { name, role, values })
        })
        .collect();
    Ok(FlightLog::new(path, names.time.clone(), aligned.time_s, channels)?
        .with_row_flags(aligned.row_flags)
        .with_reading_warnings(aligned.report.warnings.clone())
        .with_alignment(aligned.report)
        .with_date(date))
}

/// Each topic skipped: a loss when numbers it may hold are lost with it
/// (an encoding or schema magcomp cannot decode), a note when it holds
/// none magcomp reads.
fn skipped_topics(plans: &BTreeMap<u16, TopicPlan>, (notes, losses): (&mut Vec<ReadNote>, &mut Vec<Warning>)) {
    let read = |topic: &str| (plans.values()).any(|p| p.topic == topic && !matches!(p.decoder, Decoder::Skip { .. }));
    for (&channel, plan) in plans {
        match &plan.decoder {
            // The topic's other channel records are read.
            Decoder::Skip { why, lost: true } if read(&plan.topic) => losses.push(
                Reading::McapChannelLost {
                    topic: plan.topic.clone(),
                    channel,
                    why: why.clone(),
                }
                .into(),
            ),
            Decoder::Skip { why, lost: true } => losses.push(
                Reading::McapTopicLost {
                    topic: plan.topic.clone(),
                    why: why.clone(),
                }
                .into(),
            ),
            Decoder::Skip { why, lost: false } => notes.push(ReadNote::TopicSkipped {
                topic: plan.topic.clone(),
                why: why.clone(),
            }),
            _ => {}
        }
    }
}

/// The skipped topics in words, then one stream per decoded field (or per
/// ROS message field), with what could not be decoded said.
fn decoded_streams(
    path: &Path,
    options: &IngestOptions,
    (plans, decoded): (&BTreeMap<u16, TopicPlan>, BTreeMap<u16, Decoded>),
    (notes, losses): (&mut Vec<ReadNote>, &mut Vec<Warning>),
) -> Result<Vec<Stream>> {
    let names = &options.columns;
    let mut attitude_taken = false;
    skipped_topics(plans, (notes, losses));
    let mut streams: Vec<Stream> = Vec::new();
    for (id, data) in decoded {
        let plan = &plans[&id];
        if let Some(error) = &data.first_error {
            losses.push(
                Reading::McapUndecodable {
                    topic: plan.topic.clone(),
                    messages: data.errors,
                    first: error.clone(),
                }
                .into(),
            );
            if data.times_ns.is_empty() {
                return Err(Error::UnsupportedFormat {
                    path: path.to_path_buf(),
                    message: format!("no message on topic '{}' could be decoded: {error}", plan.topic),
                });
            }
        }
        if let Decoder::Ros(kind) = plan.decoder {
            let mapping = options.topics.iter().find(|m| m.topic == plan.topic);
            streams.extend(ros_streams(kind, &plan.topic, data, mapping, &mut attitude_taken));
            continue;
        }
        let integer = |field: &str| match &plan.decoder {
            Decoder::Protobuf(layout) => layout
                .names
                .iter()
                .position(|n| n == field)
                .is_some_and(|i| layout.kinds[i].is_integer()),
            _ => false,
        };
        for (field, values) in data.fields.iter().zip(data.values) {
            if values.len() != data.times_ns.len() {
                continue;
            }
            let name = channel_name(&plan.topic, field, &plan.altitude_column);
            streams.push(Stream {
                hold: integer(field) || name == names.line,
                angle: false,
                role: None,
                name,
                source: format!("{}:{field}", plan.topic),
                times_ns: data.times_ns.clone(),
                values,
            });
        }
    }
    Ok(streams)
}

/// The stream the others are aligned on: `[alignment] time_base`, or the
/// first scalar magnetometer.
fn time_base(path: &Path, options: &IngestOptions, streams: &[Stream]) -> Result<usize> {
    let names = &options.columns;
    Ok(match &options.alignment.time_base {
        Some(name) => streams.iter().position(|s| &s.name == name).ok_or_else(|| Error::Config {
            source_name: "[alignment] time_base".into(),
            message: format!(
                "no channel '{name}' in {}; the channels are: {}",
                path.display(),
                streams.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ")
            ),
        })?,
        None => streams
            .iter()
            .position(|s| s.role.clone().or_else(|| names.role_of(&s.name)) == Some(ChannelRole::ScalarMagnetometer))
            .ok_or_else(|| Error::MissingColumn {
                path: path.to_path_buf(),
                role: "scalar magnetometer",
                looked_for: "a /mag/<n>/scalar topic (or a ROS topic mapped with scalar = ...)".into(),
                hint: "Record the scalar magnetometers on /mag/<n>/scalar, map a ROS MagneticField topic with [[topic]] scalar = \"mag_1_uc\", or name the time-base channel in [alignment] time_base.".into(),
            })?,
    })
}

/// One stream per column name. Streams of one source (a topic recorded on
/// several channel records: a logger that restarted, two writers) are one
/// series, read together in time order, with a note. Streams of different
/// sources that would make the same column keep the first source's, and
/// a line in `losses` names the others.
fn joined_streams(mut streams: Vec<Stream>, notes: &mut Vec<ReadNote>, losses: &mut Vec<Warning>) -> Vec<Stream> {
    streams.sort_by(|a, b| a.name.cmp(&b.name).then(a.source.cmp(&b.source)));
    let mut joined: Vec<Stream> = Vec::with_capacity(streams.len());
    let mut parts = 1;
    for stream in streams {
        let Some(last) = joined.last_mut().filter(|l| l.name == stream.name) else {
            if parts > 1 {
                notes.push(joined_note(joined.last(), parts));
            }
            parts = 1;
            joined.push(stream);
            continue;
        };
        if last.source != stream.source {
            losses.push(
                Reading::McapColumnTwice {
                    column: stream.name.clone(),
                    read: last.source.clone(),
                    left_out: stream.source.clone(),
                    messages: stream.times_ns.len(),
                }
                .into(),
            );
            continue;
        }
        parts += 1;
        let mut pairs: Vec<(u64, f64)> = (last.times_ns.iter().copied().zip(last.values.iter().copied()))
            .chain(stream.times_ns.into_iter().zip(stream.values))
            .collect();
        pairs.sort_by_key(|(t, _)| *t);
        (last.times_ns, last.values) = pairs.into_iter().unzip();
    }
    if parts > 1 {
        notes.push(joined_note(joined.last(), parts));
    }
    joined
}

fn joined_note(stream: Option<&Stream>, parts: usize) -> ReadNote {
    let (source, messages) = stream.map_or(("?", 0), |s| (s.source.as_str(), s.times_ns.len()));
    ReadNote::TopicJoined {
        source: source.to_string(),
        parts,
        messages,
    }
}

/// What a file cut short lost, with the rows and time span read.
fn cut_short_warning(cut: &records::CutShort, time_s: &[f64]) -> Warning {
    Reading::McapCutShort {
        at_byte: cut.at_byte as u64,
        inside_record_of: (!cut.at_record_boundary).then_some(cut.of_bytes as u64),
        read: match (time_s.first(), time_s.last()) {
            (Some(first), Some(last)) => Some((time_s.len(), *first, *last)),
            _ => None,
        },
    }
    .into()
}

/// The flight's day from the channels' metadata, with every stream's times
/// made times of that day; `None`, times untouched, when no channel gives
/// a day, or (with a line in `losses`) when a message is older than its
/// midnight.
fn time_of_day(
    plans: &BTreeMap<u16, TopicPlan>,
    streams: &mut [Stream],
    losses: &mut Vec<Warning>,
) -> Option<FlightDate> {
    let date = plans.values().find_map(|p| p.date)?;
    let midnight = u64::try_from(date.midnight_unix_ns()).ok()?;
    let after_midnight = streams.iter().all(|s| s.times_ns.iter().all(|&t| t >= midnight));
    if !after_midnight {
        losses.push(
            Reading::McapBeforeItsDay {
                day: date.to_string(),
                key: DATE_KEY.to_string(),
            }
            .into(),
        );
        return None;
    }
    for stream in streams {
        stream.times_ns.iter_mut().for_each(|t| *t -= midnight);
    }
    Some(date)
}

#[cfg(test)]
mod tests {
    use super::channel_name;

    /// A compensated MCAP reads back with the CSV output's column names.
    #[test]
    fn compensated_topics_read_back_as_the_csv_columns() {
        let cases = [
            ("/mag/1/scalar", "total_nt", "mag_1_uc"),
            ("/mag/1/compensated", "total_nt", "mag_1_c"),
            ("/mag/1/compensated_sigma", "value", "mag_1_c_sigma"),
            ("/mag/1/dc", "value", "mag_1_dc"),
            ("/mag/2/igrf", "value", "mag_2_igrf"),
            ("/mag/a/vector", "y_nt", "flux_a_y"),
            ("/mag/a/vector_compensated", "z_nt", "flux_a_z_c"),
            ("/mag/b/vector_compensated_ned", "x_nt", "flux_b_n_c"),
            ("/mag/b/vector_compensated_ned", "y_nt", "flux_b_e_c"),
            ("/mag/b/vector_compensated_ned", "z_nt", "flux_b_d_c"),
            ("/grad/4_5/compensated", "value", "grad_4_5_c"),
            ("/aux/cur_strb", "value", "cur_strb"),
            ("/gps/fix", "altitude", "msl"),
            ("/weather/station", "wind", "weather_station_wind"),
        ];
        for (topic, field, column) in cases {
            assert_eq!(channel_name(topic, field, "msl"), column, "{topic} {field}");
        }
    }
}
