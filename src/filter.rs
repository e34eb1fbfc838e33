//! Zero-phase Butterworth filtering of sample columns.
//!
//! The filter is designed by `sci-rs` (the scipy `butter` algorithm, output as
//! second-order sections) and applied forward and backward as scipy's
//! `sosfiltfilt` does: odd extension of `pad` samples at each end, steady-state
//! initial conditions scaled by the first sample of each pass (Gustafsson's
//! "pad" method, Oppenheim & Schafer 1999 §5.4). The pass itself is written
//! here because it runs [`LANES`] columns at once through an interleaved
//! buffer, which hides the recurrence latency of the biquads; a test checks
//! it against `sci_rs::signal::filter::sosfiltfilt_dyn` and scipy values.

use sci_rs::signal::filter::design::{butter_dyn, DigitalFilter, FilterBandType, FilterOutputType, Sos};
use serde::{Deserialize, Serialize};

/// Columns filtered together in one pass.
pub const LANES: usize = 8;

/// Pass band of the Butterworth filter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FilterBand {
    /// No filtering.
    None,
    /// Keep frequencies between `low_hz` and `high_hz`.
    Bandpass {
        /// Lower corner, Hz.
        low_hz: f64,
        /// Upper corner, Hz.
        high_hz: f64,
    },
    /// Keep frequencies below `high_hz`.
    Lowpass {
        /// Corner, Hz.
        high_hz: f64,
    },
    /// Keep frequencies above `low_hz`.
    Highpass {
        /// Corner, Hz.
        low_hz: f64,
    },
}

impl FilterBand {
    /// Width of the pass band for data sampled at `sample_rate_hz`, Hz
    /// (up to the Nyquist frequency).
    pub fn bandwidth_hz(&self, sample_rate_hz: f64) -> f64 {
        let nyquist = sample_rate_hz / 2.0;
        match *self {
            FilterBand::None => nyquist,
            FilterBand::Bandpass { low_hz, high_hz } => high_hz.min(nyquist) - low_hz,
            FilterBand::Lowpass { high_hz } => high_hz.min(nyquist),
            FilterBand::Highpass { low_hz } => nyquist - low_hz,
        }
    }
}

/// How many samples the odd extension adds at each end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EdgePadding {
    /// scipy's default: 3·(2·sections + 1).
    Scipy,
    /// DSP.jl's `filtfilt` (used by MagNav.jl): 6·sections.
    DspJl,
    /// No extension.
    None,
}

/// Why a filter could not be built or applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// Corner frequencies out of order or above Nyquist.
    #[error("{0}")]
    BadDesign(String),
    /// The signal is too short for the edge extension.
    #[error("{samples} samples is too short to filter: zero-phase filtering needs more than {needed}")]
    TooShort {
        /// Samples given.
        samples: usize,
        /// The edge extension length; the signal must be longer.
        needed: usize,
    },
}

/// A designed zero-phase filter, ready to apply.
#[derive(Debug, Clone)]
pub struct ZeroPhaseFilter {
    /// Sections as `[b0, b1, b2, a1, a2]` with `a0 = 1`.
    sections: Vec<[f64; 5]>,
    /// Steady-state initial conditions for a unit step, per section.
    step_state: Vec<[f64; 2]>,
    pad: usize,
}

impl ZeroPhaseFilter {
    /// Designs a Butterworth filter of `poles` poles for data sampled at
    /// `sample_rate_hz` (scipy `butter(poles, …, output="sos")`).
    pub fn butterworth(
        band: FilterBand,
        poles: usize,
        sample_rate_hz: f64,
        padding: EdgePadding,
    ) -> Result<Self, FilterError> {
        let (corners, kind) = check_band(band, poles, sample_rate_hz)?;
        if corners.is_empty() {
            return Ok(ZeroPhaseFilter {
                sections: Vec::new(),
                step_state: Vec::new(),
                pad: 0,
            });
        }
        let design = butter_dyn(
            poles,
            corners,
            Some(kind),
            Some(false),
            Some(FilterOutputType::Sos),
            Some(sample_rate_hz),
        );
        let DigitalFilter::Sos(design) = design else {
            return Err(FilterError::BadDesign("filter design did not return sections".into()));
        };
        Ok(Self::from_sections(design.sos, padding))
    }

    fn from_sections(mut sos: Vec<Sos<f64>>, padding: EdgePadding) -> Self {
        sci_rs::signal::filter::sosfilt_zi_dyn::<f64, _, Sos<f64>>(sos.iter_mut());
        let count = sos.len();
        let pad = match padding {
            EdgePadding::Scipy => 3 * (2 * count + 1 - trivial_zero_count(&sos)),
            EdgePadding::DspJl => 6 * count,
            EdgePadding::None => 0,
        };
        ZeroPhaseFilter {
            sections: sos
                .iter()
                .map(|s| [s.b[0], s.b[1], s.b[2], s.a[1], s.a[2]].map(|c| c / s.a[0]))
                .collect(),
            step_state: sos.iter().map(|s| [s.zi0, s.zi1]).collect(),
            pad,
        }
    }

    /// Samples of odd extension at each end.
    pub fn pad(&self) -> usize {
        self.pad
    }

    /// Fewest samples this filter accepts.
    pub fn min_samples(&self) -> usize {
        self.pad + 1
    }

    /// Filters one signal.
    pub fn apply(&self, signal: &[f64]) -> Result<Vec<f64>, FilterError> {
        let mut out = vec![0.0; signal.len()];
        self.apply_columns(&[signal], &mut [&mut out])?;
        Ok(out)
    }

    /// Filters each of `inputs` into the matching `outputs` (equal lengths).
    pub fn apply_columns(&self, inputs: &[&[f64]], outputs: &mut [&mut [f64]]) -> Result<(), FilterError> {
        let samples = inputs.first().map_or(0, |c| c.len());
        for (input_group, output_group) in inputs.chunks(LANES).zip(outputs.chunks_mut(LANES)) {
            let fill = |interior: &mut [[f64; LANES]]| {
                for (lane, x) in input_group.iter().enumerate() {
                    for (b, &value) in interior.iter_mut().zip(x.iter()) {
                        b[lane] = value;
                    }
                }
            };
            self.apply_lanes(samples, fill, output_group, 0)?;
        }
        Ok(())
    }

    /// Filters up to [`LANES`] signals of `samples` samples that `fill`
    /// writes, one lane each, into the interleaved rows it is given. Output
    /// lane `k` receives samples `skip .. skip + outputs[k].len()` of the
    /// filtered signal, so trimming costs no copy.
    pub fn apply_lanes(
        &self,
        samples: usize,
        fill: impl FnOnce(&mut [[f64; LANES]]),
        outputs: &mut [&mut [f64]],
        skip: usize,
    ) -> Result<(), FilterError> {
        let pad = if self.sections.is_empty() { 0 } else { self.pad };
        if samples == 0 && pad == 0 {
            return Ok(());
        }
        if samples <= pad {
            return Err(FilterError::TooShort { samples, needed: pad });
        }
        let mut buffer = vec![[0.0; LANES]; samples + 2 * pad];
        fill(&mut buffer[pad..pad + samples]);
        if !self.sections.is_empty() {
            extend_odd(&mut buffer, pad, samples);
            self.both_passes(&mut buffer);
        }
        let interior = &buffer[pad + skip.min(samples)..pad + samples];
        for (lane, output) in outputs.iter_mut().enumerate() {
            for (o, b) in output.iter_mut().zip(interior) {
                *o = b[lane];
            }
        }
        Ok(())
    }

    /// Forward then backward pass over the whole buffer, with AVX2 when the
    /// processor has it. No fused multiply-add is used, so both paths give
    /// the same bits.
    fn both_passes(&self, buffer: &mut [[f64; LANES]]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the processor supports AVX2, checked just above.
            unsafe { self.both_passes_avx2(buffer) };
            return;
        }
        self.both_passes_portable(buffer);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn both_passes_avx2(&self, buffer: &mut [[f64; LANES]]) {
        self.both_passes_portable(buffer);
    }

    #[inline(always)]
    fn both_passes_portable(&self, buffer: &mut [[f64; LANES]]) {
        self.run_pass(buffer.iter_mut());
        self.run_pass(buffer.iter_mut().rev());
    }

    /// One causal pass in transposed direct form II, in place, in the order
    /// the iterator gives, starting from the steady state of the first sample.
    #[inline(always)]
    fn run_pass<'a>(&self, mut samples: impl Iterator<Item = &'a mut [f64; LANES]>) {
        let Some(first) = samples.next() else { return };
        let start = *first;
        let mut state: Vec<[[f64; LANES]; 2]> = self
            .step_state
            .iter()
            .map(|zi| [start.map(|x| zi[0] * x), start.map(|x| zi[1] * x)])
            .collect();
        self.step(first, &mut state);
        for sample in samples {
            self.step(sample, &mut state);
        }
    }

    #[inline(always)]
    fn step(&self, sample: &mut [f64; LANES], state: &mut [[[f64; LANES]; 2]]) {
        let mut x = *sample;
        for ([b0, b1, b2, a1, a2], [z0, z1]) in self.sections.iter().zip(state.iter_mut()) {
            for lane in 0..LANES {
                let y = b0 * x[lane] + z0[lane];
                z0[lane] = b1 * x[lane] - a1 * y + z1[lane];
                z1[lane] = b2 * x[lane] - a2 * y;
                x[lane] = y;
            }
        }
        *sample = x;
    }
}

/// Odd extension about each end: the `pad` rows before `buffer[pad]` and
/// after `buffer[pad + samples - 1]` mirror the interior through its end value.
fn extend_odd(buffer: &mut [[f64; LANES]], pad: usize, samples: usize) {
    let (first, last) = (buffer[pad], buffer[pad + samples - 1]);
    for k in 0..pad {
        let (inner_head, inner_tail) = (buffer[2 * pad - k], buffer[pad + samples - 2 - k]);
        for lane in 0..LANES {
            buffer[k][lane] = 2.0 * first[lane] - inner_head[lane];
            buffer[pad + samples + k][lane] = 2.0 * last[lane] - inner_tail[lane];
        }
    }
}

/// scipy shortens the default pad when sections have trailing zero taps.
fn trivial_zero_count(sos: &[Sos<f64>]) -> usize {
    let b_zeros = sos.iter().filter(|s| s.b[2] == 0.0).count();
    let a_zeros = sos.iter().filter(|s| s.a[2] == 0.0).count();
    b_zeros.min(a_zeros)
}

fn check_band(band: FilterBand, poles: usize, sample_rate_hz: f64) -> Result<(Vec<f64>, FilterBandType), FilterError> {
    let nyquist = sample_rate_hz / 2.0;
    let (corners, kind) = match band {
        FilterBand::None => return Ok((Vec::new(), FilterBandType::Lowpass)),
        FilterBand::Bandpass { low_hz, high_hz } => (vec![low_hz, high_hz], FilterBandType::Bandpass),
        FilterBand::Lowpass { high_hz } => (vec![high_hz], FilterBandType::Lowpass),
        FilterBand::Highpass { low_hz } => (vec![low_hz], FilterBandType::Highpass),
    };
    if !(1..=12).contains(&poles) {
        return Err(FilterError::BadDesign(format!(
            "{poles} poles: choose between 1 and 12 (4 is usual)"
        )));
    }
    let in_range = corners.iter().all(|&f| f > 0.0 && f < nyquist);
    let ordered = corners.windows(2).all(|w| w[0] < w[1]);
    if !sample_rate_hz.is_finite() || !in_range || !ordered {
        return Err(FilterError::BadDesign(format!(
            "corner frequencies {corners:?} Hz must be increasing and between 0 and the Nyquist frequency {nyquist} Hz of data sampled at {sample_rate_hz} Hz"
        )));
    }
    Ok((corners, kind))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bandpass() -> ZeroPhaseFilter {
        let band = FilterBand::Bandpass {
            low_hz: 0.1,
            high_hz: 0.9,
        };
        ZeroPhaseFilter::butterworth(band, 4, 10.0, EdgePadding::Scipy).unwrap()
    }

    #[test]
    fn matches_sci_rs_sosfiltfilt() {
        let band = FilterBand::Bandpass {
            low_hz: 0.1,
            high_hz: 0.9,
        };
        let design = butter_dyn(
            4,
            vec![0.1, 0.9],
            Some(FilterBandType::Bandpass),
            Some(false),
            Some(FilterOutputType::Sos),
            Some(10.0),
        );
        let DigitalFilter::Sos(design) = design else { panic!() };
        let signal: Vec<f64> = (0..500)
            .map(|k| (k as f64 * 0.37).sin() * 40.0 + (k as f64 * 0.011).cos() * 900.0)
            .collect();
        let expected = sci_rs::signal::filter::sosfiltfilt_dyn(signal.iter(), &design.sos);
        let ours = ZeroPhaseFilter::butterworth(band, 4, 10.0, EdgePadding::Scipy)
            .unwrap()
            .apply(&signal)
            .unwrap();
        let worst = ours
            .iter()
            .zip(&expected)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // Same arithmetic in a different association order: agreement to a
        // few ulps of the ~1000-unit signal.
        assert!(worst < 1e-9, "worst difference {worst}");
    }

    #[test]
    fn lanes_do_not_mix() {
        let filter = bandpass();
        let columns: Vec<Vec<f64>> = (0..11)
            .map(|c| (0..200).map(|k| ((k * (c + 1)) as f64 * 0.05).sin()).collect())
            .collect();
        let inputs: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
        let mut outputs = vec![vec![0.0; 200]; 11];
        let mut views: Vec<&mut [f64]> = outputs.iter_mut().map(Vec::as_mut_slice).collect();
        filter.apply_columns(&inputs, &mut views).unwrap();
        for (column, output) in columns.iter().zip(&outputs) {
            assert_eq!(&filter.apply(column).unwrap(), output);
        }
    }

    #[test]
    fn short_signal_is_an_error_not_a_panic() {
        let err = bandpass().apply(&[1.0; 27]).unwrap_err();
        assert_eq!(
            err,
            FilterError::TooShort {
                samples: 27,
                needed: 27
            }
        );
        assert!(bandpass().apply(&[1.0; 28]).is_ok());
    }

    #[test]
    fn rejects_corners_above_nyquist() {
        let band = FilterBand::Bandpass {
            low_hz: 0.1,
            high_hz: 6.0,
        };
        assert!(ZeroPhaseFilter::butterworth(band, 4, 10.0, EdgePadding::Scipy).is_err());
    }
}
