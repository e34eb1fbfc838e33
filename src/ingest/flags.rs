//! Why a row's outputs are missing or suspect: the `flags` column of the
//! compensated output (CONTRACT §3).
//!
//! Each row carries a set of [`Flag`]s, each a reason and the column or
//! sensor it concerns, written `reason:subject` and joined by `;` in input
//! order of discovery (reading, screening, compensation). A row that is
//! fine has none, and its cell is empty.

use std::fmt;

/// Why a row is flagged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlagKind {
    /// A multi-rate channel had no sample near the row's time (MCAP).
    Gap,
    /// A channel recorded two samples at the row's time (MCAP).
    DuplicateTime,
    /// A value beyond what the instrument can read, masked.
    OutOfRange,
    /// A fluxgate reading of almost no field, masked.
    ZeroVector,
    /// An isolated spike, masked.
    Spike,
    /// An axis dropping to zero between normal neighbours, masked.
    Dropout,
    /// A run of identical readings no working sensor makes (stuck or
    /// dead), masked.
    Stuck,
    /// A step one sensor alone makes and holds (an INS heading
    /// realigned), masked from the step until it steps back.
    Step,
    /// The scalar sample is missing.
    MissingScalar,
    /// A component of the vector sample is missing.
    MissingVector,
    /// A source column of the model, or one a reduced column removes (the
    /// base station; the position for IGRF), is missing.
    MissingSource,
    /// Beside a missing vector sample: the terms' time derivative is
    /// one-sided there, so the value stands, less accurately.
    BesideGap,
    /// The sensor lag reads the scalar beyond the end of its record.
    LagOutsideRecord,
    /// The model gives no value for another reason.
    ModelUndefined,
    /// The INS attitude is missing: the vector in north-east-down is not
    /// given.
    MissingAttitude,
    /// The compensated value lies where no instrument reads (a total field
    /// outside 1,000–100,000 nT, a vector component beyond ±100,000 nT):
    /// the model was applied far outside what it was fitted on. The
    /// value is written, flagged, and warned of.
    OutputOutOfRange,
}

impl FlagKind {
    /// The reason as written in the cell, before `:<subject>`.
    pub fn name(self) -> &'static str {
        match self {
            FlagKind::Gap => "gap",
            FlagKind::DuplicateTime => "duplicate_time",
            FlagKind::OutOfRange => "out_of_range",
            FlagKind::ZeroVector => "zero_vector",
            FlagKind::Spike => "spike",
            FlagKind::Dropout => "dropout",
            FlagKind::Stuck => "stuck",
            FlagKind::Step => "step",
            FlagKind::MissingScalar => "missing_scalar",
            FlagKind::MissingVector => "missing_vector",
            FlagKind::MissingSource => "missing_source",
            FlagKind::BesideGap => "beside_gap",
            FlagKind::LagOutsideRecord => "lag_outside_record",
            FlagKind::ModelUndefined => "model_undefined",
            FlagKind::MissingAttitude => "missing_attitude",
            FlagKind::OutputOutOfRange => "output_out_of_range",
        }
    }
}

/// One reason a row is flagged, and the column or sensor it concerns.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Flag {
    /// The reason.
    pub kind: FlagKind,
    /// The column, channel or sensor prefix.
    pub subject: String,
}

/// The flags of one row, each reason and subject once, in the order they
/// were raised.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RowFlags(Vec<Flag>);

impl RowFlags {
    /// Raises `kind` for `subject`, unless the row has it already.
    pub fn raise(&mut self, kind: FlagKind, subject: &str) {
        if !self.has(kind, subject) {
            self.0.push(Flag {
                kind,
                subject: subject.to_string(),
            });
        }
    }

    /// Whether the row has `kind` for `subject`.
    pub fn has(&self, kind: FlagKind, subject: &str) -> bool {
        self.0.iter().any(|f| f.kind == kind && f.subject == subject)
    }

    /// Whether the row is fine.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The flags, in the order they were raised.
    pub fn iter(&self) -> impl Iterator<Item = &Flag> {
        self.0.iter()
    }
}

impl fmt::Display for RowFlags {
    /// `reason:subject` joined by `;`; empty when the row is fine.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (k, flag) in self.0.iter().enumerate() {
            if k > 0 {
                f.write_str(";")?;
            }
            write!(f, "{}:{}", flag.kind.name(), flag.subject)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_reads_as_its_reasons_in_the_order_raised_each_once() {
        let mut flags = RowFlags::default();
        assert_eq!(flags.to_string(), "");
        flags.raise(FlagKind::Gap, "cur_a");
        flags.raise(FlagKind::MissingVector, "flux_b");
        flags.raise(FlagKind::Gap, "cur_a");
        flags.raise(FlagKind::Gap, "cur_b");
        assert_eq!(flags.to_string(), "gap:cur_a;missing_vector:flux_b;gap:cur_b");
        assert!(flags.has(FlagKind::MissingVector, "flux_b") && !flags.has(FlagKind::Spike, "flux_b"));
    }
}
