//! The plan file: its `[plan]` settings, the scenario it flies, and the
//! aircraft field a previous flight's model installs at each sensor.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::simulate::physics::AircraftField;
use crate::simulate::scenario::{RawScenario, ScalarSensor, Scenario, SensorLocation};

/// Realisations when `[plan]` gives none.
const DEFAULT_REALISATIONS: usize = 8;

/// Most realisations a plan may ask for.
const MOST_REALISATIONS: usize = 64;

/// `[plan]`: how to predict.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlanSettings {
    /// Simulated flights of the plan.
    pub realisations: usize,
    /// The survey uncertainty wanted, one sigma, nT.
    pub target_survey_sigma_nt: Option<f64>,
    /// The FOM wanted, nT.
    pub target_fom_nt: Option<f64>,
    /// A previous flight's model JSON (`compensate --model`): the
    /// aircraft's field at each sensor it compensates.
    pub installation: Option<PathBuf>,
    /// Most manoeuvres added (a repeat counts each time).
    pub most_additions: usize,
}

impl Default for PlanSettings {
    fn default() -> Self {
        PlanSettings {
            realisations: DEFAULT_REALISATIONS,
            target_survey_sigma_nt: None,
            target_fom_nt: None,
            installation: None,
            most_additions: 6,
        }
    }
}

/// A checked plan.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The plan file.
    pub path: PathBuf,
    /// `[plan]`.
    pub settings: PlanSettings,
    /// The planned flight.
    pub scenario: Scenario,
    /// Where each sensor's aircraft field comes from, in words.
    pub installation: String,
}

impl Plan {
    /// Reads and checks a plan file.
    pub fn load(path: &Path) -> Result<Plan> {
        let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
        let config = |message: String| Error::Config {
            source_name: path.display().to_string(),
            message,
        };
        let mut table: toml::Table = toml::from_str(&text).map_err(|e| config(e.to_string()))?;
        let settings: PlanSettings = match table.remove("plan") {
            Some(value) => value.try_into().map_err(|e| config(format!("[plan]: {e}")))?,
            None => PlanSettings::default(),
        };
        let has_scalars = table.contains_key("scalar");
        let mut raw: RawScenario = toml::Value::Table(table)
            .try_into()
            .map_err(|e| config(e.to_string()))?;
        check_plan(&settings, &raw).map_err(config)?;
        let installation = match &settings.installation {
            None => "typical values: each scalar sensor's aircraft field drawn at its location's size (tail, wing or cabin), afresh in every realisation".to_string(),
            Some(file) => {
                let file = match file.is_absolute() {
                    true => file.clone(),
                    false => path.parent().unwrap_or(Path::new(".")).join(file),
                };
                install(&mut raw, &file, has_scalars)?
            }
        };
        let scenario = Scenario::try_from(raw).map_err(config)?;
        Ok(Plan {
            path: path.to_path_buf(),
            settings,
            scenario,
            installation,
        })
    }
}

/// Refuses a plan that cannot be predicted: too few or too many simulated
/// flights, a target that is not a positive number of nT, or no box.
fn check_plan(settings: &PlanSettings, raw: &RawScenario) -> std::result::Result<(), String> {
    if !(1..=MOST_REALISATIONS).contains(&settings.realisations) {
        return Err(format!(
            "[plan] realisations = {}: give 1 to {MOST_REALISATIONS} simulated flights",
            settings.realisations
        ));
    }
    for (name, target) in [
        ("target_survey_sigma_nt", settings.target_survey_sigma_nt),
        ("target_fom_nt", settings.target_fom_nt),
    ] {
        if target.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
            return Err(format!("[plan] {name}: give a positive number of nT"));
        }
    }
    if raw.calibration.repeats == 0 {
        return Err("[calibration] repeats = 0: a plan needs a calibration box to predict".into());
    }
    Ok(())
}

/// The aircraft field of each mag_<n>_uc channel of a model JSON's
/// `models`, and the terms each leaves out (in words).
fn aircraft_fields(models: &[serde_json::Value]) -> (BTreeMap<String, AircraftField>, Vec<String>) {
    let mut fields: BTreeMap<String, AircraftField> = BTreeMap::new();
    let mut left_out: Vec<String> = Vec::new();
    for model in models {
        let (Some(channel), Some((field, unused))) =
            (model.get("channel").and_then(|c| c.as_str()), aircraft_field(model))
        else {
            continue;
        };
        if channel.starts_with("mag_") && channel.ends_with("_uc") {
            fields.insert(channel.to_string(), field);
            if !unused.is_empty() {
                left_out.push(format!("{channel}'s {}", unused.join(", ")));
            }
        }
    }
    (fields, left_out)
}

/// Sets the aircraft field of each scalar sensor of `raw` that the model
/// file at `file` compensates (all of the file's channels when the plan
/// names no sensor); says what was taken.
fn install(raw: &mut RawScenario, file: &Path, has_scalars: bool) -> Result<String> {
    let not_ours = |problem: String| {
        Error::NotOurFile {
        path: file.to_path_buf(),
        expected: "a model JSON written by compensate --model",
        problem,
        hint: "Give [plan] installation the --model file of a previous flight of this aircraft, or leave it out for typical values.",
    }
    };
    let text = crate::ingest::read_text(file).map_err(|e| Error::io(file, "reading", e))?;
    let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| not_ours(e.to_string()))?;
    let models = json
        .get("models")
        .and_then(|m| m.as_array())
        .ok_or_else(|| not_ours("it has no \"models\" list".into()))?;
    let (fields, left_out) = aircraft_fields(models);
    if fields.is_empty() {
        return Err(not_ours(
            "no model of a mag_<n>_uc channel with Tolles-Lawson coefficients and a sample rate".into(),
        ));
    }
    if !has_scalars {
        raw.scalar = fields
            .keys()
            .map(|name| ScalarSensor::new(name, SensorLocation::Tail, 0.005))
            .collect();
    }
    let mut taken = Vec::new();
    let mut typical = Vec::new();
    for sensor in &mut raw.scalar {
        match fields.get(&sensor.name) {
            Some(field) => {
                sensor.aircraft = Some(field.clone());
                taken.push(sensor.name.clone());
            }
            None => typical.push(sensor.name.clone()),
        }
    }
    Ok(installed_words(file, &taken, &left_out, &typical))
}

/// What [`install`] took from the model file at `file`, in words: the
/// sensors `taken` from it, the terms `left_out` and the sensors drawn at
/// their `typical` size.
fn installed_words(file: &Path, taken: &[String], left_out: &[String], typical: &[String]) -> String {
    let mut words = format!(
        "from {}: the aircraft's field at {} from that flight's Tolles-Lawson coefficients",
        file.display(),
        taken.join(", ")
    );
    if !left_out.is_empty() {
        words += &format!(
            "; left out, as the simulated aircraft field holds no such term: {}",
            left_out.join("; ")
        );
    }
    if !typical.is_empty() {
        words += &format!(
            "; {} not in it, so drawn at the location's typical size",
            typical.join(", ")
        );
    }
    words
}

/// The simulator's aircraft field from one model of a model JSON: the
/// permanent terms are P; the induced terms $a_{ij} u_i B_j / s$ give the
/// symmetric A ($a_{ii} = s A_{ii}$, $a_{ij} = 2 s A_{ij}$); the eddy
/// terms $b_{ij} u_i \Delta B_j / s$, ΔB per sample, give
/// $E_{ij} = b_{ij} / (s f_s)$ in seconds. Terms the model lacks are zero;
/// extension columns (lags, couplings) are left out and named. `None`
/// without coefficients or a sample rate.
fn aircraft_field(model: &serde_json::Value) -> Option<(AircraftField, Vec<String>)> {
    let names = model.get("term_names")?.as_array()?;
    let values = model.get("coefficients")?.as_array()?;
    let rate = model.get("sample_rate_hz")?.as_f64().filter(|r| *r > 0.0)?;
    let scale = (model.pointer("/spec/terms/bt_scale_nt"))
        .and_then(|s| s.as_f64())
        .filter(|s| *s > 0.0)?;
    let axis = |c: char| "xyz".find(c);
    let mut field = AircraftField {
        permanent_nt: [0.0; 3],
        induced: [[0.0; 3]; 3],
        eddy_s: [[0.0; 3]; 3],
    };
    let mut any = false;
    let mut unused = Vec::new();
    for (name, value) in names.iter().zip(values) {
        let (Some(name), Some(value)) = (name.as_str(), value.as_f64()) else {
            continue;
        };
        let letters: Vec<usize> = name.rsplit('_').next()?.chars().filter_map(axis).collect();
        match (name.split('_').next(), letters.as_slice()) {
            (Some("perm"), &[i]) => field.permanent_nt[i] = value,
            (Some("ind"), &[i, j]) if i == j => field.induced[i][i] = value / scale,
            (Some("ind"), &[i, j]) => {
                field.induced[i][j] = value / (2.0 * scale);
                field.induced[j][i] = field.induced[i][j];
            }
            (Some("eddy"), &[i, j]) => field.eddy_s[i][j] = value / (scale * rate),
            _ => {
                unused.push(name.to_string());
                continue;
            }
        }
        any = true;
    }
    (any && field.is_plausible()).then_some((field, unused))
}
