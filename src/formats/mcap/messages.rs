//! magcomp's protobuf messages for MCAP (CONTRACT §4) and a schema-driven
//! decoder for the numeric fields of any protobuf message.
//!
//! The messages are declared with `prost` and their descriptors are built in
//! code as a binary `FileDescriptorSet`, so no `protoc` is needed. Each MCAP
//! schema carries the set for its message, including
//! `google/protobuf/timestamp.proto`, so independent readers can decode
//! every message from the file alone.
//!
//! Reading does not assume our field numbers: [`MessageLayout`] resolves the
//! field names from the descriptor embedded in the file, and
//! [`MessageLayout::decode`] walks the wire format with `prost`'s encoding
//! primitives, picking out the numeric fields.

use std::collections::HashMap;

use prost::bytes::Buf;
use prost::encoding::{decode_key, decode_varint, skip_field, DecodeContext, WireType};
use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{DescriptorProto, FieldDescriptorProto, FileDescriptorProto, FileDescriptorSet, Timestamp};

/// `magcomp.ScalarMag`: a total-field reading.
#[derive(Clone, PartialEq, prost::Message)]
pub struct ScalarMag {
    /// Sample time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Sensor frame.
    #[prost(string, tag = "2")]
    pub frame_id: String,
    /// Total field, nT.
    #[prost(double, tag = "3")]
    pub total_nt: f64,
}

/// `magcomp.VectorMag`: a three-axis fluxgate reading.
#[derive(Clone, PartialEq, prost::Message)]
pub struct VectorMag {
    /// Sample time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Sensor frame.
    #[prost(string, tag = "2")]
    pub frame_id: String,
    /// Body-x component, nT.
    #[prost(double, tag = "3")]
    pub x_nt: f64,
    /// Body-y component, nT.
    #[prost(double, tag = "4")]
    pub y_nt: f64,
    /// Body-z component, nT.
    #[prost(double, tag = "5")]
    pub z_nt: f64,
}

/// `magcomp.Attitude`: INS attitude, degrees (CONTRACT §1 conventions).
#[derive(Clone, PartialEq, prost::Message)]
pub struct Attitude {
    /// Sample time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// Roll, right wing down positive.
    #[prost(double, tag = "2")]
    pub roll_deg: f64,
    /// Pitch, nose up positive.
    #[prost(double, tag = "3")]
    pub pitch_deg: f64,
    /// Yaw, clockwise from north.
    #[prost(double, tag = "4")]
    pub yaw_deg: f64,
}

/// `magcomp.Sample`: one value of an auxiliary channel.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Sample {
    /// Sample time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// The value.
    #[prost(double, tag = "2")]
    pub value: f64,
    /// Its unit, e.g. `A`, `V`, `nT`.
    #[prost(string, tag = "3")]
    pub unit: String,
}

/// `magcomp.RowFlags`: why a compensated row is missing or suspect (the
/// `flags` column of CSV output); empty when the row is fine.
#[derive(Clone, PartialEq, prost::Message)]
pub struct RowFlags {
    /// Sample time.
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    /// The flags, as the CSV's `flags` column writes them.
    #[prost(string, tag = "2")]
    pub flags: String,
}

/// `foxglove.LocationFix`, the fields magcomp writes.
#[derive(Clone, PartialEq, prost::Message)]
pub struct LocationFix {
    /// Latitude, degrees.
    #[prost(double, tag = "1")]
    pub latitude: f64,
    /// Longitude, degrees.
    #[prost(double, tag = "2")]
    pub longitude: f64,
    /// Altitude, metres.
    #[prost(double, tag = "3")]
    pub altitude: f64,
    /// Sample time.
    #[prost(message, optional, tag = "6")]
    pub timestamp: Option<Timestamp>,
    /// Frame.
    #[prost(string, tag = "7")]
    pub frame_id: String,
}

/// A protobuf `Timestamp` from nanoseconds since the epoch.
pub fn timestamp(nanoseconds: u64) -> Timestamp {
    Timestamp {
        seconds: (nanoseconds / 1_000_000_000) as i64,
        nanos: (nanoseconds % 1_000_000_000) as i32,
    }
}

fn field(name: &str, number: i32, kind: Type, type_name: Option<&str>) -> FieldDescriptorProto {
    FieldDescriptorProto {
        name: Some(name.into()),
        number: Some(number),
        label: Some(Label::Optional as i32),
        r#type: Some(kind as i32),
        type_name: type_name.map(String::from),
        json_name: Some(name.into()),
        ..Default::default()
    }
}

fn message(name: &str, fields: Vec<FieldDescriptorProto>) -> DescriptorProto {
    DescriptorProto {
        name: Some(name.into()),
        field: fields,
        ..Default::default()
    }
}

fn timestamp_file() -> FileDescriptorProto {
    FileDescriptorProto {
        name: Some("google/protobuf/timestamp.proto".into()),
        package: Some("google.protobuf".into()),
        message_type: vec![message(
            "Timestamp",
            vec![
                field("seconds", 1, Type::Int64, None),
                field("nanos", 2, Type::Int32, None),
            ],
        )],
        syntax: Some("proto3".into()),
        ..Default::default()
    }
}

const TIMESTAMP: &str = ".google.protobuf.Timestamp";

fn magcomp_file() -> FileDescriptorProto {
    let stamp = || field("timestamp", 1, Type::Message, Some(TIMESTAMP));
    let double = |name: &str, number| field(name, number, Type::Double, None);
    let string = |name: &str, number| field(name, number, Type::String, None);
    FileDescriptorProto {
        name: Some("magcomp/messages.proto".into()),
        package: Some("magcomp".into()),
        dependency: vec!["google/protobuf/timestamp.proto".into()],
        message_type: vec![
            message("ScalarMag", vec![stamp(), string("frame_id", 2), double("total_nt", 3)]),
            message(
                "VectorMag",
                vec![
                    stamp(),
                    string("frame_id", 2),
                    double("x_nt", 3),
                    double("y_nt", 4),
                    double("z_nt", 5),
                ],
            ),
            message(
                "Attitude",
                vec![
                    stamp(),
                    double("roll_deg", 2),
                    double("pitch_deg", 3),
                    double("yaw_deg", 4),
                ],
            ),
            message("Sample", vec![stamp(), double("value", 2), string("unit", 3)]),
            message("RowFlags", vec![stamp(), string("flags", 2)]),
        ],
        syntax: Some("proto3".into()),
        ..Default::default()
    }
}

fn foxglove_file() -> FileDescriptorProto {
    FileDescriptorProto {
        name: Some("foxglove/LocationFix.proto".into()),
        package: Some("foxglove".into()),
        dependency: vec!["google/protobuf/timestamp.proto".into()],
        message_type: vec![message(
            "LocationFix",
            vec![
                field("timestamp", 6, Type::Message, Some(TIMESTAMP)),
                field("frame_id", 7, Type::String, None),
                field("latitude", 1, Type::Double, None),
                field("longitude", 2, Type::Double, None),
                field("altitude", 3, Type::Double, None),
            ],
        )],
        syntax: Some("proto3".into()),
        ..Default::default()
    }
}

/// The binary `FileDescriptorSet` describing `full_name` (e.g.
/// `magcomp.ScalarMag`, `foxglove.LocationFix`), with its dependencies.
pub fn descriptor_set(full_name: &str) -> Vec<u8> {
    let file = match full_name.split('.').next() {
        Some("foxglove") => foxglove_file(),
        _ => magcomp_file(),
    };
    FileDescriptorSet {
        file: vec![timestamp_file(), file],
    }
    .encode_to_vec()
}

/// How a field's value is read from the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldKind {
    /// `double`.
    Double,
    /// `float`.
    Float,
    /// Signed integer (`int32`, `int64`, `sfixed*`, zig-zag `sint*`).
    Signed,
    /// Unsigned integer, `bool` or enum.
    Unsigned,
    /// `sint32` / `sint64` (zig-zag).
    ZigZag,
}

impl FieldKind {
    /// True for integer kinds: counters and line numbers are held, not
    /// interpolated.
    pub fn is_integer(self) -> bool {
        !matches!(self, FieldKind::Double | FieldKind::Float)
    }
}

/// The numeric top-level fields of one message type, from its descriptor.
#[derive(Debug, Clone)]
pub struct MessageLayout {
    /// Field names, in slot order.
    pub names: Vec<String>,
    /// Field kinds, in slot order.
    pub kinds: Vec<FieldKind>,
    /// Field number → slot.
    slots: HashMap<u32, usize>,
}

impl MessageLayout {
    /// Builds the layout of `full_name` from a binary `FileDescriptorSet`.
    pub fn from_descriptor_set(data: &[u8], full_name: &str) -> Result<Self, String> {
        let set = FileDescriptorSet::decode(data).map_err(|e| format!("the schema is not a FileDescriptorSet: {e}"))?;
        let wanted = full_name.trim_start_matches('.');
        let descriptor = set
            .file
            .iter()
            .flat_map(|file| {
                let package = file.package.clone().unwrap_or_default();
                file.message_type.iter().map(move |m| (package.clone(), m))
            })
            .find(|(package, m)| {
                let name = m.name.as_deref().unwrap_or_default();
                match package.is_empty() {
                    true => name == wanted,
                    false => format!("{package}.{name}") == wanted,
                }
            })
            .map(|(_, m)| m)
            .ok_or_else(|| format!("the schema does not describe message type '{wanted}'"))?;
        let mut layout = MessageLayout {
            names: Vec::new(),
            kinds: Vec::new(),
            slots: HashMap::new(),
        };
        for f in &descriptor.field {
            let repeated = f.label == Some(Label::Repeated as i32);
            let kind = match Type::try_from(f.r#type.unwrap_or_default()) {
                Ok(Type::Double) => FieldKind::Double,
                Ok(Type::Float) => FieldKind::Float,
                Ok(Type::Int32 | Type::Int64 | Type::Sfixed32 | Type::Sfixed64) => FieldKind::Signed,
                Ok(Type::Uint32 | Type::Uint64 | Type::Fixed32 | Type::Fixed64 | Type::Bool | Type::Enum) => {
                    FieldKind::Unsigned
                }
                Ok(Type::Sint32 | Type::Sint64) => FieldKind::ZigZag,
                _ => continue,
            };
            if repeated {
                continue;
            }
            let (Some(name), Some(number)) = (&f.name, f.number) else {
                continue;
            };
            layout.slots.insert(number as u32, layout.names.len());
            layout.names.push(name.clone());
            layout.kinds.push(kind);
        }
        Ok(layout)
    }

    /// Decodes one message, writing each numeric field into its slot of
    /// `values` (which must have one entry per slot; absent fields are 0 as
    /// protobuf 3 defines).
    pub fn decode(&self, data: &[u8], values: &mut [f64]) -> Result<(), String> {
        self.decode_wire(data, values).map_err(|e| match e {
            WireError::Prost(e) => e.to_string(),
            WireError::Mismatch => "a field's wire type does not match its schema".into(),
        })
    }

    fn decode_wire(&self, mut data: &[u8], values: &mut [f64]) -> Result<(), WireError> {
        values.iter_mut().for_each(|v| *v = 0.0);
        while data.has_remaining() {
            let (number, wire) = decode_key(&mut data)?;
            let slot = self.slots.get(&number).copied();
            let Some(slot) = slot else {
                skip_field(wire, number, &mut data, DecodeContext::default())?;
                continue;
            };
            let kind = self.kinds[slot];
            values[slot] = match (kind, wire) {
                (FieldKind::Double, WireType::SixtyFourBit) if data.remaining() >= 8 => data.get_f64_le(),
                (FieldKind::Float, WireType::ThirtyTwoBit) if data.remaining() >= 4 => f64::from(data.get_f32_le()),
                (FieldKind::Signed, WireType::Varint) => decode_varint(&mut data)? as i64 as f64,
                (FieldKind::Unsigned, WireType::Varint) => decode_varint(&mut data)? as f64,
                (FieldKind::ZigZag, WireType::Varint) => {
                    let raw = decode_varint(&mut data)?;
                    ((raw >> 1) as i64 ^ -((raw & 1) as i64)) as f64
                }
                (_, WireType::SixtyFourBit) if data.remaining() >= 8 => {
                    let raw = data.get_u64_le();
                    match kind {
                        FieldKind::Signed => raw as i64 as f64,
                        _ => raw as f64,
                    }
                }
                (_, WireType::ThirtyTwoBit) if data.remaining() >= 4 => {
                    let raw = data.get_u32_le();
                    match kind {
                        FieldKind::Signed => f64::from(raw as i32),
                        _ => f64::from(raw),
                    }
                }
                _ => return Err(WireError::Mismatch),
            };
        }
        Ok(())
    }
}

/// Why a message could not be decoded.
enum WireError {
    Prost(prost::DecodeError),
    Mismatch,
}

impl From<prost::DecodeError> for WireError {
    fn from(error: prost::DecodeError) -> Self {
        WireError::Prost(error)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_from_our_descriptor_decodes_our_messages() {
        let layout =
            MessageLayout::from_descriptor_set(&descriptor_set("magcomp.VectorMag"), "magcomp.VectorMag").unwrap();
        assert_eq!(layout.names, ["x_nt", "y_nt", "z_nt"]);
        let message = VectorMag {
            timestamp: Some(timestamp(1_700_000_000_123_456_789)),
            frame_id: "flux_a".into(),
            x_nt: 16_500.25,
            y_nt: -0.0,
            z_nt: 48_000.5,
        };
        let mut values = vec![f64::NAN; 3];
        layout.decode(&message.encode_to_vec(), &mut values).unwrap();
        assert_eq!(values, [16_500.25, 0.0, 48_000.5]);
        let fix = MessageLayout::from_descriptor_set(&descriptor_set("foxglove.LocationFix"), "foxglove.LocationFix")
            .unwrap();
        assert_eq!(fix.names, ["latitude", "longitude", "altitude"]);
    }

    #[test]
    fn truncated_messages_are_errors() {
        let layout = MessageLayout::from_descriptor_set(&descriptor_set("magcomp.Sample"), "magcomp.Sample").unwrap();
        let bytes = Sample {
            timestamp: None,
            value: 2.5,
            unit: "A".into(),
        }
        .encode_to_vec();
        let mut values = vec![0.0; 1];
        for cut in 1..bytes.len() {
            let _ = layout.decode(&bytes[..cut], &mut values);
        }
        assert!(layout.decode(&bytes[..5], &mut values).is_err());
    }
}
