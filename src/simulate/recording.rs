//! What the instruments record: electrical channels at the internal rate,
//! anti-alias averaging down to the output rate, noise and quantisation.

use std::f64::consts::PI;

use crate::simulate::random::Random;
use crate::simulate::trajectory::FlightPath;

/// Averages an internal-rate series down to one value per output sample:
/// a centred window of `factor + 1` samples with half weights at its ends
/// (trapezoidal), so the average is not delayed. Clamped at the ends.
pub fn average_down(internal: &[f64], factor: usize) -> Vec<f64> {
    let outputs = internal.len() / factor;
    let half = factor / 2;
    let last = internal.len() - 1;
    (0..outputs)
        .map(|j| {
            let centre = j * factor;
            if factor == 1 {
                return internal[centre];
            }
            let (start, end) = (centre as isize - half as isize, centre + factor - half);
            let at = |k: isize| internal[(k.max(0) as usize).min(last)];
            let inner: f64 = (start + 1..end as isize).map(at).sum();
            (inner + 0.5 * (at(start) + at(end as isize))) / factor as f64
        })
        .collect()
}

/// Reads `series` (internal rate, interval `dt_s`) `delay_s` late, by
/// linear interpolation; held at the first sample before the start.
pub fn delayed(series: &[f64], dt_s: f64, delay_s: f64) -> Vec<f64> {
    let shift = delay_s / dt_s;
    let last = series.len() as f64 - 1.0;
    (0..series.len())
        .map(|k| {
            let position = (k as f64 - shift).clamp(0.0, last);
            let below = position.floor() as usize;
            let weight = position - below as f64;
            let above = (below + 1).min(series.len() - 1);
            series[below] * (1.0 - weight) + series[above] * weight
        })
        .collect()
}

/// First-order lag $\tau\,\dot y + y = x$, discretised exactly for a
/// sample-and-hold input: $y_k = \alpha y_{k-1} + (1-\alpha) x_k$,
/// $\alpha = e^{-\Delta t/\tau}$.
pub fn first_order_lag(series: &[f64], dt_s: f64, tau_s: f64) -> Vec<f64> {
    let alpha = (-dt_s / tau_s).exp();
    let mut state = series.first().copied().unwrap_or(0.0);
    series
        .iter()
        .map(|x| {
            state = alpha * state + (1.0 - alpha) * x;
            state
        })
        .collect()
}

/// Rounds to the instrument's resolution of `decimals` decimal places
/// (dividing by the exact power of ten gives the double nearest the
/// decimal, so it prints short).
pub fn quantise(value: f64, decimals: i32) -> f64 {
    let scale = 10f64.powi(decimals);
    (value * scale).round() / scale + 0.0
}

/// The auxiliary channels every simulated flight records, at the internal
/// rate, in [`crate::simulate::scenario::AUXILIARY_CHANNELS`] order:
///
/// - `cur_strb`: anti-collision strobe, 2.5 A pulses of 80 ms near 1 Hz;
/// - `cur_heat`: pitot/cabin heater on a thermostat, 4 A on for 10–40 s;
/// - `cur_com1`: radio transmissions, 6 A bursts of 2–12 s;
/// - `cur_ail`: aileron servo, following the roll rate;
/// - `cur_fuel`: fuel pump, 3 A with a slow ripple;
/// - `cur_fan`: avionics fan, 1.2 A with a 0.4 Hz ripple;
/// - `vol_bus`: the 28 V bus, sagging with the total load (0.05 Ω);
/// - `trim_tab`: elevator trim, degrees, following the slow pitch and height.
pub fn auxiliary_channels(path: &FlightPath, random: &mut Random) -> Vec<Vec<f64>> {
    let n = path.poses.len();
    let dt = path.dt_s;
    let strobe_period = random.uniform(0.9, 1.1);
    let fan_phase = random.uniform(0.0, 2.0 * PI);
    let heater = switching(n, dt, random, [10.0, 40.0], [10.0, 40.0], 4.0);
    let radio = switching(n, dt, random, [20.0, 120.0], [2.0, 12.0], 6.0);
    let roll_rate: Vec<f64> = central_rate(&path.poses.iter().map(|p| p.roll_deg).collect::<Vec<_>>(), dt);
    let slow_pitch = first_order_lag(&path.poses.iter().map(|p| p.pitch_deg).collect::<Vec<_>>(), dt, 8.0);
    let mut channels: Vec<Vec<f64>> = (0..8).map(|_| Vec::with_capacity(n)).collect();
    for k in 0..n {
        let t = k as f64 * dt;
        let strobe = if (t / strobe_period).fract() < 0.08 / strobe_period {
            2.5
        } else {
            0.1
        };
        let servo = 0.3 + 0.06 * roll_rate[k].abs();
        let fuel = 3.0 + 0.2 * (2.0 * PI * t / 37.0).sin();
        let fan = 1.2 + 0.1 * (2.0 * PI * 0.4 * t + fan_phase).sin();
        let load = strobe + heater[k] + radio[k] + servo + fuel + fan;
        let trim = 1.5 - 0.4 * slow_pitch[k] + 0.0004 * path.poses[k].height_agl_m;
        for (channel, value) in
            channels
                .iter_mut()
                .zip([strobe, heater[k], radio[k], servo, fuel, fan, 28.0 - 0.05 * load, trim])
        {
            channel.push(value);
        }
    }
    channels
}

/// A load switched on for `on_s` and off for `off_s` (drawn per cycle).
fn switching(n: usize, dt: f64, random: &mut Random, off_s: [f64; 2], on_s: [f64; 2], amps: f64) -> Vec<f64> {
    let mut values = Vec::with_capacity(n);
    let mut on = false;
    while values.len() < n {
        let span = if on { on_s } else { off_s };
        let samples = (random.uniform(span[0], span[1]) / dt) as usize;
        let level = if on { amps } else { 0.0 };
        values.extend(std::iter::repeat_n(level, samples.min(n - values.len()).max(1)));
        on = !on;
    }
    values.truncate(n);
    values
}

/// A current that no column records, `n` internal samples `dt` apart,
/// zero-mean: steps switched every 10–60 s, straight ramps between levels
/// drawn every 20–90 s, or slow cycles of 20–120 s (`Mixed` adds all
/// three), each of size about `amplitude_a`. It varies independently of
/// the attitude.
pub fn unrecorded_current(
    n: usize,
    dt: f64,
    (amplitude_a, waveform): (f64, crate::simulate::scenario::Waveform),
    random: &mut Random,
) -> Vec<f64> {
    use crate::simulate::scenario::Waveform;
    let steps = switching(n, dt, random, [10.0, 60.0], [10.0, 60.0], amplitude_a);
    let mut ramps = Vec::with_capacity(n);
    let mut from = random.uniform(-1.0, 1.0) * amplitude_a;
    while ramps.len() < n {
        let samples = ((random.uniform(20.0, 90.0) / dt) as usize).max(1);
        let to = random.uniform(-1.0, 1.0) * amplitude_a;
        ramps.extend((0..samples).map(|k| from + (to - from) * k as f64 / samples as f64));
        from = to;
    }
    ramps.truncate(n);
    let period_s = random.uniform(20.0, 120.0);
    let phase = random.uniform(0.0, 2.0 * PI);
    let cycles: Vec<f64> = (0..n)
        .map(|k| amplitude_a * (2.0 * PI * k as f64 * dt / period_s + phase).sin())
        .collect();
    let current: Vec<f64> = match waveform {
        Waveform::Steps => steps,
        Waveform::Ramps => ramps,
        Waveform::Cycles => cycles,
        Waveform::Mixed => (0..n).map(|k| (steps[k] + ramps[k] + cycles[k]) / 3.0).collect(),
    };
    let mean = current.iter().sum::<f64>() / n.max(1) as f64;
    current.into_iter().map(|c| c - mean).collect()
}

/// Central-difference time derivative (one-sided at the ends), per second.
pub fn central_rate(series: &[f64], dt_s: f64) -> Vec<f64> {
    let n = series.len();
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            if a == b {
                0.0
            } else {
                (series[b] - series[a]) / ((b - a) as f64 * dt_s)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averaging_a_ramp_is_not_delayed() {
        let ramp: Vec<f64> = (0..100).map(f64::from).collect();
        let averaged = average_down(&ramp, 10);
        assert_eq!(averaged.len(), 10);
        for (j, value) in averaged.iter().enumerate().skip(1) {
            assert!((value - (j * 10) as f64).abs() < 1e-12, "{j}: {value}");
        }
    }

    #[test]
    fn a_delay_shifts_a_ramp_by_the_delay() {
        let ramp: Vec<f64> = (0..100).map(|k| k as f64 * 0.01).collect();
        let late = delayed(&ramp, 0.01, 0.125);
        assert!((late[50] - (0.5 - 0.125)).abs() < 1e-12);
    }

    #[test]
    fn a_first_order_lag_reaches_63_percent_after_one_time_constant() {
        let mut step = vec![0.0; 1001];
        step[1..].iter_mut().for_each(|v| *v = 1.0);
        let response = first_order_lag(&step, 0.001, 0.5);
        assert!((response[500] - (1.0 - (-1.0f64).exp())).abs() < 2e-3);
    }
}
