//! What reading a flight log lost or doubts, as [`Reading`] warnings: the
//! format readers' (CSV, Geosoft XYZ, MCAP, HDF5) and the checks every
//! read makes after them (the time column, the units, the columns
//! `[columns]` names, the day).

use std::fmt;
use std::path::PathBuf;

use crate::error::Number;

/// A warning of reading a flight log. Each is printed on stdout, kept in
/// the report and the quality JSON, and (for an MCAP file) in the
/// alignment's record.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    /// The time column steps forward by more than a day.
    TimeJump {
        /// The flight log.
        file: PathBuf,
        /// The time column.
        column: String,
        /// The time before the step, s.
        from_s: f64,
        /// The time after it, s.
        to_s: f64,
        /// The row after it, from 1.
        row: usize,
    },
    /// More than three such steps: their count (the first three are
    /// [`Reading::TimeJump`]s).
    TimeJumps {
        /// The flight log.
        file: PathBuf,
        /// The time column.
        column: String,
        /// Steps of more than a day in all.
        count: usize,
    },
    /// The day given (`--date` or `[[flight]] date`) is used over the one
    /// the file records.
    DayGivenOverRecorded {
        /// The flight log.
        file: PathBuf,
        /// The day given, `YYYY-MM-DD`.
        given: String,
        /// The day the file records.
        recorded: String,
    },
    /// A column `[columns]` names that the flight can be read without is
    /// not in the file.
    NamedColumnMissing {
        /// The flight log.
        file: PathBuf,
        /// The column named.
        column: String,
        /// The `[columns]` setting naming it.
        setting: String,
    },
    /// The time column's median step is too long for seconds.
    TimeNotInSeconds {
        /// The flight log.
        file: PathBuf,
        /// The time column.
        column: String,
        /// Its median step, in its own unit.
        step: f64,
    },
    /// Pitch and roll stay within ±π/2 while the yaw, read as degrees,
    /// turned: they look like radians.
    PitchRollInRadians {
        /// The flight log.
        file: PathBuf,
        /// The yaw's turn, degrees.
        yaw_turn_deg: f64,
    },
    /// The whole attitude stays within ±π/2 in pitch and roll, and its yaw
    /// spans more than 1, while the fluxgate's field turned: it looks like
    /// radians.
    AttitudeInRadians {
        /// The flight log.
        file: PathBuf,
        /// The yaw's span, in its own unit.
        yaw_span: f64,
        /// The fluxgate's horizontal field's turn in the aircraft's axes, °.
        field_turn_deg: f64,
    },
    /// The row of units gives a column a unit other than the one magcomp
    /// reads it in.
    UnitNotRead {
        /// The flight log.
        file: PathBuf,
        /// The unit, as the row gives it.
        unit: String,
        /// The column.
        column: String,
        /// The unit magcomp reads it in.
        read_in: String,
    },
    /// HDF5 datasets that are not one number per time sample, not read.
    DatasetsNotRead {
        /// The flight log.
        file: PathBuf,
        /// The time dataset.
        time: String,
        /// Each dataset left out, with its length: `'name' (N samples,
        /// not M)`.
        datasets: Vec<String>,
    },
    /// Samples repeating an earlier one exactly, read once.
    RepeatsReadOnce {
        /// The stream's topic and field.
        source: String,
        /// Samples read once.
        samples: usize,
        /// Rows that use them.
        rows: usize,
        /// The stream's column.
        column: String,
    },
    /// Times whose samples disagree, left missing.
    RepeatsDisagree {
        /// The stream's topic and field.
        source: String,
        /// Such times.
        times: usize,
        /// The first, s.
        first_s: f64,
        /// Rows that would use them.
        rows: usize,
        /// The stream's column.
        column: String,
    },
    /// The MCAP data section does not match its CRC.
    McapCrcFails,
    /// The first damaged MCAP chunk, left out.
    McapChunkDamaged {
        /// Why it cannot be read.
        why: String,
    },
    /// MCAP chunks damaged and left out, in all.
    McapChunksLeftOut {
        /// Chunks damaged.
        damaged: usize,
        /// Chunks in the file.
        of: usize,
    },
    /// One channel record of an MCAP topic whose other records magcomp
    /// reads is in an encoding it does not: only that record's messages
    /// are lost.
    McapChannelLost {
        /// The topic.
        topic: String,
        /// The channel record's id.
        channel: u16,
        /// Why it is not read.
        why: String,
    },
    /// An MCAP topic in an encoding magcomp does not read.
    McapTopicLost {
        /// The topic.
        topic: String,
        /// Why it is not read.
        why: String,
    },
    /// MCAP messages that could not be decoded, left out.
    McapUndecodable {
        /// The topic.
        topic: String,
        /// Messages left out.
        messages: usize,
        /// The first one's error.
        first: String,
    },
    /// Two MCAP sources give the same column; the second is left out.
    McapColumnTwice {
        /// The column.
        column: String,
        /// The source read.
        read: String,
        /// The source left out.
        left_out: String,
        /// Its messages.
        messages: usize,
    },
    /// The MCAP channels give a day, but some messages are older than its
    /// midnight: the times are read as they are.
    McapBeforeItsDay {
        /// The day, `YYYY-MM-DD`.
        day: String,
        /// The metadata key giving it.
        key: String,
    },
    /// The MCAP file ends without its data-end record and footer.
    McapCutShort {
        /// Where it ends, bytes.
        at_byte: u64,
        /// The file's size when it ends inside a record; `None` when it
        /// ends between two records.
        inside_record_of: Option<u64>,
        /// The rows read: count, first and last time, s.
        read: Option<(usize, f64, f64)>,
    },
}

impl fmt::Display for Reading {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reading::TimeJump { .. } | Reading::TimeJumps { .. } | Reading::DayGivenOverRecorded { .. } => {
                self.write_times(f)
            }
            Reading::NamedColumnMissing { .. }
            | Reading::DatasetsNotRead { .. }
            | Reading::RepeatsReadOnce { .. }
            | Reading::RepeatsDisagree { .. } => self.write_rows(f),
            Reading::TimeNotInSeconds { .. }
            | Reading::PitchRollInRadians { .. }
            | Reading::AttitudeInRadians { .. }
            | Reading::UnitNotRead { .. } => self.write_units(f),
            _ => self.write_mcap(f),
        }
    }
}

impl Reading {
    /// The sentence of a warning on the flight's times: the time column's
    /// jumps, the day given over the day recorded.
    fn write_times(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reading::TimeJump {
                file,
                column,
                from_s,
                to_s,
                row,
            } => write!(
                f,
                "{}: the time column '{column}' jumps by {} s ({:.1} days) from {} to {} s (row {row} of the flight): the rows after it are kept, as after any gap, but a flight this long is most likely a damaged time column or two flights joined; check the times, or split the file",
                file.display(),
                Number(to_s - from_s),
                (to_s - from_s) / 86_400.0,
                Number(*from_s),
                Number(*to_s),
            ),
            Reading::TimeJumps { file, column, count } => write!(
                f,
                "{}: the time column '{column}' jumps by more than a day {count} times in all",
                file.display()
            ),
            Reading::DayGivenOverRecorded { file, given, recorded } => write!(
                f,
                "{}: the day given ({given}, --date or [[flight]] date) is used over the day the file records ({recorded})",
                file.display()
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a warning on the rows and columns read: the columns
    /// named, the datasets left out, repeated samples.
    fn write_rows(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reading::NamedColumnMissing { file, column, setting } => write!(
                f,
                "{}: the column '{column}' named by [columns] {setting} is not in the file, so the flight is read without it",
                file.display()
            ),
            Reading::DatasetsNotRead { file, time, datasets } => write!(
                f,
                "{}: {} dataset(s) not read, as they are not one number per '{time}' sample: {}",
                file.display(),
                datasets.len(),
                datasets.join(", ")
            ),
            Reading::RepeatsReadOnce {
                source,
                samples,
                rows,
                column,
            } => write!(
                f,
                "{source}: {samples} samples repeat an earlier one exactly (same time, same value) and were read once; the {rows} rows that use them are flagged duplicate_time:{column}"
            ),
            Reading::RepeatsDisagree {
                source,
                times,
                first_s,
                rows,
                column,
            } => write!(
                f,
                "{source}: {times} times carry samples that disagree (the first at {} s); the {rows} rows that would use them are left missing and flagged duplicate_time:{column}",
                Number(*first_s)
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a warning on a column's unit.
    fn write_units(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reading::TimeNotInSeconds { file, column, step } => write!(
                f,
                "{}: the time column '{column}' steps {step} between samples at the median, and magcomp reads it in seconds: no survey records {step} s apart. If it is in milliseconds (or another unit), convert it to seconds",
                file.display()
            ),
            Reading::PitchRollInRadians { file, yaw_turn_deg } => write!(
                f,
                "{}: the INS pitch and roll never exceed π/2 in size although the yaw turned through {yaw_turn_deg:.0}°: they look like radians, and magcomp reads degrees. Convert them to degrees",
                file.display()
            ),
            Reading::AttitudeInRadians {
                file,
                yaw_span,
                field_turn_deg,
            } => write!(
                f,
                "{}: the INS attitude never exceeds π/2 in pitch and roll, and its yaw spans {yaw_span:.2}, while the fluxgate's field turned through {field_turn_deg:.0}° in the aircraft's axes: the attitude looks like radians, and magcomp reads degrees. Convert it to degrees",
                file.display()
            ),
            Reading::UnitNotRead {
                file,
                unit,
                column,
                read_in,
            } => write!(
                f,
                "{}: the row of units gives '{unit}' for the column '{column}', which magcomp reads in {read_in}: if it is not in {read_in}, convert it; magcomp's fits and compensation take it in {read_in}",
                file.display()
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of what reading an MCAP recording lost.
    fn write_mcap(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reading::McapCrcFails => f.write_str(
                "the data section does not match the CRC its data-end record gives: bytes of the recording were altered after it was written; chunks whose own CRC fails are left out (below), and any other change is read as it stands. Copy the recording again from the recorder or its backup",
            ),
            Reading::McapChunkDamaged { why } => write!(f, "a damaged chunk was left out: {why}"),
            Reading::McapChunksLeftOut { damaged, of } => write!(
                f,
                "{damaged} of {of} chunks were damaged and left out: their samples are missing from the output. Copy the recording again from the recorder or its backup, whose copy may be whole"
            ),
            Reading::McapChannelLost { topic, channel, why } => write!(
                f,
                "topic '{topic}': its channel record {channel} is not read ({why}); the topic's other channel records are, so the output holds the topic where they cover it, and the messages on record {channel} alone are lost (write them in an encoding magcomp reads)"
            ),
            Reading::McapTopicLost { topic, why } => write!(
                f,
                "topic '{topic}' is not in the output: {why}; whatever it records is lost to this run (write it in an encoding magcomp reads)"
            ),
            Reading::McapUndecodable { topic, messages, first } => write!(
                f,
                "topic '{topic}': {messages} messages could not be decoded and were left out (first: {first})"
            ),
            Reading::McapColumnTwice {
                column,
                read,
                left_out,
                messages,
            } => write!(
                f,
                "column '{column}' is given by {read} and by {left_out}; the first is read and the second's {messages} messages are left out (map one of them to another column with [[topic]])"
            ),
            Reading::McapBeforeItsDay { day, key } => write!(
                f,
                "the channels give the day {day} ({key}), but some messages are older than its midnight; the log times are read as they are (seconds since 1970-01-01), not as times of that day"
            ),
            Reading::McapCutShort {
                at_byte,
                inside_record_of,
                read,
            } => write_cut_short(f, *at_byte, *inside_record_of, *read),
            _ => write!(f, "{self:?}"),
        }
    }
}

/// The sentence of [`Reading::McapCutShort`]: where the recording ends,
/// between records or inside one, and the rows read before it.
fn write_cut_short(
    f: &mut fmt::Formatter<'_>,
    at_byte: u64,
    inside_record_of: Option<u64>,
    read: Option<(usize, f64, f64)>,
) -> fmt::Result {
    let span = match read {
        Some((rows, first, last)) => {
            format!("{rows} rows from {} to {} s", Number(first), Number(last))
        }
        None => "no row".into(),
    };
    match inside_record_of {
        None => write!(
            f,
            "the file is cut short: it ends at byte {at_byte} between two records, without the data-end record and footer every finished recording has (a logger that stopped, a copy that did not finish); read {span}, and whatever was recorded after is lost"
        ),
        Some(of) => write!(
            f,
            "the file is cut short at byte {at_byte} of {of}, inside a record; read {span}, and the rest is lost"
        ),
    }
}

/// A note of reading an MCAP file: how it was read, and what it holds
/// that magcomp has no use for. Kept in the alignment's record and
/// printed by `convert`; serialised as its sentence.
#[derive(Debug, Clone, PartialEq)]
pub enum ReadNote {
    /// The summary's chunk index misses chunks the data section holds.
    ChunkIndexIncomplete {
        /// Chunks the index lists.
        listed: usize,
        /// Chunks in the data section.
        chunks: usize,
    },
    /// The file has no chunk index magcomp could use.
    NoChunkIndex,
    /// A topic holding no numbers magcomp reads, skipped.
    TopicSkipped {
        /// The topic.
        topic: String,
        /// Why.
        why: String,
    },
    /// A topic recorded on several channel records, read together.
    TopicJoined {
        /// The stream (topic and field).
        source: String,
        /// Channel records it is on.
        parts: usize,
        /// Its messages in all.
        messages: usize,
    },
}

impl fmt::Display for ReadNote {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReadNote::ChunkIndexIncomplete { listed, chunks } => write!(
                f,
                "the summary's chunk index lists {listed} of the {chunks} chunks in the data section; the file was read by a linear scan, which reads them all"
            ),
            ReadNote::NoChunkIndex => f.write_str("the file has no usable chunk index; it was read by a linear scan"),
            ReadNote::TopicSkipped { topic, why } => write!(f, "topic '{topic}' skipped: {why}"),
            ReadNote::TopicJoined {
                source,
                parts,
                messages,
            } => write!(
                f,
                "{source} is recorded on {parts} channel records (a logger that restarted, or two writers); their {messages} messages are read together, in time order"
            ),
        }
    }
}

impl ReadNote {
    /// Whether the file was read by a linear scan rather than through its
    /// chunk index.
    pub fn scanned(&self) -> bool {
        matches!(self, ReadNote::ChunkIndexIncomplete { .. } | ReadNote::NoChunkIndex)
    }
}

impl serde::Serialize for ReadNote {
    /// As its sentence, as the record has always kept it.
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::Warning;

    /// Each reading warning prints the sentence the readers always wrote,
    /// and the quality JSON keeps it as that sentence.
    #[test]
    fn a_reading_warning_reads_as_the_readers_have_always_said_it() {
        let cases = [
            (
                Reading::McapCutShort {
                    at_byte: 38_808,
                    inside_record_of: Some(41_591),
                    read: Some((200, 46_000.0, 46_019.9)),
                },
                "the file is cut short at byte 38808 of 41591, inside a record; read 200 rows from 46000 to 46019.9 s, and the rest is lost",
            ),
            (
                Reading::McapChunksLeftOut { damaged: 1, of: 16 },
                "1 of 16 chunks were damaged and left out: their samples are missing from the output. Copy the recording again from the recorder or its backup, whose copy may be whole",
            ),
            (
                Reading::TimeJump {
                    file: "jumped.csv".into(),
                    column: "tt".into(),
                    from_s: 46_099.9,
                    to_s: 1_000_046_100.0,
                    row: 1001,
                },
                "jumped.csv: the time column 'tt' jumps by 1000000000.1 s (11574.1 days) from 46099.9 to 1000046100 s (row 1001 of the flight): the rows after it are kept, as after any gap, but a flight this long is most likely a damaged time column or two flights joined; check the times, or split the file",
            ),
            (
                Reading::UnitNotRead {
                    file: "units.csv".into(),
                    unit: "ms".into(),
                    column: "tt".into(),
                    read_in: "seconds".into(),
                },
                "units.csv: the row of units gives 'ms' for the column 'tt', which magcomp reads in seconds: if it is not in seconds, convert it; magcomp's fits and compensation take it in seconds",
            ),
        ];
        for (reading, sentence) in cases {
            let warning = Warning::from(reading);
            assert_eq!(warning.to_string(), sentence);
            assert_eq!(serde_json::to_value(&warning).unwrap(), serde_json::json!(sentence));
            assert_eq!(warning.channel(), None);
        }
    }
}
