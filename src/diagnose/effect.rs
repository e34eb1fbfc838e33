//! What a finding names: the effect and its physical parameters, typed.
//!
//! DIAGNOSIS.json writes a finding's effect as its CONTRACT §3 name
//! (`"effect": "sensor_lag"`) and the parameters as a flat object of named
//! numbers (`"parameters": {"lag_s": 0.12}`), units in the names. Here each
//! effect carries its own parameter struct, so a reader of a finding
//! matches on the effect instead of looking names up in a map;
//! [`Effect::parameters`] gives the flat names the file and the report use.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

/// The effects the diagnosis can name, by their CONTRACT §3 names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EffectKind {
    /// The scalar reads the field late (or early) against the regressors.
    SensorLag,
    /// A recorded channel drives a body-fixed field at the scalar.
    AuxCoupling,
    /// Geomagnetic variation a base station recorded.
    ExternalField,
    /// Eddy currents that respond through a first-order lag.
    EddyTimeConstant,
    /// The fluxgate's scale, non-orthogonality and offsets.
    VectorCalibration,
    /// The aircraft field's second-order part of the total field.
    SecondOrder,
    /// Interference the attitude terms cannot hold, seen by other sensors
    /// less a reference scalar, free of geology.
    CrossSensor,
    /// Structured residual nothing in the library explains.
    Unexplained,
}

impl EffectKind {
    /// The CONTRACT §3 name: `sensor_lag`, `aux_coupling`, ...
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::SensorLag => "sensor_lag",
            EffectKind::AuxCoupling => "aux_coupling",
            EffectKind::ExternalField => "external_field",
            EffectKind::EddyTimeConstant => "eddy_time_constant",
            EffectKind::VectorCalibration => "vector_calibration",
            EffectKind::SecondOrder => "second_order",
            EffectKind::CrossSensor => "cross_sensor",
            EffectKind::Unexplained => "unexplained",
        }
    }
}

impl fmt::Display for EffectKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A named effect with the parameters the diagnosis found for it.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// `sensor_lag`.
    SensorLag(SensorLag),
    /// `aux_coupling`.
    AuxCoupling(AuxCoupling),
    /// `external_field`.
    ExternalField(ExternalField),
    /// `eddy_time_constant`.
    EddyTimeConstant(EddyTimeConstant),
    /// `vector_calibration`.
    VectorCalibration(FluxgateErrors),
    /// `second_order`.
    SecondOrder(SecondOrder),
    /// `cross_sensor`.
    CrossSensor(CrossSensor),
    /// `unexplained`.
    Unexplained(Unexplained),
}

/// The scalar reads the field `lag_s` later than the fluxgate and the
/// attitude (negative: earlier).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorLag {
    /// Lag, s.
    pub lag_s: f64,
}

/// A recorded channel c coupled into the scalar through the direction
/// cosines: $c\,(k \cdot u)$ and, when its rate acts too,
/// $\dot c\,(\dot k \cdot u)$ (eddy currents a changing current induces).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AuxCoupling {
    /// Body-axis field per unit of the channel, nT per unit (x, y, z);
    /// `None` when only the rate couples.
    pub k_nt_per_unit: Option<[f64; 3]>,
    /// Body-axis field per unit/s of the channel's rate, nT·s per unit
    /// (x, y, z); `None` when only the channel itself couples.
    pub kdot_nt_s_per_unit: Option<[f64; 3]>,
}

/// The geology-free signal s of other sensors (a fluxgate's magnitude or
/// another scalar, less a reference scalar, less its attitude part)
/// coupled into the scalar through the direction cosines: $s\,(k \cdot u)$.
#[derive(Debug, Clone, PartialEq)]
pub struct CrossSensor {
    /// nT at the channel per nT of the signal, along each body axis.
    pub k: [f64; 3],
    /// What the survey, which the fit never saw, says of it; `None` where
    /// it could not be measured (no survey lines, or no scalar outside the
    /// signal to measure against).
    pub survey: Option<SurveyEvidence>,
    /// g, where the gain was fitted on the survey ($g\,s$, held out line
    /// by line): `k` is then zero.
    pub survey_gain: Option<f64>,
}

/// A cross-sensor term judged on the survey lines: the channel's
/// difference from a quiet scalar the signal does not read (both
/// compensated, RMS about its mean over the survey's line rows outside
/// the calibration), without the term and with it. What a current no
/// column records adds to a cabin sensor shows in that difference on
/// every line, and the term, fitted on the box, takes it out; a signal
/// that only stands in for another sensor's residual on the box moves it
/// by a few per cent at most (under 2 % on the clean twins of the
/// unrecorded-current campaign).
#[derive(Debug, Clone, PartialEq)]
pub struct SurveyEvidence {
    /// The quiet scalar the difference is taken from.
    pub reference: String,
    /// The difference's RMS without the term, nT.
    pub before_nt: f64,
    /// With it, nT.
    pub after_nt: f64,
    /// Survey lines on which the term lowers the difference.
    pub lines_lower: usize,
    /// Survey lines measured.
    pub lines: usize,
}

/// The least share of the channel's survey difference from the quiet
/// scalar a cross-sensor term must take out to be borne out there.
pub const SURVEY_CROSS_GAIN: f64 = 0.15;

impl SurveyEvidence {
    /// Whether the survey bears the term out: the difference falls by
    /// [`SURVEY_CROSS_GAIN`] or more overall, and on more than half the
    /// lines.
    pub fn holds(&self) -> bool {
        self.lines >= 2
            && self.after_nt <= (1.0 - SURVEY_CROSS_GAIN) * self.before_nt
            && 2 * self.lines_lower > self.lines
    }
}

/// The scalar follows a base station's record with this gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExternalField {
    /// Dimensionless gain (1 for the same variation at both), measured
    /// over the calibration windows; the model subtracts the station's
    /// variation with gain 1 whatever it is.
    pub gain: f64,
}

/// The eddy terms respond through $\tau \dot y + y = x$.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EddyTimeConstant {
    /// Time constant τ, s.
    pub tau_s: f64,
}

/// The fluxgate's calibration errors (see
/// [`crate::calibration::fluxgate::VectorCalibration`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FluxgateErrors {
    /// Scale factor of each axis (x, y, z), dimensionless.
    pub scale: [f64; 3],
    /// Offset of each axis (x, y, z), nT.
    pub offset_nt: [f64; 3],
    /// Angle by which each pair of axes (xy, xz, yz) misses 90°, degrees.
    pub non_orthogonality_deg: [f64; 3],
}

/// The total field's second-order term $|F_\perp|^2 / 2|B|$: the
/// aircraft field across the Earth's, computed from the fitted permanent
/// and induced coefficients, so it adds no coefficient of its own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SecondOrder {
    /// RMS of the term over the calibration windows, nT.
    pub term_rms_nt: f64,
}

/// What the localisation found of a residual nothing explains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Unexplained {
    /// Share of the residual's energy in structured stretches, 0–1.
    pub structured_energy_share: f64,
    /// The sensor's noise floor in the calibration band, nT.
    pub noise_floor_nt: f64,
    /// The held-out residual over that noise floor.
    pub residual_to_noise: f64,
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl Effect {
    /// Which effect this is.
    pub fn kind(&self) -> EffectKind {
        match self {
            Effect::SensorLag(_) => EffectKind::SensorLag,
            Effect::AuxCoupling(_) => EffectKind::AuxCoupling,
            Effect::ExternalField(_) => EffectKind::ExternalField,
            Effect::EddyTimeConstant(_) => EffectKind::EddyTimeConstant,
            Effect::VectorCalibration(_) => EffectKind::VectorCalibration,
            Effect::SecondOrder(_) => EffectKind::SecondOrder,
            Effect::CrossSensor(_) => EffectKind::CrossSensor,
            Effect::Unexplained(_) => EffectKind::Unexplained,
        }
    }

    /// The CONTRACT §3 name.
    pub fn name(&self) -> &'static str {
        self.kind().name()
    }

    /// The parameters under DIAGNOSIS.json's names, units in each name:
    /// `lag_s`; `k_x_nt_per_unit` … and `kdot_x_nt_s_per_unit` …; `gain`;
    /// `tau_s`; `scale_x` …, `offset_x_nt` …, `non_orthogonality_xy_deg` …;
    /// `term_rms_nt`; `k_x` … (cross-sensor, nT per nT); `structured_energy_share`, `noise_floor_nt`,
    /// `residual_to_noise`.
    pub fn parameters(&self) -> BTreeMap<String, f64> {
        let mut named = BTreeMap::new();
        let axes = |pattern: &str, values: [f64; 3], named: &mut BTreeMap<String, f64>| {
            for (axis, value) in AXES.iter().zip(values) {
                named.insert(pattern.replace("{}", axis), value);
            }
        };
        match self {
            Effect::SensorLag(p) => {
                named.insert("lag_s".into(), p.lag_s);
            }
            Effect::AuxCoupling(p) => {
                if let Some(k) = p.k_nt_per_unit {
                    axes("k_{}_nt_per_unit", k, &mut named);
                }
                if let Some(kdot) = p.kdot_nt_s_per_unit {
                    axes("kdot_{}_nt_s_per_unit", kdot, &mut named);
                }
            }
            Effect::ExternalField(p) => {
                named.insert("gain".into(), p.gain);
            }
            Effect::EddyTimeConstant(p) => {
                named.insert("tau_s".into(), p.tau_s);
            }
            Effect::VectorCalibration(p) => {
                axes("scale_{}", p.scale, &mut named);
                axes("offset_{}_nt", p.offset_nt, &mut named);
                for (pair, angle) in ["xy", "xz", "yz"].iter().zip(p.non_orthogonality_deg) {
                    named.insert(format!("non_orthogonality_{pair}_deg"), angle);
                }
            }
            Effect::SecondOrder(p) => {
                named.insert("term_rms_nt".into(), p.term_rms_nt);
            }
            Effect::CrossSensor(p) => {
                axes("k_{}", p.k, &mut named);
                if let Some(survey) = &p.survey {
                    named.insert("survey_rms_before_nt".into(), survey.before_nt);
                    named.insert("survey_rms_after_nt".into(), survey.after_nt);
                }
                if let Some(gain) = p.survey_gain {
                    named.insert("survey_gain".into(), gain);
                }
            }
            Effect::Unexplained(p) => {
                named.insert("structured_energy_share".into(), p.structured_energy_share);
                named.insert("noise_floor_nt".into(), p.noise_floor_nt);
                named.insert("residual_to_noise".into(), p.residual_to_noise);
            }
        }
        named
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameters_carry_diagnosis_json_names() {
        let coupling = Effect::AuxCoupling(AuxCoupling {
            k_nt_per_unit: Some([1.0, 2.0, 3.0]),
            kdot_nt_s_per_unit: None,
        });
        let names: Vec<String> = coupling.parameters().into_keys().collect();
        assert_eq!(names, ["k_x_nt_per_unit", "k_y_nt_per_unit", "k_z_nt_per_unit"]);
        assert_eq!(coupling.parameters()["k_y_nt_per_unit"], 2.0);
        let fluxgate = Effect::VectorCalibration(FluxgateErrors {
            scale: [1.01, 0.99, 1.0],
            offset_nt: [10.0, -20.0, 30.0],
            non_orthogonality_deg: [0.5, -0.25, 0.125],
        });
        let parameters = fluxgate.parameters();
        assert_eq!(parameters.len(), 9);
        assert_eq!(parameters["offset_y_nt"], -20.0);
        assert_eq!(parameters["non_orthogonality_xz_deg"], -0.25);
        assert_eq!(
            serde_json::to_string(&EffectKind::EddyTimeConstant).unwrap(),
            "\"eddy_time_constant\""
        );
        assert_eq!(fluxgate.to_string(), "vector_calibration");
    }

    #[test]
    fn a_finding_is_written_with_its_effect_name_and_flat_parameters() {
        let finding = crate::diagnose::Finding {
            effect: Effect::SensorLag(SensorLag { lag_s: 0.25 }),
            channel: "mag_1_uc".into(),
            source: None,
            explanation: "late".into(),
            located: Vec::new(),
            heldout_rms_before_nt: 0.5,
            heldout_rms_after_nt: 0.125,
            not_applied: None,
            anomaly_gain: None,
        };
        assert_eq!(
            serde_json::to_string(&finding).unwrap(),
            r#"{"effect":"sensor_lag","channel":"mag_1_uc","parameters":{"lag_s":0.25},"explanation":"late","located":[],"heldout_rms_before_nt":0.5,"heldout_rms_after_nt":0.125}"#
        );
    }

    #[test]
    fn the_survey_bears_a_cross_sensor_term_out_by_its_share_and_its_lines() {
        let evidence = |after_nt: f64, lines_lower: usize, lines: usize| SurveyEvidence {
            reference: "mag_1_uc".into(),
            before_nt: 1.0,
            after_nt,
            lines_lower,
            lines,
        };
        // 15 % off on 6 of 10 lines holds; 14 % off, or 5 of 10 lines, does not.
        assert!(evidence(0.85, 6, 10).holds());
        assert!(!evidence(0.86, 10, 10).holds());
        assert!(!evidence(0.5, 5, 10).holds());
        // One line is no survey.
        assert!(!evidence(0.5, 1, 1).holds());
        let cross = Effect::CrossSensor(CrossSensor {
            k: [0.5, -0.25, 2.0],
            survey: Some(evidence(0.75, 7, 8)),
            survey_gain: None,
        });
        let parameters = cross.parameters();
        assert_eq!(parameters["k_y"], -0.25);
        assert_eq!(parameters["survey_rms_before_nt"], 1.0);
        assert_eq!(parameters["survey_rms_after_nt"], 0.75);
        let unjudged = Effect::CrossSensor(CrossSensor {
            k: [0.5, -0.25, 2.0],
            survey: None,
            survey_gain: None,
        });
        assert_eq!(unjudged.parameters().len(), 3);
        let fitted = Effect::CrossSensor(CrossSensor {
            k: [0.0; 3],
            survey: Some(evidence(0.5, 8, 8)),
            survey_gain: Some(1.5),
        });
        assert_eq!(fitted.parameters()["survey_gain"], 1.5);
        assert_eq!(fitted.parameters().len(), 6);
    }
}
