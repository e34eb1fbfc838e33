//! The physics simulator: flights whose truth is known.
//!
//! `magcomp simulate SCENARIO.toml --out FLIGHT.csv|.mcap|.xyz|.h5` flies
//! the scenario's plan ([`trajectory`]) at an internal rate, computes the
//! fields at every sensor and records them as the instruments would
//! ([`recording`]). It simulates fields, not Tolles-Lawson regressors, so a
//! fit on its output is not trivially perfect:
//!
//! - the Earth's main field from IGRF-14 ([`igrf`]) at the aircraft's
//!   latitude, longitude, height and date (computed every 0.1 s and
//!   interpolated between, within 0.0001 nT); buried dipoles evaluated
//!   exactly at each sensor; a daily variation and pulsations that a base
//!   station (`diurnal`) records with noise;
//! - at each scalar sensor the aircraft adds $P + A\,B + E\,\dot B$ in body
//!   axes; the sensor reads the *norm* $|B + B_{aircraft}|$, so the
//!   second-order terms a linear model leaves out are there, as in flight;
//! - the fluxgate sees the Earth's field and its own share of the
//!   aircraft's, with noise;
//! - current channels, the bus voltage and the trim tab are recorded;
//! - every continuous channel is averaged from the internal rate to the
//!   output rate, noised and quantised; scalar sensors drop out inside
//!   their dead zone.
//!
//! [`scenario::Effect`]s add physics (sensor lag, coupling of any recorded
//! channel, fluxgate calibration errors, an eddy time constant, strong
//! pulsations) without any trace in the output's columns, names or
//! metadata. The truth, the true Earth field at every sensor, the
//! manoeuvres and the effects' parameters, goes to a separate truth file.
//! A scenario and a seed give bit-identical output.

pub use crate::model::igrf;
pub mod physics;
pub mod random;
pub mod recording;
pub mod replay;
pub mod sample_flight;
pub mod scenario;
pub mod trajectory;
pub mod truth;

use rayon::prelude::*;

use crate::error::Result;
use crate::formats::ColumnNames;
use crate::ingest::flight_log::{Channel, FlightLog};
use nalgebra::{Rotation3, Vector3};
use physics::{add, norm, AircraftField, Crust, ExternalField, FluxgateCalibration, Vector};
use random::Random;
use recording::{auxiliary_channels, average_down, central_rate, delayed, first_order_lag, quantise};
use scenario::{Effect, ScalarSensor, Scenario, SensorLocation, AUXILIARY_CHANNELS};
use trajectory::{fly, FlightPath};
pub use truth::{FluxgateTruth, SensorTruth, Truth};

/// Metres per degree of latitude (mean).
const METRES_PER_DEGREE: f64 = 111_195.0;

/// A simulated flight: what was recorded, and what was true.
#[derive(Debug, Clone)]
pub struct SimulatedFlight {
    /// The recording, as a reader would return it.
    pub log: FlightLog,
    /// What the recording does not say.
    pub truth: Truth,
}

/// Fields along the path that every sensor shares.
struct Environment {
    /// NED main + external field at the aircraft, per internal sample.
    regional_nt: Vec<Vector>,
    /// The aircraft's attitude, body to north-east-down, per internal
    /// sample: built once, for every sensor.
    attitude: Vec<Rotation3<f64>>,
    crust: Crust,
    external: ExternalField,
    main_unit: Vector,
}

/// Simulates `scenario` with its own seed.
pub fn simulate(scenario: &Scenario) -> Result<SimulatedFlight> {
    let raw = &scenario.raw;
    let root = Random::new(raw.seed);
    let path = fly(scenario, &mut root.fork("trajectory"));
    let environment = environment(scenario, &path, &root);
    let factor = raw.oversampling;
    let outputs = path.poses.len() / factor;
    let time_s: Vec<f64> = (0..outputs)
        .map(|j| raw.start_time_s + j as f64 / raw.sample_rate_hz)
        .collect();
    let auxiliary = auxiliary_channels(&path, &mut root.fork("currents"));
    let unrecorded = unrecorded_currents(scenario, &path, &root);
    let mut columns: Vec<(String, Vec<f64>)> = Vec::new();
    let mut sensors = Vec::new();
    for (index, sensor) in raw.scalar.iter().enumerate() {
        let mut random = root.fork(&format!("scalar {index}"));
        let sources = (&auxiliary[..], &unrecorded[..]);
        let (recorded, truth) = record_scalar(scenario, &path, &environment, sources, sensor, &mut random);
        columns.push((sensor.name.clone(), recorded));
        sensors.push(truth);
    }
    let mut fluxgates = Vec::new();
    for (index, fluxgate) in raw.fluxgate.iter().enumerate() {
        let mut random = root.fork(&format!("fluxgate {index}"));
        let (recorded, truth) = record_fluxgate(scenario, &path, (&environment, &unrecorded), fluxgate, &mut random);
        columns.extend(recorded);
        fluxgates.push(truth);
    }
    columns.extend(record_navigation(scenario, &path, &mut root.fork("navigation")));
    columns.push(record_base_station(
        scenario,
        &path,
        &environment,
        &mut root.fork("base station"),
    ));
    let mut random = root.fork("auxiliary noise");
    for (name, series) in AUXILIARY_CHANNELS.iter().zip(&auxiliary) {
        let noise = if name.starts_with("cur_") { 0.01 } else { 0.005 };
        let values = average_down(series, factor)
            .into_iter()
            .map(|v| quantise(v + noise * random.normal(), 3))
            .collect();
        columns.push((name.to_string(), values));
    }
    let external_nt: Vec<f64> = (0..outputs)
        .map(|j| {
            physics::dot(
                environment.external.field_nt(j as f64 * factor as f64 * path.dt_s),
                environment.main_unit,
            )
        })
        .collect();
    let date = crate::ingest::flight_date::FlightDate::parse(&scenario.raw.date);
    let log = flight_log(time_s.clone(), columns)?.with_date(date);
    let truth = Truth::new(scenario, &path, time_s, (sensors, fluxgates), external_nt);
    Ok(SimulatedFlight { log, truth })
}

fn flight_log(time_s: Vec<f64>, columns: Vec<(String, Vec<f64>)>) -> Result<FlightLog> {
    let names = ColumnNames::default();
    let channels = columns
        .into_iter()
        .map(|(name, values)| Channel {
            role: names
                .role_of(&name)
                .unwrap_or(crate::ingest::flight_log::ChannelRole::Auxiliary),
            name,
            values,
        })
        .collect();
    FlightLog::new("simulated flight", "tt", time_s, channels)
}

/// Latitude, longitude (degrees) and height above the ellipsoid (m) of a
/// pose, from its offsets north and east of the site.
fn geodetic(scenario: &Scenario, northing_m: f64, easting_m: f64, height_agl_m: f64) -> (f64, f64, f64) {
    let site = &scenario.raw.site;
    let latitude = site.latitude_deg + northing_m / METRES_PER_DEGREE;
    let longitude = site.longitude_deg + easting_m / (METRES_PER_DEGREE * site.latitude_deg.to_radians().cos());
    (latitude, longitude, site.ground_msl_m + height_agl_m)
}

fn environment(scenario: &Scenario, path: &FlightPath, root: &Random) -> Environment {
    let raw = &scenario.raw;
    let model = igrf::Igrf::fourteenth();
    let site_field = model.field(
        raw.site.latitude_deg,
        raw.site.longitude_deg,
        raw.site.ground_msl_m,
        scenario.year,
    );
    let main_unit = site_field.north_east_down_nt.map(|c| c / site_field.total_nt());
    let mut external = ExternalField::draw(
        &mut root.fork("external"),
        raw.external.diurnal_nt,
        raw.external.pulsation_nt,
    );
    for effect in &raw.effect {
        if let Effect::Pulsations { amplitude_nt } = effect {
            external.strengthen(&mut root.fork("strong pulsations"), *amplitude_nt);
        }
    }
    let on_lines = path.poses.iter().filter(|p| p.line > 0.0);
    let (mut north, mut east) = ([f64::MAX, f64::MIN], [f64::MAX, f64::MIN]);
    for pose in on_lines.chain(path.poses.first()) {
        north = [north[0].min(pose.northing_m), north[1].max(pose.northing_m)];
        east = [east[0].min(pose.easting_m), east[1].max(pose.easting_m)];
    }
    let crust = Crust::scatter(
        &mut root.fork("crust"),
        raw.crust.dipole_count,
        [north[0] - 1000.0, north[1] + 1000.0],
        [east[0] - 1000.0, east[1] + 1000.0],
        raw.crust.depth_m,
        raw.crust.moment_a_m2,
        main_unit,
    );
    // Secular variation over a flight is below 0.05 nT: one epoch serves.
    let epoch = model.at_year(scenario.year + raw.start_time_s / 86_400.0 / 365.25);
    let regional_nt = regional_field_along(scenario, path, &epoch, &external);
    let attitude = (path.poses.par_iter())
        .map(|pose| physics::body_to_ned(pose.roll_deg, pose.pitch_deg, pose.yaw_deg))
        .collect();
    Environment {
        regional_nt,
        attitude,
        crust,
        external,
        main_unit,
    }
}

/// Internal samples between the knots at which the main field and the
/// external variation are computed: a tenth of a second of flight (7.5 m
/// at 75 m/s).
fn knot_spacing(dt_s: f64) -> usize {
    ((0.1 / dt_s).round() as usize).max(1)
}

/// The main field and the external variation (NED, nT) at every pose of
/// `path`: computed at knots a tenth of a second apart and interpolated
/// between them by cubics. The interpolation is of the field less its
/// linear part about the site (its gradient times the offset north, east
/// and up), added back at each pose: what is left varies over hundreds
/// of kilometres and has no kink where a climb starts; the external
/// variation's shortest period is 10 s. Between knots both depart from a
/// cubic by far less than the recording's 0.001 nT quantum (tested
/// against the field at every pose). Computing them at every internal
/// sample took most of a simulation's time.
fn regional_field_along(
    scenario: &Scenario,
    path: &FlightPath,
    epoch: &igrf::IgrfEpoch,
    external: &ExternalField,
) -> Vec<Vector> {
    let n = path.poses.len();
    let spacing = knot_spacing(path.dt_s);
    let mut knots: Vec<usize> = (0..n).step_by(spacing).collect();
    if n > 0 && knots.last() != Some(&(n - 1)) {
        knots.push(n - 1);
    }
    let field_at = |offset: Vector| {
        let (latitude, longitude, height) = geodetic(scenario, offset[0], offset[1], offset[2]);
        epoch.field(latitude, longitude, height).north_east_down_nt
    };
    let gradient = site_gradient(&field_at);
    let linear =
        |offset: Vector| -> Vector { std::array::from_fn(|i| (0..3).map(|j| gradient[j][i] * offset[j]).sum()) };
    let offset = |k: usize| {
        let pose = &path.poses[k];
        [pose.northing_m, pose.easting_m, pose.height_agl_m]
    };
    let at_knots: Vec<Vector> = (knots.par_iter())
        .map(|&k| {
            let (main, line) = (field_at(offset(k)), linear(offset(k)));
            let variation = external.field_nt(k as f64 * path.dt_s);
            std::array::from_fn(|i| main[i] - line[i] + variation[i])
        })
        .collect();
    (0..n)
        .into_par_iter()
        .map(|k| add(interpolate_cubic(&knots, &at_knots, k), linear(offset(k))))
        .collect()
}

/// The main field's rate of change (nT/m) north, east and up at the
/// site, by central differences over 100 m: `[d/dnorth, d/deast, d/dup]`.
fn site_gradient(field_at: &impl Fn(Vector) -> Vector) -> [Vector; 3] {
    const STEP_M: f64 = 100.0;
    std::array::from_fn(|axis| {
        let (mut ahead, mut behind) = ([0.0; 3], [0.0; 3]);
        ahead[axis] = STEP_M;
        behind[axis] = -STEP_M;
        let (a, b) = (field_at(ahead), field_at(behind));
        std::array::from_fn(|i| (a[i] - b[i]) / (2.0 * STEP_M))
    })
}

/// The value at sample `k` of the cubic through the four knots nearest
/// it (fewer where the path has fewer), exact at a knot.
fn interpolate_cubic(knots: &[usize], values: &[Vector], k: usize) -> Vector {
    let right = knots.partition_point(|&knot| knot <= k);
    if right > 0 && knots[right - 1] == k {
        return values[right - 1];
    }
    let count = knots.len().min(4);
    let first = right.saturating_sub(2).min(knots.len() - count);
    let used = first..first + count;
    let x = k as f64;
    let mut sum = [0.0; 3];
    for i in used.clone() {
        let weight: f64 = (used.clone())
            .filter(|&j| j != i)
            .map(|j| (x - knots[j] as f64) / (knots[i] as f64 - knots[j] as f64))
            .product();
        for (s, v) in sum.iter_mut().zip(values[i]) {
            *s += weight * v;
        }
    }
    sum
}

/// The Earth's field in body axes at a sensor `position_m` (forward,
/// right, down of the aircraft's reference point), per internal sample.
fn earth_field_at(path: &FlightPath, environment: &Environment, position_m: Vector) -> Vec<Vector> {
    // The sensor's place (north, east, down of the start) at each pose;
    // the crust's field there, a block of poses at a time.
    const BLOCK: usize = 4096;
    let places: Vec<Vector> = (path.poses.par_iter())
        .zip(&environment.attitude)
        .map(|(pose, attitude)| {
            let lever: Vector = (attitude * Vector3::from(position_m)).into();
            [
                pose.northing_m + lever[0],
                pose.easting_m + lever[1],
                lever[2] - pose.height_agl_m,
            ]
        })
        .collect();
    let crust: Vec<Vector> = (places.par_chunks(BLOCK))
        .flat_map_iter(|block| environment.crust.fields_nt(block))
        .collect();
    (crust.par_iter())
        .zip(&environment.regional_nt)
        .zip(&environment.attitude)
        .map(|((crust, regional), attitude)| {
            let ned = add(*regional, *crust);
            attitude.inverse_transform_vector(&Vector3::from(ned)).into()
        })
        .collect()
}

/// Sizes of the aircraft field by sensor location: permanent (nT),
/// induced (dimensionless) and eddy (s).
fn field_sizes(location: SensorLocation) -> (f64, f64, f64) {
    match location {
        SensorLocation::Tail => (3.0, 6e-5, 4e-5),
        SensorLocation::Wing => (25.0, 4e-4, 2e-4),
        SensorLocation::Cabin => (250.0, 4e-3, 1e-3),
        SensorLocation::Nose => (10.0, 2e-4, 1e-4),
    }
}

/// A scalar sensor's auxiliary couplings: the columns coupled, with their
/// gain vectors, and the rates of change coupled, with theirs.
type Couplings = (Vec<(usize, Vector)>, Vec<(Vec<f64>, Vector)>);

/// What the scenario's effects do to `sensor`: an eddy time constant
/// lags the eddy currents' `drive` in place; returns the sensor's lag, s,
/// and its auxiliary couplings.
fn sensor_effects(
    scenario: &Scenario,
    sensor: &ScalarSensor,
    (dt_s, auxiliary): (f64, &[Vec<f64>]),
    drive: &mut [Vec<f64>; 3],
) -> (f64, Couplings) {
    let mut lag_s = 0.0;
    let mut couplings: Vec<(usize, Vector)> = Vec::new();
    let mut rate_couplings: Vec<(Vec<f64>, Vector)> = Vec::new();
    for effect in &scenario.raw.effect {
        match effect {
            Effect::EddyTimeConstant { channel, tau_s } if *channel == sensor.name => {
                *drive = drive.each_ref().map(|rate| first_order_lag(rate, dt_s, *tau_s));
            }
            Effect::SensorLag { channel, lag_s: lag } if *channel == sensor.name => lag_s += lag,
            Effect::AuxCoupling {
                channel,
                source,
                nt_per_unit,
                nt_per_unit_per_s,
            } if *channel == sensor.name => {
                let column = AUXILIARY_CHANNELS.iter().position(|c| c == source).unwrap_or(0);
                couplings.push((column, *nt_per_unit));
                if nt_per_unit_per_s.iter().any(|v| *v != 0.0) {
                    rate_couplings.push((central_rate(&auxiliary[column], dt_s), *nt_per_unit_per_s));
                }
            }
            _ => {}
        }
    }
    (lag_s, (couplings, rate_couplings))
}

/// A current no column records, per internal sample, with the dipole it
/// drives ([`scenario::Effect::UnrecordedCurrent`]).
struct UnrecordedCurrent {
    /// Body axes, m.
    position_m: Vector,
    /// A·m² per A, body axes.
    moment_a_m2_per_a: Vector,
    /// A, per internal sample, zero-mean.
    current_a: Vec<f64>,
}

impl UnrecordedCurrent {
    /// Its field at `position_m` (body axes) at internal sample `k`, nT.
    fn field_at(&self, position_m: Vector, k: usize) -> Vector {
        let offset = [0, 1, 2].map(|i| position_m[i] - self.position_m[i]);
        let moment = self.moment_a_m2_per_a.map(|m| m * self.current_a[k]);
        physics::dipole_field_nt(moment, offset)
    }
}

/// The scenario's unrecorded currents, each drawn from its own stream.
fn unrecorded_currents(scenario: &Scenario, path: &FlightPath, root: &Random) -> Vec<UnrecordedCurrent> {
    (scenario.raw.effect.iter().enumerate())
        .filter_map(|(index, effect)| match effect {
            Effect::UnrecordedCurrent {
                position_m,
                moment_a_m2_per_a,
                amplitude_a,
                waveform,
            } => Some(UnrecordedCurrent {
                position_m: *position_m,
                moment_a_m2_per_a: *moment_a_m2_per_a,
                current_a: crate::simulate::recording::unrecorded_current(
                    path.poses.len(),
                    path.dt_s,
                    (*amplitude_a, *waveform),
                    &mut root.fork(&format!("unrecorded current {index}")),
                ),
            }),
            _ => None,
        })
        .collect()
}

fn record_scalar(
    scenario: &Scenario,
    path: &FlightPath,
    environment: &Environment,
    (auxiliary, unrecorded): (&[Vec<f64>], &[UnrecordedCurrent]),
    sensor: &ScalarSensor,
    random: &mut Random,
) -> (Vec<f64>, SensorTruth) {
    let (permanent, induced, eddy) = field_sizes(sensor.location);
    let scale = sensor.field_scale;
    // Drawn even when the scenario gives the field, so the draws after it
    // do not depend on whether it does.
    let drawn = AircraftField::draw(random, permanent * scale, induced * scale, eddy * scale);
    let aircraft = sensor.aircraft.clone().unwrap_or(drawn);
    let earth = earth_field_at(path, environment, sensor.position_m);
    let mut drive: [Vec<f64>; 3] =
        [0, 1, 2].map(|i| central_rate(&earth.iter().map(|b| b[i]).collect::<Vec<_>>(), path.dt_s));
    let (lag_s, (couplings, rate_couplings)) = sensor_effects(scenario, sensor, (path.dt_s, auxiliary), &mut drive);
    let axis_norm = norm(sensor.dead_zone_axis).max(1e-12);
    let dead_cos = sensor.dead_zone_deg.to_radians().cos();
    let mut dead = vec![false; earth.len()];
    let totals: Vec<f64> = earth
        .iter()
        .enumerate()
        .map(|(k, b)| {
            let mut own = aircraft.at(*b, [drive[0][k], drive[1][k], drive[2][k]]);
            for (column, vector) in &couplings {
                own = add(own, vector.map(|v| v * auxiliary[*column][k]));
            }
            for (rate, vector) in &rate_couplings {
                own = add(own, vector.map(|v| v * rate[k]));
            }
            for current in unrecorded {
                own = add(own, current.field_at(sensor.position_m, k));
            }
            let total = add(*b, own);
            let cosine = physics::dot(total, sensor.dead_zone_axis) / (norm(total) * axis_norm);
            dead[k] = sensor.dead_zone_deg > 0.0 && cosine.abs() > dead_cos;
            norm(total)
        })
        .collect();
    let totals = if lag_s != 0.0 {
        delayed(&totals, path.dt_s, lag_s)
    } else {
        totals
    };
    let factor = scenario.raw.oversampling;
    let recorded: Vec<f64> = average_down(&totals, factor)
        .into_iter()
        .enumerate()
        .map(|(j, value)| {
            let noisy = quantise(value + sensor.noise_nt * random.normal(), 3);
            if dead[j * factor] {
                f64::NAN
            } else {
                noisy
            }
        })
        .collect();
    let earth_total = average_down(&earth.iter().map(|b| norm(*b)).collect::<Vec<_>>(), factor);
    let truth = SensorTruth {
        channel: sensor.name.clone(),
        location: sensor.location,
        position_m: sensor.position_m,
        aircraft,
        earth_total_nt: earth_total,
    };
    (recorded, truth)
}

/// The fluxgate's own errors when the scenario gives them: a
/// `vector_calibration` effect on it, else its `calibration`; `None`
/// leaves it the small residual errors drawn for it.
fn fluxgate_errors(scenario: &Scenario, fluxgate: &scenario::Fluxgate) -> Option<FluxgateCalibration> {
    scenario
        .raw
        .effect
        .iter()
        .find_map(|effect| match effect {
            Effect::VectorCalibration {
                sensor,
                scale,
                offset_nt,
                non_orthogonality_deg,
            } if *sensor == fluxgate.name => Some(FluxgateCalibration {
                scale: *scale,
                non_orthogonality_deg: *non_orthogonality_deg,
                offset_nt: *offset_nt,
            }),
            _ => None,
        })
        .or(fluxgate.calibration)
}

fn record_fluxgate(
    scenario: &Scenario,
    path: &FlightPath,
    (environment, unrecorded): (&Environment, &[UnrecordedCurrent]),
    fluxgate: &scenario::Fluxgate,
    random: &mut Random,
) -> (Vec<(String, Vec<f64>)>, FluxgateTruth) {
    // Drawn even when the scenario gives the field, so the draws after it
    // do not depend on whether it does.
    let drawn = AircraftField::draw(random, fluxgate.permanent_nt, fluxgate.induced, fluxgate.eddy_s);
    let own = fluxgate.aircraft.clone().unwrap_or(drawn);
    let residual = FluxgateCalibration::draw(
        random,
        fluxgate.scale_error,
        fluxgate.non_orthogonality_deg,
        fluxgate.offset_nt,
    );
    let calibration = fluxgate_errors(scenario, fluxgate).unwrap_or(residual);
    let errors = calibration.errors();
    let mounting = fluxgate
        .mounting()
        .expect("the scenario checks each fluxgate's mounting");
    let earth = earth_field_at(path, environment, fluxgate.position_m);
    let factor = scenario.raw.oversampling;
    // The eddy currents' drive: the body-axis Earth field's rate of change.
    let drive: [Vec<f64>; 3] =
        [0, 1, 2].map(|i| central_rate(&earth.iter().map(|b| b[i]).collect::<Vec<_>>(), path.dt_s));
    let readings: Vec<Vector> = earth
        .iter()
        .enumerate()
        .map(|(k, b)| {
            let mut body = add(*b, own.at(*b, [drive[0][k], drive[1][k], drive[2][k]]));
            for current in unrecorded {
                body = add(body, current.field_at(fluxgate.position_m, k));
            }
            errors.read(physics::apply(&mounting, body))
        })
        .collect();
    let columns = ["x", "y", "z"]
        .iter()
        .enumerate()
        .map(|(axis, suffix)| {
            let series: Vec<f64> = readings.iter().map(|r| r[axis]).collect();
            let values = average_down(&series, factor)
                .into_iter()
                .map(|v| quantise(v + fluxgate.noise_nt * random.normal(), 2))
                .collect();
            (format!("{}_{suffix}", fluxgate.name), values)
        })
        .collect();
    let earth_body_nt = [0, 1, 2].map(|axis| average_down(&earth.iter().map(|b| b[axis]).collect::<Vec<_>>(), factor));
    // The same field in north-east-down, rotated back with the true
    // attitude before averaging down, as the vector output is judged in it.
    let earth_ned: Vec<Vector> = earth
        .iter()
        .zip(&environment.attitude)
        .map(|(b, attitude)| (attitude * Vector3::from(*b)).into())
        .collect();
    let earth_ned_nt =
        [0, 1, 2].map(|axis| average_down(&earth_ned.iter().map(|b| b[axis]).collect::<Vec<_>>(), factor));
    let truth = FluxgateTruth {
        sensor: fluxgate.name.clone(),
        calibration,
        aircraft: own,
        mounting,
        earth_body_nt,
        earth_ned_nt,
    };
    (columns, truth)
}

/// Attitude (INS, sampled at the output instants with 0.005° noise),
/// position and line number.
fn record_navigation(scenario: &Scenario, path: &FlightPath, random: &mut Random) -> Vec<(String, Vec<f64>)> {
    let factor = scenario.raw.oversampling;
    let names = ["ins_pitch", "ins_roll", "ins_yaw", "lat", "lon", "msl", "line"];
    let mut columns: Vec<(String, Vec<f64>)> = names.iter().map(|n| (n.to_string(), Vec::new())).collect();
    for pose in path.poses.iter().step_by(factor).take(path.poses.len() / factor) {
        let (latitude, longitude, height) = geodetic(scenario, pose.northing_m, pose.easting_m, pose.height_agl_m);
        let values = [
            quantise(pose.pitch_deg + 0.005 * random.normal(), 4),
            quantise(pose.roll_deg + 0.005 * random.normal(), 4),
            quantise((pose.yaw_deg + 0.005 * random.normal()).rem_euclid(360.0), 4),
            quantise(latitude, 7),
            quantise(longitude, 7),
            quantise(height, 1),
            pose.line,
        ];
        for (column, value) in columns.iter_mut().zip(values) {
            column.1.push(value);
        }
    }
    columns
}

/// The base station: the external variation projected on the main field
/// (what a ground total-field magnetometer records), with noise.
fn record_base_station(
    scenario: &Scenario,
    path: &FlightPath,
    environment: &Environment,
    random: &mut Random,
) -> (String, Vec<f64>) {
    let factor = scenario.raw.oversampling;
    let noise = scenario.raw.external.base_station_noise_nt;
    let values = (0..path.poses.len() / factor)
        .map(|j| {
            let variation = environment.external.field_nt((j * factor) as f64 * path.dt_s);
            quantise(
                physics::dot(variation, environment.main_unit) + noise * random.normal(),
                3,
            )
        })
        .collect();
    ("diurnal".into(), values)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The main field and external variation interpolated between knots
    /// are the field at every pose, within a tenth of the recording's
    /// 0.001 nT quantum: on a flight with climbs and descents (the path's
    /// sharpest changes of height), with strong pulsations (100 nT), and
    /// at an internal step shorter than the knots' and at one longer.
    #[test]
    fn the_regional_field_between_knots_is_the_field_at_every_pose() {
        for (rate, oversampling) in [(10.0, 10), (5.0, 1)] {
            let raw = scenario::RawScenario {
                sample_rate_hz: rate,
                oversampling,
                ..scenario::RawScenario::default()
            };
            let scenario = Scenario::try_from(raw).unwrap();
            let path = fly(&scenario, &mut Random::new(7).fork("trajectory"));
            let epoch = igrf::Igrf::fourteenth().at_year(scenario.year);
            let external = ExternalField::draw(&mut Random::new(8), 100.0, 100.0);
            let interpolated = regional_field_along(&scenario, &path, &epoch, &external);
            let worst = (path.poses.iter().zip(&interpolated).enumerate())
                .map(|(k, (pose, field))| {
                    let (latitude, longitude, height) =
                        geodetic(&scenario, pose.northing_m, pose.easting_m, pose.height_agl_m);
                    let main = epoch.field(latitude, longitude, height).north_east_down_nt;
                    let exact = add(main, external.field_nt(k as f64 * path.dt_s));
                    (0..3).map(|i| (exact[i] - field[i]).abs()).fold(0.0, f64::max)
                })
                .fold(0.0, f64::max);
            println!(
                "{rate} Hz × {oversampling}: worst {worst:.2e} nT over {} poses",
                path.poses.len()
            );
            assert!(worst < 1e-4, "{rate} Hz: {worst} nT");
        }
    }
}
