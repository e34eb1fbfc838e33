//! Vector Tolles-Lawson: the part of the aircraft's field at the fluxgate
//! that moves with the manoeuvres, per body axis.
//!
//! The twelve-constant model (the parent module) holds the aircraft's
//! permanent field (in h) and its induced field (in K), fitted on the full
//! band where the Earth's field pins them. What it leaves is what follows
//! the rates of the manoeuvres: eddy currents in the skin and frames, a
//! field $E\,\dot b$ with E a 3×3 tensor in seconds (Tolles & Lawson 1950,
//! in vector form), and any induced field the full-band fit took wrongly,
//! seen in the band as $A\,b$. Per body axis c, with $v = K^{-1}(m - h)$
//! the twelve-constant output and $\hat b$ the field the fit expects
//! (reference size, INS attitude, fitted direction; the fluxgate's
//! smoothing kept, its lag left to this stage), the residual
//!
//! $$ r_c = v_c - \hat b_c = \sum_j A_{cj}\, u_j + \sum_j E_{cj}\, \dot v_j / s $$
//!
//! (u the direction of v, s = `bt_scale_nt`) is fitted on band-passed
//! calibration windows by the one fit of every model
//! ([`crate::model::fit`]): the same band-pass, λ by the same criterion,
//! the same diagnostics and jackknife. Three models, one per axis, each a
//! scalar channel `<s>_residual_<c>` of a lean flight whose vector sensor
//! is `v`. The compensated vector is $v_c$ less the predicted $r_c$.
//!
//! The permanent field is not in it: constant in body axes, it vanishes in
//! the band, and h has it. The induced terms in the band correct K only
//! where the manoeuvres show it wrong; their constant part is K's.

use serde::Serialize;

use crate::calibration::headings::{distinct_headings, same_heading};
use crate::calibration::windows::CalibrationWindow;
use crate::error::{Error, Result};
use crate::ingest::flight_log::{Channel, ChannelRole, FlightLog, VectorAxis};
use crate::model::terms::{EddyTerms, InducedTerms, TermSet};
use crate::model::{fit, FitOptions, FittedModel, ModelSpec, WindowFit};
use crate::numerics::stacked::StorePool;

/// The terms of each axis: the direction's three components (induced
/// corrections) and the field's three rates (eddy currents).
pub fn terms() -> TermSet {
    TermSet {
        permanent: false,
        induced: InducedTerms::None,
        eddy: EddyTerms::None,
        field_derivative: true,
        bias: false,
        bt_scale_nt: 50_000.0,
    }
}

/// Body axes, as the output names them.
const AXES: [&str; 3] = ["x", "y", "z"];

/// The fitted vector Tolles-Lawson stage of one fluxgate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VectorTollesLawson {
    /// One model per body axis x, y, z, of the residual on that axis.
    pub components: Vec<FittedModel>,
    /// Band-passed residual RMS over the windows before this stage, per
    /// axis, nT.
    pub band_rms_before_nt: [f64; 3],
    /// The same after, nT.
    pub band_rms_after_nt: [f64; 3],
    /// FOM-like figure per axis: the band-passed residual's peak-to-peak
    /// summed over the windows, before this stage, nT.
    pub fom_before_nt: [f64; 3],
    /// The same after, nT.
    pub fom_after_nt: [f64; 3],
    /// Each heading held out in turn (three or more headings).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out: Option<HeldOutAxes>,
}

/// Per axis, the band-passed residual on a held-out heading without this
/// stage and with it fitted on the other headings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeldOutAxes {
    /// Headings held out in turn.
    pub headings: usize,
    /// RMS without the stage, nT.
    pub before_nt: [f64; 3],
    /// RMS with the stage fitted on the other headings, nT.
    pub after_nt: [f64; 3],
}

/// The lean flight the stage reads: the twelve-constant body vector as
/// vector sensor `<prefix>_body` and each axis's residual as scalar
/// channel `<prefix>_residual_<c>` (`NaN` where no expectation).
fn lean_log(log: &FlightLog, prefix: &str, body: &[Vec<f64>; 3], residual: [Vec<f64>; 3]) -> Result<FlightLog> {
    let axes = [VectorAxis::X, VectorAxis::Y, VectorAxis::Z];
    let mut channels: Vec<Channel> = (0..3)
        .map(|k| Channel {
            name: format!("{prefix}_body_{}", AXES[k]),
            role: ChannelRole::VectorMagnetometer {
                sensor: format!("{prefix}_body"),
                axis: axes[k],
            },
            values: body[k].clone(),
        })
        .collect();
    channels.extend(residual.into_iter().enumerate().map(|(k, values)| Channel {
        name: residual_name(prefix, k),
        role: ChannelRole::ScalarMagnetometer,
        values,
    }));
    log.with_channels(channels)
}

fn residual_name(prefix: &str, axis: usize) -> String {
    format!("{prefix}_residual_{}", AXES[axis])
}

/// Fits the stage of fluxgate `prefix` on `windows`: `body` the
/// twelve-constant output on every row, `expected` the field the fit
/// expects (`NaN` where it has none).
pub fn fit_stage(
    log: &FlightLog,
    prefix: &str,
    (body, expected): (&[Vec<f64>; 3], &[Vec<f64>; 3]),
    windows: &[CalibrationWindow],
    options: &FitOptions,
) -> Result<VectorTollesLawson> {
    let residual: [Vec<f64>; 3] =
        std::array::from_fn(|k| body[k].iter().zip(&expected[k]).map(|(v, b)| v - b).collect());
    let lean = lean_log(log, prefix, body, residual)?;
    let sensor = lean
        .vector_sensor(&format!("{prefix}_body"))
        .ok_or_else(|| Error::Vector {
            sensor: prefix.into(),
            message: "the body vector is not in the lean flight".into(),
        })?;
    let spec = ModelSpec::plain(terms());
    let stores = StorePool::new();
    let components = (0..3)
        .map(|k| {
            fit(
                &lean,
                &sensor,
                &residual_name(prefix, k),
                windows,
                &spec,
                options,
                &stores,
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let figure = |pick: fn(&WindowFit) -> &[f64], summary: fn(&[&[f64]]) -> f64| -> [f64; 3] {
        std::array::from_fn(|k| {
            let parts: Vec<&[f64]> = components[k].windows.iter().map(pick).collect();
            summary(&parts)
        })
    };
    fn before(w: &WindowFit) -> &[f64] {
        &w.band_before_nt
    }
    fn after(w: &WindowFit) -> &[f64] {
        &w.band_after_nt
    }
    let held_out = held_out(&lean, (&sensor, prefix), windows, (&spec, options))?;
    Ok(VectorTollesLawson {
        band_rms_before_nt: figure(before, rms),
        band_rms_after_nt: figure(after, rms),
        fom_before_nt: figure(before, peak_to_peaks),
        fom_after_nt: figure(after, peak_to_peaks),
        held_out,
        components,
    })
}

/// RMS over every value of `parts`.
fn rms(parts: &[&[f64]]) -> f64 {
    let (sum, count) = parts
        .iter()
        .flat_map(|p| p.iter())
        .fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    (sum / count.max(1) as f64).sqrt()
}

/// The peak-to-peaks of `parts`, summed.
fn peak_to_peaks(parts: &[&[f64]]) -> f64 {
    parts
        .iter()
        .filter(|p| !p.is_empty())
        .map(|p| {
            let (low, high) = p
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
            high - low
        })
        .sum()
}

/// Each heading held out in turn: the stage fitted on the others and its
/// band-passed residual on it, against the residual without the stage.
/// `None` with fewer than three headings or a window without one.
fn held_out(
    lean: &FlightLog,
    (sensor, prefix): (&crate::ingest::flight_log::VectorSensor, &str),
    windows: &[CalibrationWindow],
    (spec, options): (&ModelSpec, &FitOptions),
) -> Result<Option<HeldOutAxes>> {
    if windows.iter().any(|w| w.heading_deg.is_none()) {
        return Ok(None);
    }
    let headings = distinct_headings(windows);
    if headings.len() < 3 {
        return Ok(None);
    }
    let stores = StorePool::new();
    let mut sums = [[0.0f64; 2]; 3];
    let mut count = [0usize; 3];
    for &heading in &headings {
        let (held, kept): (Vec<CalibrationWindow>, Vec<CalibrationWindow>) = windows
            .iter()
            .cloned()
            .partition(|w| w.heading_deg.is_some_and(|h| same_heading(h, heading)));
        for k in 0..3 {
            let model = fit(lean, sensor, &residual_name(prefix, k), &kept, spec, options, &stores)?;
            for window in model.held_out(lean, sensor, &held, options)? {
                for (b, a) in window.band_before_nt.iter().zip(&window.band_after_nt) {
                    sums[k][0] += b * b;
                    sums[k][1] += a * a;
                    count[k] += 1;
                }
            }
        }
    }
    Ok(Some(HeldOutAxes {
        headings: headings.len(),
        before_nt: std::array::from_fn(|k| (sums[k][0] / count[k].max(1) as f64).sqrt()),
        after_nt: std::array::from_fn(|k| (sums[k][1] / count[k].max(1) as f64).sqrt()),
    }))
}

impl VectorTollesLawson {
    /// `body` (the twelve-constant output of fluxgate `prefix` on every row
    /// of `log`) less each axis's predicted residual, where predicted.
    pub fn apply(&self, log: &FlightLog, prefix: &str, body: &mut [Vec<f64>; 3]) -> Result<()> {
        apply_components(&self.components, log, prefix, body)
    }
}

/// [`VectorTollesLawson::apply`] with its models of each body axis,
/// `components` (a model saved from another flight holds them).
pub(crate) fn apply_components(
    components: &[FittedModel],
    log: &FlightLog,
    prefix: &str,
    body: &mut [Vec<f64>; 3],
) -> Result<()> {
    let empty = || vec![f64::NAN; log.len()];
    let lean = lean_log(log, prefix, body, [empty(), empty(), empty()])?;
    for (k, model) in components.iter().enumerate() {
        let prediction = model.predict(&lean)?;
        for (value, h) in body[k].iter_mut().zip(&prediction.interference_nt) {
            if h.is_finite() {
                *value -= h;
            }
        }
    }
    Ok(())
}
