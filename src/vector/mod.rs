//! Vector compensation: the Earth's field in INS body axes and in
//! north-east-down, from a fluxgate corrected by the twelve-constant model.
//!
//! A fluxgate on an aircraft reads
//!
//! $$ m_i = K\,R_i\,b_i + h, \qquad b_i = F_i\,u, $$
//!
//! with $R_i$ the INS rotation from north-east-down to body axes at row i
//! ($R_i = R_{nb}^\top$, $R_{nb} = R_z(\psi)R_y(\theta)R_x(\phi)$, CONTRACT
//! §1), $b_i$ the Earth's field in north-east-down, K (nine constants) the
//! fluxgate's scale factors, non-orthogonality and mounting rotation
//! together with the aircraft's induced (soft-iron) field, and h (three
//! constants) its offsets together with the aircraft's permanent
//! (hard-iron) field, both in the fluxgate's axes (the deviation model of
//! compass swinging: Bowditch; Gebre-Egziabher et al. 2006 for the
//! magnetometer form).
//!
//! **The Earth's field.** Over a calibration box the field's direction $u$
//! hardly changes (an anomaly of 100 nT turns it by 0.1°), but its size
//! does (diurnal variation, anomalies). So $b_i = F_i u$: the size is the
//! scalar magnetometer's reading $F_i$ on the same row (a compensated
//! channel, so the aircraft's interference is not taken for the Earth's),
//! the direction one unit vector, inclination I (down positive) and
//! declination D (east of north) fitted with K and h. IGRF-14 at the
//! box's mean position and the flight's date gives the starting direction;
//! without a position the start is the best of a 5° grid.
//!
//! **What the data determine.** Tying $|b_i|$ to the scalar fixes the
//! overall scale, which $K b$ alone leaves free ($K/s$, $s\,b$). The
//! mounting rotation between fluxgate and INS axes is part of K and is
//! determined, and so is u, but only through the pitches and rolls: on
//! level flight $R_i = R_z(\psi_i)$ commutes with a rotation about the
//! vertical, so a declination error δ and a fluxgate yawed by −δ read the
//! same. The box's manoeuvres separate them; a box without them leaves
//! the horizontal components uncertain by $F\cos I\,\delta$, which the
//! fit's condition number and held-out residual show.
//!
//! **The fit.** Gauss-Newton on the fourteen parameters (K, h, I, D) with
//! the residuals $K R_i F_i u + h - m_i$ of every component of every
//! calibration row, each step from the R factor of the Jacobian (never its
//! normal equations), halved until the cost falls. K and h start from the
//! linear least-squares fit at the starting direction.
//!
//! **The output.** $\hat b^{body}_i = K^{-1}(m_i - h)$ on every row with a
//! fluxgate reading (no attitude needed), and $\hat b^{NED}_i =
//! R_i^\top \hat b^{body}_i$ where the attitude is recorded too: the
//! latter carries the INS's attitude noise, $F\,\sigma_\theta$ per
//! component (0.005° is 4 nT at 50 000 nT).

use std::ops::Range;

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::Serialize;

use crate::error::{Error, Result};
use crate::flight_log::{AttitudeAngle, ChannelRole, FlightLog, VectorSensor};
use crate::holdout::{distinct_headings, same_heading};
use crate::igrf::{decimal_year, Igrf};
use crate::numerics::linalg::{small_svd, tall_skinny_r};
use crate::windows::CalibrationWindow;

/// `[vector]` settings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VectorOptions {
    /// Compensate the vector whenever the flight has INS attitude and a
    /// calibration box.
    pub enabled: bool,
}

impl Default for VectorOptions {
    fn default() -> Self {
        VectorOptions { enabled: true }
    }
}

/// Most Gauss-Newton iterations.
const MOST_ITERATIONS: usize = 50;

/// The rotation from body axes (forward, right, down) to north-east-down:
/// $R_{nb} = R_z(\psi) R_y(\theta) R_x(\phi)$, yaw ψ clockwise from north,
/// pitch θ nose up, roll φ right wing down (CONTRACT §1).
pub fn body_to_ned(roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> Rotation3<f64> {
    Rotation3::from_euler_angles(roll_deg.to_radians(), pitch_deg.to_radians(), yaw_deg.to_radians())
}

/// Unit vector of inclination `inclination` and declination `declination`
/// (radians) in north-east-down, and its derivatives by each.
fn direction(inclination: f64, declination: f64) -> [Vector3<f64>; 3] {
    let (si, ci) = inclination.sin_cos();
    let (sd, cd) = declination.sin_cos();
    [
        Vector3::new(ci * cd, ci * sd, si),
        Vector3::new(-si * cd, -si * sd, ci),
        Vector3::new(-ci * sd, ci * cd, 0.0),
    ]
}

/// Where the fit's starting direction came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "from", rename_all = "snake_case")]
pub enum FieldStart {
    /// IGRF-14 at the box's mean position.
    Igrf {
        /// Decimal year used (the flight's date, or 2025.0 without one).
        year: f64,
        /// Whether the year is the flight's own date.
        dated: bool,
        /// IGRF inclination, degrees.
        inclination_deg: f64,
        /// IGRF declination, degrees.
        declination_deg: f64,
        /// IGRF total field, nT.
        total_nt: f64,
    },
    /// The best direction of a 5° grid (no position recorded).
    Grid,
}

/// Held-out residual of the model: each heading predicted by a fit on the
/// others.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeldOut {
    /// Headings left out in turn.
    pub headings: usize,
    /// RMS of the predicted less the recorded reading per fluxgate axis, nT.
    pub rms_nt: [f64; 3],
}

/// A fitted twelve-constant model of one fluxgate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VectorModel {
    /// Fluxgate prefix.
    pub sensor: String,
    /// Scalar channel whose reading sets the Earth field's size.
    pub reference: String,
    /// K: fluxgate reading per unit body-axis field (rows: fluxgate axes).
    pub soft_iron: [[f64; 3]; 3],
    /// h: the reading with no Earth field, nT.
    pub hard_iron_nt: [f64; 3],
    /// Fitted inclination of the Earth's field over the box, degrees.
    pub inclination_deg: f64,
    /// Fitted declination, degrees east of north.
    pub declination_deg: f64,
    /// The starting direction.
    pub start: FieldStart,
    /// Calibration rows fitted.
    pub rows: usize,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// σ₁/σ₁₄ of the Jacobian with unit-norm columns.
    pub condition_number: f64,
    /// In-sample RMS residual per fluxgate axis, nT.
    pub residual_rms_nt: [f64; 3],
    /// Held out by heading, with three headings or more.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out: Option<HeldOut>,
}

/// The compensated vector of one fluxgate on every row.
#[derive(Debug, Clone, PartialEq)]
pub struct CompensatedVector {
    /// Fluxgate prefix.
    pub sensor: String,
    /// The Earth's field in INS body axes, nT (`NaN` without a reading).
    pub body_nt: [Vec<f64>; 3],
    /// The Earth's field in north-east-down, nT (`NaN` without a reading
    /// or an attitude).
    pub ned_nt: [Vec<f64>; 3],
}

/// One calibration row: the fluxgate reading, the rotation NED → body and
/// the field's size.
#[derive(Debug, Clone, Copy)]
struct Sample {
    reading: Vector3<f64>,
    ned_to_body: Matrix3<f64>,
    total_nt: f64,
}

/// The INS attitude (roll, pitch, yaw) columns of `log`, degrees.
pub fn attitude(log: &FlightLog) -> Option<[&[f64]; 3]> {
    let angle = |wanted: AttitudeAngle| {
        log.channels()
            .iter()
            .find(|c| c.role == ChannelRole::Attitude(wanted))
            .map(|c| c.values.as_slice())
    };
    Some([
        angle(AttitudeAngle::Roll)?,
        angle(AttitudeAngle::Pitch)?,
        angle(AttitudeAngle::Yaw)?,
    ])
}

/// NED → body rotation of row `i`, when its attitude is recorded.
fn ned_to_body(attitude: &[&[f64]; 3], i: usize) -> Option<Matrix3<f64>> {
    let [roll, pitch, yaw] = attitude.map(|c| c[i]);
    (roll.is_finite() && pitch.is_finite() && yaw.is_finite())
        .then(|| body_to_ned(roll, pitch, yaw).inverse().into_inner())
}

/// Fits the twelve-constant model of `sensor` on the rows of `windows`,
/// the field's size from `reference` (a scalar channel's values on every
/// row of `log`, named `reference_name`).
pub fn fit(
    log: &FlightLog,
    sensor: &VectorSensor,
    windows: &[CalibrationWindow],
    (reference_name, reference): (&str, &[f64]),
) -> Result<VectorModel> {
    let attitude = attitude(log).ok_or_else(|| Error::Vector {
        sensor: sensor.prefix.clone(),
        message: "the flight records no INS attitude (roll, pitch and yaw)".into(),
    })?;
    let rows = window_rows(log, windows);
    let samples = samples(log, sensor, &attitude, reference, rows.iter().cloned());
    let start = start_direction(log, rows.iter().cloned(), &samples);
    let mut model = fit_samples(&samples, &start.0).ok_or_else(|| Error::Vector {
        sensor: sensor.prefix.clone(),
        message: format!(
            "{} calibration rows with a fluxgate reading, an attitude and a '{reference_name}' reading: too few, or the attitudes too alike, to fit twelve constants",
            samples.len()
        ),
    })?;
    model.sensor = sensor.prefix.clone();
    model.reference = reference_name.into();
    model.start = start.1;
    model.held_out = held_out(log, sensor, windows, &attitude, reference, &start.0);
    Ok(model)
}

/// The rows of `log` inside `windows`, in time order.
fn window_rows(log: &FlightLog, windows: &[CalibrationWindow]) -> Vec<Range<usize>> {
    let time = log.time_s();
    windows
        .iter()
        .map(|w| time.partition_point(|t| *t < w.t_start)..time.partition_point(|t| *t <= w.t_end))
        .filter(|r| !r.is_empty())
        .collect()
}

/// The usable samples of `rows`: a full fluxgate reading, an attitude and
/// a positive reference.
fn samples(
    log: &FlightLog,
    sensor: &VectorSensor,
    attitude: &[&[f64]; 3],
    reference: &[f64],
    rows: impl Iterator<Item = Range<usize>>,
) -> Vec<Sample> {
    let field = log.vector_components(sensor);
    rows.flatten()
        .filter_map(|i| {
            let reading = Vector3::new(field[0][i], field[1][i], field[2][i]);
            let total_nt = reference[i];
            if !(reading.iter().all(|v| v.is_finite()) && total_nt.is_finite() && total_nt > 0.0) {
                return None;
            }
            Some(Sample {
                reading,
                ned_to_body: ned_to_body(attitude, i)?,
                total_nt,
            })
        })
        .collect()
}

/// The starting direction (inclination, declination in radians): IGRF-14
/// at the mean position of `rows` when the flight records one, else the
/// best of a 5° grid.
fn start_direction(
    log: &FlightLog,
    rows: impl Iterator<Item = Range<usize>>,
    samples: &[Sample],
) -> ((f64, f64), FieldStart) {
    let column = |names: &[&str]| {
        names
            .iter()
            .find_map(|n| log.channel(n).filter(|c| c.role == ChannelRole::Position))
            .map(|c| c.values.as_slice())
    };
    let (latitude, longitude) = (column(&["lat", "ins_lat"]), column(&["lon", "ins_lon"]));
    let height = column(&["msl", "alt", "utm_z", "ins_alt"]);
    if let (Some(latitude), Some(longitude)) = (latitude, longitude) {
        let (mut sum, mut count) = ([0.0; 3], 0usize);
        for i in rows.flatten() {
            let h = height.map_or(0.0, |h| h[i]);
            if latitude[i].is_finite() && longitude[i].is_finite() && h.is_finite() {
                sum = [sum[0] + latitude[i], sum[1] + longitude[i], sum[2] + h];
                count += 1;
            }
        }
        if count > 0 {
            let [lat, lon, h] = sum.map(|s| s / count as f64);
            let (year, dated) = match log.date() {
                Some(d) => (decimal_year(d.year, d.month, d.day, 43_200.0), true),
                None => (2025.0, false),
            };
            let model = Igrf::fourteenth();
            let (first, last) = model.valid_years();
            let main = model.field(lat, lon, h, year.clamp(first, last));
            let start = FieldStart::Igrf {
                year,
                dated,
                inclination_deg: main.inclination_deg(),
                declination_deg: main.declination_deg(),
                total_nt: main.total_nt(),
            };
            return (
                (main.inclination_deg().to_radians(), main.declination_deg().to_radians()),
                start,
            );
        }
    }
    let mut best = (f64::INFINITY, (0.0, 0.0));
    for i in -17..=17 {
        for d in 0..72 {
            let angles = ((i as f64 * 5.0).to_radians(), (d as f64 * 5.0).to_radians());
            if let Some((_, _, cost)) = linear_fit(samples, direction(angles.0, angles.1)[0]) {
                if cost < best.0 {
                    best = (cost, angles);
                }
            }
        }
    }
    (best.1, FieldStart::Grid)
}

/// K and h by linear least squares at direction `u`, and the cost.
fn linear_fit(samples: &[Sample], u: Vector3<f64>) -> Option<(Matrix3<f64>, Vector3<f64>, f64)> {
    if samples.len() < 8 {
        return None;
    }
    let regressors: [Vec<f64>; 3] = std::array::from_fn(|k| {
        samples
            .iter()
            .map(|s| (s.ned_to_body * u)[k] * s.total_nt)
            .collect()
    });
    let ones = vec![1.0; samples.len()];
    let mut k = Matrix3::zeros();
    let mut h = Vector3::zeros();
    let mut cost = 0.0;
    for j in 0..3 {
        let target: Vec<f64> = samples.iter().map(|s| s.reading[j]).collect();
        let columns = [&regressors[0][..], &regressors[1], &regressors[2], &ones, &target];
        let r = tall_skinny_r(&columns);
        let beta = back_substitute(&r, 4)?;
        for c in 0..3 {
            k[(j, c)] = beta[c];
        }
        h[j] = beta[3];
        cost += r[(4, 4)].powi(2);
    }
    Some((k, h, cost))
}

/// Solves the leading `p`×`p` block of upper-triangular `r` against its
/// column p; `None` when a pivot vanishes.
fn back_substitute(r: &faer::Mat<f64>, p: usize) -> Option<Vec<f64>> {
    let mut x = vec![0.0; p];
    for i in (0..p).rev() {
        let pivot = r[(i, i)];
        if pivot == 0.0 || !pivot.is_finite() {
            return None;
        }
        let sum: f64 = ((i + 1)..p).map(|j| r[(i, j)] * x[j]).sum();
        x[i] = (r[(i, p)] - sum) / pivot;
    }
    Some(x)
}

/// The parameters: K row by row, h, inclination, declination.
#[derive(Debug, Clone, Copy)]
struct Parameters {
    k: Matrix3<f64>,
    h: Vector3<f64>,
    inclination: f64,
    declination: f64,
}

impl Parameters {
    fn step(&self, delta: &[f64], scale: f64) -> Parameters {
        let mut next = *self;
        for j in 0..3 {
            for c in 0..3 {
                next.k[(j, c)] += scale * delta[3 * j + c];
            }
            next.h[j] += scale * delta[9 + j];
        }
        next.inclination += scale * delta[12];
        next.declination += scale * delta[13];
        next
    }

    /// Sum of squared residuals over `samples`.
    fn cost(&self, samples: &[Sample]) -> f64 {
        let u = direction(self.inclination, self.declination)[0];
        samples
            .iter()
            .map(|s| (self.k * (s.ned_to_body * u) * s.total_nt + self.h - s.reading).norm_squared())
            .sum()
    }
}

/// Gauss-Newton from the linear fit at `start`; `None` when the samples
/// cannot determine the parameters.
fn fit_samples(samples: &[Sample], start: &(f64, f64)) -> Option<VectorModel> {
    let (k, h, _) = linear_fit(samples, direction(start.0, start.1)[0])?;
    let mut parameters = Parameters {
        k,
        h,
        inclination: start.0,
        declination: start.1,
    };
    let mut cost = parameters.cost(samples);
    let mut iterations = 0;
    let mut condition_number = f64::INFINITY;
    while iterations < MOST_ITERATIONS {
        iterations += 1;
        let (delta, condition) = gauss_newton_step(samples, &parameters)?;
        condition_number = condition;
        let mut scale = 1.0;
        let mut improved = None;
        for _ in 0..30 {
            let candidate = parameters.step(&delta, scale);
            let candidate_cost = candidate.cost(samples);
            if candidate_cost <= cost {
                improved = Some((candidate, candidate_cost));
                break;
            }
            scale *= 0.5;
        }
        let Some((next, next_cost)) = improved else {
            break;
        };
        let fell = cost - next_cost;
        parameters = next;
        cost = next_cost;
        if fell <= 1e-13 * cost.max(f64::MIN_POSITIVE) {
            break;
        }
    }
    let u = direction(parameters.inclination, parameters.declination)[0];
    let mut squares = [0.0; 3];
    for s in samples {
        let r = parameters.k * (s.ned_to_body * u) * s.total_nt + parameters.h - s.reading;
        for j in 0..3 {
            squares[j] += r[j] * r[j];
        }
    }
    parameters.k.try_inverse()?;
    // Inclination in [-90°, 90°], declination in (-180°, 180°].
    let (mut inclination, mut declination) = (parameters.inclination, parameters.declination);
    if inclination.cos() < 0.0 {
        inclination = std::f64::consts::PI - inclination;
        declination += std::f64::consts::PI;
    }
    inclination = inclination.sin().atan2(inclination.cos().abs());
    declination = declination.sin().atan2(declination.cos());
    Some(VectorModel {
        sensor: String::new(),
        reference: String::new(),
        soft_iron: std::array::from_fn(|j| std::array::from_fn(|c| parameters.k[(j, c)])),
        hard_iron_nt: std::array::from_fn(|j| parameters.h[j]),
        inclination_deg: inclination.to_degrees(),
        declination_deg: declination.to_degrees(),
        start: FieldStart::Grid,
        rows: samples.len(),
        iterations,
        condition_number,
        residual_rms_nt: squares.map(|s| (s / samples.len() as f64).sqrt()),
        held_out: None,
    })
}

/// The Gauss-Newton step minimising $\lVert J\Delta + r\rVert$, from the R
/// factor of $[J \mid -r]$, and the condition number of J with unit-norm
/// columns.
fn gauss_newton_step(samples: &[Sample], parameters: &Parameters) -> Option<(Vec<f64>, f64)> {
    let n = samples.len() * 3;
    let [u, du_di, du_dd] = direction(parameters.inclination, parameters.declination);
    let mut columns: Vec<Vec<f64>> = vec![vec![0.0; n]; 15];
    for (i, s) in samples.iter().enumerate() {
        let body = s.ned_to_body * u * s.total_nt;
        let by_inclination = parameters.k * (s.ned_to_body * du_di) * s.total_nt;
        let by_declination = parameters.k * (s.ned_to_body * du_dd) * s.total_nt;
        let residual = parameters.k * body + parameters.h - s.reading;
        for j in 0..3 {
            let row = 3 * i + j;
            for c in 0..3 {
                columns[3 * j + c][row] = body[c];
            }
            columns[9 + j][row] = 1.0;
            columns[12][row] = by_inclination[j];
            columns[13][row] = by_declination[j];
            columns[14][row] = -residual[j];
        }
    }
    let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
    let r = tall_skinny_r(&views);
    let delta = back_substitute(&r, 14)?;
    let norms: Vec<f64> = (0..14)
        .map(|j| (0..=j).map(|i| r[(i, j)].powi(2)).sum::<f64>().sqrt())
        .collect();
    let scaled = faer::Mat::from_fn(14, 14, |i, j| r[(i, j)] / norms[j]);
    let (_, sigma, _) = small_svd(scaled.as_ref())?;
    let condition = sigma[0] / sigma[13];
    Some((delta, condition))
}

/// Each heading of `windows` predicted by a fit on the others; `None` with
/// fewer than three headings.
fn held_out(
    log: &FlightLog,
    sensor: &VectorSensor,
    windows: &[CalibrationWindow],
    attitude: &[&[f64]; 3],
    reference: &[f64],
    start: &(f64, f64),
) -> Option<HeldOut> {
    if windows.iter().any(|w| w.heading_deg.is_none()) {
        return None;
    }
    let headings = distinct_headings(windows);
    if headings.len() < 3 {
        return None;
    }
    let (mut squares, mut count) = ([0.0; 3], 0usize);
    for &heading in &headings {
        let (held, kept): (Vec<CalibrationWindow>, Vec<CalibrationWindow>) = windows
            .iter()
            .cloned()
            .partition(|w| w.heading_deg.is_some_and(|h| same_heading(h, heading)));
        let training = samples(log, sensor, attitude, reference, window_rows(log, &kept).into_iter());
        let model = fit_samples(&training, start)?;
        let k = Matrix3::from_fn(|j, c| model.soft_iron[j][c]);
        let h = Vector3::from(model.hard_iron_nt);
        let u = direction(model.inclination_deg.to_radians(), model.declination_deg.to_radians())[0];
        for s in samples(log, sensor, attitude, reference, window_rows(log, &held).into_iter()) {
            let r = k * (s.ned_to_body * u) * s.total_nt + h - s.reading;
            for j in 0..3 {
                squares[j] += r[j] * r[j];
            }
            count += 1;
        }
    }
    (count > 0).then(|| HeldOut {
        headings: headings.len(),
        rms_nt: squares.map(|s| (s / count as f64).sqrt()),
    })
}

impl VectorModel {
    /// The Earth's field in body axes and north-east-down on every row of
    /// `log`: $K^{-1}(m_i - h)$, rotated with the INS attitude where it is
    /// recorded.
    pub fn compensate(&self, log: &FlightLog) -> Result<CompensatedVector> {
        let sensor = log.vector_sensor(&self.sensor).ok_or_else(|| Error::Vector {
            sensor: self.sensor.clone(),
            message: "the flight does not record this fluxgate".into(),
        })?;
        let k = Matrix3::from_fn(|j, c| self.soft_iron[j][c]);
        let inverse = k.try_inverse().ok_or_else(|| Error::Vector {
            sensor: self.sensor.clone(),
            message: "the fitted K is singular".into(),
        })?;
        let h = Vector3::from(self.hard_iron_nt);
        let field = log.vector_components(&sensor);
        let attitude = attitude(log);
        let rows = log.len();
        let mut body_nt: [Vec<f64>; 3] = std::array::from_fn(|_| vec![f64::NAN; rows]);
        let mut ned_nt: [Vec<f64>; 3] = std::array::from_fn(|_| vec![f64::NAN; rows]);
        for i in 0..rows {
            let reading = Vector3::new(field[0][i], field[1][i], field[2][i]);
            if !reading.iter().all(|v| v.is_finite()) {
                continue;
            }
            let body = inverse * (reading - h);
            for j in 0..3 {
                body_nt[j][i] = body[j];
            }
            if let Some(to_body) = attitude.as_ref().and_then(|a| ned_to_body(a, i)) {
                let ned = to_body.transpose() * body;
                for j in 0..3 {
                    ned_nt[j][i] = ned[j];
                }
            }
        }
        Ok(CompensatedVector {
            sensor: self.sensor.clone(),
            body_nt,
            ned_nt,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings of a known K, h and field direction over attitudes that
    /// turn through every heading with ±15° of pitch and roll.
    fn synthetic(k: Matrix3<f64>, h: Vector3<f64>, u: Vector3<f64>) -> Vec<Sample> {
        (0..2000)
            .map(|i| {
                let t = i as f64 * 0.1;
                let yaw = t * 1.8;
                let roll = 15.0 * (t * 0.7).sin();
                let pitch = 8.0 * (t * 0.45).cos();
                let total_nt = 52_000.0 + 30.0 * (t * 0.01).sin();
                let ned_to_body = body_to_ned(roll, pitch, yaw).inverse().into_inner();
                Sample {
                    reading: k * (ned_to_body * u) * total_nt + h,
                    ned_to_body,
                    total_nt,
                }
            })
            .collect()
    }

    #[test]
    fn known_constants_and_direction_are_recovered_from_a_distant_start() {
        let k = Matrix3::new(1.03, 0.012, -0.008, 0.004, 0.97, 0.015, -0.011, 0.009, 1.02);
        let h = Vector3::new(950.0, -1200.0, 640.0);
        let (inclination, declination) = (70f64.to_radians(), (-12f64).to_radians());
        let samples = synthetic(k, h, direction(inclination, declination)[0]);
        let model = fit_samples(&samples, &(65f64.to_radians(), (-4f64).to_radians())).unwrap();
        for j in 0..3 {
            for c in 0..3 {
                assert!((model.soft_iron[j][c] - k[(j, c)]).abs() < 1e-9, "{model:?}");
            }
            assert!((model.hard_iron_nt[j] - h[j]).abs() < 1e-5, "{model:?}");
            assert!(model.residual_rms_nt[j] < 1e-6, "{model:?}");
        }
        assert!((model.inclination_deg - 70.0).abs() < 1e-9, "{model:?}");
        assert!((model.declination_deg + 12.0).abs() < 1e-9, "{model:?}");
    }

    #[test]
    fn without_pitch_or_roll_the_declination_is_not_determined() {
        // Level flight: a declination error and a fluxgate yawed the
        // other way read the same, and the Jacobian says so.
        let k = Matrix3::identity();
        let h = Vector3::new(100.0, 0.0, -50.0);
        let u = direction(70f64.to_radians(), 0.0)[0];
        let level: Vec<Sample> = (0..500)
            .map(|i| {
                let yaw = i as f64 * 0.72;
                let ned_to_body = body_to_ned(0.0, 0.0, yaw).inverse().into_inner();
                Sample {
                    reading: k * (ned_to_body * u) * 50_000.0 + h,
                    ned_to_body,
                    total_nt: 50_000.0,
                }
            })
            .collect();
        let parameters = Parameters {
            k,
            h,
            inclination: 70f64.to_radians(),
            declination: 0.0,
        };
        let condition = gauss_newton_step(&level, &parameters).map(|(_, c)| c);
        assert!(condition.is_none_or(|c| c > 1e12), "{condition:?}");
        let turning = synthetic(k, h, u);
        let (_, condition) = gauss_newton_step(&turning, &parameters).unwrap();
        assert!(condition < 1e4, "{condition}");
    }
}
