//! Each scalar magnetometer against a fluxgate's magnitude: glitches held
//! longer than a sensor's own continuity can judge.
//!
//! A scalar and a fluxgate on one aircraft read the same Earth's field:
//! the crust, the diurnal variation and the aircraft's passage over them
//! move both alike. The scalar's departure from the fluxgate's magnitude,
//! d = B_scalar − |B_fluxgate|, changes only as the aircraft's own field at
//! the two sensors and the fluxgate's calibration do: with attitude,
//! smoothly, and by an electrical load switching, a few hundred nT at
//! most. A step of d larger than [`LEAST_STEP_NT`] (and than
//! [`NOISE_MULTIPLE`] times the flight's median step) between two samples
//! under [`LONGEST_STEP_S`] apart, made by one sensor while the other
//! holds still (the other moves by under a quarter of the step), is a
//! glitch's edge. A run entered by such a step and left, within
//! [`REACH_S`], by one of the other sign made by the same sensor, after
//! which d is back where it was before the run (within a quarter of the
//! step, and within [`AIRCRAFT_SWING_NT`]), is masked: in the scalar, or
//! in the fluxgate axis that stepped most. The screen's continuity check
//! finds such runs up to 10 s on a scalar and 2 s on a fluxgate axis,
//! since beyond that the field itself could have moved; against the other
//! sensor the field's own change cancels, and runs of any length up to
//! [`REACH_S`] are found. Without a fluxgate nothing is judged.

use crate::ingest::agreement::{median, Masks, NOISE_MULTIPLE};
use crate::ingest::flight_log::{ChannelRole, FlightLog, VectorSensor};
use crate::ingest::screen::{MaskReason, AIRCRAFT_SWING_NT};

/// Smallest step of a scalar's departure from the fluxgate's magnitude
/// that is a glitch's edge, nT: an electrical load switching moves a
/// cabin sensor by a few hundred nT at most. On a noisy pair the edge must
/// also pass [`NOISE_MULTIPLE`] times the median step.
pub const LEAST_STEP_NT: f64 = 1_000.0;

/// Longest run looked for, s.
pub const REACH_S: f64 = 600.0;

/// Two samples further apart than this are not judged as a step, s.
pub const LONGEST_STEP_S: f64 = 1.0;

/// Which sensor made a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mover {
    Scalar,
    /// The fluxgate, by the index of the axis that stepped most.
    Fluxgate(usize),
}

/// An edge: the usable rows either side, the step of d and who made it.
#[derive(Debug, Clone, Copy)]
struct Step {
    before: usize,
    after: usize,
    size_nt: f64,
    mover: Mover,
}

/// The rows of each channel (by index) to mask because a scalar's
/// departure from the first fluxgate's magnitude steps out and back;
/// `masked` are the rows screening already masked, which are not read.
pub fn departures(log: &FlightLog, masked: &Masks) -> Masks {
    let mut found = Masks::new();
    let Some(sensor) = log.vector_sensors().into_iter().next() else {
        return found;
    };
    let taken = |channel: usize| {
        let mut rows = vec![false; log.len()];
        for (row, _) in masked.get(&channel).into_iter().flatten() {
            rows[*row] = true;
        }
        rows
    };
    let axes_taken = sensor.axes.map(taken);
    let reading = |k: usize| sensor.axes.map(|axis| log.channels()[axis].values[k]);
    let magnitude: Vec<f64> = (0..log.len())
        .map(|k| match axes_taken.iter().any(|t| t[k]) {
            true => f64::NAN,
            false => reading(k).iter().map(|c| c * c).sum::<f64>().sqrt(),
        })
        .collect();
    let scalars = (log.channels().iter().enumerate()).filter(|(_, c)| c.role == ChannelRole::ScalarMagnetometer);
    for (index, channel) in scalars {
        let own = taken(index);
        let rows: Vec<usize> = (0..log.len())
            .filter(|&k| !own[k] && channel.values[k].is_finite() && magnitude[k].is_finite())
            .collect();
        let mut pair = Pair {
            log,
            sensor: &sensor,
            scalar: &channel.values,
            magnitude: &magnitude,
            least_nt: LEAST_STEP_NT,
        };
        // A noisy sensor's own steps are no glitch's edges.
        let mut sizes: Vec<f64> = (rows.windows(2))
            .filter(|w| log.time_s()[w[1]] - log.time_s()[w[0]] <= LONGEST_STEP_S)
            .map(|w| (pair.departure(w[1]) - pair.departure(w[0])).abs())
            .collect();
        pair.least_nt = LEAST_STEP_NT.max(NOISE_MULTIPLE * median(&mut sizes));
        let steps: Vec<Step> = (rows.windows(2)).filter_map(|w| pair.step(w[0], w[1])).collect();
        for (mover, (first, last)) in pair.runs(&steps) {
            let channel = match mover {
                Mover::Scalar => index,
                Mover::Fluxgate(axis) => sensor.axes[axis],
            };
            let run = rows.iter().filter(|&&r| r >= first && r <= last);
            let entry = found.entry(channel).or_default();
            entry.extend(run.map(|&r| (r, MaskReason::Departure)));
        }
    }
    found
}

/// One scalar and the fluxgate it is judged against.
struct Pair<'a> {
    log: &'a FlightLog,
    sensor: &'a VectorSensor,
    scalar: &'a [f64],
    magnitude: &'a [f64],
    /// The smallest step that is a glitch's edge, nT.
    least_nt: f64,
}

impl Pair<'_> {
    /// The scalar's departure from the fluxgate's magnitude at row `k`.
    fn departure(&self, k: usize) -> f64 {
        self.scalar[k] - self.magnitude[k]
    }

    /// The step from usable row `a` to the next usable row `b`, when it is
    /// a glitch's edge.
    fn step(&self, a: usize, b: usize) -> Option<Step> {
        let time = self.log.time_s();
        let size_nt = self.departure(b) - self.departure(a);
        if size_nt.abs() <= self.least_nt || time[b] - time[a] > LONGEST_STEP_S {
            return None;
        }
        let (scalar, fluxgate) = (self.scalar[b] - self.scalar[a], self.magnitude[b] - self.magnitude[a]);
        let still = |change: f64| change.abs() < size_nt.abs() / 4.0;
        let mover = match (still(fluxgate), still(scalar)) {
            (true, false) => Mover::Scalar,
            (false, true) => {
                let axis_step = |i: usize| {
                    let values = &self.log.channels()[self.sensor.axes[i]].values;
                    (values[b] - values[a]).abs()
                };
                Mover::Fluxgate((0..3).max_by(|&i, &j| axis_step(i).total_cmp(&axis_step(j)))?)
            }
            _ => return None,
        };
        Some(Step {
            before: a,
            after: b,
            size_nt,
            mover,
        })
    }

    /// The runs `steps` enclose, as (who is at fault, first and last row).
    fn runs(&self, steps: &[Step]) -> Vec<(Mover, (usize, usize))> {
        let time = self.log.time_s();
        let mut found = Vec::new();
        let mut i = 0;
        while i < steps.len() {
            let entry = steps[i];
            let tolerance = (entry.size_nt.abs() / 4.0).min(AIRCRAFT_SWING_NT);
            let back = (steps[i + 1..].iter().enumerate())
                .take_while(|(_, s)| time[s.before] - time[entry.after] <= REACH_S)
                .find(|(_, s)| {
                    s.mover == entry.mover
                        && s.size_nt.signum() != entry.size_nt.signum()
                        && (self.departure(s.after) - self.departure(entry.before)).abs() <= tolerance
                });
            match back {
                Some((offset, exit)) => {
                    found.push((entry.mover, (entry.after, exit.before)));
                    i += offset + 2;
                }
                None => i += 1,
            }
        }
        found
    }
}
