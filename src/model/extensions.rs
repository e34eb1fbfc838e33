//! Physics the 18 Tolles-Lawson terms leave out: what `diagnose` finds,
//! and what a [`super::ModelSpec`] adds to its terms once a diagnosis is
//! accepted.
//!
//! The [`Extensions`] of one scalar channel are
//! - a fluxgate calibration the channel is fitted on ($\hat b = C(m - o)$);
//! - a sensor lag: the scalar reads the field `lag_s` late, so its record
//!   is read `lag_s` earlier (linear interpolation) before the fit and
//!   before compensation;
//! - an eddy time constant τ: the nine eddy terms $u_i \dot B_j$ give way
//!   to $u_i\,L_\tau[\dot B_j]$, with $L_\tau$ the first-order lag
//!   $\tau \dot y + y = x$;
//! - the total field's second-order term: a scalar magnetometer reads
//!   $|B + F|$, which Tolles-Lawson writes as $|B| + u \cdot F$. With a
//!   large aircraft field F (hundreds of nT in a cabin) the part across B
//!   adds $|F_\perp|^2 / 2|B|$, a few tenths of a nT that varies with
//!   attitude as no first-order term does. The term takes F = P + M B from
//!   the fitted permanent and induced coefficients, so it adds no
//!   parameter: the scalar less the term of one fit is fitted again, twice
//!   ([`SECOND_ORDER_PASSES`]);
//! - source terms, in the order they were accepted: an auxiliary column c
//!   driving a body-fixed field, seen as $(c - \bar c)(k_x u_x + k_y u_y +
//!   k_z u_z)$, or a base-station column subtracted from the scalar
//!   before the fit with gain 1, $c - \bar c$ (no coefficient).
//!   The level $\bar c$ is the column's median on the flight the model was
//!   fitted on: the steady part of a body-fixed field is the permanent
//!   terms' already.
//!   Other sensors' geology-free signal s ([`crate::model::cross_sensor`])
//!   enters as $s\,(k \cdot u)$ fitted on the box, or as $g\,s$ with a
//!   gain the survey lines fitted, subtracted before the fit and predicted
//!   as interference.

use serde::{Deserialize, Serialize};

use crate::calibration::fluxgate::VectorCalibration;
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::model::terms::TermSet;
use crate::numerics::solve::Criterion;

/// A recorded column whose variation enters the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SourceTerm {
    /// A body-fixed field proportional to the column: three regressors
    /// $(c - \bar c) u_i$.
    AuxCoupling {
        /// The column.
        column: String,
        /// $\bar c$, in the column's unit.
        level: f64,
    },
    /// The field of eddy currents that a changing column (a current)
    /// induces in nearby conductors, body-fixed and proportional to its
    /// rate of change: three regressors $\dot c\, u_i$, with $\dot c$ the
    /// central difference over the recorded times. It refines an
    /// [`SourceTerm::AuxCoupling`] of the same column.
    AuxCouplingRate {
        /// The column.
        column: String,
    },
    /// Geomagnetic variation recorded by a base station: $c - \bar c$
    /// subtracted from the scalar before the fit, gain 1, no coefficient.
    ExternalField {
        /// The column.
        column: String,
        /// $\bar c$, nT.
        level: f64,
    },
    /// Interference other sensors see and the attitude terms cannot hold
    /// ([`crate::model::cross_sensor`]): three regressors $s\,u_i$ of the
    /// geology-free signal s fitted on the box, or, with a gain fitted on
    /// the survey, $g\,s$ subtracted from the scalar before the fit (no
    /// coefficient), as a base station's record is.
    CrossSensor {
        /// The sensors read, `flux_c|mag_5_uc`.
        name: String,
        /// How the signal is made from them.
        signal: crate::model::cross_sensor::CrossSignal,
        /// g, nT at the channel per nT of the signal, where the survey
        /// fitted it ([`crate::diagnose`]'s survey step); `None` for the
        /// box's three regressors.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        survey_gain: Option<f64>,
    },
}

impl SourceTerm {
    /// The column the term reads.
    pub fn column(&self) -> &str {
        match self {
            SourceTerm::AuxCoupling { column, .. }
            | SourceTerm::AuxCouplingRate { column }
            | SourceTerm::ExternalField { column, .. } => column,
            SourceTerm::CrossSensor { name, .. } => name,
        }
    }

    /// Whether the term is the base station's record of the external
    /// field, not a coupling to an aircraft column.
    pub fn is_external_field(&self) -> bool {
        matches!(self, SourceTerm::ExternalField { .. })
    }

    /// A cross-sensor signal's gain fitted on the survey, where the term
    /// is one: it adds no regressor to the box's fit.
    pub fn survey_gain(&self) -> Option<f64> {
        match self {
            SourceTerm::CrossSensor { survey_gain, .. } => *survey_gain,
            _ => None,
        }
    }
}

/// Physics added to one channel's Tolles-Lawson model. The default is
/// plain Tolles-Lawson.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Extensions {
    /// Fluxgate calibration applied before the terms are built.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vector_calibration: Option<VectorCalibration>,
    /// The scalar reads the field this late, s (negative: early).
    pub lag_s: f64,
    /// Eddy time constant, s; 0 keeps the instantaneous eddy terms.
    pub eddy_tau_s: f64,
    /// The total field's second-order term, from the fitted aircraft field.
    pub second_order: bool,
    /// Source terms, in the order they were accepted.
    pub sources: Vec<SourceTerm>,
    /// The statistic that picks λ, when the diagnosis found the other one
    /// predicts held-out headings better than the pipeline's `[solve]`
    /// choice; `None` keeps that choice.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lambda_criterion: Option<Criterion>,
}

impl Extensions {
    /// Plain Tolles-Lawson: nothing added.
    pub fn is_plain(&self) -> bool {
        self == &Extensions::default()
    }

    /// One line for people: what the model adds.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let Some(c) = &self.vector_calibration {
            parts.push(format!("{} calibrated", c.sensor));
        }
        if self.lag_s != 0.0 {
            parts.push(format!("sensor lag {:.3} s", self.lag_s));
        }
        if self.eddy_tau_s > 0.0 {
            parts.push(format!("eddy τ {:.2} s", self.eddy_tau_s));
        }
        if self.second_order {
            parts.push("second-order term".into());
        }
        if let Some(criterion) = self.lambda_criterion {
            parts.push(format!("λ by {}", criterion.describe()));
        }
        for source in &self.sources {
            parts.push(match source {
                SourceTerm::AuxCoupling { column, .. } => format!("coupling to {column}"),
                SourceTerm::AuxCouplingRate { column } => format!("coupling to the rate of {column}"),
                SourceTerm::ExternalField { column, .. } => format!("base station {column}"),
                SourceTerm::CrossSensor {
                    name,
                    survey_gain: Some(gain),
                    ..
                } => format!("cross-sensor signal {name} × {gain:.3} (fitted on the survey)"),
                SourceTerm::CrossSensor { name, .. } => format!("cross-sensor signal {name}"),
            });
        }
        match parts.is_empty() {
            true => "plain Tolles-Lawson".into(),
            false => parts.join(", "),
        }
    }
}

/// Rate of change of a column per second: the central difference
/// $(c_{k+1} - c_{k-1})/(t_{k+1} - t_{k-1})$, one-sided at the ends; a
/// missing neighbour gives a missing rate.
pub fn rate_of_change(values: &[f64], time_s: &[f64]) -> Vec<f64> {
    (0..values.len()).map(|k| rate_at(values, time_s, k)).collect()
}

/// [`rate_of_change`] at row `k` alone.
pub(crate) fn rate_at(values: &[f64], time_s: &[f64], k: usize) -> f64 {
    let n = values.len();
    let (a, b) = (k.saturating_sub(1), (k + 1).min(n.saturating_sub(1)));
    match a == b {
        true => 0.0,
        false => (values[b] - values[a]) / (time_s[b] - time_s[a]),
    }
}

/// Unit field direction per row.
pub fn field_directions(log: &FlightLog, sensor: &VectorSensor) -> [Vec<f64>; 3] {
    let field = log.vector_components(sensor);
    [0, 1, 2].map(|i| {
        (0..log.len())
            .map(|k| field[i][k] / (field[0][k].powi(2) + field[1][k].powi(2) + field[2][k].powi(2)).sqrt())
            .collect()
    })
}

/// The median of a column's finite values (0 when it has none).
pub fn column_level(values: &[f64]) -> f64 {
    let mut finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return 0.0;
    }
    let middle = finite.len() / 2;
    *finite.select_nth_unstable_by(middle, f64::total_cmp).1
}

/// Refits on the scalar less the second-order term after the first fit.
/// The term is a few tenths of a nT against hundreds in the first-order
/// fit, so the aircraft field it is computed from changes by about a part
/// in a thousand a pass: two passes leave it converged.
pub const SECOND_ORDER_PASSES: usize = 2;

/// What the total field adds to the first-order projection, per row:
/// $|B + F| - |B| - u \cdot F$ with $F = P + M B + E \dot B$ from the
/// permanent, induced and eddy coefficients of `terms`
/// ([`TermSet::aircraft_field`], [`TermSet::eddy_tensor`]) and B the
/// vector magnetometer's field ($\dot B$ its per-sample central difference
/// between finite samples, as the eddy terms take it). The term is
/// $|F_\perp|^2 / 2|B|$ to first order: the eddy field's own square is a
/// thousandth of a nT, but its product with the permanent and induced
/// field is not. On a cabin sensor (F of a few hundred nT) in a roll
/// (eddy field of 10-20 nT), it is about 0.1 nT, and it follows the roll
/// rate. `NaN` where B is.
pub fn second_order_term(field: [&[f64]; 3], terms: &TermSet, coefficients: &[f64]) -> Vec<f64> {
    let (permanent, tensor) = terms.aircraft_field(coefficients);
    let eddy = terms.eddy_tensor(coefficients);
    let rates = field.map(rate_between_finite);
    (0..field[0].len())
        .map(|k| {
            let b = [field[0][k], field[1][k], field[2][k]];
            let db = [rates[0][k], rates[1][k], rates[2][k]];
            let total = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
            let f: [f64; 3] = [0, 1, 2].map(|i| {
                permanent[i]
                    + (0..3).map(|j| tensor[i][j] * b[j]).sum::<f64>()
                    + (0..3).map(|j| eddy[i][j] * db[j]).sum::<f64>()
            });
            let along = (b[0] * f[0] + b[1] * f[1] + b[2] * f[2]) / total;
            let across_squared = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2] - along * along).max(0.0);
            // |B + F| − |B| − u·F, written to keep precision: with
            // a = |B| + u·F, |B + F| = √(a² + |F⊥|²), and √(a² + c) − a =
            // c / (√(a² + c) + a).
            let a = total + along;
            across_squared / ((a * a + across_squared).sqrt() + a)
        })
        .collect()
}

/// Per-sample central difference of `values` between finite samples:
/// one-sided beside a missing one, 0 for a sample alone, `NaN` where the
/// value is.
fn rate_between_finite(values: &[f64]) -> Vec<f64> {
    let finite = |k: Option<usize>| k.and_then(|k| values.get(k)).copied().filter(|v| v.is_finite());
    (0..values.len())
        .map(|k| match (finite(k.checked_sub(1)), values[k], finite(Some(k + 1))) {
            (_, v, _) if !v.is_finite() => f64::NAN,
            (Some(before), _, Some(after)) => (after - before) / 2.0,
            (None, v, Some(after)) => after - v,
            (Some(before), v, None) => v - before,
            (None, _, None) => 0.0,
        })
        .collect()
}

/// The scalar read `lag_s` earlier: value at t + lag by linear
/// interpolation; `NaN` where t + lag is outside the record. `time_s`
/// increases strictly, as a flight log's does.
pub fn advanced(values: &[f64], time_s: &[f64], lag_s: f64) -> Vec<f64> {
    let mut column = vec![0.0; values.len()];
    advance_into(values, time_s, lag_s, 0..values.len(), &mut column);
    column
}

/// [`advanced`] on `rows` alone, zero elsewhere; each value is the one
/// the whole column would have.
pub(crate) fn advanced_on(values: &[f64], time_s: &[f64], lag_s: f64, rows: &[std::ops::Range<usize>]) -> Vec<f64> {
    let mut column = vec![0.0; values.len()];
    for range in rows {
        let range = range.start.min(values.len())..range.end.min(values.len());
        advance_into(values, time_s, lag_s, range, &mut column);
    }
    column
}

/// Fills `column` over `rows` with `values` read `lag_s` later.
fn advance_into(values: &[f64], time_s: &[f64], lag_s: f64, rows: std::ops::Range<usize>, column: &mut [f64]) {
    let Some(&first) = time_s.get(rows.start) else {
        return;
    };
    // Time increases strictly, so the first sample at or after t + lag
    // moves only forward: one search for the first row, then one walk.
    let mut upper = time_s.partition_point(|&t| t < first + lag_s);
    for k in rows {
        let at = time_s[k] + lag_s;
        while upper < time_s.len() && time_s[upper] < at {
            upper += 1;
        }
        column[k] = if upper == 0 || upper >= time_s.len() {
            f64::NAN
        } else {
            let (t0, t1) = (time_s[upper - 1], time_s[upper]);
            let weight = (at - t0) / (t1 - t0);
            values[upper - 1] + weight * (values[upper] - values[upper - 1])
        };
    }
}

/// Per-sample central difference of `values` passed through a first-order
/// lag of `tau_s`, $\tau \dot y + y = x$, restarted after every missing
/// sample.
///
/// The lag is discretised for an input that varies linearly between
/// samples (ramp invariance):
/// $y_k = \alpha y_{k-1} + b_0 x_k + b_1 x_{k-1}$ with $\alpha = e^{-\Delta t/\tau}$,
/// $b_0 = 1 - r(1-\alpha)$, $b_1 = r(1-\alpha) - \alpha$, $r = \tau/\Delta t$.
/// Its mean delay is τ, as the continuous lag's is. The simpler
/// $y_k = \alpha y_{k-1} + (1-\alpha) x_k$ delays by only $\tau - \Delta t/2$, so a
/// τ fitted with it comes out half a sample (0.05 s at 10 Hz) too long.
pub(crate) fn lagged_rate(values: &[f64], dt: f64, tau_s: f64) -> Vec<f64> {
    let rate = crate::model::terms::central_difference(values);
    let alpha = (-dt / tau_s).exp();
    let ratio = tau_s / dt;
    let (b0, b1) = (1.0 - ratio * (1.0 - alpha), ratio * (1.0 - alpha) - alpha);
    let mut state = f64::NAN;
    let mut previous = f64::NAN;
    rate.iter()
        .map(|&x| {
            state = if !x.is_finite() {
                f64::NAN
            } else if state.is_finite() {
                alpha * state + b0 * x + b1 * previous
            } else {
                x
            };
            previous = x;
            state
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn advancing_by_a_fraction_of_a_sample_interpolates() {
        let time: Vec<f64> = (0..5).map(|k| k as f64 * 0.1).collect();
        let values: Vec<f64> = time.iter().map(|t| 10.0 * t).collect();
        let read = advanced(&values, &time, 0.025);
        // 10 × (t + 0.025) inside; the last sample has nothing after it.
        for k in 0..4 {
            assert!((read[k] - (10.0 * time[k] + 0.25)).abs() < 1e-12, "{k}: {}", read[k]);
        }
        assert!(read[4].is_nan());
    }

    #[test]
    fn lagged_rate_settles_to_a_constant_rate() {
        // A ramp of 2 per sample: its rate is 2 everywhere, and the lag
        // passes a constant unchanged.
        let ramp: Vec<f64> = (0..50).map(|k| 2.0 * k as f64).collect();
        assert!(lagged_rate(&ramp, 0.1, 0.5).iter().all(|r| (r - 2.0).abs() < 1e-12));
        // After a step in rate to 1 the gap to it closes by e^{−Δt/τ} a sample.
        let bend: Vec<f64> = (0..50).map(|k| if k < 10 { 0.0 } else { (k - 10) as f64 }).collect();
        let lagged = lagged_rate(&bend, 0.1, 0.5);
        let alpha = (-0.2f64).exp();
        for k in 11..30 {
            let ratio = (1.0 - lagged[k + 1]) / (1.0 - lagged[k]);
            assert!((ratio - alpha).abs() < 1e-9, "{k}: {ratio}");
        }
        assert!(
            lagged[9].abs() < 1e-12 && lagged[20] > 0.8 && lagged[20] < 0.9,
            "{}",
            lagged[20]
        );
    }

    /// A rate rising steadily comes out of the lag τ late, as from the
    /// continuous lag: not half a sample early, as a first-order
    /// recursion on the samples alone would give it.
    #[test]
    fn lagged_rate_is_late_by_tau_on_a_ramp() {
        // Values k²/2 have the central difference k inside the record.
        let values: Vec<f64> = (0..400).map(|k| (k * k) as f64 / 2.0).collect();
        for tau_s in [0.15, 0.5, 1.2] {
            let lagged = lagged_rate(&values, 0.1, tau_s);
            for (k, y) in lagged.iter().enumerate().take(398).skip(300) {
                let expected = k as f64 - tau_s / 0.1;
                assert!(
                    (y - expected).abs() < 1e-6,
                    "τ {tau_s} s, sample {k}: {y} against {expected}"
                );
            }
        }
    }

    #[test]
    fn column_level_is_the_median_of_finite_values() {
        assert_eq!(column_level(&[5.0, f64::NAN, 1.0, 3.0]), 3.0);
        assert_eq!(column_level(&[f64::NAN]), 0.0);
    }

    #[test]
    fn second_order_term_is_what_the_total_field_adds_to_the_projection() {
        // A cabin-sized aircraft field: P of 600 nT, a soft-iron tensor of
        // 1e-2 and an eddy tensor of 1e-2 per sample (0.1 s at 10 Hz), in a
        // 52 000 nT field seen at three attitudes.
        let permanent = [420.0, -310.0, 280.0];
        let eddy = [[0.011, -0.006, 0.002], [0.004, -0.009, 0.007], [-0.003, 0.005, 0.008]];
        let tensor = [[0.012, -0.004, 0.003], [-0.004, -0.008, 0.006], [0.003, 0.006, 0.010]];
        let terms = TermSet::magnav();
        let s = terms.bt_scale_nt;
        let mut coefficients = permanent.to_vec();
        for (i, j) in [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)] {
            coefficients.push(if i == j {
                tensor[i][i] * s
            } else {
                2.0 * tensor[i][j] * s
            });
        }
        coefficients.extend((0..9).map(|k| eddy[k / 3][k % 3] * s));
        let fields = [
            [18_000.0, -2_000.0, 48_700.0],
            [-15_500.0, 9_000.0, 48_000.0],
            [3_000.0, 21_000.0, 47_400.0],
        ];
        let field: [Vec<f64>; 3] = [0, 1, 2].map(|i| fields.iter().map(|b| b[i]).collect());
        let term = second_order_term([&field[0], &field[1], &field[2]], &terms, &coefficients);
        let design = terms.design_matrix([&field[0], &field[1], &field[2]], std::slice::from_ref(&(0..3)));
        // The per-sample rate over the run of three: forward, central,
        // backward.
        let rate = |k: usize, j: usize| match k {
            0 => fields[1][j] - fields[0][j],
            1 => (fields[2][j] - fields[0][j]) / 2.0,
            _ => fields[2][j] - fields[1][j],
        };
        for (k, b) in fields.iter().enumerate() {
            let f: Vec<f64> = (0..3)
                .map(|i| {
                    permanent[i]
                        + (0..3).map(|j| tensor[i][j] * b[j]).sum::<f64>()
                        + (0..3).map(|j| eddy[i][j] * rate(k, j)).sum::<f64>()
                })
                .collect();
            let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let total = norm(*b);
            let projection: f64 = (0..3).map(|i| b[i] * f[i]).sum::<f64>() / total;
            // The coefficients reproduce the first-order interference u·F…
            assert!((design.predict_row(k, &coefficients) - projection).abs() < 1e-9);
            // …and the term is the rest of |B + F| − |B| (1e-9 nT: the
            // direct difference loses digits the term keeps).
            let exact = norm([b[0] + f[0], b[1] + f[1], b[2] + f[2]]) - total - projection;
            assert!((term[k] - exact).abs() < 1e-8, "{k}: {} vs {exact}", term[k]);
            // About |F⊥|²/2|B|: tenths of a nT to a few nT here.
            assert!(exact > 0.05 && exact < 20.0, "{exact}");
        }
    }
}
