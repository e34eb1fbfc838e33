//! Shared by the diagnosis tests: a simulated flight with the tail, cabin
//! and wing sensors, diagnosed with the default settings.

use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::Diagnosis;
use magcomp::pipeline::{diagnose_flight, StageOptions};
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
    let flight = simulate(scenario).unwrap();
    let pipeline = Pipeline::default();
    let job = FlightJob {
        diagnosis: None,
        input: "simulated".into(),
        vector: None,
        channels: None,
        windows: Vec::new(),
    };
    diagnose_flight(&flight.log, &job, &StageOptions::from(&pipeline), &pipeline.diagnose).unwrap()
}
