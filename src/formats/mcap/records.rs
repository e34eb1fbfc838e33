//! Bounded reading of MCAP records (<https://mcap.dev/spec>).
//!
//! Every length field is checked against the bytes that are actually there
//! before anything is allocated or sliced, and a chunk decompresses into at
//! most its declared size, which must itself be plausible. A truncated,
//! bit-flipped or hostile file therefore gives an error (or, when only the
//! end is lost, the records before the damage), never a panic or an
//! out-of-memory abort. Schema and channel records are decoded with the
//! `mcap` crate's record parser; message headers, chunks and the summary's
//! chunk index are read here.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::Read;

/// Record opcodes used here.
mod op {
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const DATA_END: u8 = 0x0F;
}

/// Largest decompressed chunk accepted, bytes.
const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// A schema record.
#[derive(Debug, Clone)]
pub struct SchemaRecord {
    /// Schema name, e.g. `magcomp.ScalarMag`.
    pub name: String,
    /// `protobuf`, `jsonschema`, `ros2msg`, ...
    pub encoding: String,
    /// The schema itself.
    pub data: Vec<u8>,
}

/// A channel record.
#[derive(Debug, Clone)]
pub struct ChannelRecord {
    /// Schema id (0: none).
    pub schema_id: u16,
    /// Topic.
    pub topic: String,
    /// `protobuf`, `json`, `cdr`, ...
    pub message_encoding: String,
    /// Channel metadata.
    pub metadata: BTreeMap<String, String>,
}

/// One message, borrowing its payload.
#[derive(Debug, Clone, Copy)]
pub struct MessageRef<'a> {
    /// Channel id.
    pub channel_id: u16,
    /// Log time, ns.
    pub log_time: u64,
    /// Encoded payload.
    pub data: &'a [u8],
}

/// Schemas and channels met so far, by id (first definition wins).
#[derive(Debug, Default, Clone)]
pub struct Definitions {
    /// Schemas by id.
    pub schemas: BTreeMap<u16, SchemaRecord>,
    /// Channels by id.
    pub channels: BTreeMap<u16, ChannelRecord>,
}

impl Definitions {
    /// Records a schema or channel record; other records are ignored.
    fn learn(&mut self, opcode: u8, body: &[u8]) -> Result<(), String> {
        if opcode != op::SCHEMA && opcode != op::CHANNEL {
            return Ok(());
        }
        match mcap::parse_record(opcode, body).map_err(|e| format!("bad schema or channel record: {e}"))? {
            mcap::records::Record::Schema { header, data } => {
                self.schemas.entry(header.id).or_insert(SchemaRecord {
                    name: header.name,
                    encoding: header.encoding,
                    data: data.into_owned(),
                });
            }
            mcap::records::Record::Channel(channel) => {
                self.channels.entry(channel.id).or_insert(ChannelRecord {
                    schema_id: channel.schema_id,
                    topic: channel.topic,
                    message_encoding: channel.message_encoding,
                    metadata: channel.metadata,
                });
            }
            _ => {}
        }
        Ok(())
    }

    /// Adds what `other` defines and `self` does not.
    pub fn merge(&mut self, other: Definitions) {
        for (id, schema) in other.schemas {
            self.schemas.entry(id).or_insert(schema);
        }
        for (id, channel) in other.channels {
            self.channels.entry(id).or_insert(channel);
        }
    }
}

fn u64_at(bytes: &[u8], at: usize) -> Option<u64> {
    let slice = bytes.get(at..at.checked_add(8)?)?;
    Some(u64::from_le_bytes(slice.try_into().ok()?))
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let slice = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes(slice.try_into().ok()?))
}

/// Calls `each(opcode, body, offset)` for the records laid end to end in
/// `bytes` from `start`, stopping after a footer or data-end record.
/// Returns the offset where reading stopped and whether the records ran
/// past the end of `bytes` (truncation).
fn walk<'a>(
    bytes: &'a [u8],
    start: usize,
    mut each: impl FnMut(u8, &'a [u8], usize) -> Result<(), String>,
) -> Result<(usize, bool), String> {
    let mut at = start;
    while at < bytes.len() {
        let (Some(&opcode), Some(length)) = (bytes.get(at), u64_at(bytes, at + 1)) else {
            return Ok((at, true));
        };
        let body = at + 9;
        let end = usize::try_from(length).ok().and_then(|l| body.checked_add(l));
        let Some(end) = end.filter(|&e| e <= bytes.len()) else {
            return Ok((at, true));
        };
        each(opcode, &bytes[body..end], at)?;
        at = end;
        if opcode == op::FOOTER || opcode == op::DATA_END {
            break;
        }
    }
    Ok((at, false))
}

/// Parses a message record body.
pub fn message(body: &[u8]) -> Option<MessageRef<'_>> {
    let channel_id = u16::from_le_bytes(body.get(0..2)?.try_into().ok()?);
    let log_time = u64_at(body, 6)?;
    Some(MessageRef {
        channel_id,
        log_time,
        data: body.get(22..)?,
    })
}

/// Decompresses a chunk record body (bounded by its declared size).
pub fn chunk_records(body: &[u8]) -> Result<Cow<'_, [u8]>, String> {
    let bad = |what: &str| format!("a chunk's {what} is damaged");
    let uncompressed = u64_at(body, 16).ok_or_else(|| bad("header"))?;
    let name_length = u32_at(body, 28).ok_or_else(|| bad("header"))? as usize;
    let name_end = 32usize
        .checked_add(name_length)
        .ok_or_else(|| bad("compression name"))?;
    let compression = body.get(32..name_end).ok_or_else(|| bad("compression name"))?;
    let records_length = u64_at(body, name_end).ok_or_else(|| bad("records length"))?;
    let records_start = name_end + 8;
    let records = usize::try_from(records_length)
        .ok()
        .and_then(|l| records_start.checked_add(l))
        .and_then(|end| body.get(records_start..end))
        .ok_or_else(|| bad("records length"))?;
    let limit = MAX_CHUNK_BYTES.min((records.len() as u64).saturating_mul(200).saturating_add(1 << 20));
    if uncompressed > limit {
        return Err(format!(
            "a chunk declares {uncompressed} bytes uncompressed from {} compressed",
            records.len()
        ));
    }
    let size = uncompressed as usize;
    let out = match compression {
        b"" => Cow::Borrowed(records),
        b"zstd" => Cow::Owned(zstd::bulk::decompress(records, size).map_err(|e| format!("zstd: {e}"))?),
        b"lz4" => {
            let mut out = Vec::with_capacity(size);
            lz4::Decoder::new(records)
                .and_then(|d| d.take(size as u64 + 1).read_to_end(&mut out))
                .map_err(|e| format!("lz4: {e}"))?;
            Cow::Owned(out)
        }
        other => {
            return Err(format!(
                "unknown chunk compression '{}'",
                String::from_utf8_lossy(other)
            ))
        }
    };
    if out.len() != size {
        return Err(format!(
            "a chunk decompresses to {} bytes, not the {size} it declares",
            out.len()
        ));
    }
    // A CRC of 0 means the writer computed none.
    let crc = u32_at(body, 24).ok_or_else(|| bad("header"))?;
    let found = crc32fast::hash(&out);
    if crc != 0 && found != crc {
        return Err(format!(
            "a chunk's records do not match their CRC (recorded {crc:08x}, computed {found:08x}): bytes inside it were altered"
        ));
    }
    Ok(out)
}

/// Whether the data section (the file up to its data-end record) matches
/// the CRC that record gives; `None` when it gives none (0) or the file
/// has no data-end record.
pub fn data_section_crc_holds(bytes: &[u8]) -> Option<bool> {
    let mut data_end = None;
    walk(bytes, mcap::MAGIC.len(), |opcode, body, at| {
        if opcode == op::DATA_END {
            data_end = Some((at, u32_at(body, 0)));
        }
        Ok(())
    })
    .ok()?;
    let (at, crc) = data_end?;
    let crc = crc.filter(|&c| c != 0)?;
    Some(crc32fast::hash(&bytes[..at]) == crc)
}

/// Calls `each` for every message in a chunk's (decompressed) records, and
/// collects the schemas and channels it defines.
pub fn chunk_messages<'a>(
    records: &'a [u8],
    definitions: &mut Definitions,
    mut each: impl FnMut(MessageRef<'a>),
) -> Result<(), String> {
    let (_, truncated) = walk(records, 0, |opcode, body, _| {
        match opcode {
            op::MESSAGE => each(message(body).ok_or("a message record is damaged")?),
            _ => definitions.learn(opcode, body)?,
        }
        Ok(())
    })?;
    match truncated {
        true => Err("a chunk's records run past its end".into()),
        false => Ok(()),
    }
}

/// The data section: chunk bodies in file order, messages outside chunks,
/// the schemas and channels outside chunks, and remarks.
#[derive(Debug, Default)]
pub struct DataSection<'a> {
    /// Chunk record bodies, in file order.
    pub chunks: Vec<&'a [u8]>,
    /// Messages outside chunks, in file order.
    pub messages: Vec<MessageRef<'a>>,
    /// Schemas and channels outside chunks (and from the summary).
    pub definitions: Definitions,
    /// How the file was read and what was wrong with it.
    pub notes: Vec<crate::messages::ReadNote>,
    /// Where the file was cut short, when it was.
    pub cut_short: Option<CutShort>,
}

/// A file that ends before its data section does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CutShort {
    /// Where reading stopped, bytes.
    pub at_byte: usize,
    /// The file's length, bytes.
    pub of_bytes: usize,
    /// Whether it ends between two whole records (no data-end record nor
    /// footer follows), rather than inside one.
    pub at_record_boundary: bool,
}

/// Finds the chunks of an MCAP file: through the summary's chunk index when
/// the file has a valid one, else by walking the data section. A file cut
/// short is read up to the damage, with a note.
pub fn data_section(bytes: &[u8]) -> Result<DataSection<'_>, String> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err("the file does not start with the MCAP magic bytes".into());
    }
    let index = indexed(bytes);
    let mut section = DataSection::default();
    let mut messages = Vec::new();
    let mut chunks = Vec::new();
    let mut definitions = Definitions::default();
    let mut last = None;
    let (stopped, truncated) = walk(bytes, mcap::MAGIC.len(), |opcode, body, _| {
        last = Some(opcode);
        match opcode {
            op::CHUNK => chunks.push(body),
            op::MESSAGE => messages.push(message(body).ok_or("a message record is damaged")?),
            _ => definitions.learn(opcode, body)?,
        }
        Ok(())
    })?;
    // The summary's chunk index is used when it lists every chunk the
    // data section holds; an index that lost an entry would lose that
    // chunk's rows without a word.
    match index {
        Some(section) if !truncated && section.chunks.len() == chunks.len() => return Ok(section),
        Some(listed) => section.notes.push(crate::messages::ReadNote::ChunkIndexIncomplete {
            listed: listed.chunks.len(),
            chunks: chunks.len(),
        }),
        None => section.notes.push(crate::messages::ReadNote::NoChunkIndex),
    }
    section.chunks = chunks;
    section.messages = messages;
    section.definitions = definitions;
    let ended = matches!(last, Some(op::DATA_END | op::FOOTER));
    if truncated || !ended {
        if section.chunks.is_empty() && section.messages.is_empty() {
            return Err(format!("the file is cut short at byte {stopped}, before any message"));
        }
        section.cut_short = Some(CutShort {
            at_byte: stopped,
            of_bytes: bytes.len(),
            at_record_boundary: !truncated,
        });
    }
    Ok(section)
}

/// The chunks listed by a valid summary section, or `None`.
fn indexed(bytes: &[u8]) -> Option<DataSection<'_>> {
    let magic = mcap::MAGIC.len();
    let footer_at = bytes.len().checked_sub(magic + 9 + 20)?;
    if !bytes.ends_with(mcap::MAGIC) || bytes[footer_at] != op::FOOTER || u64_at(bytes, footer_at + 1)? != 20 {
        return None;
    }
    let summary_start = usize::try_from(u64_at(bytes, footer_at + 9)?).ok()?;
    if summary_start < magic || summary_start >= footer_at {
        return None;
    }
    let mut section = DataSection::default();
    let mut chunks = Vec::new();
    let mut definitions = Definitions::default();
    let walked = walk(&bytes[..footer_at], summary_start, |opcode, body, _| {
        if opcode == op::CHUNK_INDEX {
            let start = u64_at(body, 16).and_then(|s| usize::try_from(s).ok());
            let length = u64_at(body, 24).and_then(|l| usize::try_from(l).ok());
            let chunk = start
                .zip(length)
                .and_then(|(s, l)| Some((s, s.checked_add(l)?)))
                .filter(|&(s, e)| s >= magic && e <= summary_start && e - s > 9 && bytes[s] == op::CHUNK)
                .filter(|&(s, e)| u64_at(bytes, s + 1) == Some((e - s - 9) as u64))
                .ok_or("a chunk index entry does not point at a chunk")?;
            chunks.push(&bytes[chunk.0 + 9..chunk.1]);
            return Ok(());
        }
        definitions.learn(opcode, body)
    });
    match walked {
        Ok((_, false)) if !chunks.is_empty() => {
            section.chunks = chunks;
            section.definitions = definitions;
            Some(section)
        }
        _ => None,
    }
}
