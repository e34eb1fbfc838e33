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
//! scalar magnetometer's reading $F_i$ on the same row, less the
//! Tolles-Lawson interference so the aircraft's field is not taken for
//! the Earth's (the whole interference where its terms pin its mean, else
//! its variation about the recorded reading's mean over the box;
//! [`Reference::levelled`]: the scalar's level error is the vector's
//! scale error, stated by [`Reference::level_sigma_nt`]), the direction one unit vector, inclination I (down positive) and
//! declination D (east of north) fitted with K and h. IGRF-14 at the
//! box's mean position and the flight's date gives the starting direction;
//! without a position it is IGRF-14 at the `[site]` of pipeline.toml, and
//! without one the best of a 5° grid.
//!
//! **The field's sign.** K is any 3×3 matrix, so the fluxgate may sit any
//! way round (axes permuted, reversed, turned): the linear fit at the
//! start takes the mounting into K before Gauss-Newton refines it, and
//! [`Mounting`] reads it back off K. But then $K u$ and $(-K)(-u)$ read
//! alike, and the data cannot tell the field pointing down and north from
//! the field pointing up and south. IGRF-14's direction chooses where
//! there is a position; without one the fit takes the sign that makes the
//! fluxgate's axes right-handed and says the direction is unverified
//! ([`FieldSign`]).
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
//! **The fit.** Gauss-Newton on sixteen parameters (K, h, I, D, and the
//! fluxgate's lag τ and smoothing s against the INS) with the residuals
//! $K (b_i - τ\,\Delta b_i + s\,\Delta^2 b_i) + h - m_i$, $b_i = R_i F_i u$,
//! of every component of every calibration row, each step from the R
//! factor of the Jacobian (never its normal equations), halved until the
//! cost falls, the rows Huber-weighted. K and h start from the linear
//! least-squares fit at the starting direction. The differences leave out
//! the row's own attitude, whose noise would otherwise bias the fit (see
//! `differences`).
//!
//! **The output.** $\hat b^{body}_i = K^{-1}(m_i - h)$ on every row with a
//! fluxgate reading (no attitude needed), and $\hat b^{NED}_i =
//! R_i^\top \hat b^{body}_i$ where the attitude is recorded too: the
//! latter carries the INS's attitude noise, $F\,\sigma_\theta$ per
//! component (0.005° is 4 nT at 50 000 nT).

use std::ops::Range;

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use crate::calibration::headings::{distinct_headings, same_heading};
use crate::calibration::windows::CalibrationWindow;
use crate::error::{Error, Result};
use crate::ingest::flight_log::{ChannelRole, FlightLog, VectorSensor};
use crate::model::igrf::{decimal_year, Igrf};
use crate::numerics::linalg::{small_svd, tall_skinny_r, tall_skinny_r_of};

pub mod tolles_lawson;

pub use tolles_lawson::VectorTollesLawson;

/// `[vector]` settings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VectorOptions {
    /// Compensate the vector of every fluxgate when the flight has INS
    /// attitude and a calibration box (`[vector] enabled`, on by default).
    pub enabled: bool,
    /// Fit the vector Tolles-Lawson stage ([`tolles_lawson`]) after the
    /// twelve constants (`[vector] tolles_lawson`, on by default).
    pub tolles_lawson: bool,
    /// Where the survey was flown, for flights without a position
    /// (`[site]`; none by default).
    pub site: Option<Site>,
}

impl Default for VectorOptions {
    /// On: its survey-line accuracy is shown on flight plans drawn at
    /// random in `tests/vector.rs`.
    fn default() -> Self {
        VectorOptions {
            enabled: true,
            tolles_lawson: true,
            site: None,
        }
    }
}

/// Most Gauss-Newton iterations.
const MOST_ITERATIONS: usize = 50;

pub use crate::ingest::flight_log::body_to_ned;

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
    /// IGRF-14 at the box's mean position, or at the `[site]` when the
    /// flight records none.
    Igrf {
        /// Whether the position is the flight's own or the `[site]`'s.
        position: PositionSource,
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
    /// The best direction of a 5° grid (no position recorded, no
    /// `[site]`).
    Grid,
}

impl FieldStart {
    /// IGRF-14's unit direction of the field (north, east, down), when the
    /// fit started from it.
    fn igrf_direction(&self) -> Option<Vector3<f64>> {
        match *self {
            FieldStart::Igrf {
                inclination_deg,
                declination_deg,
                ..
            } => Some(direction(inclination_deg.to_radians(), declination_deg.to_radians())[0]),
            FieldStart::Grid => None,
        }
    }
}

/// Where the position IGRF-14 is evaluated at came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PositionSource {
    /// The flight's position columns on the box's rows.
    Recorded,
    /// `[site]` in pipeline.toml (the flight records no position).
    Site,
}

/// `[site]`: where and when the survey was flown, for a flight whose file
/// records no position (or no date). The vector stage takes IGRF-14's
/// field direction there to choose the field's sign and to check the fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Site {
    /// Geodetic latitude, degrees north.
    pub latitude_deg: f64,
    /// Longitude, degrees east.
    pub longitude_deg: f64,
    /// Height above mean sea level, m.
    pub height_m: f64,
    /// The survey's date, used when the flight has none of its own.
    pub date: Option<crate::ingest::flight_date::FlightDate>,
}

/// How the fit chose the sign of the Earth field's direction.
///
/// The twelve constants determine the field's direction only up to its
/// sign: $K R_i F_i u = (-K) R_i F_i (-u)$ on every row, so a fluxgate
/// whose three axes all read reversed, under a field pointing up and
/// south, records exactly what the true one does. Something outside the
/// data has to choose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FieldSign {
    /// The sign nearer IGRF-14's direction (position recorded or `[site]`).
    Igrf,
    /// No position: the sign that makes the fluxgate's axes right-handed
    /// (det K > 0), as a three-axis fluxgate's are; unverified.
    RightHandedAxes,
}

/// How the fluxgate sits against the INS body axes, read off the fitted K:
/// the rotation nearest K (its polar factor), the body axis nearest each
/// fluxgate axis, and how far the fluxgate is turned from those axes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Mounting {
    /// The body axis (forward x, right y, down z) each fluxgate axis x, y,
    /// z reads nearest along, with its sign, e.g. `["-z", "+x", "-y"]`.
    pub axes: [String; 3],
    /// The angle between those body axes and the fluxgate's own, degrees:
    /// a mounting misalignment (no turn is more than about 63° from the
    /// nearest axes).
    pub misalignment_deg: f64,
    /// Whether the fluxgate's axes are right-handed (det K > 0). A
    /// left-handed triad under a field whose sign IGRF fixes means an axis
    /// reads reversed (wiring, or a sign in the file).
    pub right_handed: bool,
}

impl Mounting {
    /// The mounting K describes (rows: fluxgate axes, columns: body axes).
    fn of(k: &Matrix3<f64>) -> Mounting {
        let right_handed = k.determinant() > 0.0;
        let svd = k.svd(true, true);
        let rotation = match (svd.u, svd.v_t) {
            (Some(u), Some(v_t)) => u * v_t,
            _ => Matrix3::identity(),
        };
        // The signed permutation nearest the rotation: the assignment of
        // body axes to fluxgate axes with the largest summed |cosines|.
        const ORDERS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
        let score = |order: &[usize; 3]| (0..3).map(|j| rotation[(j, order[j])].abs()).sum::<f64>();
        let order = ORDERS
            .iter()
            .copied()
            .max_by(|a, b| score(a).total_cmp(&score(b)))
            .unwrap_or([0, 1, 2]);
        let mut nearest = Matrix3::zeros();
        let axes = std::array::from_fn(|j| {
            let sign = if rotation[(j, order[j])] < 0.0 { -1.0 } else { 1.0 };
            nearest[(j, order[j])] = sign;
            format!("{}{}", if sign < 0.0 { '-' } else { '+' }, ['x', 'y', 'z'][order[j]])
        });
        // The turn between the permuted body axes and the fluxgate's; a
        // reflection left in (signs read off a turn near 45°) is taken out.
        let turn = nearest.transpose() * rotation;
        let turn = if turn.determinant() < 0.0 { -turn } else { turn };
        let misalignment_deg = ((turn.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
        Mounting {
            axes,
            misalignment_deg,
            right_handed,
        }
    }

    /// `-z, +x, -y` (turned 45.0°), for notes.
    pub fn describe(&self) -> String {
        format!(
            "fluxgate axes along body {} (turned {:.1}° from them{})",
            self.axes.join(", "),
            self.misalignment_deg,
            if self.right_handed { "" } else { "; left-handed" }
        )
    }
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

/// How surely the vector's reference level is known: what no manoeuvre
/// pins scales the vector, so it is its uncertainty along the field.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ReferenceLevel {
    /// Whether the level is the reference's reading less its whole
    /// modelled interference (its terms pin the mean), not its recorded
    /// mean over the box ([`Reference::levelled`]).
    pub pinned: bool,
    /// One sigma of the level, nT, where it is pinned: the aircraft's
    /// isotropic induced field at the sensor, which no manoeuvre shows
    /// ([`Reference::level_sigma_nt`]).
    pub sigma_nt: Option<f64>,
    /// That sigma per body-axis component over the flight, nT: times the
    /// RMS of the component's share of the field.
    pub component_sigma_nt: Option<[f64; 3]>,
}

/// A fitted twelve-constant model of one fluxgate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VectorModel {
    /// Fluxgate prefix.
    pub sensor: String,
    /// Scalar channel whose reading sets the Earth field's size.
    pub reference: String,
    /// The reference's modelled interference over the box, RMS about its
    /// mean, nT (see [`Reference::swing_nt`]).
    pub reference_swing_nt: f64,
    /// How surely the reference's level is known.
    pub reference_level: ReferenceLevel,
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
    /// How the field's sign was chosen.
    pub field_sign: FieldSign,
    /// How the fluxgate sits against the INS body axes.
    pub mounting: Mounting,
    /// Calibration rows fitted.
    pub rows: usize,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// σ₁/σ₁₆ of the Jacobian with unit-norm columns.
    pub condition_number: f64,
    /// In-sample RMS residual per fluxgate axis, nT.
    pub residual_rms_nt: [f64; 3],
    /// The fluxgate's lag behind the INS attitude, in sample intervals.
    pub fluxgate_lag_samples: f64,
    /// The fluxgate's smoothing against the INS, in units of the second
    /// difference (1/24 ≈ 0.042: averaging over one sample interval).
    pub fluxgate_smoothing: f64,
    /// Held out by heading, with three headings or more.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out: Option<HeldOut>,
    /// The vector Tolles-Lawson stage, when fitted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tolles_lawson: Option<VectorTollesLawson>,
    /// What went wrong with the vector Tolles-Lawson stage, when asked
    /// for: not fitted, or fitted without refitting the constants.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tolles_lawson_warning: Option<String>,
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

/// What one row says of the Earth's field: the rotation NED → body, the
/// field's size, and IGRF's turn of its direction across the box (its
/// unit direction here less its mean over the box, about 0.01° a km,
/// added to the fitted direction).
#[derive(Debug, Clone, Copy)]
struct Point {
    ned_to_body: Matrix3<f64>,
    total_nt: f64,
    turn: Vector3<f64>,
}

impl Point {
    /// The Earth's field here in body axes for box direction `u`.
    fn body(&self, u: &Vector3<f64>) -> Vector3<f64> {
        self.ned_to_body * ((u + self.turn).normalize() * self.total_nt)
    }
}

/// One calibration row with its neighbours: the fluxgate reading and the
/// field at the two rows before it, at it and at the two after.
#[derive(Debug, Clone, Copy)]
struct Sample {
    reading: Vector3<f64>,
    points: [Point; 5],
}

impl Sample {
    /// The body-axis field the fluxgate reads for direction `u`: the
    /// field at the row's instant, `lag` samples late and smoothed by
    /// `smoothing` times its second difference (see [`differences`]).
    fn body(&self, u: &Vector3<f64>, lag: f64, smoothing: f64) -> Vector3<f64> {
        let [first, second, at] = differences(self.points.map(|p| p.body(u)));
        at - lag * first + smoothing * second
    }
}

/// The first and second differences of the field at a row (per sample
/// interval) and the field itself, from the field at rows i−2 … i+2.
///
/// A timing offset between fluxgate and INS is a lag times the first
/// difference; a fluxgate that averages over its interval, read against
/// an INS that samples an instant, is smoothed by 1/24 of the second (the
/// boxcar's second-order term). Neither difference uses the row's own
/// attitude: $(f_{+1} - f_{-1})/2$ and $(f_{+2} - f_{+1} - f_{-1} +
/// f_{-2})/3$ (both exact to second order). The usual $f_{+1} - 2f_0 +
/// f_{-1}$ holds −2 times the row's own attitude noise, which the fit
/// then uses to average that noise: the smoothing goes to about 1/3 and
/// the fitted inclination 0.01° off (10 nT on the survey) for any attitude
/// noise above 0.001°.
fn differences([far_before, before, at, after, far_after]: [Vector3<f64>; 5]) -> [Vector3<f64>; 3] {
    [
        (after - before) * 0.5,
        (far_after - after - before + far_before) / 3.0,
        at,
    ]
}

/// NED → body rotation of row `i`, when its attitude is recorded.
fn ned_to_body(attitude: &[&[f64]; 3], i: usize) -> Option<Matrix3<f64>> {
    let [roll, pitch, yaw] = attitude.map(|c| c[i]);
    (roll.is_finite() && pitch.is_finite() && yaw.is_finite())
        .then(|| body_to_ned(roll, pitch, yaw).inverse().into_inner())
}

/// Fits the twelve-constant model of `sensor` on the rows of `windows`
/// and of the box `spans` (start, end; the whole box, its turns
/// included), the field's size from `reference`. Each heading of
/// `windows` is held out in turn for the held-out residual.
///
/// The turns between a box's legs matter: a steady bank of 20° or more
/// for half a minute pins the field's inclination and declination, which
/// the manoeuvres' fast, small swings pin less well (a fluxgate averages
/// over its sample interval while an INS samples an instant, a mismatch
/// that grows with the manoeuvre's rate).
pub fn fit(
    log: &FlightLog,
    sensor: &VectorSensor,
    (windows, spans): (&[CalibrationWindow], &[(f64, f64)]),
    reference: &Reference,
    (site, tolles_lawson): (Option<&Site>, Option<&crate::model::FitOptions>),
) -> Result<VectorModel> {
    let (reference_name, reference_nt) = (&reference.channel, reference.total_nt.as_slice());
    let attitude = log.attitude().ok_or_else(|| Error::Vector {
        sensor: sensor.prefix.clone(),
        message: "the flight records no INS attitude (roll, pitch and yaw)".into(),
    })?;
    let rows = union(window_rows(log, &spanned(windows, spans)));
    let (angles, start, turns) = start_direction(log, sensor, &rows, (&attitude, reference_nt), site);
    let igrf = start.igrf_direction();
    let readings = log.vector_components(sensor);
    let inputs = (&attitude, reference_nt, &turns, readings);
    let calibration = samples(log, inputs, rows.iter().cloned());
    // The fit on every heading and the held-out fits (each heading on the
    // others) are independent: side by side.
    let (model, held) = rayon::join(
        || fit_samples(&calibration, &angles),
        || held_out(log, windows, inputs, &angles),
    );
    let named = (sensor.prefix.clone(), reference_name.clone(), reference.swing_nt);
    let fitted = model.ok_or_else(|| too_few_rows(sensor, reference_name, calibration.len()))?;
    let mut model = fitted.identified(igrf, named, (start, held));
    let Some(options) = tolles_lawson else {
        return Ok(model);
    };
    // The eddy field biases the twelve constants (it is large where the
    // manoeuvres turn fastest): the stage fitted on the first constants'
    // output, its field taken from the readings, the constants refitted on
    // what remains, and the stage fitted again on the new constants'
    // output of the recorded readings.
    let stage = |model: &VectorModel, body: &[Vec<f64>; 3]| -> Result<VectorTollesLawson> {
        let expected = model.expected_body(log, inputs, windows);
        tolles_lawson::fit_stage(log, &sensor.prefix, (body, &expected), windows, options)
    };
    let no_stage = |e: Error| format!("no stage (the eddy currents' field is left in the vector): {e}");
    let raw = twelve_constant_body(log, &model.sensor, (&model.soft_iron, &model.hard_iron_nt))?;
    let first = match stage(&model, &raw) {
        Ok(first) => first,
        Err(e) => {
            model.tolles_lawson_warning = Some(no_stage(e));
            return Ok(model);
        }
    };
    let mut body = raw.clone();
    first.apply(log, &sensor.prefix, &mut body)?;
    let corrected = without_eddy_field(readings, &model.soft_iron, (&raw, &body));
    let corrected_inputs = (&attitude, reference_nt, &turns, corrected.each_ref().map(Vec::as_slice));
    match fit_samples(&samples(log, corrected_inputs, rows.iter().cloned()), &angles) {
        Some(refitted) => {
            let named = (model.sensor, model.reference, model.reference_swing_nt);
            let held = held_out(log, windows, corrected_inputs, &angles);
            model = refitted.identified(igrf, named, (model.start, held));
        }
        None => {
            model.tolles_lawson_warning = Some(NOT_REFITTED.into());
            model.tolles_lawson = Some(first);
            return Ok(model);
        }
    }
    let body = twelve_constant_body(log, &model.sensor, (&model.soft_iron, &model.hard_iron_nt))?;
    match stage(&model, &body) {
        Ok(second) => model.tolles_lawson = Some(second),
        Err(e) => model.tolles_lawson_warning = Some(no_stage(e)),
    }
    Ok(model)
}

/// The fluxgate's `readings` less the eddy currents' field the vector
/// Tolles-Lawson stage took out of the twelve constants' output (`raw`
/// before the stage, `body` after it), brought back into the fluxgate's
/// axes by the soft-iron matrix.
fn without_eddy_field(
    readings: [&[f64]; 3],
    soft_iron: &[[f64; 3]; 3],
    (raw, body): (&[Vec<f64>; 3], &[Vec<f64>; 3]),
) -> [Vec<f64>; 3] {
    let k = Matrix3::from_fn(|j, c| soft_iron[j][c]);
    let mut corrected: [Vec<f64>; 3] = readings.map(<[f64]>::to_vec);
    for i in 0..corrected[0].len() {
        let eddy = k * Vector3::new(raw[0][i] - body[0][i], raw[1][i] - body[1][i], raw[2][i] - body[2][i]);
        for j in 0..3 {
            corrected[j][i] -= eddy[j];
        }
    }
    corrected
}

/// The error for a fluxgate whose `rows` calibration samples cannot fit
/// the twelve constants against the `reference` channel.
fn too_few_rows(sensor: &VectorSensor, reference: &str, rows: usize) -> Error {
    Error::Vector {
        sensor: sensor.prefix.clone(),
        message: format!(
            "{rows} calibration rows with a fluxgate reading, an attitude and a '{reference}' reading: too few, or the attitudes too alike, to fit twelve constants"
        ),
    }
}

/// The vector Tolles-Lawson stage's warning when the twelve constants
/// cannot be refitted on the readings without the eddy currents' field.
const NOT_REFITTED: &str = "the twelve constants could not be refitted without the eddy currents' field, so they keep its bias; the stage is the first fit's";

/// The Earth field's size on every row, from one scalar channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// The scalar channel.
    pub channel: String,
    /// The field's size on every row of the flight, nT.
    pub total_nt: Vec<f64>,
    /// The channel's modelled interference over the box, RMS about its
    /// mean, nT: how strongly the aircraft's field reaches the sensor.
    /// It ranks the channels (the least disturbed is the surest level);
    /// it does not bound the level's error, which the aircraft's
    /// permanent field seen steadily in level flight can exceed.
    pub swing_nt: f64,
    /// Whether the level is the reading less the whole modelled
    /// interference (the channel's terms pin its mean), not the reading's
    /// own mean over the box.
    pub pinned: bool,
    /// One sigma of the level where it is pinned, nT
    /// ([`Reference::level_sigma_nt`]); `None` otherwise.
    pub level_sigma_nt: Option<f64>,
}

impl Reference {
    /// The field's size from scalar channel `channel`: its reading
    /// `recorded` less the modelled interference's variation, the level
    /// kept at the recorded reading's mean over the box (`windows` and
    /// `spans`).
    ///
    /// Tying $|b_i|$ to a scalar fixes the vector's scale, so an error δ
    /// in the scalar's level over the box is an error $δ\,b_k/F$ on each
    /// component $b_k$ of the vector. The band-passed Tolles-Lawson fit
    /// does not fix that level: its induced terms sum to a constant
    /// ($\cos^2X + \cos^2Y + \cos^2Z = 1$), so the modelled
    /// interference's mean is free by a few nT to hundreds. The recorded
    /// reading's mean over the box is wrong only by the aircraft's mean
    /// field at the sensor (a few nT at a tail stinger), which no
    /// calibration manoeuvre pins. `None` when no box row has both a
    /// reading and an interference.
    ///
    /// Where the channel's terms hold no isotropic direction (`pinned`:
    /// the default's 16, whose induced part is traceless), the modelled
    /// interference's mean is pinned too: the permanent field's and the
    /// anisotropic induced field's means follow from how they vary with
    /// the attitude. The level is then the reading less the whole
    /// modelled interference, wrong only by the aircraft's isotropic
    /// induced field at the sensor, a multiple of the Earth's field that
    /// no attitude shows ([`Reference::level_sigma_nt`] states its size).
    pub fn levelled(
        log: &FlightLog,
        (channel, pinned): (&str, bool),
        (recorded, interference): (&[f64], &[f64]),
        (windows, spans): (&[CalibrationWindow], &[(f64, f64)]),
    ) -> Option<Reference> {
        let rows = union(window_rows(log, &spanned(windows, spans)));
        let boxed: Vec<f64> = rows
            .into_iter()
            .flatten()
            .filter(|&i| recorded[i].is_finite() && interference[i].is_finite())
            .map(|i| interference[i])
            .collect();
        if boxed.is_empty() {
            return None;
        }
        let count = boxed.len() as f64;
        let mean = boxed.iter().sum::<f64>() / count;
        let swing_nt = (boxed.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / count).sqrt();
        let kept = if pinned { 0.0 } else { mean };
        Some(Reference {
            channel: channel.into(),
            total_nt: recorded.iter().zip(interference).map(|(m, h)| m - (h - kept)).collect(),
            swing_nt,
            pinned,
            level_sigma_nt: None,
        })
    }

    /// One sigma of a pinned level, nT: the aircraft's isotropic induced
    /// field at the sensor, $m F$ with $m$ a third of the induced tensor's
    /// trace, which no attitude shows. What the fit does show is the
    /// tensor's traceless part $T$; an induced tensor with no preferred
    /// axis has $E[m^2] = E\,\|T\|_F^2 / 8$ (a symmetric tensor of
    /// independent entries of one size σ: its trace over three has
    /// variance σ²/3, its traceless part a squared norm of 8σ²/3), so the
    /// level's sigma is $F \|T\|_F / \sqrt 8$. `induced` is the fitted
    /// tensor (nT per nT), `field_nt` the field's size.
    pub fn level_sigma_nt(induced: &[[f64; 3]; 3], field_nt: f64) -> f64 {
        let trace = (induced[0][0] + induced[1][1] + induced[2][2]) / 3.0;
        let traceless: f64 = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| (induced[i][j] - if i == j { trace } else { 0.0 }).powi(2))
            .sum();
        field_nt * (traceless / 8.0).sqrt()
    }
}

/// `windows` and the box `spans` as one list of windows.
fn spanned(windows: &[CalibrationWindow], spans: &[(f64, f64)]) -> Vec<CalibrationWindow> {
    let mut spanned: Vec<CalibrationWindow> = windows.to_vec();
    spanned.extend(spans.iter().map(|&(t0, t1)| CalibrationWindow::new(t0, t1)));
    spanned
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

/// `ranges` merged where they overlap or touch, in order.
fn union(mut ranges: Vec<Range<usize>>) -> Vec<Range<usize>> {
    ranges.sort_by_key(|r| (r.start, r.end));
    let mut merged: Vec<Range<usize>> = Vec::new();
    for range in ranges {
        match merged.last_mut() {
            Some(last) if range.start <= last.end => last.end = last.end.max(range.end),
            _ => merged.push(range),
        }
    }
    merged
}

/// What a row's sample is built from: the INS attitude (roll, pitch, yaw),
/// the reference's size, IGRF's turn across the box, and the fluxgate
/// readings (x, y, z) fitted.
type Inputs<'a> = (&'a [&'a [f64]; 3], &'a [f64], &'a Turns, [&'a [f64]; 3]);

/// The usable samples of `rows`: a full fluxgate reading, an attitude and
/// a positive reference.
fn samples(log: &FlightLog, inputs: Inputs, rows: impl Iterator<Item = Range<usize>>) -> Vec<Sample> {
    indexed_samples(log, inputs, rows).into_iter().map(|(_, s)| s).collect()
}

/// [`samples`] with the row of each.
fn indexed_samples(
    log: &FlightLog,
    (attitude, reference, turns, field): Inputs,
    rows: impl Iterator<Item = Range<usize>>,
) -> Vec<(usize, Sample)> {
    let time = log.time_s();
    let step = log.median_interval_s();
    let point = |i: usize| {
        let total_nt = reference[i];
        (total_nt.is_finite() && total_nt > 0.0).then_some(())?;
        Some(Point {
            ned_to_body: ned_to_body(attitude, i)?,
            total_nt,
            turn: turns.at(i),
        })
    };
    // A row needs two neighbours each side, one sample interval apart.
    let even = |a: usize| ((time[a + 1] - time[a]) - step).abs() <= 0.25 * step;
    rows.flatten()
        .filter(|&i| i > 1 && i + 2 < log.len() && (i - 2..i + 2).all(even))
        .filter_map(|i| {
            let reading = Vector3::new(field[0][i], field[1][i], field[2][i]);
            reading.iter().all(|v| v.is_finite()).then_some(())?;
            Some((
                i,
                Sample {
                    reading,
                    points: [point(i - 2)?, point(i - 1)?, point(i)?, point(i + 1)?, point(i + 2)?],
                },
            ))
        })
        .collect()
}

/// IGRF's turn of the field's direction across the box, by row.
#[derive(Debug, Default)]
struct Turns(std::collections::BTreeMap<usize, Vector3<f64>>);

impl Turns {
    fn at(&self, row: usize) -> Vector3<f64> {
        self.0.get(&row).copied().unwrap_or_else(Vector3::zeros)
    }
}

/// The starting direction (inclination, declination in radians) and the
/// main field's turn across `rows`: IGRF-14 at every row with a position
/// (their mean direction the start) when the flight records one; else
/// IGRF-14 at the `[site]` with no turn; else the best of a 5° grid (whose
/// cost is the same for u and −u, see [`FieldSign`]) and no turn.
fn start_direction(
    log: &FlightLog,
    sensor: &VectorSensor,
    rows: &[Range<usize>],
    (attitude, reference): (&[&[f64]; 3], &[f64]),
    site: Option<&Site>,
) -> ((f64, f64), FieldStart, Turns) {
    let column = |names: &[&str]| {
        names
            .iter()
            .find_map(|n| log.channel(n).filter(|c| c.role == ChannelRole::Position))
            .map(|c| c.values.as_slice())
    };
    let (latitude, longitude) = (column(&["lat", "ins_lat"]), column(&["lon", "ins_lon"]));
    let height = column(&["msl", "alt", "utm_z", "ins_alt"]);
    let (year, dated) = match log.date().or(site.and_then(|s| s.date)) {
        Some(d) => (decimal_year(d.year, d.month, d.day, 43_200.0), true),
        None => (2025.0, false),
    };
    let model = Igrf::fourteenth();
    let (first, last) = model.valid_years();
    let epoch = model.at_year(year.clamp(first, last));
    if let (Some(latitude), Some(longitude)) = (latitude, longitude) {
        let mut directions = std::collections::BTreeMap::new();
        let (mut sum, mut total) = (Vector3::zeros(), 0.0);
        for i in rows.iter().cloned().flatten() {
            let h = height.map_or(0.0, |h| h[i]);
            if !(latitude[i].is_finite() && longitude[i].is_finite() && h.is_finite()) {
                continue;
            }
            let field = Vector3::from(epoch.field(latitude[i], longitude[i], h).north_east_down_nt);
            sum += field.normalize();
            total += field.norm();
            directions.insert(i, field.normalize());
        }
        if !directions.is_empty() {
            let count = directions.len() as f64;
            let mean = sum.normalize();
            let inclination = mean[2].asin();
            let declination = mean[1].atan2(mean[0]);
            let start = FieldStart::Igrf {
                position: PositionSource::Recorded,
                year,
                dated,
                inclination_deg: inclination.to_degrees(),
                declination_deg: declination.to_degrees(),
                total_nt: total / count,
            };
            let turns = Turns(directions.into_iter().map(|(i, u)| (i, u - mean)).collect());
            return ((inclination, declination), start, turns);
        }
    }
    let turns = Turns::default();
    if let Some(site) = site {
        let (angles, start) = at_site(&epoch, site, (year, dated));
        return (angles, start, turns);
    }
    let field = log.vector_components(sensor);
    let samples = samples(log, (attitude, reference, &turns, field), rows.iter().cloned());
    (best_on_grid(GridScore::new(&samples).as_ref()), FieldStart::Grid, turns)
}

/// IGRF-14's field direction (inclination, declination, radians) at the
/// `[site]`, and the start it makes; `year` decimal, `dated` whether it is
/// a date given (the flight's, or the `[site]`'s) rather than the default.
fn at_site(epoch: &crate::model::igrf::IgrfEpoch, site: &Site, (year, dated): (f64, bool)) -> ((f64, f64), FieldStart) {
    let field = Vector3::from(
        epoch
            .field(site.latitude_deg, site.longitude_deg, site.height_m)
            .north_east_down_nt,
    );
    let unit = field.normalize();
    let (inclination, declination) = (unit[2].asin(), unit[1].atan2(unit[0]));
    let start = FieldStart::Igrf {
        position: PositionSource::Site,
        year,
        dated,
        inclination_deg: inclination.to_degrees(),
        declination_deg: declination.to_degrees(),
        total_nt: field.norm(),
    };
    ((inclination, declination), start)
}

/// The direction (inclination, declination, radians) of the 5° grid that
/// `score` costs least; (0, 0) without a score.
fn best_on_grid(score: Option<&GridScore>) -> (f64, f64) {
    let mut best = (f64::INFINITY, (0.0, 0.0));
    for i in -17..=17 {
        for d in 0..72 {
            let angles = ((i as f64 * 5.0).to_radians(), (d as f64 * 5.0).to_radians());
            if let Some(cost) = score.and_then(|s| s.cost(&direction(angles.0, angles.1)[0])) {
                if cost < best.0 {
                    best = (cost, angles);
                }
            }
        }
    }
    best.1
}

/// The cost of [`linear_fit`] at any direction u, from sums over the
/// samples gathered once, for the 5° grid of starting directions (2,520
/// directions; scoring each on every row took seconds on a long box).
///
/// With no turn and no lag, a row's field in body axes is $A_i u$, $A_i =
/// F_i R_i$, linear in u. With the intercept h the fit of reading
/// component j is the fit of its centred values $\tilde y_{ij}$ on $\tilde
/// A_i u$ ($A_i$ less its mean), whose residual sum of squares is
/// $\sum_i \tilde y_{ij}^2 - c_j^\top S^{-1} c_j$ with $S = \sum_i \tilde A_i u
/// u^\top \tilde A_i^\top$ (quadratic in u: 81 sums) and $c_j = (\sum_i
/// \tilde y_{ij} \tilde A_i) u$ (27 sums).
struct GridScore {
    /// $\sum_i \tilde A_i[a, c] \tilde A_i[b, d]$ at `[a][b][c][d]`.
    second: [[[[f64; 3]; 3]; 3]; 3],
    /// $\sum_i \tilde y_{ij} \tilde A_i$ for reading component j.
    cross: [Matrix3<f64>; 3],
    /// $\sum_i \tilde y_{ij}^2$.
    squares: [f64; 3],
}

impl GridScore {
    /// The sums over `samples`; `None` with fewer than [`linear_fit`] needs.
    fn new(samples: &[Sample]) -> Option<GridScore> {
        if samples.len() < 8 {
            return None;
        }
        let count = samples.len() as f64;
        let field = |s: &Sample| s.points[2].ned_to_body * s.points[2].total_nt;
        let mean_field = samples.iter().map(field).sum::<Matrix3<f64>>() / count;
        let mean_reading = samples.iter().map(|s| s.reading).sum::<Vector3<f64>>() / count;
        let mut score = GridScore {
            second: [[[[0.0; 3]; 3]; 3]; 3],
            cross: [Matrix3::zeros(); 3],
            squares: [0.0; 3],
        };
        for s in samples {
            let a = field(s) - mean_field;
            let y = s.reading - mean_reading;
            for (first, row) in score.second.iter_mut().enumerate() {
                for (second, block) in row.iter_mut().enumerate() {
                    for (c, line) in block.iter_mut().enumerate() {
                        for (d, sum) in line.iter_mut().enumerate() {
                            *sum += a[(first, c)] * a[(second, d)];
                        }
                    }
                }
            }
            for j in 0..3 {
                score.cross[j] += a * y[j];
                score.squares[j] += y[j] * y[j];
            }
        }
        Some(score)
    }

    /// The residual sum of squares of the linear fit at direction `u`;
    /// `None` when the field's variation there spans less than three axes.
    fn cost(&self, u: &Vector3<f64>) -> Option<f64> {
        let spread = Matrix3::from_fn(|a, b| {
            let block = &self.second[a][b];
            (0..3)
                .map(|c| (0..3).map(|d| block[c][d] * u[c] * u[d]).sum::<f64>())
                .sum::<f64>()
        });
        let cholesky = spread.cholesky()?;
        Some(
            (0..3)
                .map(|j| {
                    let c = self.cross[j] * u;
                    self.squares[j] - c.dot(&cholesky.solve(&c))
                })
                .sum(),
        )
    }
}

/// K and h by linear least squares at direction `u`, and the cost.
fn linear_fit(samples: &[Sample], u: Vector3<f64>) -> Option<(Matrix3<f64>, Vector3<f64>, f64)> {
    if samples.len() < 8 {
        return None;
    }
    let regressors: [Vec<f64>; 3] = std::array::from_fn(|k| samples.iter().map(|s| s.points[2].body(&u)[k]).collect());
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
    /// The fluxgate's lag behind the INS, samples.
    lag: f64,
    /// The fluxgate's smoothing against the INS (1/24: a boxcar over one
    /// sample interval).
    smoothing: f64,
}

/// Parameters fitted: K (9), h (3), inclination, declination, lag,
/// smoothing.
const PARAMETERS: usize = 16;

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
        next.lag += scale * delta[14];
        next.smoothing += scale * delta[15];
        next
    }

    /// The predicted less the recorded reading of `s`.
    fn residual(&self, s: &Sample, u: &Vector3<f64>) -> Vector3<f64> {
        self.k * s.body(u, self.lag, self.smoothing) + self.h - s.reading
    }

    /// Weighted sum of squared residuals over `samples`.
    fn cost(&self, samples: &[Sample], weights: &[f64]) -> f64 {
        let u = direction(self.inclination, self.declination)[0];
        samples
            .iter()
            .zip(weights)
            .map(|(s, w)| w * self.residual(s, &u).norm_squared())
            .sum()
    }

    /// Huber weights of the rows at these parameters: 1 within
    /// [`HUBER_SPREAD`] times the median residual size, falling as its
    /// inverse beyond. A row where the INS attitude and the fluxgate
    /// disagree (one sampled at an instant, the other averaged over the
    /// interval, at the onset of a fast roll) weighs little.
    fn weights(&self, samples: &[Sample]) -> Vec<f64> {
        let u = direction(self.inclination, self.declination)[0];
        let sizes: Vec<f64> = samples.iter().map(|s| self.residual(s, &u).norm()).collect();
        let mut sorted = sizes.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
        let limit = HUBER_SPREAD * median;
        sizes
            .iter()
            .map(|&r| if r <= limit || limit <= 0.0 { 1.0 } else { limit / r })
            .collect()
    }
}

/// Residual sizes beyond this many medians are down-weighted (Huber): for
/// Gaussian errors the median size of a 3-vector is 1.54σ, so 2.5 medians
/// is about 3.9σ and leaves clean rows alone.
const HUBER_SPREAD: f64 = 2.5;

impl Parameters {
    /// The step along `delta` halved until the weighted cost on `samples`
    /// is no more than `cost` (at most 30 halvings), with its cost; `None`
    /// when none is.
    fn halving_step(
        &self,
        delta: &[f64],
        (samples, weights): (&[Sample], &[f64]),
        cost: f64,
    ) -> Option<(Parameters, f64)> {
        let mut scale = 1.0;
        for _ in 0..30 {
            let candidate = self.step(delta, scale);
            let candidate_cost = candidate.cost(samples, weights);
            if candidate_cost <= cost {
                return Some((candidate, candidate_cost));
            }
            scale *= 0.5;
        }
        None
    }
}

/// Iteratively reweighted Gauss-Newton from the linear fit at `start`;
/// `None` when the samples cannot determine the parameters.
fn fit_samples(samples: &[Sample], start: &(f64, f64)) -> Option<VectorModel> {
    let (k, h, _) = linear_fit(samples, direction(start.0, start.1)[0])?;
    let mut parameters = Parameters {
        k,
        h,
        inclination: start.0,
        declination: start.1,
        lag: 0.0,
        smoothing: 0.0,
    };
    let mut iterations = 0;
    let mut condition_number = f64::INFINITY;
    while iterations < MOST_ITERATIONS {
        iterations += 1;
        let weights = parameters.weights(samples);
        let cost = parameters.cost(samples, &weights);
        let (delta, condition) = gauss_newton_step(samples, &weights, &parameters)?;
        condition_number = condition;
        let Some((next, next_cost)) = parameters.halving_step(&delta, (samples, &weights), cost) else {
            break;
        };
        parameters = next;
        if cost - next_cost <= 1e-12 * cost.max(f64::MIN_POSITIVE) {
            break;
        }
    }
    let u = direction(parameters.inclination, parameters.declination)[0];
    let mut squares = [0.0; 3];
    for s in samples {
        let r = parameters.residual(s, &u);
        for j in 0..3 {
            squares[j] += r[j] * r[j];
        }
    }
    parameters.k.try_inverse()?;
    // Inclination in [-90°, 90°], declination in (-180°, 180°].
    let unit = u;
    let inclination = unit[2].clamp(-1.0, 1.0).asin();
    let declination = unit[1].atan2(unit[0]);
    Some(VectorModel {
        sensor: String::new(),
        reference: String::new(),
        reference_swing_nt: 0.0,
        reference_level: ReferenceLevel::default(),
        soft_iron: std::array::from_fn(|j| std::array::from_fn(|c| parameters.k[(j, c)])),
        hard_iron_nt: std::array::from_fn(|j| parameters.h[j]),
        inclination_deg: inclination.to_degrees(),
        declination_deg: declination.to_degrees(),
        start: FieldStart::Grid,
        field_sign: FieldSign::RightHandedAxes,
        mounting: Mounting::of(&parameters.k),
        rows: samples.len(),
        iterations,
        condition_number,
        residual_rms_nt: squares.map(|s| (s / samples.len() as f64).sqrt()),
        held_out: None,
        tolles_lawson: None,
        tolles_lawson_warning: None,
        fluxgate_lag_samples: parameters.lag,
        fluxgate_smoothing: parameters.smoothing,
    })
}

/// The Gauss-Newton step minimising $\lVert W^{1/2}(J\Delta + r)\rVert$,
/// from the R factor of $W^{1/2}[J \mid -r]$, and the condition number of
/// $W^{1/2}J$ with unit-norm columns. The derivatives by the angles leave
/// out the box's small turn (it changes them by 1e-3 of themselves); the
/// cost the step is judged by keeps it.
fn gauss_newton_step(samples: &[Sample], weights: &[f64], parameters: &Parameters) -> Option<(Vec<f64>, f64)> {
    let n = samples.len() * 3;
    let [u, du_di, du_dd] = direction(parameters.inclination, parameters.declination);
    let (lag, smoothing) = (parameters.lag, parameters.smoothing);
    // Sample i's rows 3i..3i+3 of W^{1/2}[J | -r], each block of rows
    // formed where it is factored.
    let r = tall_skinny_r_of(n, PARAMETERS + 1, |rows, mut block| {
        for i in rows.start / 3..rows.end.div_ceil(3) {
            let (s, w) = (&samples[i], weights[i]);
            let root = w.sqrt();
            let body = s.body(&u, lag, smoothing);
            let [first, second, _] = differences(s.points.map(|p| p.body(&u)));
            let by_lag = parameters.k * -first;
            let by_smoothing = parameters.k * second;
            let at = s.points[2];
            let by_inclination = parameters.k * (at.ned_to_body * du_di) * at.total_nt;
            let by_declination = parameters.k * (at.ned_to_body * du_dd) * at.total_nt;
            let residual = parameters.k * body + parameters.h - s.reading;
            for j in (0..3).filter(|j| rows.contains(&(3 * i + j))) {
                let row = 3 * i + j - rows.start;
                for c in 0..3 {
                    block[(row, 3 * j + c)] = root * body[c];
                }
                block[(row, 9 + j)] = root;
                block[(row, 12)] = root * by_inclination[j];
                block[(row, 13)] = root * by_declination[j];
                block[(row, 14)] = root * by_lag[j];
                block[(row, 15)] = root * by_smoothing[j];
                block[(row, PARAMETERS)] = -root * residual[j];
            }
        }
    });
    let delta = back_substitute(&r, PARAMETERS)?;
    let norms: Vec<f64> = (0..PARAMETERS)
        .map(|j| (0..=j).map(|i| r[(i, j)].powi(2)).sum::<f64>().sqrt())
        .collect();
    let scaled = faer::Mat::from_fn(PARAMETERS, PARAMETERS, |i, j| r[(i, j)] / norms[j]);
    let (_, sigma, _) = small_svd(scaled.as_ref())?;
    let condition = sigma[0] / sigma[PARAMETERS - 1];
    Some((delta, condition))
}

/// Each heading of `windows` predicted by a fit on the others; `None` with
/// fewer than three headings.
fn held_out(log: &FlightLog, windows: &[CalibrationWindow], inputs: Inputs, start: &(f64, f64)) -> Option<HeldOut> {
    if windows.iter().any(|w| w.heading_deg.is_none()) {
        return None;
    }
    let headings = distinct_headings(windows);
    if headings.len() < 3 {
        return None;
    }
    // Each heading's squared residuals and count, from its own fit on the
    // others; summed in heading order, whatever order they finish in.
    let per_heading: Vec<Option<([f64; 3], usize)>> = headings
        .par_iter()
        .map(|&heading| {
            let (held, kept): (Vec<CalibrationWindow>, Vec<CalibrationWindow>) = windows
                .iter()
                .cloned()
                .partition(|w| w.heading_deg.is_some_and(|h| same_heading(h, heading)));
            let training = samples(log, inputs, window_rows(log, &kept).into_iter());
            let model = fit_samples(&training, start)?;
            let parameters = Parameters {
                k: Matrix3::from_fn(|j, c| model.soft_iron[j][c]),
                h: Vector3::from(model.hard_iron_nt),
                inclination: model.inclination_deg.to_radians(),
                declination: model.declination_deg.to_radians(),
                lag: model.fluxgate_lag_samples,
                smoothing: model.fluxgate_smoothing,
            };
            let u = direction(parameters.inclination, parameters.declination)[0];
            let (mut squares, mut count) = ([0.0; 3], 0usize);
            for s in samples(log, inputs, window_rows(log, &held).into_iter()) {
                let r = parameters.residual(&s, &u);
                for j in 0..3 {
                    squares[j] += r[j] * r[j];
                }
                count += 1;
            }
            Some((squares, count))
        })
        .collect();
    let (mut squares, mut count) = ([0.0; 3], 0usize);
    for (heading_squares, heading_count) in per_heading.into_iter().collect::<Option<Vec<_>>>()? {
        for j in 0..3 {
            squares[j] += heading_squares[j];
        }
        count += heading_count;
    }
    (count > 0).then(|| HeldOut {
        headings: headings.len(),
        rms_nt: squares.map(|s| (s / count as f64).sqrt()),
    })
}

impl VectorModel {
    /// This fit oriented ([`Self::orient`]: by IGRF-14's direction `igrf`
    /// when there is one, else so that K's axes are right-handed), named
    /// by its fluxgate, reference channel and that channel's swing, with
    /// its start and held-out residual.
    fn identified(
        mut self,
        igrf: Option<Vector3<f64>>,
        (sensor, reference, swing_nt): (String, String, f64),
        (start, held_out): (FieldStart, Option<HeldOut>),
    ) -> Self {
        self.orient(igrf);
        self.sensor = sensor;
        self.reference = reference;
        self.reference_swing_nt = swing_nt;
        self.start = start;
        self.held_out = held_out;
        self
    }

    /// Chooses the sign of the field's direction, which the data leave
    /// free (see [`FieldSign`]): the one nearer IGRF-14's direction `igrf`
    /// when there is one, else the one that makes K's axes right-handed;
    /// then reads the mounting off K.
    fn orient(&mut self, igrf: Option<Vector3<f64>>) {
        let u = direction(self.inclination_deg.to_radians(), self.declination_deg.to_radians())[0];
        let k = Matrix3::from_fn(|j, c| self.soft_iron[j][c]);
        let (flip, sign) = match igrf {
            Some(expected) => (u.dot(&expected) < 0.0, FieldSign::Igrf),
            None => (k.determinant() < 0.0, FieldSign::RightHandedAxes),
        };
        if flip {
            self.soft_iron = self.soft_iron.map(|row| row.map(|v| -v));
            self.inclination_deg = -self.inclination_deg;
            self.declination_deg = (self.declination_deg + 360.0).rem_euclid(360.0) - 180.0;
        }
        self.field_sign = sign;
        self.mounting = Mounting::of(&Matrix3::from_fn(|j, c| self.soft_iron[j][c]));
    }

    /// The field the fitted constants expect in body axes on the rows of
    /// `windows` (`NaN` elsewhere and where a row lacks an attitude, a
    /// reference or its neighbours): the reference's size along the
    /// fitted direction, rotated with the INS attitude, the fluxgate's
    /// smoothing kept and its lag left out (a lag is what the Tolles-Lawson
    /// stage's rate terms take, with the eddy currents).
    fn expected_body(&self, log: &FlightLog, inputs: Inputs, windows: &[CalibrationWindow]) -> [Vec<f64>; 3] {
        let u = direction(self.inclination_deg.to_radians(), self.declination_deg.to_radians())[0];
        let mut expected: [Vec<f64>; 3] = std::array::from_fn(|_| vec![f64::NAN; log.len()]);
        let rows = union(window_rows(log, windows));
        for (i, sample) in indexed_samples(log, inputs, rows.into_iter()) {
            let body = sample.body(&u, 0.0, self.fluxgate_smoothing);
            for k in 0..3 {
                expected[k][i] = body[k];
            }
        }
        expected
    }

    /// The Earth's field in body axes and north-east-down on every row of
    /// `log`: $K^{-1}(m_i - h)$ less the vector Tolles-Lawson stage's
    /// prediction where it is fitted, rotated with the INS attitude where
    /// that is recorded.
    pub fn compensate(&self, log: &FlightLog) -> Result<CompensatedVector> {
        let stage = self.tolles_lawson.as_ref().map(|s| s.components.as_slice());
        compensate_with(log, &self.sensor, (&self.soft_iron, &self.hard_iron_nt), stage)
    }
}

/// [`VectorModel::compensate`] from its constants: fluxgate `sensor`'s
/// reading per unit body-axis field K and its reading with no field h,
/// and the vector Tolles-Lawson stage's models of each body axis when
/// there is one (a model saved from another flight holds these).
pub fn compensate_with(
    log: &FlightLog,
    sensor: &str,
    (soft_iron, hard_iron_nt): (&[[f64; 3]; 3], &[f64; 3]),
    stage: Option<&[crate::model::FittedModel]>,
) -> Result<CompensatedVector> {
    let mut body_nt = twelve_constant_body(log, sensor, (soft_iron, hard_iron_nt))?;
    if let Some(components) = stage {
        tolles_lawson::apply_components(components, log, sensor, &mut body_nt)?;
    }
    let attitude = log.attitude();
    let rows = log.len();
    let mut ned_nt: [Vec<f64>; 3] = std::array::from_fn(|_| vec![f64::NAN; rows]);
    for i in 0..rows {
        let body = Vector3::new(body_nt[0][i], body_nt[1][i], body_nt[2][i]);
        if !body.iter().all(|v| v.is_finite()) {
            continue;
        }
        if let Some(to_body) = attitude.as_ref().and_then(|a| ned_to_body(a, i)) {
            let ned = to_body.transpose() * body;
            for j in 0..3 {
                ned_nt[j][i] = ned[j];
            }
        }
    }
    Ok(CompensatedVector {
        sensor: sensor.to_string(),
        body_nt,
        ned_nt,
    })
}

/// $K^{-1}(m_i - h)$ on every row of `log` (`NaN` without a reading).
fn twelve_constant_body(
    log: &FlightLog,
    prefix: &str,
    (soft_iron, hard_iron_nt): (&[[f64; 3]; 3], &[f64; 3]),
) -> Result<[Vec<f64>; 3]> {
    let sensor = log.vector_sensor(prefix).ok_or_else(|| Error::Vector {
        sensor: prefix.to_string(),
        message: "the flight does not record this fluxgate".into(),
    })?;
    let k = Matrix3::from_fn(|j, c| soft_iron[j][c]);
    let inverse = k.try_inverse().ok_or_else(|| Error::Vector {
        sensor: prefix.to_string(),
        message: "the fitted K is singular".into(),
    })?;
    let h = Vector3::from(*hard_iron_nt);
    let field = log.vector_components(&sensor);
    let mut body_nt: [Vec<f64>; 3] = std::array::from_fn(|_| vec![f64::NAN; log.len()]);
    for i in 0..log.len() {
        let reading = Vector3::new(field[0][i], field[1][i], field[2][i]);
        if !reading.iter().all(|v| v.is_finite()) {
            continue;
        }
        let body = inverse * (reading - h);
        for j in 0..3 {
            body_nt[j][i] = body[j];
        }
    }
    Ok(body_nt)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The level's sigma is the traceless part's Frobenius norm over √8,
    /// times the field: diag(1, −1, 0)·10⁻³ at 50 000 nT has norm √2·10⁻³,
    /// so 25 nT; an isotropic tensor, which no attitude shows and the fit
    /// never returns, adds nothing.
    #[test]
    fn the_level_sigma_follows_the_traceless_induced_tensor() {
        let tensor = [[1e-3, 0.0, 0.0], [0.0, -1e-3, 0.0], [0.0, 0.0, 0.0]];
        assert!((Reference::level_sigma_nt(&tensor, 50_000.0) - 25.0).abs() < 1e-9);
        let isotropic = [[2e-3, 0.0, 0.0], [0.0, 2e-3, 0.0], [0.0, 0.0, 2e-3]];
        assert!(Reference::level_sigma_nt(&isotropic, 50_000.0).abs() < 1e-9);
        let off_diagonal = [[0.0, 1e-3, 0.0], [1e-3, 0.0, 0.0], [0.0, 0.0, 0.0]];
        assert!((Reference::level_sigma_nt(&off_diagonal, 50_000.0) - 25.0).abs() < 1e-9);
    }

    /// A pinned reference is the reading less the whole interference; an
    /// unpinned one keeps the reading's mean over the box.
    #[test]
    fn a_pinned_reference_takes_the_whole_interference_out() {
        let time: Vec<f64> = (0..10).map(f64::from).collect();
        let log = FlightLog::new(std::path::Path::new("t.csv"), "time", time, Vec::new()).unwrap();
        let recorded = vec![50_010.0; 10];
        let interference: Vec<f64> = (0..10).map(|k| 10.0 + f64::from(k % 2)).collect();
        let windows = [CalibrationWindow::new(0.0, 9.0)];
        let pinned =
            Reference::levelled(&log, ("mag_1_uc", true), (&recorded, &interference), (&windows, &[])).unwrap();
        let kept = Reference::levelled(&log, ("mag_1_uc", false), (&recorded, &interference), (&windows, &[])).unwrap();
        assert_eq!(pinned.total_nt[0], 50_000.0);
        assert_eq!(pinned.total_nt[1], 49_999.0);
        assert!((kept.total_nt[0] - 50_010.5).abs() < 1e-9);
        assert!(pinned.pinned && !kept.pinned);
    }

    /// Samples of consecutive rows read as `k`·field + `h`, the attitude of
    /// row t given by `attitude(t)` (roll, pitch, yaw).
    fn rows(
        count: usize,
        (k, h, u): (Matrix3<f64>, Vector3<f64>, Vector3<f64>),
        attitude: impl Fn(f64) -> (f64, f64, f64),
    ) -> Vec<Sample> {
        let points: Vec<Point> = (0..count + 4)
            .map(|i| {
                let t = i as f64 * 0.1;
                let (roll, pitch, yaw) = attitude(t);
                Point {
                    ned_to_body: body_to_ned(roll, pitch, yaw).inverse().into_inner(),
                    total_nt: 52_000.0 + 30.0 * (t * 0.01).sin(),
                    turn: Vector3::zeros(),
                }
            })
            .collect();
        (2..count + 2)
            .map(|i| Sample {
                reading: k * points[i].body(&u) + h,
                points: [points[i - 2], points[i - 1], points[i], points[i + 1], points[i + 2]],
            })
            .collect()
    }

    /// Every heading with ±15° of roll and ±8° of pitch.
    fn turning(t: f64) -> (f64, f64, f64) {
        (15.0 * (t * 0.7).sin(), 8.0 * (t * 0.45).cos(), t * 1.8)
    }

    fn parameters(k: Matrix3<f64>, h: Vector3<f64>, inclination_deg: f64) -> Parameters {
        Parameters {
            k,
            h,
            inclination: inclination_deg.to_radians(),
            declination: 0.0,
            lag: 0.0,
            smoothing: 0.0,
        }
    }

    #[test]
    fn known_constants_and_direction_are_recovered_from_a_distant_start() {
        let k = Matrix3::new(1.03, 0.012, -0.008, 0.004, 0.97, 0.015, -0.011, 0.009, 1.02);
        let h = Vector3::new(950.0, -1200.0, 640.0);
        let (inclination, declination) = (70f64.to_radians(), (-12f64).to_radians());
        let samples = rows(2000, (k, h, direction(inclination, declination)[0]), turning);
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
        assert!(
            model.fluxgate_lag_samples.abs() < 1e-7 && model.fluxgate_smoothing.abs() < 1e-7,
            "{model:?}"
        );
    }

    #[test]
    fn the_grid_score_from_sums_is_the_linear_fits_residual_at_every_direction() {
        // Readings with a deterministic ±5 nT disturbance, so the cost is
        // not zero at the true direction; the closed form must match the
        // QR fit's residual sum of squares to 1e-7 of itself everywhere
        // the grid looks, the true direction included.
        let k = Matrix3::new(1.03, 0.012, -0.008, 0.004, 0.97, 0.015, -0.011, 0.009, 1.02);
        let h = Vector3::new(950.0, -1200.0, 640.0);
        let mut samples = rows(
            3000,
            (k, h, direction(62f64.to_radians(), 8f64.to_radians())[0]),
            turning,
        );
        for (i, s) in samples.iter_mut().enumerate() {
            s.reading += Vector3::new(
                5.0 * (i as f64 * 0.37).sin(),
                3.0 * (i as f64 * 1.3).cos(),
                -4.0 * (i as f64 * 0.11).sin(),
            );
        }
        let score = GridScore::new(&samples).unwrap();
        let mut best = (f64::INFINITY, (0, 0));
        for i in -17..=17 {
            for d in (0..72).step_by(5) {
                let u = direction((i as f64 * 5.0).to_radians(), (d as f64 * 5.0).to_radians())[0];
                let (_, _, expected) = linear_fit(&samples, u).unwrap();
                let cost = score.cost(&u).unwrap();
                assert!(
                    (cost - expected).abs() <= 1e-7 * expected,
                    "{i} {d}: {cost} against {expected}"
                );
                if cost < best.0 {
                    best = (cost, (i, d));
                }
            }
        }
        let u = direction(62f64.to_radians(), 8f64.to_radians())[0];
        let (_, _, expected) = linear_fit(&samples, u).unwrap();
        assert!((score.cost(&u).unwrap() - expected).abs() <= 1e-7 * expected);
        assert!(
            expected < best.0,
            "the true direction scores best: {expected} against {best:?}"
        );
    }

    #[test]
    fn a_fluxgate_that_lags_and_averages_is_fitted_with_its_lag_and_smoothing() {
        // Readings of the field 0.3 samples late and smoothed as a boxcar
        // over one interval (1/24 of the second difference).
        let k = Matrix3::new(1.01, 0.0, 0.0, 0.005, 0.99, 0.0, 0.0, 0.0, 1.0);
        let h = Vector3::new(300.0, -200.0, 100.0);
        let u = direction(68f64.to_radians(), 5f64.to_radians())[0];
        let mut samples = rows(2000, (k, h, u), turning);
        for s in &mut samples {
            s.reading = k * s.body(&u, 0.3, 1.0 / 24.0) + h;
        }
        let model = fit_samples(&samples, &(66f64.to_radians(), 3f64.to_radians())).unwrap();
        assert!((model.fluxgate_lag_samples - 0.3).abs() < 1e-6, "{model:?}");
        assert!((model.fluxgate_smoothing - 1.0 / 24.0).abs() < 1e-6, "{model:?}");
        assert!((model.inclination_deg - 68.0).abs() < 1e-7, "{model:?}");
        assert!((model.declination_deg - 5.0).abs() < 1e-7, "{model:?}");
    }

    #[test]
    fn attitude_noise_leaves_the_constants_unbiased() {
        // An INS whose roll, pitch and yaw each carry 0.005° of white noise
        // (4 nT per component at 47 600 nT), a fluxgate read exactly. The
        // constants and direction fitted on 10 000 rows predict a
        // survey-line field to within 0.5 nT per component on each of four
        // noise draws; a second difference through the row's own attitude
        // (see `differences`) took the inclination 0.01° off and this
        // error to 4–6 nT.
        let k = Matrix3::new(0.93, -0.02, 0.015, -0.045, 1.04, -0.0035, -0.004, -0.0145, 1.073);
        let h = Vector3::new(-1600.0, -1000.0, -220.0);
        let (inclination, declination) = (47.6f64, 2.6f64);
        let u = direction(inclination.to_radians(), declination.to_radians())[0];
        let attitude = |i: usize| {
            let t = i as f64 * 0.05;
            (15.0 * (t * 0.7).sin(), 8.0 * (t * 0.45).cos(), (t * 1.8) % 360.0)
        };
        let point = |(roll, pitch, yaw): (f64, f64, f64)| Point {
            ned_to_body: body_to_ned(roll, pitch, yaw).inverse().into_inner(),
            total_nt: 47_600.0,
            turn: Vector3::zeros(),
        };
        for draw in 0..4 {
            let mut random = crate::simulate::random::Random::new(draw);
            let sigma = 0.005;
            let mut noisy = |(roll, pitch, yaw): (f64, f64, f64)| {
                point((
                    roll + sigma * random.normal(),
                    pitch + sigma * random.normal(),
                    yaw + sigma * random.normal(),
                ))
            };
            let recorded: Vec<Point> = (0..10_004).map(|i| noisy(attitude(i))).collect();
            let samples: Vec<Sample> = (2..10_002)
                .map(|i| Sample {
                    reading: k * point(attitude(i)).body(&u) + h,
                    points: [
                        recorded[i - 2],
                        recorded[i - 1],
                        recorded[i],
                        recorded[i + 1],
                        recorded[i + 2],
                    ],
                })
                .collect();
            let model = fit_samples(&samples, &(47f64.to_radians(), 2f64.to_radians())).unwrap();
            let fitted = Matrix3::from_fn(|j, c| model.soft_iron[j][c]);
            let body = Vector3::new(-32_000.0, -3_600.0, 35_300.0);
            let error = fitted.try_inverse().unwrap() * (k * body + h - Vector3::from(model.hard_iron_nt)) - body;
            assert!(error.amax() < 0.5, "draw {draw}: {error:?}, {model:?}");
            assert!((model.inclination_deg - inclination).abs() < 0.002, "{model:?}");
        }
    }

    #[test]
    fn without_pitch_or_roll_the_declination_is_not_determined() {
        // Level flight: a declination error and a fluxgate yawed the
        // other way read the same, and the Jacobian says so.
        let (k, h) = (Matrix3::identity(), Vector3::new(100.0, 0.0, -50.0));
        let u = direction(70f64.to_radians(), 0.0)[0];
        let level = rows(500, (k, h, u), |t| (0.0, 0.0, t * 7.2));
        let condition = gauss_newton_step(&level, &[1.0; 500], &parameters(k, h, 70.0)).map(|(_, c)| c);
        assert!(condition.is_none_or(|c| c > 1e12), "{condition:?}");
        let turning = rows(2000, (k, h, u), turning);
        let (_, condition) = gauss_newton_step(&turning, &[1.0; 2000], &parameters(k, h, 70.0)).unwrap();
        assert!(condition < 1e5, "{condition}");
    }
}
