//! SCENARIO.toml: what to fly, what the aircraft is made of, and which
//! effects to conceal.
//!
//! Every table and field has a default, so an empty file is a valid
//! scenario: a four-heading box at 3000 m and four survey lines at 300 m over
//! eastern Ontario, a tail stinger and a cabin magnetometer, one fluxgate,
//! the usual current channels, and no concealed effect.
//!
//! ```toml
//! seed = 7
//! date = "2026-06-15"       # IGRF epoch (UTC day)
//! start_time_s = 46000.0    # seconds past midnight UTC
//! sample_rate_hz = 10.0
//! oversampling = 10         # internal rate = oversampling × sample rate
//!
//! [site]
//! latitude_deg = 45.3
//! longitude_deg = -75.7
//! ground_msl_m = 80.0
//!
//! [calibration]
//! headings_deg = [20.0, 110.0, 200.0, 290.0]
//! altitude_m = 3000.0
//! repeats = 1               # boxes flown
//! cycles = [2, 4]           # per manoeuvre, drawn per manoeuvre
//! period_s = [4.0, 8.0]
//! pitch_deg = 5.0
//! roll_deg = 10.0
//! yaw_deg = 5.0
//! omit = ["yaw@290"]        # manoeuvres the pilot forgets
//! weaken = ["roll@110=0.2"] # manoeuvres flown at a fraction of the amplitude
//! extra = ["roll@110"]      # manoeuvres flown again at the end of their leg
//! turbulence_deg = 0.05
//!
//! [survey]
//! line_count = 4
//! line_heading_deg = 0.0
//! line_length_m = 9000.0
//! line_spacing_m = 500.0
//! tie_count = 0             # tie lines across the block after its last line
//! altitude_m = 300.0
//! turbulence_deg = 0.8
//!
//! [[scalar]]                # one per scalar magnetometer
//! name = "mag_1_uc"
//! location = "tail"         # tail | wing | cabin: sets the aircraft field's size
//! noise_nt = 0.005
//! # aircraft = { permanent_nt = [..], induced = [[..], [..], [..]], eddy_s = [[..], [..], [..]] }
//! #                         # this aircraft's field instead of one drawn for the location
//!
//! [[fluxgate]]              # one per vector magnetometer
//! name = "flux_a"
//! permanent_nt = 40.0       # sizes the aircraft's field at the fluxgate is drawn at
//! # aircraft = { .. }       # or the field itself, as for a scalar
//!
//! [[effect]]                # concealed in the output, written to the truth file
//! kind = "sensor_lag"
//! channel = "mag_1_uc"
//! lag_s = 0.15
//! ```

use std::path::Path;

use serde::Deserialize;

use crate::diagnose::EffectKind;
use crate::error::{Error, Result};
use crate::simulate::igrf::decimal_year;
use crate::simulate::physics::AircraftField;

/// A scenario, as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RawScenario {
    /// Random seed; the same scenario and seed give the same bytes.
    pub seed: u64,
    /// UTC day of the flight, `YYYY-MM-DD`.
    pub date: String,
    /// First sample, seconds past midnight UTC.
    pub start_time_s: f64,
    /// Output sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Internal samples per output sample (anti-alias averaging).
    pub oversampling: usize,
    /// Where the survey is.
    pub site: Site,
    /// The calibration box.
    pub calibration: Calibration,
    /// The survey lines.
    pub survey: Survey,
    /// The ground below.
    pub crust: Crust,
    /// Geomagnetic variation.
    pub external: External,
    /// Scalar magnetometers.
    pub scalar: Vec<ScalarSensor>,
    /// Fluxgate (vector) magnetometers.
    pub fluxgate: Vec<Fluxgate>,
    /// Concealed effects.
    pub effect: Vec<Effect>,
}

impl Default for RawScenario {
    fn default() -> Self {
        RawScenario {
            seed: 1,
            date: "2026-06-15".into(),
            start_time_s: 46_000.0,
            sample_rate_hz: 10.0,
            oversampling: 10,
            site: Site::default(),
            calibration: Calibration::default(),
            survey: Survey::default(),
            crust: Crust::default(),
            external: External::default(),
            scalar: vec![
                ScalarSensor::new("mag_1_uc", SensorLocation::Tail, 0.005),
                ScalarSensor::new("mag_2_uc", SensorLocation::Cabin, 0.01),
            ],
            fluxgate: vec![Fluxgate::default()],
            effect: Vec::new(),
        }
    }
}

/// `[site]`: the survey area's origin.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Site {
    /// Geodetic latitude of the first survey line's start, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees east.
    pub longitude_deg: f64,
    /// Ground height above mean sea level (≈ ellipsoid here), m.
    pub ground_msl_m: f64,
}

impl Default for Site {
    fn default() -> Self {
        Site {
            latitude_deg: 45.3,
            longitude_deg: -75.7,
            ground_msl_m: 80.0,
        }
    }
}

/// `[calibration]`: the FOM box and the pilot's habits.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Calibration {
    /// Leg headings, degrees clockwise from north, in flying order.
    pub headings_deg: Vec<f64>,
    /// Height above ground, m.
    pub altitude_m: f64,
    /// How many times the box is flown.
    pub repeats: usize,
    /// Cycles per manoeuvre, drawn uniformly from this inclusive range.
    pub cycles: [usize; 2],
    /// Manoeuvre period range, s.
    pub period_s: [f64; 2],
    /// Pitch amplitude, degrees.
    pub pitch_deg: f64,
    /// Roll amplitude, degrees.
    pub roll_deg: f64,
    /// Yaw amplitude, degrees.
    pub yaw_deg: f64,
    /// Manoeuvres left out, as `kind@heading`, e.g. `yaw@290`.
    pub omit: Vec<String>,
    /// Manoeuvres flown at a fraction of their amplitude, as
    /// `kind@heading=fraction`, e.g. `roll@110=0.2`.
    pub weaken: Vec<String>,
    /// Manoeuvres flown once more at the end of their leg (after its pitch,
    /// roll and yaw), as `kind@heading`, e.g. `roll@110`; a heading must be
    /// one of `headings_deg`.
    pub extra: Vec<String>,
    /// Standard deviation of attitude turbulence on the legs, degrees.
    pub turbulence_deg: f64,
    /// Standard deviation of a slow (30 s) drift of the held heading on the
    /// legs, degrees: a pilot who lets the track wander.
    pub heading_wander_deg: f64,
    /// Ground speed, m/s.
    pub speed_m_s: f64,
    /// Where the boxes are flown: before the survey lines, between two
    /// halves of them, or after them.
    pub position: BoxPosition,
    /// The last leg runs on into the survey: after its manoeuvres the
    /// aircraft holds the heading, descends straight to survey height and
    /// flies the next survey line on that same heading, with no turn.
    pub continue_into_survey: bool,
    /// The first leg follows a straight climb to box height on its own
    /// heading (from survey height, or from the ground at the start).
    pub climb_before: bool,
    /// Turns between legs go the long way round (a clover leaf: 270° for a
    /// 90° change of heading).
    pub clover_leaf: bool,
    /// Level flight on each leg before its first manoeuvre, s (drawn per leg).
    pub lead_in_s: [f64; 2],
    /// Level flight after each manoeuvre, s (drawn per manoeuvre). Real
    /// crews often fly the three back to back: `[0, 1]`.
    pub pause_s: [f64; 2],
    /// Level flight between a leg's last manoeuvre and the turn to the
    /// next leg, s (drawn per leg); unset, the last manoeuvre's pause. Real
    /// crews often roll into the turn 0–4 s after the yaw: `[0, 4]`.
    pub turn_after_s: Option<[f64; 2]>,
    /// Rate of the turns between legs, degrees/s (drawn per turn); the bank
    /// follows from the speed (3°/s at 70 m/s banks 20.5°).
    pub turn_rate_deg_s: [f64; 2],
    /// Time to roll into (and out of) the turns between legs, s (drawn per
    /// turn): the heading's rate follows the bank as it builds, so the
    /// heading leaves the leg gradually, as a real aircraft's does. Zero
    /// (the default) starts the turn's rate at once.
    pub turn_entry_s: [f64; 2],
    /// The airframe's cross-axis response to the pilot's input.
    pub coupling: Coupling,
    /// The line number each box carries in the line column, in flying
    /// order (SGL files number their calibration lines, e.g. 1002.20);
    /// boxes beyond the list carry 0, as off-line flight does.
    pub line_numbers: Vec<f64>,
}

/// `[calibration.coupling]`: the motion of the other axes during a
/// manoeuvre, as a fraction of the driven axis's amplitude, drawn per
/// manoeuvre from each range, with a phase lag drawn from `lag_deg`.
/// Measured on a real survey aircraft: roll 0.2× a pitch, adverse yaw
/// 0.25–0.3× a roll, roll 0.4–0.46× a yaw.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Coupling {
    /// Roll during a pitch manoeuvre.
    pub pitch_roll: [f64; 2],
    /// Pitch during a roll manoeuvre.
    pub roll_pitch: [f64; 2],
    /// Yaw during a roll manoeuvre (adverse yaw, against the roll).
    pub roll_yaw: [f64; 2],
    /// Roll during a yaw manoeuvre (the wing that advances lifts).
    pub yaw_roll: [f64; 2],
    /// Phase lag of the coupled motion behind the driven one, degrees.
    pub lag_deg: [f64; 2],
}

impl Default for Coupling {
    fn default() -> Self {
        Coupling {
            pitch_roll: [0.0, 0.0],
            roll_pitch: [0.0, 0.0],
            roll_yaw: [0.0, 0.0],
            yaw_roll: [0.0, 0.0],
            lag_deg: [0.0, 0.0],
        }
    }
}

/// Where the calibration boxes sit in the flight.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum BoxPosition {
    /// Before the survey lines.
    #[default]
    Start,
    /// Between the first half of the survey lines and the rest.
    Middle,
    /// After the survey lines.
    End,
}

impl Default for Calibration {
    fn default() -> Self {
        Calibration {
            headings_deg: vec![20.0, 110.0, 200.0, 290.0],
            altitude_m: 3000.0,
            repeats: 1,
            cycles: [2, 4],
            period_s: [4.0, 8.0],
            pitch_deg: 5.0,
            roll_deg: 10.0,
            yaw_deg: 5.0,
            omit: Vec::new(),
            weaken: Vec::new(),
            extra: Vec::new(),
            turbulence_deg: 0.05,
            heading_wander_deg: 0.0,
            speed_m_s: 70.0,
            position: BoxPosition::Start,
            continue_into_survey: false,
            climb_before: false,
            clover_leaf: false,
            lead_in_s: [20.0, 20.0],
            pause_s: [8.0, 14.0],
            turn_after_s: None,
            turn_rate_deg_s: [3.0, 3.0],
            turn_entry_s: [0.0, 0.0],
            coupling: Coupling::default(),
            line_numbers: Vec::new(),
        }
    }
}

/// `[survey]`: lines flown after the box.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Survey {
    /// Number of lines; they alternate direction.
    pub line_count: usize,
    /// Heading of the first line, degrees.
    pub line_heading_deg: f64,
    /// Line length, m.
    pub line_length_m: f64,
    /// Distance between lines, m; 0 reflies one line in both directions
    /// (a heading test).
    pub line_spacing_m: f64,
    /// Tie lines flown across the block of lines after its last line,
    /// perpendicular to them and spread evenly along them (numbered from
    /// 9001): where each crosses a line, the survey measures the same
    /// ground on two headings.
    pub tie_count: usize,
    /// Height above ground, m.
    pub altitude_m: f64,
    /// Attitude turbulence, degrees (standard deviation).
    pub turbulence_deg: f64,
    /// Ground speed, m/s.
    pub speed_m_s: f64,
}

impl Default for Survey {
    fn default() -> Self {
        Survey {
            line_count: 4,
            line_heading_deg: 0.0,
            line_length_m: 9000.0,
            line_spacing_m: 500.0,
            tie_count: 0,
            altitude_m: 300.0,
            turbulence_deg: 0.8,
            speed_m_s: 60.0,
        }
    }
}

/// `[crust]`: buried dipoles under the survey area.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Crust {
    /// Number of dipoles.
    pub dipole_count: usize,
    /// Depth range below ground, m.
    pub depth_m: [f64; 2],
    /// Typical moment, A·m².
    pub moment_a_m2: f64,
}

impl Default for Crust {
    fn default() -> Self {
        Crust {
            dipole_count: 8,
            depth_m: [150.0, 800.0],
            moment_a_m2: 1.5e8,
        }
    }
}

/// `[external]`: diurnal variation and pulsations.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct External {
    /// Amplitude of the daily variation, nT.
    pub diurnal_nt: f64,
    /// RMS amplitude of Pc3–Pc5 pulsations (10–600 s), nT.
    pub pulsation_nt: f64,
    /// Base-station noise, nT.
    pub base_station_noise_nt: f64,
}

impl Default for External {
    fn default() -> Self {
        External {
            diurnal_nt: 15.0,
            pulsation_nt: 0.3,
            base_station_noise_nt: 0.02,
        }
    }
}

/// Where a scalar sensor sits, which sets its aircraft field's size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorLocation {
    /// Tail stinger, far from the airframe: a few nT.
    Tail,
    /// Wing-tip pod: tens of nT.
    Wing,
    /// Inside the cabin: hundreds of nT.
    Cabin,
    /// On a nose boom, ahead of the engines: about ten nT.
    Nose,
}

/// `[[scalar]]`: one scalar magnetometer.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScalarSensor {
    /// Column name, `mag_<n>_uc`.
    pub name: String,
    /// Where it sits.
    pub location: SensorLocation,
    /// White noise, nT (standard deviation at the internal rate).
    #[serde(default = "default_scalar_noise")]
    pub noise_nt: f64,
    /// Multiplies the location's aircraft-field size.
    #[serde(default = "one")]
    pub field_scale: f64,
    /// Sensor axis in body axes; the sensor drops out when the field lies
    /// within `dead_zone_deg` of it (optically pumped dead zone).
    #[serde(default = "default_dead_zone_axis")]
    pub dead_zone_axis: [f64; 3],
    /// Dead-zone half-angle, degrees; 0 for none.
    #[serde(default)]
    pub dead_zone_deg: f64,
    /// Position in body axes (forward, right, down), m.
    #[serde(default)]
    pub position_m: [f64; 3],
    /// The aircraft's field at this sensor, instead of one drawn at the
    /// location's size (a previous flight's model, for a plan).
    #[serde(default)]
    pub aircraft: Option<AircraftField>,
}

fn default_scalar_noise() -> f64 {
    0.005
}

fn one() -> f64 {
    1.0
}

fn default_dead_zone_axis() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

impl ScalarSensor {
    /// A sensor at `location`'s usual place with white noise `noise_nt`.
    pub fn new(name: &str, location: SensorLocation, noise_nt: f64) -> Self {
        ScalarSensor {
            name: name.into(),
            location,
            noise_nt,
            field_scale: 1.0,
            dead_zone_axis: default_dead_zone_axis(),
            dead_zone_deg: 0.0,
            position_m: match location {
                SensorLocation::Tail => [-9.0, 0.0, -0.5],
                SensorLocation::Wing => [-1.0, 7.0, 0.0],
                SensorLocation::Cabin => [1.5, 0.3, 0.2],
                SensorLocation::Nose => [7.0, 0.0, 0.3],
            },
            aircraft: None,
        }
    }
}

/// `[[fluxgate]]`: one vector magnetometer.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Fluxgate {
    /// Column prefix, `flux_<s>`.
    pub name: String,
    /// White noise per axis, nT.
    pub noise_nt: f64,
    /// Size of the aircraft's permanent field at the fluxgate, nT.
    pub permanent_nt: f64,
    /// Size of the induced coefficients at the fluxgate (dimensionless).
    pub induced: f64,
    /// Size of the eddy-current coefficients at the fluxgate, s: the
    /// aircraft's field there moves with the rate of change of the body-axis
    /// Earth field (0: none, the default).
    pub eddy_s: f64,
    /// Size of the residual scale-factor errors left by the factory
    /// calibration (drawn per axis in ±this).
    pub scale_error: f64,
    /// Size of the residual non-orthogonality, degrees.
    pub non_orthogonality_deg: f64,
    /// Size of the residual offsets, nT.
    pub offset_nt: f64,
    /// The aircraft's field at the fluxgate, instead of one drawn at
    /// these sizes (one airframe flown on several days).
    pub aircraft: Option<AircraftField>,
    /// The residual calibration errors, instead of ones drawn at these
    /// sizes (one instrument flown on several days).
    pub calibration: Option<crate::simulate::physics::FluxgateCalibration>,
    /// The body axis (forward x, right y, down z) each fluxgate axis x, y,
    /// z reads along, with its sign: `["-z", "x", "-y"]` is a fluxgate on
    /// its side (default `["x", "y", "z"]`). Three reversed or an odd
    /// permutation with one reversed make a left-handed triad.
    pub axes: [String; 3],
    /// The fluxgate turned from those axes about its own: roll, pitch,
    /// yaw, degrees (default none).
    pub turn_deg: [f64; 3],
    /// Position in body axes (forward, right, down), m: where it reads
    /// the crust's field and an unrecorded source's
    /// (default `[1.0, 0.0, -0.3]`, above the cabin floor).
    pub position_m: [f64; 3],
}

impl Fluxgate {
    /// The reading per body-axis field (rows: fluxgate axes): the axes'
    /// signed permutation, then the turn.
    pub fn mounting(&self) -> std::result::Result<[[f64; 3]; 3], String> {
        let bad = || {
            format!(
                "[[fluxgate]] '{}': axes = {:?}: give each fluxgate axis as a body axis x, y or z, with a sign if reversed (\"-z\"), each body axis once",
                self.name, self.axes
            )
        };
        let mut permutation = [[0.0; 3]; 3];
        let mut used = [false; 3];
        for (row, text) in self.axes.iter().enumerate() {
            let text = text.trim();
            let (sign, name) = match text.strip_prefix('-') {
                Some(rest) => (-1.0, rest),
                None => (1.0, text.strip_prefix('+').unwrap_or(text)),
            };
            let axis = ["x", "y", "z"].iter().position(|a| *a == name).ok_or_else(bad)?;
            if std::mem::replace(&mut used[axis], true) {
                return Err(bad());
            }
            permutation[row][axis] = sign;
        }
        if !self.turn_deg.iter().all(|a| a.is_finite()) {
            return Err(format!("[[fluxgate]] '{}': turn_deg must be finite degrees", self.name));
        }
        let [roll, pitch, yaw] = self.turn_deg;
        let columns = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| {
            crate::simulate::physics::to_body(crate::simulate::physics::apply(&permutation, e), roll, pitch, yaw)
        });
        Ok(std::array::from_fn(|row| std::array::from_fn(|c| columns[c][row])))
    }
}

impl Default for Fluxgate {
    fn default() -> Self {
        Fluxgate {
            name: "flux_a".into(),
            noise_nt: 0.1,
            permanent_nt: 40.0,
            induced: 2e-3,
            eddy_s: 0.0,
            scale_error: 5e-4,
            non_orthogonality_deg: 0.03,
            offset_nt: 5.0,
            aircraft: None,
            calibration: None,
            axes: ["x", "y", "z"].map(String::from),
            turn_deg: [0.0; 3],
            position_m: DEFAULT_FLUXGATE_POSITION_M,
        }
    }
}

/// Where a fluxgate sits unless the scenario says: forward of the
/// reference point, just above it.
pub const DEFAULT_FLUXGATE_POSITION_M: [f64; 3] = [1.0, 0.0, -0.3];

/// How an unrecorded current varies: independently of the attitude.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Waveform {
    /// Switched on and off for 10–60 s at a time.
    Steps,
    /// Straight runs between levels drawn every 20–90 s.
    Ramps,
    /// Slow cycles of 20–120 s.
    Cycles,
    /// All three added.
    Mixed,
}

fn mixed() -> Waveform {
    Waveform::Mixed
}

fn is_zero_vector(vector: &[f64; 3]) -> bool {
    vector.iter().all(|v| *v == 0.0)
}

/// `[[effect]]`: one physical effect the output does not reveal.
#[derive(Debug, Clone, PartialEq, Deserialize, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Effect {
    /// The scalar channel reads the field `lag_s` late.
    SensorLag {
        /// Scalar channel.
        channel: String,
        /// Delay, s (positive: scalar late).
        lag_s: f64,
    },
    /// A recorded channel's field reaches a scalar sensor: the sensor sees
    /// `source × nt_per_unit + d(source)/dt × nt_per_unit_per_s` (body
    /// axes) added to the field.
    AuxCoupling {
        /// Scalar channel.
        channel: String,
        /// Recorded column that drives the field (current, trim tab, ...).
        source: String,
        /// Field per unit of the source at the sensor, body axes, nT/unit.
        nt_per_unit: [f64; 3],
        /// Field per unit/s of the source's rate of change (eddy currents
        /// it induces in nearby conductors), body axes, nT·s/unit; zero by
        /// default.
        #[serde(default, skip_serializing_if = "is_zero_vector")]
        nt_per_unit_per_s: [f64; 3],
    },
    /// The fluxgate's own scale, offset and non-orthogonality errors.
    VectorCalibration {
        /// Fluxgate prefix.
        sensor: String,
        /// Scale factors per axis (1 = perfect).
        scale: [f64; 3],
        /// Offsets per axis, nT.
        offset_nt: [f64; 3],
        /// Non-orthogonality angles (xy, xz, yz), degrees.
        non_orthogonality_deg: [f64; 3],
    },
    /// Eddy currents respond through a first-order lag of `tau_s`.
    EddyTimeConstant {
        /// Scalar channel.
        channel: String,
        /// Time constant, s.
        tau_s: f64,
    },
    /// Strong geomagnetic pulsations, seen by the base station too.
    Pulsations {
        /// RMS amplitude, nT.
        amplitude_nt: f64,
    },
    /// A current no column records (a heater, a radio, a pump on a circuit
    /// the logger does not tap): a dipole at `position_m` whose moment
    /// follows the current, seen by every sensor near it (the cabin
    /// scalars and a cabin fluxgate) and varying in time independently
    /// of the attitude, so no Tolles-Lawson term holds it.
    UnrecordedCurrent {
        /// Position in body axes (forward, right, down), m.
        position_m: [f64; 3],
        /// Dipole moment per ampere, body axes, A·m² per A.
        moment_a_m2_per_a: [f64; 3],
        /// Size of the current's variation, A.
        amplitude_a: f64,
        /// How it varies (default mixed).
        #[serde(default = "mixed")]
        waveform: Waveform,
    },
}

impl Effect {
    /// The scalar channel the effect acts on, when it acts on one.
    pub fn channel(&self) -> Option<&str> {
        match self {
            Effect::SensorLag { channel, .. }
            | Effect::AuxCoupling { channel, .. }
            | Effect::EddyTimeConstant { channel, .. } => Some(channel),
            _ => None,
        }
    }

    /// The effect the diagnosis should name for it.
    pub fn kind(&self) -> EffectKind {
        match self {
            Effect::SensorLag { .. } => EffectKind::SensorLag,
            Effect::AuxCoupling { .. } => EffectKind::AuxCoupling,
            Effect::VectorCalibration { .. } => EffectKind::VectorCalibration,
            Effect::EddyTimeConstant { .. } => EffectKind::EddyTimeConstant,
            Effect::Pulsations { .. } => EffectKind::ExternalField,
            Effect::UnrecordedCurrent { .. } => EffectKind::CrossSensor,
        }
    }
}

/// A checked scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// The settings as written (all checked).
    pub raw: RawScenario,
    /// Decimal year of the flight (IGRF epoch).
    pub year: f64,
}

/// The recorded auxiliary channels every simulated flight carries.
pub const AUXILIARY_CHANNELS: [&str; 8] = [
    "cur_strb", "cur_heat", "cur_com1", "cur_ail", "cur_fuel", "cur_fan", "vol_bus", "trim_tab",
];

impl Scenario {
    /// Reads and checks a scenario file.
    pub fn load(path: &Path) -> Result<Scenario> {
        let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
        let raw: RawScenario = toml::from_str(&text).map_err(|e| Error::Config {
            source_name: path.display().to_string(),
            message: e.to_string(),
        })?;
        Scenario::try_from(raw).map_err(|message| Error::Config {
            source_name: path.display().to_string(),
            message,
        })
    }
}

impl TryFrom<RawScenario> for Scenario {
    type Error = String;

    fn try_from(raw: RawScenario) -> std::result::Result<Self, String> {
        let year = parse_date(&raw.date)?;
        check_rates(&raw)?;
        check_flight_plan(&raw)?;
        check_sizes(&raw)?;
        check_sensors(&raw)?;
        for effect in &raw.effect {
            check_effect(&raw, effect)?;
        }
        Ok(Scenario { raw, year })
    }
}

fn parse_date(date: &str) -> std::result::Result<f64, String> {
    let parts: Vec<&str> = date.split('-').collect();
    let bad = || format!("date = \"{date}\": write the UTC day as YYYY-MM-DD, between 1900 and 2030");
    let [year, month, day] = parts.as_slice() else {
        return Err(bad());
    };
    let (year, month, day) = (
        year.parse::<i32>().map_err(|_| bad())?,
        month.parse::<u32>().map_err(|_| bad())?,
        day.parse::<u32>().map_err(|_| bad())?,
    );
    if !(1900..2030).contains(&year) || !(1..=12).contains(&month) || !(1..=31).contains(&day) {
        return Err(bad());
    }
    let leap = year % 4 == 0 && (year % 100 != 0 || year % 400 == 0);
    let days = match month {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    if day > days {
        return Err(format!("date = \"{date}\": that month has {days} days"));
    }
    Ok(decimal_year(year, month, day, 0.0))
}

fn check_rates(raw: &RawScenario) -> std::result::Result<(), String> {
    if !(raw.sample_rate_hz > 0.0 && raw.sample_rate_hz <= 1000.0) {
        return Err(format!(
            "sample_rate_hz = {}: give a rate between 0 and 1000 Hz",
            raw.sample_rate_hz
        ));
    }
    if raw.oversampling == 0 || raw.oversampling > 100 {
        return Err(format!(
            "oversampling = {}: give 1 to 100 internal samples per output sample",
            raw.oversampling
        ));
    }
    if !raw.start_time_s.is_finite() {
        return Err("start_time_s must be a finite number of seconds".into());
    }
    Ok(())
}

fn check_flight_plan(raw: &RawScenario) -> std::result::Result<(), String> {
    let box_ = &raw.calibration;
    if box_.headings_deg.is_empty() && box_.repeats > 0 {
        return Err("[calibration] headings_deg is empty: give the box's leg headings, e.g. [0, 90, 180, 270]".into());
    }
    if box_.cycles[0] == 0 || box_.cycles[0] > box_.cycles[1] {
        return Err(format!(
            "[calibration] cycles = {:?}: give [fewest, most] with fewest ≥ 1",
            box_.cycles
        ));
    }
    if !(box_.period_s[0] > 0.5 && box_.period_s[0] <= box_.period_s[1]) {
        return Err(format!(
            "[calibration] period_s = {:?}: give [shortest, longest] above 0.5 s",
            box_.period_s
        ));
    }
    check_box_manoeuvres(box_)?;
    let turn_after = ("turn_after_s", box_.turn_after_s.unwrap_or(box_.pause_s));
    for (name, range) in [("lead_in_s", box_.lead_in_s), ("pause_s", box_.pause_s), turn_after] {
        if !(range[0] >= 0.0 && range[0] <= range[1] && range[1] < 3600.0) {
            return Err(format!(
                "[calibration] {name} = {range:?}: give [shortest, longest] in seconds, 0 ≤ shortest ≤ longest"
            ));
        }
    }
    if let Some(number) = box_.line_numbers.iter().find(|n| !n.is_finite() || **n < 0.0) {
        return Err(format!(
            "[calibration] line_numbers holds {number}: give each box's line number as a non-negative number (0 for none)"
        ));
    }
    let rates = box_.turn_rate_deg_s;
    if !(rates[0] >= 0.5 && rates[0] <= rates[1] && rates[1] <= 10.0) {
        return Err(format!(
            "[calibration] turn_rate_deg_s = {rates:?}: give [slowest, fastest] between 0.5 and 10 degrees/s"
        ));
    }
    let entry = box_.turn_entry_s;
    if !(entry[0] >= 0.0 && entry[0] <= entry[1] && entry[1] <= 30.0) {
        return Err(format!(
            "[calibration] turn_entry_s = {entry:?}: give [shortest, longest] between 0 and 30 s"
        ));
    }
    check_coupling(&box_.coupling)?;
    let speeds = [box_.speed_m_s, raw.survey.speed_m_s];
    if speeds.iter().any(|s| !(*s > 1.0 && *s < 400.0)) {
        return Err("speed_m_s must lie between 1 and 400 m/s".into());
    }
    if raw.survey.line_count > 0 && !(raw.survey.line_length_m > 0.0 && raw.survey.line_spacing_m >= 0.0) {
        return Err("[survey] line_length_m must be positive and line_spacing_m not negative (0 reflies the same line both ways)".into());
    }
    Ok(())
}

/// Each manoeuvre the box omits, weakens or flies again names one of its
/// legs.
fn check_box_manoeuvres(box_: &Calibration) -> std::result::Result<(), String> {
    let on_a_leg = |heading: f64| box_.headings_deg.iter().any(|h| (h - heading).abs() < 0.5);
    for omitted in &box_.omit {
        let (_, heading) = parse_omission(omitted)?;
        if !on_a_leg(heading) {
            return Err(format!(
                "[calibration] omit = \"{omitted}\": {heading} is not one of headings_deg {:?}",
                box_.headings_deg
            ));
        }
    }
    for weakened in &box_.weaken {
        let (_, heading, _) = parse_weakening(weakened)?;
        if !on_a_leg(heading) {
            return Err(format!(
                "[calibration] weaken = \"{weakened}\": {heading} is not one of headings_deg {:?}",
                box_.headings_deg
            ));
        }
    }
    for extra in &box_.extra {
        let (_, heading) = parse_omission(extra)
            .map_err(|_| format!("[calibration] extra = \"{extra}\": write kind@heading, e.g. \"roll@110\""))?;
        if !box_.headings_deg.iter().any(|h| (h - heading).abs() < 0.5) {
            return Err(format!(
                "[calibration] extra = \"{extra}\": {heading} is not one of headings_deg {:?}; a manoeuvre is flown again on one of the box's legs",
                box_.headings_deg
            ));
        }
    }
    Ok(())
}

/// The airframe's coupled motion: fractions within [0, 1], lags within
/// ±180°.
fn check_coupling(coupling: &Coupling) -> std::result::Result<(), String> {
    for (name, range) in [
        ("pitch_roll", coupling.pitch_roll),
        ("roll_pitch", coupling.roll_pitch),
        ("roll_yaw", coupling.roll_yaw),
        ("yaw_roll", coupling.yaw_roll),
    ] {
        if !(range[0] >= 0.0 && range[0] <= range[1] && range[1] <= 1.0) {
            return Err(format!(
                "[calibration.coupling] {name} = {range:?}: give [least, most] as fractions of the driven axis's amplitude, 0 ≤ least ≤ most ≤ 1"
            ));
        }
    }
    let lag = coupling.lag_deg;
    if !(lag[0] >= -180.0 && lag[0] <= lag[1] && lag[1] <= 180.0) {
        return Err(format!(
            "[calibration.coupling] lag_deg = {lag:?}: give [least, most] in degrees within ±180"
        ));
    }
    Ok(())
}

/// Most samples simulated inside one flight (its length times the sample
/// rate times the oversampling): 10⁷ is a 28-hour survey at 100 Hz inside,
/// a few GB of memory.
const MOST_INTERNAL_SAMPLES: f64 = 1e7;

/// Most dipole evaluations (dipoles times internal samples): 2·10¹⁰ takes
/// about a minute.
const MOST_DIPOLE_EVALUATIONS: f64 = 2e10;

/// The site, and sizes bounded so that a scenario cannot run away: each
/// bound is in its error.
fn check_sizes(raw: &RawScenario) -> std::result::Result<(), String> {
    let site = &raw.site;
    if !(site.latitude_deg.is_finite() && site.latitude_deg.abs() <= 89.0) {
        return Err(format!(
            "[site] latitude_deg = {}: give degrees north within ±89",
            site.latitude_deg
        ));
    }
    if !(site.longitude_deg.is_finite() && site.longitude_deg.abs() <= 360.0) {
        return Err(format!(
            "[site] longitude_deg = {}: give degrees east within ±360",
            site.longitude_deg
        ));
    }
    for (name, value, most) in [
        ("[calibration] repeats", raw.calibration.repeats, 20),
        ("[survey] line_count", raw.survey.line_count, 1000),
        ("[survey] tie_count", raw.survey.tie_count, 100),
        ("[crust] dipole_count", raw.crust.dipole_count, 10_000),
    ] {
        if value > most {
            return Err(format!("{name} = {value}: at most {most}"));
        }
    }
    let survey = &raw.survey;
    if survey.line_count > 0 && survey.line_length_m > 1e6 {
        return Err(format!(
            "[survey] line_length_m = {}: at most 1,000 km (1e6 m)",
            survey.line_length_m
        ));
    }
    // The flight's length, roughly: the lines, and ten minutes per leg of
    // each box with the turns.
    let legs = raw.calibration.repeats * raw.calibration.headings_deg.len();
    let ties = survey.tie_count as f64
        * ((survey.line_count as f64 + 2.0) * survey.line_spacing_m.max(200.0) / survey.speed_m_s + 300.0);
    let seconds =
        survey.line_count as f64 * survey.line_length_m / survey.speed_m_s + ties + 600.0 * (legs as f64 + 1.0);
    let samples = seconds * raw.sample_rate_hz * raw.oversampling as f64;
    if samples > MOST_INTERNAL_SAMPLES {
        return Err(format!(
            "the flight would take about {:.1} h, {samples:.1e} samples at {} Hz × {} oversampling: at most {MOST_INTERNAL_SAMPLES:.0e}; fly fewer or shorter lines, or a lower rate",
            seconds / 3600.0,
            raw.sample_rate_hz,
            raw.oversampling
        ));
    }
    let evaluations = samples * raw.crust.dipole_count as f64;
    if evaluations > MOST_DIPOLE_EVALUATIONS {
        return Err(format!(
            "[crust] dipole_count = {} over {samples:.1e} samples is {evaluations:.1e} dipole evaluations: at most {MOST_DIPOLE_EVALUATIONS:.0e}; use fewer dipoles",
            raw.crust.dipole_count
        ));
    }
    Ok(())
}

/// Parses `kind@heading` (e.g. `yaw@290`) into the kind and heading.
pub fn parse_omission(text: &str) -> std::result::Result<(crate::calibration::windows::ManoeuvreKind, f64), String> {
    use crate::calibration::windows::ManoeuvreKind;
    let bad = || format!("[calibration] omit = \"{text}\": write kind@heading, e.g. \"yaw@290\"");
    let (kind, heading) = text.split_once('@').ok_or_else(bad)?;
    let kind = match kind.trim() {
        "pitch" => ManoeuvreKind::Pitch,
        "roll" => ManoeuvreKind::Roll,
        "yaw" => ManoeuvreKind::Yaw,
        _ => return Err(bad()),
    };
    Ok((kind, heading.trim().parse::<f64>().map_err(|_| bad())?))
}

/// Parses `kind@heading=fraction` (e.g. `roll@110=0.2`) into the kind,
/// heading and the fraction of the amplitude flown (0 to 1).
pub fn parse_weakening(
    text: &str,
) -> std::result::Result<(crate::calibration::windows::ManoeuvreKind, f64, f64), String> {
    let bad = || {
        format!("[calibration] weaken = \"{text}\": write kind@heading=fraction, e.g. \"roll@110=0.2\", the fraction from 0 to 1")
    };
    let (manoeuvre, fraction) = text.split_once('=').ok_or_else(bad)?;
    let (kind, heading) = parse_omission(manoeuvre).map_err(|_| bad())?;
    let fraction: f64 = fraction.trim().parse().map_err(|_| bad())?;
    if !(0.0..=1.0).contains(&fraction) {
        return Err(bad());
    }
    Ok((kind, heading, fraction))
}

fn check_sensors(raw: &RawScenario) -> std::result::Result<(), String> {
    if raw.scalar.is_empty() || raw.fluxgate.is_empty() {
        return Err("a scenario needs at least one [[scalar]] and one [[fluxgate]] sensor".into());
    }
    for sensor in &raw.scalar {
        let well_named = sensor.name.starts_with("mag_") && sensor.name.ends_with("_uc");
        if !(well_named && sensor.noise_nt >= 0.0 && sensor.field_scale >= 0.0) {
            return Err(format!(
                "[[scalar]] '{}': name it mag_<n>_uc and give non-negative noise_nt and field_scale",
                sensor.name
            ));
        }
        if let Some(field) = &sensor.aircraft {
            if !field.is_plausible() {
                return Err(format!(
                    "[[scalar]] '{}': aircraft: give a finite field, permanent_nt within ±1e6 nT, induced within ±1 and eddy_s within ±10 s",
                    sensor.name
                ));
            }
        }
    }
    let mut names: Vec<&str> = raw.scalar.iter().map(|s| s.name.as_str()).collect();
    names.extend(raw.fluxgate.iter().map(|f| f.name.as_str()));
    names.sort_unstable();
    if let Some(pair) = names.windows(2).find(|p| p[0] == p[1]) {
        return Err(format!("sensor '{}' is listed twice", pair[0]));
    }
    if let Some(f) = raw.fluxgate.iter().find(|f| !f.name.starts_with("flux_")) {
        return Err(format!("[[fluxgate]] '{}': name it flux_<s>, e.g. flux_a", f.name));
    }
    for fluxgate in &raw.fluxgate {
        fluxgate.mounting()?;
    }
    if let Some(f) = (raw.fluxgate.iter()).find(|f| f.aircraft.as_ref().is_some_and(|a| !a.is_plausible())) {
        return Err(format!(
            "[[fluxgate]] '{}': aircraft: give a finite field, permanent_nt within ±1e6 nT, induced within ±1 and eddy_s within ±10 s",
            f.name
        ));
    }
    Ok(())
}

/// An unrecorded current's dipole is finite, its current within 1000 A,
/// and no sensor within 0.1 m of it (where its far field does not hold).
fn check_unrecorded_current(
    raw: &RawScenario,
    (position_m, moment_a_m2_per_a): (&[f64; 3], &[f64; 3]),
    amplitude_a: f64,
) -> std::result::Result<(), String> {
    let finite = position_m.iter().chain(moment_a_m2_per_a).all(|v| v.is_finite());
    if !(finite && (0.0..1000.0).contains(&amplitude_a)) {
        return Err(format!(
            "[[effect]] unrecorded_current: give a finite position_m and moment_a_m2_per_a, and amplitude_a in [0, 1000) A (got {amplitude_a})"
        ));
    }
    let sensors = (raw.scalar.iter().map(|s| s.position_m)).chain(raw.fluxgate.iter().map(|f| f.position_m));
    if let Some(p) = sensors.into_iter().find(|p| {
        let d: f64 = p.iter().zip(position_m).map(|(a, b)| (a - b) * (a - b)).sum();
        d.sqrt() < 0.1
    }) {
        return Err(format!(
            "[[effect]] unrecorded_current: position_m {position_m:?} is within 0.1 m of a sensor at {p:?}; a dipole's field there is not its far field"
        ));
    }
    Ok(())
}

fn check_effect(raw: &RawScenario, effect: &Effect) -> std::result::Result<(), String> {
    if let Some(channel) = effect.channel().filter(|c| !raw.scalar.iter().any(|s| s.name == *c)) {
        return Err(format!(
            "[[effect]] {}: channel '{channel}' is not one of the [[scalar]] sensors",
            effect.kind().name()
        ));
    }
    match effect {
        Effect::SensorLag { lag_s, .. } => {
            if lag_s.is_nan() || lag_s.abs() >= 2.0 {
                return Err(format!("[[effect]] sensor_lag: lag_s = {lag_s} must lie within ±2 s"));
            }
        }
        Effect::AuxCoupling { source, .. } => {
            if !AUXILIARY_CHANNELS.contains(&source.as_str()) {
                return Err(format!(
                    "[[effect]] aux_coupling: source '{source}' is not a simulated channel; use one of {}",
                    AUXILIARY_CHANNELS.join(", ")
                ));
            }
        }
        Effect::VectorCalibration { sensor, scale, .. } => {
            if !raw.fluxgate.iter().any(|f| &f.name == sensor) {
                return Err(format!(
                    "[[effect]] vector_calibration: sensor '{sensor}' is not a [[fluxgate]]"
                ));
            }
            if scale.iter().any(|s| !(*s > 0.5 && *s < 2.0)) {
                return Err(format!(
                    "[[effect]] vector_calibration: scale {scale:?} must lie between 0.5 and 2"
                ));
            }
        }
        Effect::EddyTimeConstant { tau_s, .. } => {
            if !(*tau_s > 0.0 && *tau_s < 10.0) {
                return Err(format!(
                    "[[effect]] eddy_time_constant: tau_s = {tau_s} must lie in (0, 10) s"
                ));
            }
        }
        Effect::Pulsations { amplitude_nt } => {
            if !(*amplitude_nt >= 0.0 && *amplitude_nt < 1000.0) {
                return Err(format!(
                    "[[effect]] pulsations: amplitude_nt = {amplitude_nt} must lie in [0, 1000)"
                ));
            }
        }
        Effect::UnrecordedCurrent {
            position_m,
            moment_a_m2_per_a,
            amplitude_a,
            ..
        } => check_unrecorded_current(raw, (position_m, moment_a_m2_per_a), *amplitude_a)?,
    }
    Ok(())
}
