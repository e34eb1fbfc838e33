//! Shared by the diagnosis tests: a simulated flight with the tail, cabin
//! and wing sensors, diagnosed with the default settings; and every
//! channel of a flight fitted with its diagnosed model.

// Each test binary uses its own share of these helpers.
#![allow(dead_code)]

use std::collections::BTreeMap;

use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::Diagnosis;
use magcomp::flight_log::{FlightLog, VectorSensor};
use magcomp::model::{Extensions, FittedModel, ModelSpec};
use magcomp::pipeline::diagnose_flight;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::simulate;
use magcomp::windows::CalibrationWindow;

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
pub fn with_unrelated_columns(log: &magcomp::flight_log::FlightLog, count: usize) -> magcomp::flight_log::FlightLog {
    use magcomp::flight_log::{Channel, ChannelRole, FlightLog};
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
pub fn diagnose_log(log: &magcomp::flight_log::FlightLog) -> Diagnosis {
    let pipeline = Pipeline::default();
    let job = FlightJob {
        diagnosis: None,
        force_diagnosis: false,
        date: None,
        input: "simulated".into(),
        vector: None,
        channels: None,
        windows: Vec::new(),
    };
    diagnose_flight(log, &job, &pipeline.settings, &pipeline.settings.diagnose).unwrap()
}

/// The held-out RMS of `model` on `channel`, scored as the diagnosis
/// scores its candidates, on `log`'s detected box.
pub fn heldout_rms(log: &magcomp::flight_log::FlightLog, channel: &str, model: &magcomp::model::Extensions) -> f64 {
    let pipeline = Pipeline::default();
    let options = pipeline.settings.clone();
    let windows = magcomp::detect::detect_manoeuvres(log, &options.detect)
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
