//! What a flight is doing while it is processed, for a progress display.
//!
//! The pipeline tells a [`Meter`] as each stage of a flight begins, and as
//! the steps of a long stage (the channels it diagnoses, fits or assesses)
//! are done. The command line draws it as a bar per flight on a terminal;
//! a library caller that wants nothing passes [`Silent`]. A meter never
//! changes what a flight computes.

/// A stage of a flight's processing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Reading the flight's file (and, in a campaign, hashing it to tell
    /// whether its outputs are current).
    Reading,
    /// Screening the samples, finding the calibration box and its
    /// manoeuvres, calibrating the fluxgate.
    Preparing,
    /// Searching for the physics the model leaves out, channel by channel.
    Diagnosing,
    /// The evidence rule: whether each channel's findings would help the
    /// survey.
    Checking,
    /// Fitting each channel's model (a step each), then the analysis of
    /// each fit's excitation.
    Fitting,
    /// Compensating every row and assessing each channel (a step each:
    /// figures, held-out transfer, the sigma column) with the vector
    /// stage beside it, then the gradients and the reduced columns.
    Assessing,
    /// Writing the outputs.
    Writing,
}

impl Stage {
    /// The stage as a progress line says it.
    pub fn words(self) -> &'static str {
        match self {
            Stage::Reading => "reading",
            Stage::Preparing => "finding the box",
            Stage::Diagnosing => "diagnosing",
            Stage::Checking => "checking findings",
            Stage::Fitting => "fitting",
            Stage::Assessing => "assessing",
            Stage::Writing => "writing",
        }
    }
}

/// Receives a flight's progress. Called from any of the flight's threads.
pub trait Meter: Sync {
    /// `stage` begins, with `steps` steps to do (0: one step whose
    /// progress is not counted).
    fn begin(&self, stage: Stage, steps: u64);
    /// One more step of the stage begun last is done.
    fn step(&self);
}

/// A meter that shows nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct Silent;

impl Meter for Silent {
    fn begin(&self, _: Stage, _: u64) {}
    fn step(&self) {}
}
