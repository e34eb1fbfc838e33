//! A base station's record as the fit subtracts it: the external field's
//! variation, with the frequencies where the station's own noise is all
//! there is taken out.
//!
//! The aircraft's sensors read the external field (the daily variation,
//! pulsations) as the station does, and a model with the station's term
//! is fitted on the scalar less the station's record
//! ([`crate::model::SourceTerm::ExternalField`]). The external field's
//! spectrum falls steeply with frequency; the station's noise does not.
//! Above the frequency where the one sinks under the other, subtracting
//! the record adds the station's noise to the fit's target and takes
//! nothing out of it, and the band-pass the fit is made in keeps much of
//! that noise.
//!
//! On a clean simulated flight (plan 95 of `tests/default_safety.rs`: six
//! sensors, 20 Hz, a station with 0.020 nT of white noise whose external
//! field has nothing above 0.1 Hz) the station's record put 0.0054 nT of
//! noise into the 0.1–0.9 Hz band while taking out 0.024 nT of the
//! external field. That noise moved the poorly excited coefficients
//! (the lateral permanent term, standard error 0.25 nT) enough to take
//! the tail sensor's survey error from 0.0068 to 0.0202 nT against the
//! truth. Subtracting the exact external field instead helped the same
//! channel (0.0058 nT), and so did the station's record low-passed at
//! 0.16 Hz (0.0090 nT).
//!
//! [`quiet_station`] finds the frequency from the record alone: the
//! station's white noise from its fourth difference, then, octave by
//! octave down from the Nyquist frequency, the record's variance in the
//! octave against the noise's share of it. The first octave with at least
//! as much signal as noise (variance above twice the noise's) holds the
//! highest frequency where the station tells the external field; the
//! record is low-passed at its upper edge. A record that is signal up to
//! the Nyquist frequency (or that has no measurable noise, such as a
//! station sampled at 1 Hz and held between its samples) is used as
//! recorded.

use crate::ingest::flight_log::{Channel, FlightLog};
use crate::numerics::filter::{EdgePadding, FilterBand, ZeroPhaseFilter};
use crate::numerics::segments::valid_runs;

pub use crate::messages::StationFilter;

/// The lowest corner a station's record is low-passed at, Hz: the
/// external field's pulsations reach periods of 10 minutes and its daily
/// variation far longer, below any band a Tolles-Lawson fit is made in.
pub const LOWEST_CORNER_HZ: f64 = 0.01;

/// Poles of the low-pass and of the octave filters.
const POLES: usize = 4;

/// How much variance an octave must hold against the station's noise
/// alone to count as signal: twice, as much signal as noise.
const SIGNAL_OVER_NOISE: f64 = 2.0;

/// Below this white noise, nT, a record has no noise to measure but its
/// own rounding: a station sampled slower than the flight and held or
/// interpolated between its samples has none.
const NO_NOISE_NT: f64 = 1e-6;

/// The station's record where its noise takes over, taken out.
#[derive(Debug, Clone, PartialEq)]
pub struct QuietStation {
    /// The record filtered as [`Self::filter`] says, one value per row; a
    /// missing sample stays missing.
    pub values: Vec<f64>,
    /// How it was filtered.
    pub filter: StationFilter,
    /// The station's white noise, nT (one sigma).
    pub noise_nt: f64,
}

/// What [`FlightLog::derived`] names the quiet record of a station.
const DERIVED: &str = "quiet station";

/// The quiet record ([`QuietStation`]) of the station `column` of `log`,
/// computed once per log; `None` without the column.
pub fn shared_quiet_station(log: &FlightLog, column: &str) -> Option<std::sync::Arc<QuietStation>> {
    log.derived(column, DERIVED, |channel| quiet_station(log, channel))
}

/// The quiet record of the station `channel` of `log` (see the module
/// doc).
pub fn quiet_station(log: &FlightLog, channel: &Channel) -> QuietStation {
    let values = &channel.values;
    let interval = log.median_interval_s();
    let noise_nt = white_noise_nt(values);
    let as_recorded = |filter| QuietStation {
        values: values.clone(),
        filter,
        noise_nt,
    };
    if !(interval.is_finite() && interval > 0.0 && noise_nt.is_finite()) {
        return as_recorded(StationFilter::TooShort);
    }
    if noise_nt <= NO_NOISE_NT {
        return as_recorded(StationFilter::NoNoise);
    }
    let rate_hz = 1.0 / interval;
    let valid: Vec<bool> = values.iter().map(|v| v.is_finite()).collect();
    let runs = valid_runs(log.time_s(), &valid, 0..values.len(), interval);
    let nyquist = rate_hz / 2.0;
    let mut upper = nyquist;
    while upper > LOWEST_CORNER_HZ {
        let lower = upper / 2.0;
        let band = match upper >= nyquist {
            true => FilterBand::Highpass { low_hz: lower },
            false => FilterBand::Bandpass {
                low_hz: lower,
                high_hz: upper,
            },
        };
        let noise = noise_nt * noise_nt * (upper - lower) / nyquist;
        match robust_variance(&filtered(values, &runs, band, rate_hz)) {
            Some(variance) if variance > SIGNAL_OVER_NOISE * noise => break,
            // Nothing long enough to filter: nothing to judge by.
            None => return as_recorded(StationFilter::TooShort),
            Some(_) => upper = lower,
        }
    }
    if upper >= nyquist {
        return as_recorded(StationFilter::SignalToNyquist);
    }
    let corner_hz = upper.max(LOWEST_CORNER_HZ);
    let mut quiet = values.clone();
    let low = filtered(values, &runs, FilterBand::Lowpass { high_hz: corner_hz }, rate_hz);
    // A run too short for the filter stays as recorded, and is counted.
    let mut recorded_samples = 0;
    for (run, piece) in runs.iter().zip(&low) {
        match piece {
            Some(piece) => quiet[run.clone()].copy_from_slice(piece),
            None => recorded_samples += run.len(),
        }
    }
    QuietStation {
        values: quiet,
        filter: StationFilter::LowPassed {
            corner_hz,
            recorded_samples,
        },
        noise_nt,
    }
}

/// Each run of `values` filtered to `band`; `None` for a run too short
/// for the filter (or where it cannot be designed).
fn filtered(values: &[f64], runs: &[std::ops::Range<usize>], band: FilterBand, rate_hz: f64) -> Vec<Option<Vec<f64>>> {
    let Ok(filter) = ZeroPhaseFilter::butterworth(band, POLES, rate_hz, EdgePadding::Scipy) else {
        return vec![None; runs.len()];
    };
    (runs.iter())
        .map(|run| filter.apply(&values[run.clone()]).ok())
        .collect()
}

/// The variance of the filtered runs from their median absolute value
/// (a spike does not make noise look like signal); `None` where no run
/// could be filtered.
fn robust_variance(pieces: &[Option<Vec<f64>>]) -> Option<f64> {
    let mut magnitudes: Vec<f64> = (pieces.iter().flatten().flatten()).map(|v| v.abs()).collect();
    if magnitudes.is_empty() {
        return None;
    }
    let middle = magnitudes.len() / 2;
    let median = *magnitudes.select_nth_unstable_by(middle, f64::total_cmp).1;
    Some((MAD_TO_SIGMA * median).powi(2))
}

/// A normal variable's standard deviation over its median absolute value.
const MAD_TO_SIGMA: f64 = 1.482_602_218_505_602;

/// The station's white noise, nT: the fourth difference of consecutive
/// finite samples, its median absolute value as a standard deviation
/// (spikes and steps do not count), with the Seequent QCNOISE
/// normalisation ([`crate::numerics::statistics::WHITE_NOISE_PER_FOURTH_DIFFERENCE`]).
fn white_noise_nt(values: &[f64]) -> f64 {
    let mut differences: Vec<f64> = (values.windows(5))
        .map(|w| (w[0] - 4.0 * w[1] + 6.0 * w[2] - 4.0 * w[3] + w[4]) / 16.0)
        .filter(|d| d.is_finite())
        .map(f64::abs)
        .collect();
    if differences.is_empty() {
        return f64::NAN;
    }
    let middle = differences.len() / 2;
    let median = *differences.select_nth_unstable_by(middle, f64::total_cmp).1;
    MAD_TO_SIGMA * median * crate::numerics::statistics::WHITE_NOISE_PER_FOURTH_DIFFERENCE
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_log::ChannelRole;

    /// A station sampled at `rate_hz` for `seconds`: a pulsation of
    /// period `period_s` and amplitude 2 nT, a slow drift, and white noise
    /// of `noise_nt` from a fixed generator.
    fn station(rate_hz: f64, seconds: f64, period_s: f64, noise_nt: f64) -> FlightLog {
        let n = (rate_hz * seconds) as usize;
        let time: Vec<f64> = (0..n).map(|k| k as f64 / rate_hz).collect();
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut normal = || {
            // Sum of twelve uniforms less six: near enough a unit normal.
            (0..12)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        };
        let values: Vec<f64> = (time.iter())
            .map(|t| 50_000.0 + 0.01 * t + 2.0 * (std::f64::consts::TAU * t / period_s).sin() + noise_nt * normal())
            .collect();
        let channel = Channel {
            name: "diurnal".into(),
            role: ChannelRole::BaseStation,
            values,
        };
        FlightLog::new("station.csv", "time", time, vec![channel]).unwrap()
    }

    #[test]
    fn a_noisy_station_is_low_passed_above_its_pulsations_and_keeps_them() {
        let log = station(20.0, 3600.0, 12.0, 0.02);
        let quiet = quiet_station(&log, log.channel("diurnal").unwrap());
        // The noise as drawn, within 5 %.
        assert!((quiet.noise_nt - 0.02).abs() < 0.001, "noise {}", quiet.noise_nt);
        // The pulsation (1/12 Hz) lies in the octave 0.078–0.156 Hz: the
        // corner is its upper edge.
        let corner = quiet.filter.corner_hz().expect("a corner");
        assert!((corner - 10.0 / 64.0).abs() < 1e-12, "corner {corner}");
        // The record less its quiet version is the noise above the
        // corner, 0.02 × √(1 − 0.156/10) nT, and what the zero-phase
        // low-pass (gain 1/(1 + (f/corner)⁸)) takes of the 2 nT
        // pulsation: 0.7 % of it, 0.0093 nT RMS.
        let gain = 1.0 / (1.0 + (1.0 / 12.0 / corner).powi(2 * POLES as i32));
        let expected = (0.02f64.powi(2) * (1.0 - corner / 10.0) + (2.0 * (1.0 - gain)).powi(2) / 2.0).sqrt();
        let values = &log.channel("diurnal").unwrap().values;
        let middle = 2000..values.len() - 2000;
        let removed: Vec<f64> = middle.map(|k| values[k] - quiet.values[k]).collect();
        let rms = crate::numerics::statistics::root_mean_square(&removed);
        assert!(
            (rms - expected).abs() < 0.001,
            "removed {rms} nT, expected {expected} nT"
        );
    }

    /// A run between two gaps too short for the low-pass is subtracted as
    /// recorded, and the note counts its samples: a low-passed record
    /// never holds raw samples unsaid.
    #[test]
    fn a_short_run_between_gaps_is_counted_and_kept_as_recorded() {
        let log = station(20.0, 3600.0, 12.0, 0.02);
        let recorded = &log.channel("diurnal").unwrap().values;
        // Ten valid samples between two gaps, mid-flight.
        let short = 30_000..30_010;
        let gappy: Vec<f64> = (recorded.iter().enumerate())
            .map(|(k, v)| match k == short.start - 1 || k == short.end {
                true => f64::NAN,
                false => *v,
            })
            .collect();
        let log = log.with_values("diurnal", gappy).unwrap();
        let quiet = quiet_station(&log, log.channel("diurnal").unwrap());
        let StationFilter::LowPassed {
            corner_hz,
            recorded_samples,
        } = quiet.filter
        else {
            panic!("{:?}", quiet.filter);
        };
        assert!((corner_hz - 10.0 / 64.0).abs() < 1e-9, "corner {corner_hz}");
        assert_eq!(recorded_samples, 10);
        assert!(short
            .clone()
            .all(|k| quiet.values[k].to_bits() == recorded[k].to_bits()));
        // The long runs are low-passed: the noise is gone there.
        assert!((0..20_000).any(|k| quiet.values[k] != recorded[k]));
        let note = crate::messages::Note::QuietStation {
            column: "diurnal".into(),
            filter: quiet.filter,
            noise_nt: quiet.noise_nt,
            channels: vec!["mag_1_uc".into()],
        };
        let text = note.to_string();
        assert!(
            text.contains("low-passed at 0.156 Hz")
                && text.contains(
                    "10 of its samples, in runs between gaps too short to filter, are subtracted as recorded"
                ),
            "{text}"
        );
    }

    #[test]
    fn a_station_without_measurable_noise_is_used_as_recorded() {
        let log = station(10.0, 1200.0, 30.0, 0.0);
        let quiet = quiet_station(&log, log.channel("diurnal").unwrap());
        assert_eq!(quiet.filter, StationFilter::NoNoise, "noise {}", quiet.noise_nt);
        assert_eq!(quiet.values, log.channel("diurnal").unwrap().values);
    }

    #[test]
    fn a_station_with_signal_to_its_nyquist_frequency_or_too_short_to_filter_is_used_as_recorded() {
        // A 1.5 Hz signal at 5 Hz, 2 nT against 0.02 nT of noise: the top
        // octave (1.25–2.5 Hz) holds it. The fourth difference counts
        // 83 % of it as noise (its gain there, (2 sin 0.3π)⁴ ≈ 6.9 against
        // white noise's √70), and the octave's variance is still three
        // times that noise's share.
        let log = station(5.0, 1200.0, 1.0 / 1.5, 0.02);
        let quiet = quiet_station(&log, log.channel("diurnal").unwrap());
        assert_eq!(quiet.filter, StationFilter::SignalToNyquist, "noise {}", quiet.noise_nt);
        assert_eq!(quiet.values, log.channel("diurnal").unwrap().values);
        // Every other sample missing: no run longer than one sample.
        let log = station(10.0, 600.0, 30.0, 0.02);
        let gappy: Vec<f64> = (log.channel("diurnal").unwrap().values.iter().enumerate())
            .map(|(k, v)| if k % 2 == 0 { *v } else { f64::NAN })
            .collect();
        let log = log.with_values("diurnal", gappy.clone()).unwrap();
        let quiet = quiet_station(&log, log.channel("diurnal").unwrap());
        assert_eq!(quiet.filter, StationFilter::TooShort, "noise {}", quiet.noise_nt);
        assert!(quiet.values.iter().zip(&gappy).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn the_quiet_record_is_computed_once_per_log_and_its_clones() {
        let log = station(10.0, 600.0, 30.0, 0.02);
        let first = shared_quiet_station(&log, "diurnal").unwrap();
        let clone = log.clone();
        let again = shared_quiet_station(&clone, "diurnal").unwrap();
        assert!(std::sync::Arc::ptr_eq(&first, &again));
        // A log whose station was replaced derives it again.
        let replaced = log.with_values("diurnal", vec![50_000.0; log.len()]).unwrap();
        let other = shared_quiet_station(&replaced, "diurnal").unwrap();
        assert!(other.values.iter().all(|v| *v == 50_000.0));
        assert!(shared_quiet_station(&log, "missing").is_none());
    }
}
