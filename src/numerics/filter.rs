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
use std::ops::Range;

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
    /// How the sections are evaluated.
    form: Form,
    /// Steady-state initial conditions for a unit step, per section.
    step_state: Vec<[f64; 2]>,
    pad: usize,
}

/// How the sections of a filter are evaluated.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Form {
    /// Each section as designed: five multiply-adds.
    General,
    /// A Butterworth band-pass of N poles has N zeros at z = 1 and N at
    /// z = −1. Pairing one of each in every section gives numerators
    /// `gain·(1 − z⁻²)`; with the gain applied once to the input, a section
    /// costs one addition and two multiply-adds. The poles keep the
    /// design's pairing and order.
    Bandpass { gain: f64 },
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
                form: Form::General,
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
        let filter = Self::from_sections(design.sos, padding);
        Ok(match kind {
            FilterBandType::Bandpass => filter.in_bandpass_form(),
            _ => filter,
        })
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
            form: Form::General,
            step_state: sos.iter().map(|s| [s.zi0, s.zi1]).collect(),
            pad,
        }
    }

    /// The same transfer function in [`Form::Bandpass`], when the
    /// numerators are the band-pass's: monic factors `1 ± 2z⁻¹ + z⁻²` or
    /// `1 − z⁻²` times a gain, with as many zeros at 1 as at −1. Otherwise
    /// the filter as it is.
    fn in_bandpass_form(self) -> Self {
        let mut gain = 1.0;
        let mut balance = 0i64;
        for &[b0, b1, b2, ..] in &self.sections {
            let (c1, c2) = (b1 / b0, b2 / b0);
            let near = |a: f64, b: f64| (a - b).abs() < 1e-12;
            balance += match () {
                _ if near(c1, 2.0) && near(c2, 1.0) => -2,
                _ if near(c1, -2.0) && near(c2, 1.0) => 2,
                _ if near(c1, 0.0) && near(c2, -1.0) => 0,
                _ => return self,
            };
            gain *= b0;
        }
        if balance != 0 || !gain.is_finite() || gain == 0.0 {
            return self;
        }
        let sections: Vec<[f64; 5]> = self.sections.iter().map(|s| [1.0, 0.0, -1.0, s[3], s[4]]).collect();
        // Steady state under a constant unit input: the first section sees
        // the gain, and a section's DC output is its input times
        // (b0 + b1 + b2)/(1 + a1 + a2), which is zero here.
        let mut input = gain;
        let step_state = sections
            .iter()
            .map(|&[b0, b1, b2, a1, a2]| {
                let output = input * (b0 + b1 + b2) / (1.0 + a1 + a2);
                let state = [output - b0 * input, b2 * input - a2 * output];
                debug_assert_eq!(state[0], b1 * input - a1 * output + state[1]);
                input = output;
                state
            })
            .collect();
        ZeroPhaseFilter {
            sections,
            form: Form::Bandpass { gain },
            step_state,
            pad: self.pad,
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
        let mut rows = vec![[0.0; LANES]; samples];
        fill(&mut rows);
        let kept = outputs.first().map_or(0, |o| o.len());
        let mut panel = vec![[0.0; LANES]; kept.min(samples.saturating_sub(skip))];
        self.apply_panel(
            samples,
            |range, out| out.copy_from_slice(&rows[range]),
            &mut [&mut panel],
            skip,
        )?;
        scatter(&panel, outputs, 0);
        Ok(())
    }

    /// Filters up to [`LANES`] signals of `samples` samples, one per lane,
    /// into `output`: `source(range, rows)` writes samples `range` into
    /// `rows`, and the segments of `output`, taken in order, receive samples
    /// `skip ..` of the filtered signal (as many as they hold, up to the end).
    ///
    /// The output rows are filled and filtered in place, forward then
    /// backward, so the only working memory besides them is the samples past
    /// the output and the odd extension at each end.
    pub fn apply_panel(
        &self,
        samples: usize,
        mut source: impl FnMut(Range<usize>, &mut [[f64; LANES]]),
        output: &mut [&mut [[f64; LANES]]],
        skip: usize,
    ) -> Result<(), FilterError> {
        let start = skip.min(samples);
        let held: usize = output.iter().map(|segment| segment.len()).sum();
        let end = (start + held).min(samples);
        if self.sections.is_empty() {
            for_each_chunk(output, start, end, |range, rows| source(range, rows));
            return Ok(());
        }
        let pad = self.pad;
        if samples <= pad {
            return Err(FilterError::TooShort { samples, needed: pad });
        }
        // Odd extension about each end: 2·x₀ − x_{pad−k} before the signal,
        // 2·x_{n−1} − x_{n−2−k} after it.
        let mut head = vec![[0.0; LANES]; pad + 1];
        source(0..pad + 1, &mut head);
        let mut tail = vec![[0.0; LANES]; pad + 1];
        source(samples - pad - 1..samples, &mut tail);
        let mut front: Vec<[f64; LANES]> = (0..pad).map(|k| odd(head[0], head[pad - k])).collect();
        let back: Vec<[f64; LANES]> = (0..pad).map(|k| odd(tail[pad], tail[pad - 1 - k])).collect();
        // Forward pass: extension, the samples before the output, the
        // output in place, the samples after it, extension.
        // Without an extension the steady state is scaled by the first
        // sample itself (scipy with padlen = 0).
        let mut state = self.initial_state(front.first().unwrap_or(&head[0]));
        self.run(&mut state, front.iter_mut());
        let mut chunk = [[0.0; LANES]; CHUNK_ROWS];
        for first in (0..start).step_by(CHUNK_ROWS) {
            let range = first..(first + CHUNK_ROWS).min(start);
            let rows = &mut chunk[..range.len()];
            source(range, rows);
            self.run(&mut state, rows.iter_mut());
        }
        for_each_chunk(output, start, end, |range, rows| {
            source(range, rows);
            self.run(&mut state, rows.iter_mut());
        });
        let past = samples - end;
        let mut after = vec![[0.0; LANES]; past + pad];
        source(end..samples, &mut after[..past]);
        after[past..].copy_from_slice(&back);
        self.run(&mut state, after.iter_mut());
        let mut remaining = end - start;
        let used: Vec<usize> = output
            .iter()
            .map(|segment| {
                let take = segment.len().min(remaining);
                remaining -= take;
                take
            })
            .collect();
        // Backward pass from the far end of the extension (or of the
        // output, when nothing follows it) to the first output.
        let last_output = output
            .iter()
            .zip(&used)
            .rev()
            .find(|(_, &u)| u > 0)
            .map(|(s, &u)| s[u - 1]);
        let Some(last) = after.last().copied().or(last_output) else {
            return Ok(());
        };
        let mut state = self.initial_state(&last);
        self.run(&mut state, after.iter_mut().rev());
        for (segment, used) in output.iter_mut().zip(used).rev() {
            self.run(&mut state, segment[..used].iter_mut().rev());
        }
        Ok(())
    }

    /// Steady-state section states for a signal that has always been `x`.
    fn initial_state(&self, x: &[f64; LANES]) -> Vec<[[f64; LANES]; 2]> {
        self.step_state
            .iter()
            .map(|zi| [x.map(|v| zi[0] * v), x.map(|v| zi[1] * v)])
            .collect()
    }

    /// Runs the sections over `rows` in the order given, in place, with
    /// AVX-512 or AVX2 when the processor has them. Every path uses fused
    /// multiply-adds in the same order, so they give the same bits.
    fn run<'a>(&self, state: &mut [[[f64; LANES]; 2]], rows: impl Iterator<Item = &'a mut [f64; LANES]>) {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the processor supports AVX-512F and FMA, checked just above.
                unsafe { self.run_avx512(state, rows) };
                return;
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                // SAFETY: the processor supports AVX2 and FMA, checked just above.
                unsafe { self.run_avx2(state, rows) };
                return;
            }
        }
        self.run_portable(state, rows);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,fma")]
    unsafe fn run_avx512<'a>(&self, state: &mut [[[f64; LANES]; 2]], rows: impl Iterator<Item = &'a mut [f64; LANES]>) {
        self.run_portable(state, rows);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2<'a>(&self, state: &mut [[[f64; LANES]; 2]], rows: impl Iterator<Item = &'a mut [f64; LANES]>) {
        self.run_portable(state, rows);
    }

    /// Transposed direct form II, section by section. The usual section
    /// counts run with their states held in registers across samples
    /// (the same operations in the same order as the general loop).
    #[inline(always)]
    fn run_portable<'a>(&self, state: &mut [[[f64; LANES]; 2]], rows: impl Iterator<Item = &'a mut [f64; LANES]>) {
        let s = &self.sections;
        let general = (None, general_section);
        let bandpass = |gain| (Some(gain), bandpass_section);
        match (self.form, s.len()) {
            (Form::General, 1) => run_sections::<1>(general, s, state, rows),
            (Form::General, 2) => run_sections::<2>(general, s, state, rows),
            (Form::General, 3) => run_sections::<3>(general, s, state, rows),
            (Form::General, 4) => run_sections::<4>(general, s, state, rows),
            (Form::General, 5) => run_sections::<5>(general, s, state, rows),
            (Form::General, 6) => run_sections::<6>(general, s, state, rows),
            (Form::Bandpass { gain }, 1) => run_sections::<1>(bandpass(gain), s, state, rows),
            (Form::Bandpass { gain }, 2) => run_sections::<2>(bandpass(gain), s, state, rows),
            (Form::Bandpass { gain }, 3) => run_sections::<3>(bandpass(gain), s, state, rows),
            (Form::Bandpass { gain }, 4) => run_sections::<4>(bandpass(gain), s, state, rows),
            (Form::Bandpass { gain }, 5) => run_sections::<5>(bandpass(gain), s, state, rows),
            (Form::Bandpass { gain }, 6) => run_sections::<6>(bandpass(gain), s, state, rows),
            _ => self.run_any(state, rows),
        }
    }

    /// [`Self::run_portable`] for any number of sections.
    #[inline(always)]
    fn run_any<'a>(&self, state: &mut [[[f64; LANES]; 2]], rows: impl Iterator<Item = &'a mut [f64; LANES]>) {
        for sample in rows {
            let mut x = *sample;
            if let Form::Bandpass { gain } = self.form {
                x = x.map(|v| gain * v);
            }
            for (&section, [z0, z1]) in self.sections.iter().zip(state.iter_mut()) {
                for lane in 0..LANES {
                    x[lane] = match self.form {
                        Form::General => general_section(section, x[lane], &mut z0[lane], &mut z1[lane]),
                        Form::Bandpass { .. } => bandpass_section(section, x[lane], &mut z0[lane], &mut z1[lane]),
                    };
                }
            }
            *sample = x;
        }
    }
}

/// One sample through a section in transposed direct form II; returns the
/// output and advances the states.
#[inline(always)]
fn general_section([b0, b1, b2, a1, a2]: [f64; 5], x: f64, z0: &mut f64, z1: &mut f64) -> f64 {
    let y = b0.mul_add(x, *z0);
    *z0 = (-a1).mul_add(y, b1.mul_add(x, *z1));
    *z1 = (-a2).mul_add(y, b2 * x);
    y
}

/// [`general_section`] for the numerator `1 − z⁻²` of [`Form::Bandpass`].
#[inline(always)]
fn bandpass_section([_, _, _, a1, a2]: [f64; 5], x: f64, z0: &mut f64, z1: &mut f64) -> f64 {
    let y = x + *z0;
    *z0 = (-a1).mul_add(y, *z1);
    *z1 = (-a2).mul_add(y, -x);
    y
}

/// `N` sections over `rows`, their coefficients and states copied into
/// locals so they stay in registers from one sample to the next; each
/// sample is first multiplied by `gain`, when there is one, and passed
/// through `section` ([`general_section`] or [`bandpass_section`]).
#[inline(always)]
fn run_sections<'a, const N: usize>(
    (gain, section): (Option<f64>, impl Fn([f64; 5], f64, &mut f64, &mut f64) -> f64),
    sections: &[[f64; 5]],
    state: &mut [[[f64; LANES]; 2]],
    rows: impl Iterator<Item = &'a mut [f64; LANES]>,
) {
    let coefficients: [[f64; 5]; N] = std::array::from_fn(|s| sections[s]);
    let mut z: [[[f64; LANES]; 2]; N] = std::array::from_fn(|s| state[s]);
    for sample in rows {
        let mut x = match gain {
            Some(gain) => sample.map(|v| gain * v),
            None => *sample,
        };
        for s in 0..N {
            let [z0, z1] = &mut z[s];
            for lane in 0..LANES {
                x[lane] = section(coefficients[s], x[lane], &mut z0[lane], &mut z1[lane]);
            }
        }
        *sample = x;
    }
    state[..N].copy_from_slice(&z);
}

/// Rows per chunk of a streamed pass (32 KiB).
const CHUNK_ROWS: usize = 512;

/// Calls `each(samples, rows)` over the segments of `output` in chunks of
/// at most [`CHUNK_ROWS`], for samples `start..end` in order.
fn for_each_chunk(
    output: &mut [&mut [[f64; LANES]]],
    start: usize,
    end: usize,
    mut each: impl FnMut(Range<usize>, &mut [[f64; LANES]]),
) {
    let mut first = start;
    for segment in output.iter_mut() {
        let used = segment.len().min(end - first);
        for rows in segment[..used].chunks_mut(CHUNK_ROWS) {
            each(first..first + rows.len(), rows);
            first += rows.len();
        }
    }
}

/// $2a - b$ lane by lane.
fn odd(a: [f64; LANES], b: [f64; LANES]) -> [f64; LANES] {
    std::array::from_fn(|lane| 2.0 * a[lane] - b[lane])
}

/// Writes `rows` into `outputs` from row `at`, lane `k` to output `k`.
fn scatter(rows: &[[f64; LANES]], outputs: &mut [&mut [f64]], at: usize) {
    for (lane, output) in outputs.iter_mut().enumerate() {
        for (o, row) in output[at..at + rows.len()].iter_mut().zip(rows) {
            *o = row[lane];
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
    if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
        return Err(FilterError::BadDesign(
            "the sample rate is unknown: the data needs at least two samples at distinct times".into(),
        ));
    }
    if !in_range || !ordered {
        return Err(FilterError::BadDesign(format!(
            "corner frequencies {corners:?} Hz must be increasing and between 0 and the Nyquist frequency {nyquist} Hz"
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
        let worst = worst_difference(&ours, &expected);
        // Same arithmetic in a different association order: agreement to a
        // few ulps of the ~1000-unit signal.
        assert!(worst < 1e-9, "worst difference {worst}");
    }

    /// The largest absolute difference between two signals.
    fn worst_difference(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)
    }

    /// The band-pass's one-addition sections give the designed sections'
    /// output, on a long record with a survey-sized offset and for odd and
    /// even pole counts; other bands keep the designed sections.
    #[test]
    fn bandpass_form_equals_the_designed_sections() {
        let signal: Vec<f64> = (0..20_000)
            .map(|k| 52_000.0 + (k as f64 * 0.003).sin() * 800.0 + (k as f64 * 0.41).sin() * 3.0)
            .collect();
        for poles in [3, 4, 6] {
            let band = FilterBand::Bandpass {
                low_hz: 0.1,
                high_hz: 0.9,
            };
            let (corners, kind) = check_band(band, poles, 10.0).unwrap();
            let design = butter_dyn(
                poles,
                corners,
                Some(kind),
                Some(false),
                Some(FilterOutputType::Sos),
                Some(10.0),
            );
            let DigitalFilter::Sos(design) = design else { panic!() };
            let designed = ZeroPhaseFilter::from_sections(design.sos, EdgePadding::Scipy);
            let filter = ZeroPhaseFilter::butterworth(band, poles, 10.0, EdgePadding::Scipy).unwrap();
            assert!(matches!(filter.form, Form::Bandpass { .. }), "{poles} poles");
            assert_eq!(designed.form, Form::General);
            let (ours, reference) = (filter.apply(&signal).unwrap(), designed.apply(&signal).unwrap());
            let worst = worst_difference(&ours, &reference);
            // Rounding of a 52,000 nT record: a few ulps of the input.
            assert!(worst < 1e-8, "{poles} poles: worst difference {worst} nT");
            let amplitude = reference.iter().map(|v| v.abs()).fold(0.0, f64::max);
            assert!(amplitude > 1.0, "the pass band holds the 0.65 Hz part");
        }
        let low = ZeroPhaseFilter::butterworth(FilterBand::Lowpass { high_hz: 1.0 }, 4, 10.0, EdgePadding::Scipy);
        assert_eq!(low.unwrap().form, Form::General);
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

    /// The processor-specific passes, the portable one and the general
    /// section loop agree to the bit.
    #[test]
    fn filter_paths_give_the_same_bits() {
        let filter = bandpass();
        let mut rows: Vec<[f64; LANES]> = (0..300)
            .map(|k| std::array::from_fn(|lane| ((k * (lane + 2)) as f64 * 0.07).sin() * 50.0))
            .collect();
        let mut copy = rows.clone();
        let mut general = rows.clone();
        let mut state = filter.initial_state(&rows[0]);
        let mut portable_state = state.clone();
        let mut general_state = state.clone();
        filter.run(&mut state, rows.iter_mut());
        filter.run_portable(&mut portable_state, copy.iter_mut());
        filter.run_any(&mut general_state, general.iter_mut());
        let bits = |r: &[[f64; LANES]]| r.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&rows), bits(&copy));
        // The register-held sections equal the general loop, states included.
        assert_eq!(bits(&rows), bits(&general));
        assert_eq!(state, general_state);
    }

    /// Filtering in place, with trimming, equals filtering the whole signal.
    #[test]
    fn streamed_trimmed_output_equals_the_whole_signal() {
        let filter = bandpass();
        let signal: Vec<f64> = (0..1700)
            .map(|k| (k as f64 * 0.13).sin() + (k as f64 * 0.002).cos() * 30.0)
            .collect();
        let whole = filter.apply(&signal).unwrap();
        let mut kept = vec![[0.0; LANES]; 1700 - 2 * 37];
        let (first, second) = kept.split_at_mut(500);
        filter
            .apply_panel(
                signal.len(),
                |range, rows| {
                    for (row, &v) in rows.iter_mut().zip(&signal[range]) {
                        *row = [v; LANES];
                    }
                },
                &mut [first, second],
                37,
            )
            .unwrap();
        for lane in 0..LANES {
            let column: Vec<f64> = kept.iter().map(|row| row[lane]).collect();
            assert_eq!(&whole[37..1700 - 37], &column[..]);
        }
    }

    /// Without edge extension (scipy's padlen = 0) each pass starts from
    /// the steady state of its own first sample.
    #[test]
    fn no_edge_extension_starts_from_the_end_samples() {
        let band = FilterBand::Bandpass {
            low_hz: 0.1,
            high_hz: 0.9,
        };
        let filter = ZeroPhaseFilter::butterworth(band, 4, 10.0, EdgePadding::None).unwrap();
        let signal: Vec<f64> = (0..300).map(|k| (k as f64 * 0.21).sin() * 20.0 + 5.0).collect();
        let mut rows: Vec<[f64; LANES]> = signal.iter().map(|&v| [v; LANES]).collect();
        let mut state = filter.initial_state(&rows[0]);
        filter.run_any(&mut state, rows.iter_mut());
        let mut state = filter.initial_state(&rows[rows.len() - 1]);
        filter.run_any(&mut state, rows.iter_mut().rev());
        let expected: Vec<f64> = rows.iter().map(|r| r[0]).collect();
        assert_eq!(filter.apply(&signal).unwrap(), expected);
        // Trimmed as in a fit: the kept samples are the same values.
        let mut kept = vec![[0.0; LANES]; 300 - 2 * 20];
        filter
            .apply_panel(
                300,
                |range, out| out.copy_from_slice(&rows_of(&signal[range])),
                &mut [&mut kept],
                20,
            )
            .unwrap();
        assert!(kept.iter().zip(&expected[20..280]).all(|(k, e)| k[3] == *e));
    }

    fn rows_of(values: &[f64]) -> Vec<[f64; LANES]> {
        values.iter().map(|&v| [v; LANES]).collect()
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
