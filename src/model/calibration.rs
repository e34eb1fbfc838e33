//! The calibration a model is fitted on: one flight's log, its vector
//! sensor, the scalar channels to fit and the calibration windows.

use crate::flight_log::{FlightLog, VectorSensor};
use crate::windows::CalibrationWindow;

/// What every fit of a flight shares: the log (with the fluxgate as the
/// fit reads it), the vector sensor whose direction cosines make the
/// terms, the scalar channels to fit and the windows fitted on. Built once
/// per flight ([`crate::pipeline::PreparedFlight::calibration`]) and handed
/// to each stage instead of its four parts.
#[derive(Debug, Clone, Copy)]
pub struct Calibration<'a> {
    /// The flight log the fits read.
    pub log: &'a FlightLog,
    /// The vector magnetometer of the direction cosines.
    pub sensor: &'a VectorSensor,
    /// The scalar channels to fit.
    pub channels: &'a [String],
    /// The calibration windows.
    pub windows: &'a [CalibrationWindow],
}

impl<'a> Calibration<'a> {
    /// The same calibration read from `log` instead (the flight with its
    /// fluxgate calibrated, say).
    pub fn on(self, log: &'a FlightLog) -> Self {
        Calibration { log, ..self }
    }
}
