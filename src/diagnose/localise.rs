//! Where a channel's held-out residual is, in time, in frequency and
//! against the recorded columns.
//!
//! - **Noise floor.** White sensor noise σ from the fourth difference over
//!   the whole flight (its median, so that manoeuvres do not count),
//!   carried into a band of width $w$ as $σ\sqrt{w/(f_s/2)}$.
//! - **Per window.** Held-out RMS of each manoeuvre before and after the
//!   findings.
//! - **Spectrum.** The held-out residual's RMS in four equal sub-bands of
//!   the fitting band (a DFT of each window's residual, Parseval), against
//!   the noise floor in the same sub-band.
//! - **Structured stretches.** Blocks of [`BLOCK_S`] seconds whose residual
//!   RMS exceeds [`STRUCTURE_FACTOR`] times both the channel's median block
//!   and the in-band noise floor: something happened there that the model
//!   does not describe.
//! - **Coherence.** For every recorded auxiliary column c, the in-band
//!   $R^2$ of the residual on the body-fixed field it would drive,
//!   $c\,u_x, c\,u_y, c\,u_z$ (band-passed on the same runs). With a few
//!   thousand samples and three regressors, chance gives about 0.001.

use std::ops::Range;

use serde::Serialize;

use crate::ingest::flight_log::{ChannelRole, FlightLog};
use crate::model::{FitOptions, WindowFit};
use crate::numerics::filter::ZeroPhaseFilter;
use crate::numerics::linalg::solve_spd;
use crate::quality::root_mean_square;

use super::Located;

/// Length of a block scanned for structure, s.
pub const BLOCK_S: f64 = 5.0;

/// How far a block must stand above the median block and the noise floor
/// to count as structured.
pub const STRUCTURE_FACTOR: f64 = 4.0;

/// Columns reported by coherence.
const COHERENCE_COLUMNS: usize = 5;

/// One manoeuvre's held-out residual.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WindowResidual {
    /// Manoeuvre and heading.
    pub label: String,
    /// Start, flight time.
    pub t_start: f64,
    /// End, flight time.
    pub t_end: f64,
    /// Plain Tolles-Lawson, held out, nT.
    pub heldout_rms_baseline_nt: f64,
    /// With the findings, held out, nT.
    pub heldout_rms_final_nt: f64,
}

/// The held-out residual in one frequency band.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandResidual {
    /// Lower edge, Hz.
    pub low_hz: f64,
    /// Upper edge, Hz.
    pub high_hz: f64,
    /// RMS of the final held-out residual in the band, nT.
    pub residual_rms_nt: f64,
    /// RMS white sensor noise would have there, nT.
    pub noise_rms_nt: f64,
}

/// A recorded column's in-band coherence with the residual.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Coherence {
    /// Column.
    pub column: String,
    /// $R^2$ of the residual on $c\,u_x, c\,u_y, c\,u_z$.
    pub r_squared: f64,
}

/// One manoeuvre's held-out band-passed residual as a time series, before
/// and after the findings (the report plots it; not in DIAGNOSIS.json).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ResidualTrace {
    /// Manoeuvre and heading.
    pub label: String,
    /// (flight time, nT) with plain Tolles-Lawson.
    pub before: Vec<(f64, f64)>,
    /// (flight time, nT) with the findings.
    pub after: Vec<(f64, f64)>,
}

/// Everything [`localise`] finds for one channel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Localisation {
    /// White-noise RMS in the fitting band, nT.
    pub noise_floor_nt: f64,
    /// Per manoeuvre.
    pub windows: Vec<WindowResidual>,
    /// Per sub-band of the fitting band.
    pub spectrum: Vec<BandResidual>,
    /// Blocks where the final residual is structured.
    pub structured: Vec<Located>,
    /// Share of the final residual's energy in those blocks.
    pub structured_energy_share: f64,
    /// The most coherent columns, best first.
    pub coherence: Vec<Coherence>,
    /// Per manoeuvre, the residual itself.
    #[serde(skip)]
    pub traces: Vec<ResidualTrace>,
}

/// Localises the held-out residual of `channel`: `baseline` and `last` are
/// the held-out window fits of plain Tolles-Lawson and of the final model;
/// `direction` the unit field direction per row.
pub fn localise(
    log: &FlightLog,
    channel: &str,
    (baseline, last): (&[WindowFit], &[WindowFit]),
    direction: &[Vec<f64>; 3],
    options: &FitOptions,
) -> Localisation {
    let fs = 1.0 / log.median_interval_s();
    let (low, high) = band_edges(options, fs);
    let sigma = log.channel(channel).map_or(0.0, |c| sensor_noise(&c.values));
    let noise_in = |width: f64| sigma * (width / (fs / 2.0)).sqrt();
    let windows = baseline
        .iter()
        .zip(last)
        .map(|(b, a)| WindowResidual {
            label: a.window.display_label(),
            t_start: a.window.t_start,
            t_end: a.window.t_end,
            heldout_rms_baseline_nt: root_mean_square(&b.band_after_nt),
            heldout_rms_final_nt: root_mean_square(&a.band_after_nt),
        })
        .collect();
    let edges: Vec<f64> = (0..=4).map(|k| low + (high - low) * k as f64 / 4.0).collect();
    let spectrum = edges
        .windows(2)
        .map(|e| BandResidual {
            low_hz: e[0],
            high_hz: e[1],
            residual_rms_nt: band_rms(last, fs, e[0], e[1]),
            noise_rms_nt: noise_in(e[1] - e[0]),
        })
        .collect();
    let (structured, structured_energy_share) = structured_blocks(log, last, fs, noise_in(high - low));
    let coherence = coherence(log, last, direction, options, fs);
    let series = |fit: &WindowFit| -> Vec<(f64, f64)> {
        sample_rows(fit)
            .map(|row| log.time_s()[row])
            .zip(fit.band_after_nt.iter().copied())
            .collect()
    };
    let traces = baseline
        .iter()
        .zip(last)
        .map(|(b, a)| ResidualTrace {
            label: a.window.display_label(),
            before: series(b),
            after: series(a),
        })
        .collect();
    Localisation {
        traces,
        noise_floor_nt: noise_in(high - low),
        windows,
        spectrum,
        structured,
        structured_energy_share,
        coherence,
    }
}

/// White sensor noise σ of a whole channel, robustly: the median absolute
/// fourth difference (straight flight dominates a flight, so manoeuvres and
/// anomalies do not inflate it), as a Gaussian σ (× 1.4826), divided by
/// the fourth difference's gain $\sqrt{70}$.
fn sensor_noise(values: &[f64]) -> f64 {
    let mut differences: Vec<f64> = values
        .windows(5)
        .filter(|w| w.iter().all(|v| v.is_finite()))
        .map(|w| (w[0] - 4.0 * w[1] + 6.0 * w[2] - 4.0 * w[3] + w[4]).abs())
        .collect();
    if differences.is_empty() {
        return 0.0;
    }
    let middle = differences.len() / 2;
    let (_, median, _) = differences.select_nth_unstable_by(middle, f64::total_cmp);
    *median * 1.4826 / 70f64.sqrt()
}

/// The fitting band's edges, Hz (a low-pass starts at 0, a high-pass ends
/// at Nyquist).
fn band_edges(options: &FitOptions, fs: f64) -> (f64, f64) {
    use crate::numerics::filter::FilterBand;
    match options.filter.band {
        FilterBand::Bandpass { low_hz, high_hz } => (low_hz, high_hz),
        FilterBand::Lowpass { high_hz } => (0.0, high_hz),
        FilterBand::Highpass { low_hz } => (low_hz, fs / 2.0),
        FilterBand::None => (0.0, fs / 2.0),
    }
}

/// RMS of the residuals' content between `low` and `high` Hz: each
/// window's DFT (a real FFT, exact for any length), Parseval, pooled over
/// windows by sample count.
fn band_rms(fits: &[WindowFit], fs: f64, low: f64, high: f64) -> f64 {
    let mut planner = realfft::RealFftPlanner::<f64>::new();
    let (mut energy, mut samples) = (0.0, 0usize);
    for fit in fits {
        let n = fit.band_after_nt.len();
        if n < 8 {
            continue;
        }
        let transform = planner.plan_fft_forward(n);
        let mut input = fit.band_after_nt.clone();
        let mut spectrum = transform.make_output_vec();
        if transform.process(&mut input, &mut spectrum).is_err() {
            continue;
        }
        // Bins 1 to ⌈n/2⌉ − 1, each standing for both halves of the
        // spectrum (the Nyquist bin of an even n is left out, as the mean).
        let power: f64 = (1..n.div_ceil(2))
            .filter(|&k| {
                let f = k as f64 * fs / n as f64;
                f >= low && f < high
            })
            .map(|k| 2.0 * spectrum[k].norm_sqr())
            .sum();
        energy += power / n as f64;
        samples += n;
    }
    (energy / samples.max(1) as f64).sqrt()
}

/// Flight rows of a window's used samples, in stacked order.
fn sample_rows(fit: &WindowFit) -> impl Iterator<Item = usize> + '_ {
    fit.flight_rows.iter().flat_map(Clone::clone)
}

/// Blocks of [`BLOCK_S`] whose residual RMS stands [`STRUCTURE_FACTOR`]
/// above the median block and the in-band noise, merged where they touch,
/// and their share of the residual energy.
fn structured_blocks(log: &FlightLog, fits: &[WindowFit], fs: f64, noise_nt: f64) -> (Vec<Located>, f64) {
    let length = ((BLOCK_S * fs).round() as usize).max(4);
    let time = log.time_s();
    // (rms, energy, first row, last row, window label)
    let mut blocks: Vec<(f64, f64, usize, usize, String)> = Vec::new();
    for fit in fits {
        let rows: Vec<usize> = sample_rows(fit).collect();
        for (chunk, rows) in fit.band_after_nt.chunks(length).zip(rows.chunks(length)) {
            if chunk.len() * 2 < length {
                continue;
            }
            let energy: f64 = chunk.iter().map(|v| v * v).sum();
            blocks.push((
                (energy / chunk.len() as f64).sqrt(),
                energy,
                rows[0],
                rows[rows.len() - 1],
                fit.window.display_label(),
            ));
        }
    }
    if blocks.len() < 4 {
        return (Vec::new(), 0.0);
    }
    let mut sorted: Vec<f64> = blocks.iter().map(|b| b.0).collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let bar = STRUCTURE_FACTOR * median.max(noise_nt);
    let total: f64 = blocks.iter().map(|b| b.1).sum();
    let mut located: Vec<Located> = Vec::new();
    let mut energy = 0.0;
    let mut last_row = usize::MAX;
    for (rms, e, first, end, label) in blocks {
        if rms <= bar {
            continue;
        }
        energy += e;
        match located.last_mut() {
            Some(previous) if last_row != usize::MAX && first <= last_row + 1 => previous.t_end = time[end],
            _ => located.push(Located {
                t_start: time[first],
                t_end: time[end],
                label,
            }),
        }
        last_row = end;
    }
    (located, energy / total.max(f64::MIN_POSITIVE))
}

/// In-band $R^2$ of the residual on $c\,u_i$ for every auxiliary column c,
/// the [`COHERENCE_COLUMNS`] best.
fn coherence(
    log: &FlightLog,
    fits: &[WindowFit],
    direction: &[Vec<f64>; 3],
    options: &FitOptions,
    fs: f64,
) -> Vec<Coherence> {
    let settings = options.filter;
    let Ok(filter) = ZeroPhaseFilter::butterworth(settings.band, settings.poles, fs, settings.padding) else {
        return Vec::new();
    };
    let trim = settings.trim_samples;
    let runs: Vec<Range<usize>> = fits.iter().flat_map(|f| f.flight_rows.iter().cloned()).collect();
    let residual: Vec<f64> = fits.iter().flat_map(|f| f.band_after_nt.iter().copied()).collect();
    let total: f64 = residual.iter().map(|v| v * v).sum();
    if total <= 0.0 {
        return Vec::new();
    }
    let mut found: Vec<Coherence> = log
        .channels()
        .iter()
        .filter(|c| matches!(c.role, ChannelRole::Auxiliary) && !super::is_magnetic_product(&c.name))
        .filter(|c| !super::cross::is_cross_column(&c.name))
        .filter_map(|c| {
            // Band-passed c·u_i on the same trimmed runs as the residual.
            let regressors: Vec<Vec<f64>> = (0..3)
                .map(|axis| {
                    let mut out = Vec::with_capacity(residual.len());
                    for run in &runs {
                        let whole = run.start - trim..run.end + trim;
                        let signal: Vec<f64> = whole.map(|i| c.values[i] * direction[axis][i]).collect();
                        let filtered = filter.apply(&signal).ok()?;
                        out.extend_from_slice(&filtered[trim..filtered.len() - trim]);
                    }
                    (out.len() == residual.len() && out.iter().all(|v| v.is_finite())).then_some(out)
                })
                .collect::<Option<_>>()?;
            let gram = faer::Mat::from_fn(3, 3, |i, j| {
                regressors[i]
                    .iter()
                    .zip(&regressors[j])
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
            });
            let right: Vec<f64> = regressors
                .iter()
                .map(|r| r.iter().zip(&residual).map(|(a, b)| a * b).sum())
                .collect();
            let beta = solve_spd(gram.as_ref(), &right)?;
            let explained: f64 = beta.iter().zip(&right).map(|(b, r)| b * r).sum();
            Some(Coherence {
                column: c.name.clone(),
                r_squared: (explained / total).clamp(0.0, 1.0),
            })
        })
        .collect();
    found.sort_by(|a, b| b.r_squared.total_cmp(&a.r_squared));
    found.truncate(COHERENCE_COLUMNS);
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::windows::CalibrationWindow;

    fn window_of(values: Vec<f64>) -> WindowFit {
        WindowFit {
            window: CalibrationWindow::new(0.0, values.len() as f64 / 10.0),
            stacked_rows: 0..values.len(),
            samples_used: values.len(),
            samples_dropped: 0,
            samples_in_window: values.len(),
            samples_lost_to_gaps: 0,
            flight_rows: std::iter::once(0..values.len()).collect(),
            band_before_nt: Vec::new(),
            band_after_nt: values,
        }
    }

    #[test]
    fn band_rms_puts_a_sine_in_its_band() {
        // 0.3 Hz, amplitude 2 nT, 200 samples at 10 Hz (a whole number of
        // cycles): RMS √2 in 0.2–0.4 Hz, nothing in 0.5–0.9 Hz.
        let sine: Vec<f64> = (0..200)
            .map(|k| 2.0 * (std::f64::consts::TAU * 0.3 * k as f64 / 10.0).sin())
            .collect();
        let fits = [window_of(sine)];
        assert!((band_rms(&fits, 10.0, 0.2, 0.4) - 2f64.sqrt()).abs() < 1e-9);
        assert!(band_rms(&fits, 10.0, 0.5, 0.9) < 1e-9);
    }

    #[test]
    fn band_rms_matches_the_direct_transform_on_any_length() {
        // A prime and an even length, noise-like values: the FFT's band
        // power against the DFT summed term by term.
        for n in [997usize, 1000] {
            let x: Vec<f64> = (0..n)
                .map(|k| ((k * 7919 % 1009) as f64 / 504.5 - 1.0) + (k as f64 * 0.37).sin())
                .collect();
            let (fs, low, high) = (10.0, 0.1, 0.9);
            let mut power = 0.0;
            for k in 1..n.div_ceil(2) {
                let f = k as f64 * fs / n as f64;
                if f < low || f >= high {
                    continue;
                }
                let (mut re, mut im) = (0.0, 0.0);
                for (t, v) in x.iter().enumerate() {
                    let angle = std::f64::consts::TAU * (k * t % n) as f64 / n as f64;
                    re += v * angle.cos();
                    im -= v * angle.sin();
                }
                power += 2.0 * (re * re + im * im);
            }
            let direct = (power / n as f64 / n as f64).sqrt();
            let fast = band_rms(&[window_of(x)], fs, low, high);
            assert!((fast - direct).abs() < 1e-10 * direct, "{n}: {fast} against {direct}");
        }
    }

    #[test]
    fn sensor_noise_recovers_white_noise_under_a_smooth_signal() {
        // σ = 0.05 nT of uniform noise (variance a²/3) on a slow sweep.
        let mut state = 12345u64;
        let values: Vec<f64> = (0..20_000)
            .map(|k| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let uniform = (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
                50_000.0 + 30.0 * (k as f64 * 0.001).sin() + 0.05 * 3f64.sqrt() * uniform
            })
            .collect();
        // The median-based estimate assumes Gaussian differences; the fourth
        // difference of uniform noise is close to Gaussian (within 5 %).
        let sigma = sensor_noise(&values);
        assert!((sigma - 0.05).abs() < 0.05 * 0.05, "σ {sigma}");
    }
}
