//! How a fitted model scales a crustal anomaly: the survey's own figure of
//! whether the compensation keeps the geology.
//!
//! A crustal anomaly δ adds to the Earth's field along its direction, so
//! the scalar reads it in full and the vector magnetometer's field becomes
//! $B (1 + δ/|B|)$, its direction unchanged. The compensated value is the
//! scalar less the predicted interference $H(B)$, so it carries the anomaly
//! with the gain
//!
//! $$ g = 1 - \frac{\partial H}{\partial δ}
//!      = 1 - \frac{H_1(B)}{|B|} - \sum_c s_c \, \beta_c \cdot u
//!        - \frac{2\,Q(B)}{|B|} $$
//!
//! where $H_1$ is the part of the Tolles-Lawson prediction built from terms
//! of degree one in the field (induced and eddy forms at the recorded
//! field direction, [`TermSet::field_degrees`]; the permanent terms are
//! direction cosines alone and do not change), $Q$ the second-order term
//! (of degree two, taken numerically), and each coupled source column $c$
//! counts through $s_c = \partial c / \partial δ$, its slope against the
//! channel's recorded total field over the survey lines: zero for a
//! current, one for a column that holds the Earth's field (another
//! aircraft's compensated field given as a channel). A base station's
//! record is subtracted as the Earth's time variation and a lag reads the
//! scalar earlier: neither scales the geology.
//!
//! 1.0 keeps the geology. Plain Tolles-Lawson's two isotropic directions
//! ($|B|$ and $d|B|/dt$) are what scale it most: fitted, they take in the
//! geology of the box (Gnadt 2022 discusses the 18 terms' collinearity).

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::ingest::flight_log::FlightLog;
use crate::model::terms::TermSet;

use super::prepared::scalar_values;
use super::{second_order_term, FittedModel, Prepared, SharedDesign, SourceTerm};

/// A model's gain on a crustal anomaly over the survey's rows.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AnomalyGain {
    /// The median gain over the rows, 1.0 keeping the geology.
    pub median: f64,
    /// The smallest gain of a row.
    pub min: f64,
    /// The largest gain of a row.
    pub max: f64,
    /// Rows the gain was taken over.
    pub rows: usize,
    /// Which rows those are.
    pub over: GainRows,
}

/// Which rows an [`AnomalyGain`] was taken over: the survey's attitudes
/// when the flight has them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GainRows {
    /// The survey lines (a non-zero line number) outside the calibration.
    SurveyLines,
    /// Every row outside the calibration windows (no line numbers).
    OutsideCalibration,
    /// Every row (the flight is all calibration).
    WholeFlight,
}

impl AnomalyGain {
    /// How far the median departs from 1.
    pub fn departure(&self) -> f64 {
        (self.median - 1.0).abs()
    }

    /// "×1.003 (0.998–1.007 over 5,120 survey rows)".
    pub fn describe(&self) -> String {
        let over = match self.over {
            GainRows::SurveyLines => "survey-line rows",
            GainRows::OutsideCalibration => "rows outside the calibration",
            GainRows::WholeFlight => "rows",
        };
        format!(
            "×{:.3} ({:.3}–{:.3} over {} {over})",
            self.median, self.min, self.max, self.rows
        )
    }
}

/// The default tolerance on an anomaly gain: a compensation that scales
/// the geology by more than 2 % either way is not applied silently. The
/// 16 terms kept a real flight's anomalies at 1.000–1.009, MagNav.jl's 18
/// scaled them by 0.45–1.56 (docs/measurements.md).
pub const ANOMALY_GAIN_TOLERANCE: f64 = 0.02;

impl TermSet {
    /// How each term scales with the field's magnitude, in column order:
    /// 0 for the permanent terms and the constant (direction cosines
    /// alone), 1 for the induced, eddy and field-derivative terms (the
    /// field or its rate times cosines).
    pub fn field_degrees(&self) -> Vec<u8> {
        self.names()
            .iter()
            .map(|name| u8::from(!(name.starts_with("perm_") || name == "bias")))
            .collect()
    }

    /// `coefficients` (of these terms first) with every term of degree
    /// zero in the field set to zero: what predicts the part that moves
    /// with the field's magnitude.
    pub fn degree_one_part(&self, coefficients: &[f64]) -> Vec<f64> {
        (self.field_degrees().iter().zip(coefficients))
            .map(|(&degree, &b)| if degree == 1 { b } else { 0.0 })
            .collect()
    }
}

impl FittedModel {
    /// The model's [`AnomalyGain`] on `log`, over its survey rows;
    /// `None` where no row has a finite gain. `shared` holds the
    /// flight's terms when the compensation built them already.
    pub fn anomaly_gain(&self, log: &FlightLog, shared: &[SharedDesign]) -> Result<Option<AnomalyGain>> {
        let (rows, over) = gain_rows(log, self);
        let gains = self.anomaly_gain_at(log, shared, &rows)?;
        Ok(summarise(gains, over))
    }

    /// The gain at each of `rows` of `log` (`NaN` where an input is
    /// missing): what an anomaly there comes out at, as a fraction of it.
    pub fn anomaly_gain_at(&self, log: &FlightLog, shared: &[SharedDesign], rows: &[usize]) -> Result<Vec<f64>> {
        let sensor = self.sensor_in(log)?;
        let prepared = Prepared::new(log, &sensor, &self.channel, &self.spec)?;
        let terms = self.spec.fitted_terms();
        let design = self.terms_design(shared, &prepared.log, &sensor);
        let degree_one = terms.degree_one_part(&self.coefficients);
        let field = prepared.log.vector_components(&sensor);
        let magnitude = |row: usize| field.iter().map(|c| c[row] * c[row]).sum::<f64>().sqrt();
        let extra_part = &self.coefficients[design.columns.len().min(self.coefficients.len())..];
        let extra = ExtraGains::of(&prepared, extra_part, self, log, rows)?;
        let second_order = match self.spec.extensions.second_order {
            true => Some(second_order_rate(field, &terms, &self.coefficients)),
            false => None,
        };
        Ok(rows
            .iter()
            .map(|&row| {
                let b = magnitude(row);
                let induced = design.predict_row(row, &degree_one) + extra.degree_one(row);
                let second = second_order.as_ref().map_or(0.0, |q| q[row]);
                let cosines = [0, 1, 2].map(|i| field[i][row] / b);
                let coupled: f64 = (0..3).map(|i| extra.sources[i] * cosines[i]).sum::<f64>()
                    + (extra.cross.iter())
                        .map(|(rate, k)| rate[row] * (0..3).map(|i| k[i] * cosines[i]).sum::<f64>())
                        .sum::<f64>()
                    + extra.fixed.iter().map(|(rate, g)| rate[row] * g).sum::<f64>();
                1.0 - induced / b - second - coupled
            })
            .collect())
    }
}

/// $\partial Q / \partial δ$ per row: the second-order term with the field
/// scaled by $1 + ε$, less the term, over $ε|B|$.
fn second_order_rate(field: [&[f64]; 3], terms: &TermSet, coefficients: &[f64]) -> Vec<f64> {
    const EPSILON: f64 = 1e-4;
    let scaled: Vec<Vec<f64>> = field
        .iter()
        .map(|c| c.iter().map(|v| v * (1.0 + EPSILON)).collect())
        .collect();
    let raised = second_order_term([&scaled[0], &scaled[1], &scaled[2]], terms, coefficients);
    let term = second_order_term(field, terms, coefficients);
    (0..term.len())
        .map(|k| {
            let b = field.iter().map(|c| c[k] * c[k]).sum::<f64>().sqrt();
            (raised[k] - term[k]) / (EPSILON * b)
        })
        .collect()
}

/// What the extension columns add to the gain: the lagged eddy columns
/// (degree one in the field) and the coupled sources (through their slope
/// against the total field).
struct ExtraGains<'p> {
    /// (column values, coefficient) of the degree-one extension columns.
    degree_one: Vec<(&'p [f64], f64)>,
    /// $\sum_c s_c \beta_c$: the coupled sources' coefficients on
    /// $(c - \bar c) u$, each times its column's slope against the field.
    sources: [f64; 3],
    /// Each cross-sensor signal's rate with the anomaly per row, and its
    /// coefficients on $s\,u$.
    cross: Vec<(Vec<f64>, [f64; 3])>,
    /// Each survey-fitted cross-sensor signal's rate with the anomaly per
    /// row, and its gain.
    fixed: Vec<(Vec<f64>, f64)>,
}

impl<'p> ExtraGains<'p> {
    fn of(
        prepared: &'p Prepared<'_>,
        coefficients: &[f64],
        model: &FittedModel,
        log: &FlightLog,
        rows: &[usize],
    ) -> Result<Self> {
        let mut degree_one = Vec::new();
        let mut columns = prepared.extra.iter().zip(coefficients);
        if model.spec.extensions.eddy_tau_s > 0.0 {
            degree_one.extend(columns.by_ref().take(9).map(|(c, &b)| (c.values.as_slice(), b)));
        }
        let mut sources = [0.0; 3];
        let mut cross = Vec::new();
        let mut fixed = Vec::new();
        let recorded = scalar_values(log, &model.channel)?;
        for source in &model.spec.extensions.sources {
            match source {
                SourceTerm::AuxCoupling { column, .. } => {
                    let three: Vec<f64> = columns.by_ref().take(3).map(|(_, &b)| b).collect();
                    let Some(values) = log.channel(column).map(|c| c.values.as_slice()) else {
                        continue;
                    };
                    let slope = field_slope(values, recorded, rows, log);
                    for (sum, b) in sources.iter_mut().zip(three) {
                        *sum += slope * b;
                    }
                }
                SourceTerm::CrossSensor {
                    signal,
                    survey_gain: Some(gain),
                    ..
                } => fixed.push((signal.anomaly_rate(log)?, *gain)),
                SourceTerm::CrossSensor { signal, .. } => {
                    let three: Vec<f64> = columns.by_ref().take(3).map(|(_, &b)| b).collect();
                    let weights = [0, 1, 2].map(|i| three.get(i).copied().unwrap_or(0.0));
                    cross.push((signal.anomaly_rate(log)?, weights));
                }
                // The rate of a column scales an anomaly's rate, not the
                // anomaly: no gain at the survey's wavelengths.
                SourceTerm::AuxCouplingRate { .. } => columns.by_ref().take(3).for_each(drop),
                SourceTerm::ExternalField { .. } => {}
            }
        }
        Ok(ExtraGains {
            degree_one,
            sources,
            cross,
            fixed,
        })
    }

    fn degree_one(&self, row: usize) -> f64 {
        self.degree_one.iter().map(|(c, b)| c[row] * b).sum()
    }
}

/// The slope of `values` against the channel's recorded total field over
/// `rows`, each survey line's mean removed: how much of the Earth's field
/// the column carries. Zero where either does not vary.
fn field_slope(values: &[f64], recorded: &[f64], rows: &[usize], log: &FlightLog) -> f64 {
    let lines = log.survey_lines();
    let groups: Vec<Vec<usize>> = match lines.is_empty() {
        true => vec![rows.to_vec()],
        false => lines.into_iter().map(|(_, r)| r).collect(),
    };
    let (mut covariance, mut variance) = (0.0, 0.0);
    for group in groups {
        let pairs: Vec<(f64, f64)> = (group.iter())
            .map(|&r| (values[r], recorded[r]))
            .filter(|(v, f)| v.is_finite() && f.is_finite())
            .collect();
        if pairs.len() < 2 {
            continue;
        }
        let n = pairs.len() as f64;
        let (mean_v, mean_f) = pairs.iter().fold((0.0, 0.0), |(a, b), (v, f)| (a + v / n, b + f / n));
        for (v, f) in pairs {
            covariance += (v - mean_v) * (f - mean_f);
            variance += (f - mean_f) * (f - mean_f);
        }
    }
    match variance > 0.0 {
        true => covariance / variance,
        false => 0.0,
    }
}

/// How much of the Earth's field `values` carry: their slope against the
/// total field `recorded` (a scalar's record) over the survey rows outside
/// `windows`, each survey line's mean removed ([`AnomalyGain`]'s source
/// term). Zero where either does not vary.
pub fn survey_field_slope(
    log: &FlightLog,
    (values, recorded): (&[f64], &[f64]),
    windows: &[crate::calibration::windows::CalibrationWindow],
) -> f64 {
    let (rows, _) = rows_outside(log, windows.iter().map(|w| w.rows(log.time_s())));
    field_slope(values, recorded, &rows, log)
}

/// The rows a model's gain is taken over: the survey lines outside its
/// calibration windows, else every row outside them, else every row.
fn gain_rows(log: &FlightLog, model: &FittedModel) -> (Vec<usize>, GainRows) {
    rows_outside(log, model.windows.iter().map(|w| w.window.rows(log.time_s())))
}

/// The survey lines' rows outside `windows` (row ranges), else every row
/// outside them, else every row.
fn rows_outside(log: &FlightLog, windows: impl Iterator<Item = std::ops::Range<usize>>) -> (Vec<usize>, GainRows) {
    let mut calibration = vec![false; log.len()];
    for rows in windows {
        for row in rows {
            calibration[row] = true;
        }
    }
    let survey: Vec<usize> = (log.survey_lines().into_iter())
        .flat_map(|(_, rows)| rows)
        .filter(|&r| !calibration[r])
        .collect();
    if !survey.is_empty() {
        return (survey, GainRows::SurveyLines);
    }
    let outside: Vec<usize> = (0..log.len()).filter(|&r| !calibration[r]).collect();
    match outside.is_empty() {
        false => (outside, GainRows::OutsideCalibration),
        true => ((0..log.len()).collect(), GainRows::WholeFlight),
    }
}

/// Median, minimum and maximum of the finite gains.
fn summarise(gains: Vec<f64>, over: GainRows) -> Option<AnomalyGain> {
    let mut finite: Vec<f64> = gains.into_iter().filter(|g| g.is_finite()).collect();
    if finite.is_empty() {
        return None;
    }
    finite.sort_by(f64::total_cmp);
    let n = finite.len();
    let median = match n % 2 {
        1 => finite[n / 2],
        _ => 0.5 * (finite[n / 2 - 1] + finite[n / 2]),
    };
    Some(AnomalyGain {
        median,
        min: finite[0],
        max: finite[n - 1],
        rows: n,
        over,
    })
}
