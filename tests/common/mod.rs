//! Shared by the diagnosis tests: a simulated flight with the tail, cabin
//! and wing sensors, diagnosed with the default settings; and every
//! channel of a flight fitted with its diagnosed model.

// Each test binary uses its own share of these helpers.
#![allow(dead_code)]

use std::collections::BTreeMap;

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::Diagnosis;
use magcomp::ingest::flight_log::{FlightLog, VectorSensor};
use magcomp::model::{Extensions, FittedModel, ModelSpec};
use magcomp::pipeline::diagnose_flight;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::simulate;

/// A short box-and-one-line flight with a tail (`mag_1_uc`), a cabin
/// (`mag_2_uc`) and a wing (`mag_3_uc`) sensor, plus `effects` (TOML
/// `[[effect]]` tables).
pub fn three_sensor_scenario(seed: u64, effects: &str) -> Scenario {
    let text = format!(
        r#"
        seed = {seed}
        [survey]
        line_count = 1
        line_length_m = 2000.0
        [[scalar]]
        name = "mag_1_uc"
        location = "tail"
        [[scalar]]
        name = "mag_2_uc"
        location = "cabin"
        [[scalar]]
        name = "mag_3_uc"
        location = "wing"
        {effects}
        "#
    );
    let raw: RawScenario = toml::from_str(&text).unwrap();
    Scenario::try_from(raw).unwrap()
}

/// Simulates `scenario` and diagnoses it on its detected box.
pub fn diagnose_simulated(scenario: &Scenario) -> Diagnosis {
    diagnose_log(&simulate(scenario).unwrap().log)
}

/// `log` with `count` slow auxiliary columns that nothing magnetic
/// follows (temperatures, pressures, settings): sines of periods 2π·40 s,
/// 2π·57 s, 2π·74 s, … with a faint 2π·3.1 s ripple.
pub fn with_unrelated_columns(
    log: &magcomp::ingest::flight_log::FlightLog,
    count: usize,
) -> magcomp::ingest::flight_log::FlightLog {
    use magcomp::ingest::flight_log::{Channel, ChannelRole, FlightLog};
    let mut channels = log.channels().to_vec();
    for extra in 0..count {
        let period = 40.0 + 17.0 * extra as f64;
        let values = log
            .time_s()
            .iter()
            .map(|t| (t / period).sin() + 0.1 * (t / 3.1).cos())
            .collect();
        channels.push(Channel {
            name: format!("aux_{extra:02}"),
            role: ChannelRole::Auxiliary,
            values,
        });
    }
    FlightLog::new(log.source(), log.time_column(), log.time_s().to_vec(), channels).unwrap()
}

/// Diagnoses `log` on its detected box with the default settings.
pub fn diagnose_log(log: &magcomp::ingest::flight_log::FlightLog) -> Diagnosis {
    let pipeline = Pipeline::default();
    let job = FlightJob::new("simulated");
    diagnose_flight(log, &job, &pipeline.settings, &pipeline.settings.diagnose).unwrap()
}

/// The held-out RMS of `model` on `channel`, scored as the diagnosis
/// scores its candidates, on `log`'s detected box.
pub fn heldout_rms(
    log: &magcomp::ingest::flight_log::FlightLog,
    channel: &str,
    model: &magcomp::model::Extensions,
) -> f64 {
    let pipeline = Pipeline::default();
    let options = pipeline.settings.clone();
    let windows = magcomp::calibration::detect::detect_manoeuvres(log, &options.detect)
        .unwrap()
        .calibration_windows(options.detect.window_margin_s);
    let sensor = magcomp::pipeline::choose_vector_sensor(log, None).unwrap();
    let spec = magcomp::model::ModelSpec::new(options.terms, model.clone());
    magcomp::diagnose::heldout_rms(log, &sensor, channel, &windows, &spec, &options.fit).unwrap()
}

/// Every channel fitted on `windows` with its extensions in `plan` (plain
/// Tolles-Lawson where the plan has none), on the pipeline's terms and fit
/// settings, the fits sharing one store pool.
pub fn fit_channels(
    log: &FlightLog,
    sensor: &VectorSensor,
    (channels, windows): (&[String], &[CalibrationWindow]),
    pipeline: &Pipeline,
    plan: &BTreeMap<String, Extensions>,
) -> Vec<FittedModel> {
    let stores = magcomp::numerics::stacked::StorePool::new();
    channels
        .iter()
        .map(|channel| {
            let spec = ModelSpec::of_channel(pipeline.settings.terms, plan, channel);
            magcomp::model::fit(log, sensor, channel, windows, &spec, &pipeline.settings.fit, &stores).unwrap()
        })
        .collect()
}

/// The opening of a scenario drawn from `draw` for `seed`: the sample
/// rate (10 or 20 Hz), a site from 60° S to 65° N anywhere in longitude, a
/// box of four headings 90° apart from a random base, 2–4 km up, with
/// pitches of 3–8°, rolls of 8–20° and yaws of 3–8°, and the survey lines'
/// heading. It ends inside `[survey]`, so the caller's survey keys follow.
/// Drawn in a fixed order: the plan stays the same for a seed.
pub fn random_box(seed: u64, draw: &mut magcomp::simulate::random::Random) -> String {
    let base = draw.uniform(0.0, 90.0);
    let headings: Vec<f64> = (0..4).map(|k| base + 90.0 * k as f64).collect();
    format!(
        r#"
        seed = {seed}
        sample_rate_hz = {rate}
        [site]
        latitude_deg = {latitude}
        longitude_deg = {longitude}
        [calibration]
        headings_deg = {headings:?}
        altitude_m = {altitude}
        pitch_deg = {pitch}
        roll_deg = {roll}
        yaw_deg = {yaw}
        [survey]
        line_heading_deg = {line_heading}
        "#,
        rate = if draw.uniform(0.0, 1.0) < 0.5 { 10.0 } else { 20.0 },
        latitude = draw.uniform(-60.0, 65.0),
        longitude = draw.uniform(-180.0, 180.0),
        altitude = draw.uniform(2000.0, 4000.0),
        pitch = draw.uniform(3.0, 8.0),
        roll = draw.uniform(8.0, 20.0),
        yaw = draw.uniform(3.0, 8.0),
        line_heading = draw.uniform(0.0, 180.0),
    )
}

/// Settings of `compensate --plain` without the vector stage.
pub fn plain() -> magcomp::config::Settings {
    let mut settings = magcomp::config::Settings::default();
    settings.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    settings.vector.enabled = false;
    settings
}

/// Scenario tables of a tail and a wing magnetometer (`mag_1_uc`,
/// `mag_2_uc`) and a fluxgate (`flux_a`).
pub const TAIL_AND_WING: &str = r#"
[[scalar]]
name = "mag_1_uc"
location = "tail"
[[scalar]]
name = "mag_2_uc"
location = "wing"
[[fluxgate]]
name = "flux_a"
"#;

/// How the two extra sensors of [`paired_sensors_flight`] are mounted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairLayout {
    /// Two wing-tip pods, ±half-span right.
    Wings,
    /// A nose boom and a tail stinger.
    NoseTail,
    /// Two tail sensors, one above the other.
    Stacked,
}

/// A flight plan drawn from `seed` with a tail sensor (`mag_1_uc`), a pair
/// (`mag_4_uc`, `mag_5_uc`) mounted by `seed % 3` as wing tips, nose and
/// tail, or stacked in the tail, and a fluxgate (`flux_a`): the pair's
/// separation, the site, the box's headings, altitude and manoeuvres
/// ([`random_box`]), the survey height (100–300 m over 24 dipoles
/// 80–400 m down, gradients of tenths of a nT/m to several nT/m), the
/// lines' heading, the sample rate and the pulsations' size (0.1–1 nT).
/// Returns the flight, the layout and the pair's separation (m).
pub fn paired_sensors_flight(seed: u64) -> (magcomp::simulate::SimulatedFlight, PairLayout, f64) {
    let mut draw = magcomp::simulate::random::Random::new(seed).fork("gradient test flight");
    let layout = [PairLayout::Wings, PairLayout::NoseTail, PairLayout::Stacked][(seed % 3) as usize];
    let (location, a, b) = match layout {
        PairLayout::Wings => {
            let half = draw.uniform(5.0, 9.0);
            ("wing", [0.0, -half, 0.0], [0.0, half, 0.0])
        }
        PairLayout::NoseTail => {
            let length = draw.uniform(10.0, 16.0);
            ("tail", [length / 2.0, 0.0, 0.0], [-length / 2.0, 0.0, 0.0])
        }
        PairLayout::Stacked => {
            let height = draw.uniform(1.0, 2.5);
            ("tail", [-8.0, 0.0, -height], [-8.0, 0.0, 0.0])
        }
    };
    let separation = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
    let opening = random_box(seed, &mut draw);
    let text = format!(
        r#"
        {opening}
        line_count = 3
        line_length_m = 6000.0
        altitude_m = {survey_altitude}
        [crust]
        dipole_count = 24
        depth_m = [80.0, 400.0]
        moment_a_m2 = 3.0e8
        [external]
        pulsation_nt = {pulsation}
        [[scalar]]
        name = "mag_1_uc"
        location = "tail"
        [[scalar]]
        name = "mag_4_uc"
        location = "{location}"
        position_m = {a:?}
        [[scalar]]
        name = "mag_5_uc"
        location = "{location}"
        position_m = {b:?}
        [[fluxgate]]
        name = "flux_a"
        "#,
        survey_altitude = draw.uniform(100.0, 300.0),
        pulsation = draw.uniform(0.1, 1.0),
    );
    let raw: RawScenario = toml::from_str(&text).unwrap();
    (simulate(&Scenario::try_from(raw).unwrap()).unwrap(), layout, separation)
}

/// One channel's survey-line samples: its `mag_<n>_c_sigma` and its true
/// error, both relative to the calibration windows' level (the column
/// leaves the level out, and a sensor's constant offset is seen by no
/// calibration).
pub struct SigmaColumn {
    pub sigma_nt: Vec<f64>,
    pub error_nt: Vec<f64>,
}

impl SigmaColumn {
    /// The survey-line (`line` > 0) samples of `channel`, compensated with
    /// `model`, against `truth`.
    pub fn of(
        model: &FittedModel,
        channel: &magcomp::compensate::CompensatedChannel,
        truth: &[f64],
        line: &[f64],
    ) -> SigmaColumn {
        let sigma = channel.sigma_nt.as_ref().expect("a jackknife: a sigma column");
        let error = |i: usize| channel.values[i] - truth[i];
        let calibration: Vec<usize> = (model.windows.iter())
            .flat_map(|w| w.flight_rows.iter().cloned().flatten())
            .filter(|&i| error(i).is_finite())
            .collect();
        assert!(calibration.len() > 100, "{}: calibration rows", model.channel);
        let level = calibration.iter().map(|&i| error(i)).sum::<f64>() / calibration.len() as f64;
        let survey: Vec<usize> = (0..line.len())
            .filter(|&i| line[i] > 0.0 && error(i).is_finite() && sigma[i].is_finite())
            .collect();
        SigmaColumn {
            sigma_nt: survey.iter().map(|&i| sigma[i]).collect(),
            error_nt: survey.iter().map(|&i| error(i) - level).collect(),
        }
    }

    /// Root mean square of `values`.
    pub fn rms(values: &[f64]) -> f64 {
        (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
    }

    /// Samples whose error lies within `k` sigma.
    pub fn within(&self, k: f64) -> usize {
        (self.error_nt.iter().zip(&self.sigma_nt))
            .filter(|(e, s)| e.abs() <= k * **s)
            .count()
    }

    /// Fraction of samples within `k` sigma.
    pub fn fraction_within(&self, k: f64) -> f64 {
        self.within(k) as f64 / self.error_nt.len() as f64
    }
}

/// A fluxgate mounting drawn with `draw`: one of the 24 turns that take the
/// body axes onto themselves (on its side, upside down, backwards), as
/// `[[fluxgate]] axes`, and when `turned` a further turn (`turn_deg`) of up
/// to 15° in roll and pitch and 30–45° in yaw (a fluxgate set diagonally on
/// its shelf).
pub fn random_mounting(draw: &mut magcomp::simulate::random::Random, turned: bool) -> ([String; 3], [f64; 3]) {
    let orders = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut proper = Vec::new();
    for (k, order) in orders.iter().enumerate() {
        // Orders 1, 2 and 5 swap one pair: odd.
        let parity = if [1, 2, 5].contains(&k) { -1.0 } else { 1.0 };
        for signs in 0..8 {
            let sign = |j: usize| if signs >> j & 1 == 1 { -1.0 } else { 1.0 };
            if parity * sign(0) * sign(1) * sign(2) > 0.0 {
                proper.push(std::array::from_fn(|j| {
                    format!("{}{}", if sign(j) < 0.0 { "-" } else { "" }, ["x", "y", "z"][order[j]])
                }));
            }
        }
    }
    assert_eq!(proper.len(), 24);
    let axes: [String; 3] = proper[(draw.uniform(0.0, 24.0) as usize).min(23)].clone();
    let turn = if turned {
        let yaw = draw.uniform(30.0, 45.0);
        [
            draw.uniform(-15.0, 15.0),
            draw.uniform(-15.0, 15.0),
            if draw.uniform(0.0, 1.0) < 0.5 { -yaw } else { yaw },
        ]
    } else {
        [0.0; 3]
    };
    (axes, turn)
}

/// The box flown as real crews fly it (measured on a survey aircraft):
/// pitch, roll and yaw back to back, turns rolled into, and the airframe's
/// cross-axis response to each manoeuvre, drawn from `crew`.
pub fn fly_box_as_crews_do(
    box_: &mut magcomp::simulate::scenario::Calibration,
    crew: &mut magcomp::simulate::random::Random,
) {
    box_.pause_s = [0.0, crew.uniform(0.0, 1.5)];
    let quickest = crew.uniform(1.5, 4.0);
    box_.turn_entry_s = [quickest, crew.uniform(quickest, 6.0)];
    let mut range = |low: f64, high: f64| {
        let a = crew.uniform(low, high);
        [a, crew.uniform(a, high)]
    };
    let coupling = &mut box_.coupling;
    coupling.pitch_roll = range(0.1, 0.3);
    coupling.roll_pitch = range(0.0, 0.1);
    coupling.roll_yaw = range(0.2, 0.4);
    coupling.yaw_roll = range(0.3, 0.55);
    coupling.lag_deg = [0.0, 60.0];
}

/// A reproducible sequence of `count` 64-bit values from `seed`
/// (SplitMix64): the tests' own generator, independent of the simulator's.
pub fn splitmix64(seed: u64, count: usize) -> Vec<u64> {
    let mut state = seed;
    (0..count)
        .map(|_| {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        })
        .collect()
}

/// A crustal anomaly added to `flight`'s survey lines: a Gaussian in time
/// of `amplitude_nt` and half-width `width_s`, centred at `centre_row`, on
/// every scalar channel and along every fluxgate's field (each component
/// scaled by $1 + δ/|B|$), as the Earth's field carries it. Returns the
/// log and δ per row.
pub fn with_anomaly(
    log: &magcomp::ingest::flight_log::FlightLog,
    (centre_row, amplitude_nt, width_s): (usize, f64, f64),
) -> (magcomp::ingest::flight_log::FlightLog, Vec<f64>) {
    let time = log.time_s();
    let centre = time[centre_row];
    let delta: Vec<f64> = (time.iter())
        .map(|t| amplitude_nt * (-((t - centre) / width_s).powi(2)).exp())
        .collect();
    let mut out = log.clone();
    for name in log.scalar_channels() {
        let values: Vec<f64> = (log.channel(name).unwrap().values.iter())
            .zip(&delta)
            .map(|(v, d)| v + d)
            .collect();
        out = out.with_values(name, values).unwrap();
    }
    for sensor in log.vector_sensors() {
        let field = log.vector_components(&sensor);
        let scale: Vec<f64> = (0..log.len())
            .map(|k| {
                let magnitude = field.iter().map(|c| c[k] * c[k]).sum::<f64>().sqrt();
                1.0 + delta[k] / magnitude
            })
            .collect();
        for axis in sensor.axes {
            let channel = &log.channels()[axis];
            let values: Vec<f64> = (channel.values.iter()).zip(&scale).map(|(v, s)| v * s).collect();
            out = out.with_values(&channel.name, values).unwrap();
        }
    }
    (out, delta)
}

/// A clean flight plan drawn from `seed`: the layout, rate, length, site,
/// box, diurnal variation and the fluxgate's mounting. No concealed effect.
pub fn clean_plan(seed: u64) -> RawScenario {
    use magcomp::simulate::random::Random;
    use magcomp::simulate::scenario::{ScalarSensor, SensorLocation};
    let mut draw = Random::new(0x5AFE ^ seed).fork("clean flight");
    let mut raw = RawScenario {
        seed: 20_000 + seed,
        ..RawScenario::default()
    };
    let rates = [5.0, 10.0, 10.0, 20.0, 50.0];
    raw.sample_rate_hz = rates[draw.integer(0, rates.len() - 1)];
    raw.oversampling = (100.0 / raw.sample_rate_hz).round().max(1.0) as usize;
    // 20–240 minutes, fewer at the high rates so that a flight stays
    // under about 100,000 rows.
    let longest_min = (100_000.0 / raw.sample_rate_hz / 60.0).min(240.0);
    let minutes = draw.uniform(20.0, longest_min.max(21.0));
    let locations = [
        SensorLocation::Tail,
        SensorLocation::Cabin,
        SensorLocation::Wing,
        SensorLocation::Nose,
    ];
    let count = draw.integer(1, 8);
    raw.scalar = (0..count)
        .map(|k| {
            let location = match k {
                0 => SensorLocation::Tail,
                _ => locations[draw.integer(0, locations.len() - 1)],
            };
            ScalarSensor::new(&format!("mag_{}_uc", k + 1), location, draw.uniform(0.002, 0.02))
        })
        .collect();
    raw.site.latitude_deg = draw.uniform(-60.0, 70.0);
    raw.site.longitude_deg = draw.uniform(-180.0, 180.0);
    raw.external.diurnal_nt = draw.uniform(10.0, 100.0);
    let box_ = &mut raw.calibration;
    let base = draw.uniform(0.0, 90.0).round();
    box_.headings_deg = (0..4).map(|k| base + 90.0 * k as f64).collect();
    box_.pitch_deg = draw.uniform(3.0, 6.0);
    box_.roll_deg = draw.uniform(6.0, 12.0);
    box_.yaw_deg = draw.uniform(3.0, 6.0);
    box_.turbulence_deg = draw.uniform(0.02, 0.2);
    box_.altitude_m = draw.uniform(1500.0, 4000.0);
    // The survey: lines of 5–15 minutes filling the rest of the flight.
    let survey = &mut raw.survey;
    survey.speed_m_s = draw.uniform(55.0, 75.0);
    let line_min = draw.uniform(5.0, 15.0);
    survey.line_length_m = line_min * 60.0 * survey.speed_m_s;
    survey.line_count = (((minutes - 12.0) / (line_min + 1.0)).round() as usize).max(1);
    survey.line_heading_deg = draw.uniform(0.0, 180.0).round();
    survey.altitude_m = draw.uniform(100.0, 400.0);
    survey.turbulence_deg = draw.uniform(0.2, 1.0);
    raw.crust.dipole_count = 12;
    // Half the boxes flown as real crews fly them (measured on a survey
    // aircraft): pitch, roll and yaw back to back, turns rolled into, and
    // the airframe's cross-axis response to each manoeuvre (its own draws:
    // the rest of the plan is unchanged).
    let mut crew = Random::new(0x5AFE ^ seed).fork("clean flight crew");
    if crew.uniform(0.0, 1.0) < 0.5 {
        fly_box_as_crews_do(&mut raw.calibration, &mut crew);
    }
    // Tie lines across the block, as most surveys fly them (their own
    // draws: the rest of the plan is unchanged).
    let mut ties = Random::new(0x5AFE ^ seed).fork("clean flight ties");
    if ties.uniform(0.0, 1.0) < 0.8 {
        raw.survey.tie_count = ties.integer(1, 4);
    }
    // The fluxgate mounted any way round, as on real aircraft (its own
    // draws: the rest of the plan is unchanged).
    let mut mount = Random::new(0x5AFE ^ seed).fork("clean flight mounting");
    let turned = mount.uniform(0.0, 1.0) < 0.5;
    let (axes, turn) = random_mounting(&mut mount, turned);
    raw.fluxgate[0].axes = axes;
    raw.fluxgate[0].turn_deg = turn;
    raw
}
