//! Mapping column names to channel roles.
//!
//! The defaults are the SGL 2020 field names used by MagNav.jl and the public
//! MagNav challenge data (CONTRACT §1): `tt`, `line`, `mag_<n>_uc`,
//! `flux_<s>_{x,y,z,t}`, `ins_pitch`/`ins_roll`/`ins_yaw`, `lat`/`lon`/
//! `utm_z`/`msl`/`alt` and `diurnal`. A `[columns]` table in pipeline.toml
//! replaces any of them.

use serde::Deserialize;

use std::path::Path;

use crate::error::{Error, Result};
use crate::ingest::flight_log::{AttitudeAngle, ChannelRole, FlightLog, VectorAxis};
use crate::messages::{Reading, Warning};

/// The names of `log`'s columns, time first, for a message (at most 40).
fn column_list(log: &FlightLog) -> String {
    let names: Vec<String> = std::iter::once(log.time_column())
        .chain(log.channels().iter().map(|c| c.name.as_str()))
        .map(|n| format!("'{n}'"))
        .collect();
    match names.len() {
        0..=40 => names.join(", "),
        n => format!("{} and {} more", names[..40].join(", "), n - 40),
    }
}

/// Names of the three columns of one vector magnetometer.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VectorColumns {
    /// The sensor's name in outputs and on the command line, e.g. `flux_a`.
    pub prefix: String,
    /// Column holding the body-x component, nT.
    pub x: String,
    /// Column holding the body-y component, nT.
    pub y: String,
    /// Column holding the body-z component, nT.
    pub z: String,
}

/// Which column plays which role.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColumnNames {
    /// Time column, seconds.
    pub time: String,
    /// Survey line number column.
    pub line: String,
    /// Scalar magnetometer columns; `None` means every `mag_<n>_uc`.
    pub scalar: Option<Vec<String>>,
    /// Vector magnetometers given explicitly, in addition to every
    /// `flux_<s>_x/y/z` triple found by name.
    pub vector: Vec<VectorColumns>,
    /// Pitch column, degrees, nose up positive.
    pub pitch: String,
    /// Roll column, degrees, right wing down positive.
    pub roll: String,
    /// Yaw column, degrees clockwise from north.
    pub yaw: String,
    /// Position columns (latitude, longitude, heights).
    pub position: Vec<String>,
    /// Base-station (diurnal) column, nT.
    pub base_station: String,
    /// The columns `[columns]` named, as against the defaults: each must be
    /// in the flight ([`ColumnNames::check_given`]).
    pub given: Vec<GivenColumn>,
}

/// A column named in `[columns]`, with the setting that named it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GivenColumn {
    /// The setting, e.g. `scalar` or `roll`.
    pub setting: &'static str,
    /// The column's name as given.
    pub column: String,
}

impl Default for ColumnNames {
    fn default() -> Self {
        ColumnNames {
            time: "tt".into(),
            line: "line".into(),
            scalar: None,
            vector: Vec::new(),
            pitch: "ins_pitch".into(),
            roll: "ins_roll".into(),
            yaw: "ins_yaw".into(),
            position: ["lat", "lon", "utm_z", "msl", "alt"].map(String::from).to_vec(),
            base_station: "diurnal".into(),
            given: Vec::new(),
        }
    }
}

impl ColumnNames {
    /// Checks that every column `[columns]` named is in `log`, read from
    /// `path`, so that a misspelt name is never silently an auxiliary
    /// column or a role left empty. A scalar or vector magnetometer the
    /// flight lacks is an error (its channel would be dropped), and so is
    /// an attitude angle missing beside another that is there (a typo that
    /// would leave the flight without attitude); the warnings returned name
    /// a missing line, base-station or position column, and attitude
    /// columns missing where the flight has no attitude at all (flown
    /// without INS).
    pub fn check_given(&self, path: &Path, log: &FlightLog) -> Result<Vec<Warning>> {
        let missing: Vec<&GivenColumn> = (self.given.iter())
            .filter(|g| g.column != log.time_column() && log.channel(&g.column).is_none())
            .collect();
        let some_attitude = (log.channels().iter()).any(|c| matches!(c.role, ChannelRole::Attitude(_)));
        let error = |g: &GivenColumn, role: &'static str| Error::MissingColumn {
            path: path.to_path_buf(),
            role,
            looked_for: format!("'{}', named by [columns] {}", g.column, g.setting),
            hint: format!(
                "Correct the name in pipeline.toml's [columns]; the file's columns are {}.",
                column_list(log)
            ),
        };
        let mut warnings = Vec::new();
        for g in missing {
            match g.setting {
                "scalar" => return Err(error(g, "scalar magnetometer")),
                "vector" => return Err(error(g, "vector magnetometer")),
                "pitch" | "roll" | "yaw" if some_attitude => return Err(error(g, "INS attitude")),
                setting => warnings.push(
                    Reading::NamedColumnMissing {
                        file: path.to_path_buf(),
                        column: g.column.to_string(),
                        setting: setting.to_string(),
                    }
                    .into(),
                ),
            }
        }
        Ok(warnings)
    }

    /// The role of the column called `name`, or `None` for the time column.
    pub fn role_of(&self, name: &str) -> Option<ChannelRole> {
        if name == self.time {
            return None;
        }
        Some(self.named_role(name).unwrap_or(ChannelRole::Auxiliary))
    }

    /// True when `name` has a role other than auxiliary, so its cells must
    /// be numbers.
    pub fn is_required_numeric(&self, name: &str) -> bool {
        name == self.time || self.named_role(name).is_some()
    }

    /// A column `[columns]` gives a role that its name gives another:
    /// `pitch = "mag_1_uc"` when every `mag_<n>_uc` is a scalar. The
    /// message names both roles and the fix.
    pub fn role_taken_by_name(&self) -> Option<String> {
        let asked = |setting: &str| match setting {
            "pitch" => Some(ChannelRole::Attitude(AttitudeAngle::Pitch)),
            "roll" => Some(ChannelRole::Attitude(AttitudeAngle::Roll)),
            "yaw" => Some(ChannelRole::Attitude(AttitudeAngle::Yaw)),
            "line" => Some(ChannelRole::Line),
            "base_station" => Some(ChannelRole::BaseStation),
            "position" => Some(ChannelRole::Position),
            _ => None,
        };
        self.given.iter().find_map(|g| {
            let wanted = asked(g.setting)?;
            let got = self.named_role(&g.column)?;
            (got != wanted).then(|| {
                let by_name = match got {
                    ChannelRole::ScalarMagnetometer => "a scalar magnetometer by its name (every mag_<n>_uc is one unless [columns] scalar lists the scalars)".to_string(),
                    ChannelRole::VectorMagnetometer { sensor, .. } => format!("an axis of the vector magnetometer '{sensor}' by its name"),
                    _ => "given another role by another setting".to_string(),
                };
                format!(
                    "[columns] {} = \"{}\": that column is {by_name}, and a column plays one role; name the {} column, or list the scalars in [columns] scalar without it",
                    g.setting, g.column, g.setting
                )
            })
        })
    }

    fn named_role(&self, name: &str) -> Option<ChannelRole> {
        if let Some(role) = self.explicit_vector_role(name) {
            return Some(role);
        }
        if self.is_scalar(name) {
            return Some(ChannelRole::ScalarMagnetometer);
        }
        if let Some(role) = sgl_vector_role(name) {
            return Some(role);
        }
        let attitude = [
            (&self.pitch, AttitudeAngle::Pitch),
            (&self.roll, AttitudeAngle::Roll),
            (&self.yaw, AttitudeAngle::Yaw),
        ];
        if let Some((_, angle)) = attitude.iter().find(|(n, _)| *n == name) {
            return Some(ChannelRole::Attitude(*angle));
        }
        if name == self.line {
            Some(ChannelRole::Line)
        } else if name == self.base_station {
            Some(ChannelRole::BaseStation)
        } else if self.position.iter().any(|p| p == name) {
            Some(ChannelRole::Position)
        } else {
            None
        }
    }

    fn is_scalar(&self, name: &str) -> bool {
        match &self.scalar {
            Some(list) => list.iter().any(|s| s == name),
            None => is_sgl_scalar(name),
        }
    }

    fn explicit_vector_role(&self, name: &str) -> Option<ChannelRole> {
        self.vector.iter().find_map(|v| {
            let axis = [(&v.x, VectorAxis::X), (&v.y, VectorAxis::Y), (&v.z, VectorAxis::Z)]
                .into_iter()
                .find(|(column, _)| *column == name)?
                .1;
            Some(ChannelRole::VectorMagnetometer {
                sensor: v.prefix.clone(),
                axis,
            })
        })
    }
}

/// SGL field names whose lowercase name is not derived by a rule, with the
/// name the same field has in the SGL HDF5 files and MagNav.jl. Sources: the
/// field list of the SGL 2020 XYZ deliveries (`readmes/Data-readme.txt` of
/// early MagNav.jl versions) against MagNav.jl's
/// `readmes/sgl_2020_fields_readme.txt`, which lists the same fields in the
/// same order.
const SGL_IRREGULAR_NAMES: &[(&str, &str)] = &[
    ("TIME", "tt"),
    ("FLT", "flight"),
    ("MSL-Z", "msl"),
    ("LONG", "lon"),
    // The XYZ attitude is the INS solution ("INS computed aircraft pitch").
    ("PITCH", "ins_pitch"),
    ("ROLL", "ins_roll"),
    ("AZIMUTH", "ins_yaw"),
    // Early MagNav.jl HDF5 files called the same field `ins_azim`.
    ("INS_AZIM", "ins_yaw"),
    ("OGS_HGT", "ogs_alt"),
    ("INS_HGT", "ins_alt"),
    ("INS_VEL_N", "ins_vn"),
    ("INS_VEL_W", "ins_vw"),
    ("INS_VEL_V", "ins_vu"),
    ("PITCHRT", "pitch_rate"),
    ("ROLLRT", "roll_rate"),
    ("YAWRT", "yaw_rate"),
    ("LONG_ACC", "lgtl_acc"),
    ("LAT_ACC", "ltrl_acc"),
    ("NORM_ACC", "nrml_acc"),
    ("TRUE_AS", "tas"),
    ("TOT_P", "total_p"),
    ("CUR_ACHi", "cur_ac_hi"),
    ("CUR_ACLo", "cur_ac_lo"),
    ("CUR_IHTR", "cur_heat"),
    ("V_SERVO", "vol_srvo"),
];

/// The CONTRACT name of a field name as SGL spells it in Geosoft XYZ
/// deliveries (the MagNav challenge data): the lowercase name the same field
/// has in the SGL HDF5 files and MagNav.jl. The first rule that applies wins:
///
/// 1. A table of irregular names: `TIME` → `tt`, `FLT` → `flight`, `MSL-Z` →
///    `msl`, `LONG` → `lon`, `PITCH`/`ROLL`/`AZIMUTH` (the INS attitude) →
///    `ins_pitch`/`ins_roll`/`ins_yaw`, `OGS_HGT` → `ogs_alt`, `INS_VEL_N` →
///    `ins_vn`, `PITCHRT` → `pitch_rate`, `LONG_ACC` → `lgtl_acc`, `TRUE_AS`
///    → `tas`, `CUR_ACHi` → `cur_ac_hi`, `CUR_IHTR` → `cur_heat`, `V_SERVO`
///    → `vol_srvo`, …
/// 2. Scalar magnetometers `<KIND>MAG<n>`: `UNCOMPMAG<n>` → `mag_<n>_uc`,
///    `COMPMAG<n>` → `mag_<n>_c`, `LAGMAG<n>` → `mag_<n>_lag`, `DCMAG<n>` →
///    `mag_<n>_dc`, `IGRFMAG<n>` → `mag_<n>_igrf`.
/// 3. Fluxgates `FLUX<s>_<axis>`: `FLUXB_X` → `flux_b_x`, `FLUXD_TOT` (or
///    `FLUXD_T`) → `flux_d_t`.
/// 4. Currents and voltages `CUR_<sensor>`, `V_<sensor>` or `VOL_<sensor>`
///    → `cur_<sensor>` / `vol_<sensor>`, lowercased, with `_` before a
///    number that follows a letter and before a trailing lowercase polarity
///    `p`/`n`: `CUR_COM1` → `cur_com_1`, `V_BAT2` → `vol_bat_2`, `V_RESp` →
///    `vol_res_p`, `CUR_STRB` → `cur_strb`.
/// 5. Any other name in uppercase ASCII letters, digits, `_` and `-` is
///    lowercased with `-` → `_`: `UTM-X` → `utm_x`, `DIURNAL` → `diurnal`,
///    `INS_ACC_X` → `ins_acc_x`.
///
/// `None` for every other name (lowercase or mixed case such as `mag_1_uc`
/// or `Cur_Strb`, non-ASCII, no letter at all): the reader keeps it as
/// written.
pub fn sgl_uppercase_alias(name: &str) -> Option<String> {
    if let Some((_, contract)) = SGL_IRREGULAR_NAMES.iter().find(|(sgl, _)| *sgl == name) {
        return Some((*contract).to_string());
    }
    sgl_magnetometer_alias(name)
        .or_else(|| sgl_fluxgate_alias(name))
        .or_else(|| sgl_electrical_alias(name))
        .or_else(|| is_sgl_uppercase(name).then(|| name.to_ascii_lowercase().replace('-', "_")))
}

/// Uppercase ASCII letters, digits, `_` and `-`, with at least one letter.
fn is_sgl_uppercase(name: &str) -> bool {
    name.bytes().any(|b| b.is_ascii_uppercase())
        && name
            .bytes()
            .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// One or more ASCII digits.
fn is_number(text: &str) -> bool {
    !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit())
}

/// `UNCOMPMAG1` → `mag_1_uc`, `COMPMAG1` → `mag_1_c`, `LAGMAG1` →
/// `mag_1_lag`, `DCMAG1` → `mag_1_dc`, `IGRFMAG1` → `mag_1_igrf`.
fn sgl_magnetometer_alias(name: &str) -> Option<String> {
    let (kind, number) = name.split_once("MAG")?;
    let suffix = match kind {
        "UNCOMP" => "uc",
        "COMP" => "c",
        "LAG" => "lag",
        "DC" => "dc",
        "IGRF" => "igrf",
        _ => return None,
    };
    is_number(number).then(|| format!("mag_{number}_{suffix}"))
}

/// `FLUXB_X` → `flux_b_x`; `FLUXB_TOT` and `FLUXB_T` → `flux_b_t`.
fn sgl_fluxgate_alias(name: &str) -> Option<String> {
    let (letter, component) = name.strip_prefix("FLUX")?.split_once('_')?;
    let component = match component {
        "X" => "x",
        "Y" => "y",
        "Z" => "z",
        "TOT" | "T" => "t",
        _ => return None,
    };
    let is_letter = letter.len() == 1 && letter.bytes().all(|b| b.is_ascii_uppercase());
    is_letter.then(|| format!("flux_{}_{component}", letter.to_ascii_lowercase()))
}

/// `CUR_COM1` → `cur_com_1`, `V_BAT2` and `VOL_BAT2` → `vol_bat_2`, `V_RESp`
/// → `vol_res_p`: the sensor name lowercased, with `_` before a trailing
/// number that follows a letter and before a trailing polarity `p`/`n`.
fn sgl_electrical_alias(name: &str) -> Option<String> {
    let (prefix, sensor) = [("CUR_", "cur"), ("VOL_", "vol"), ("V_", "vol")]
        .iter()
        .find_map(|(sgl, contract)| Some((*contract, name.strip_prefix(sgl)?)))?;
    let (stem, polarity) = match sensor.strip_suffix(['p', 'n']) {
        Some(stem) => (stem, &sensor[stem.len()..]),
        None => (sensor, ""),
    };
    let starts_with_letter = stem.bytes().next().is_some_and(|b| b.is_ascii_uppercase());
    if !starts_with_letter || !is_sgl_uppercase(stem) || stem.contains('-') {
        return None;
    }
    let digits_from = stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    let (word, number) = stem.split_at(digits_from);
    let mut contract = format!("{prefix}_{}", word.to_ascii_lowercase());
    if !number.is_empty() && word.bytes().last().is_some_and(|b| b.is_ascii_uppercase()) {
        contract.push('_');
    }
    contract.push_str(number);
    if !polarity.is_empty() {
        contract.push('_');
        contract.push_str(polarity);
    }
    Some(contract)
}

/// `mag_<n>_uc` with n one or more digits.
fn is_sgl_scalar(name: &str) -> bool {
    name.strip_prefix("mag_")
        .and_then(|rest| rest.strip_suffix("_uc"))
        .is_some_and(is_number)
}

/// `flux_<s>_x|y|z|t` with s one lowercase letter.
fn sgl_vector_role(name: &str) -> Option<ChannelRole> {
    let rest = name.strip_prefix("flux_")?;
    let (letter, component) = rest.split_once('_')?;
    if letter.len() != 1 || !letter.bytes().all(|b| b.is_ascii_lowercase()) {
        return None;
    }
    let sensor = format!("flux_{letter}");
    let axis = match component {
        "x" => VectorAxis::X,
        "y" => VectorAxis::Y,
        "z" => VectorAxis::Z,
        "t" => return Some(ChannelRole::VectorTotal { sensor }),
        _ => return None,
    };
    Some(ChannelRole::VectorMagnetometer { sensor, axis })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sgl_names_get_their_roles() {
        let names = ColumnNames::default();
        assert_eq!(names.role_of("tt"), None);
        assert_eq!(names.role_of("mag_4_uc"), Some(ChannelRole::ScalarMagnetometer));
        assert_eq!(names.role_of("mag_1_c"), Some(ChannelRole::Auxiliary));
        assert_eq!(
            names.role_of("flux_c_y"),
            Some(ChannelRole::VectorMagnetometer {
                sensor: "flux_c".into(),
                axis: VectorAxis::Y
            })
        );
        assert_eq!(
            names.role_of("flux_b_t"),
            Some(ChannelRole::VectorTotal {
                sensor: "flux_b".into()
            })
        );
        assert_eq!(
            names.role_of("ins_yaw"),
            Some(ChannelRole::Attitude(AttitudeAngle::Yaw))
        );
        assert_eq!(names.role_of("cur_strb"), Some(ChannelRole::Auxiliary));
        assert_eq!(names.role_of("diurnal"), Some(ChannelRole::BaseStation));
    }

    /// Every field of the SGL 2020 XYZ deliveries (MagNav.jl
    /// `readmes/Data-readme.txt`, in file order) beside the name the same
    /// field has in the SGL 2020 HDF5 files (`readmes/sgl_2020_fields_readme.txt`,
    /// same order), plus Flux A and Mag 6 of the later flights.
    const SGL_2020_XYZ_TO_HDF5: &[(&str, &str)] = &[
        ("LINE", "line"),
        ("FLT", "flight"),
        ("YEAR", "year"),
        ("DOY", "doy"),
        ("TIME", "tt"),
        ("UTM-X", "utm_x"),
        ("UTM-Y", "utm_y"),
        ("UTM-Z", "utm_z"),
        ("MSL-Z", "msl"),
        ("LAT", "lat"),
        ("LONG", "lon"),
        ("BARO", "baro"),
        ("RADAR", "radar"),
        ("TOPO", "topo"),
        ("DEM", "dem"),
        ("DRAPE", "drape"),
        ("PITCH", "ins_pitch"),
        ("ROLL", "ins_roll"),
        ("AZIMUTH", "ins_yaw"),
        ("DIURNAL", "diurnal"),
        ("COMPMAG1", "mag_1_c"),
        ("LAGMAG1", "mag_1_lag"),
        ("DCMAG1", "mag_1_dc"),
        ("IGRFMAG1", "mag_1_igrf"),
        ("UNCOMPMAG1", "mag_1_uc"),
        ("UNCOMPMAG2", "mag_2_uc"),
        ("UNCOMPMAG3", "mag_3_uc"),
        ("UNCOMPMAG4", "mag_4_uc"),
        ("UNCOMPMAG5", "mag_5_uc"),
        ("UNCOMPMAG6", "mag_6_uc"),
        ("FLUXA_X", "flux_a_x"),
        ("FLUXA_Y", "flux_a_y"),
        ("FLUXA_Z", "flux_a_z"),
        ("FLUXA_TOT", "flux_a_t"),
        ("FLUXB_X", "flux_b_x"),
        ("FLUXB_Y", "flux_b_y"),
        ("FLUXB_Z", "flux_b_z"),
        ("FLUXB_TOT", "flux_b_t"),
        ("FLUXC_X", "flux_c_x"),
        ("FLUXC_Y", "flux_c_y"),
        ("FLUXC_Z", "flux_c_z"),
        ("FLUXC_TOT", "flux_c_t"),
        ("FLUXD_X", "flux_d_x"),
        ("FLUXD_Y", "flux_d_y"),
        ("FLUXD_Z", "flux_d_z"),
        ("FLUXD_TOT", "flux_d_t"),
        ("OGS_MAG", "ogs_mag"),
        ("OGS_HGT", "ogs_alt"),
        ("INS_ACC_X", "ins_acc_x"),
        ("INS_ACC_Y", "ins_acc_y"),
        ("INS_ACC_Z", "ins_acc_z"),
        ("INS_WANDER", "ins_wander"),
        ("INS_LAT", "ins_lat"),
        ("INS_LON", "ins_lon"),
        ("INS_HGT", "ins_alt"),
        ("INS_VEL_N", "ins_vn"),
        ("INS_VEL_W", "ins_vw"),
        ("INS_VEL_V", "ins_vu"),
        ("PITCHRT", "pitch_rate"),
        ("ROLLRT", "roll_rate"),
        ("YAWRT", "yaw_rate"),
        ("LONG_ACC", "lgtl_acc"),
        ("LAT_ACC", "ltrl_acc"),
        ("NORM_ACC", "nrml_acc"),
        ("TRUE_AS", "tas"),
        ("PITOT_P", "pitot_p"),
        ("STATIC_P", "static_p"),
        ("TOT_P", "total_p"),
        ("CUR_COM1", "cur_com_1"),
        ("CUR_ACHi", "cur_ac_hi"),
        ("CUR_ACLo", "cur_ac_lo"),
        ("CUR_TANK", "cur_tank"),
        ("CUR_FLAP", "cur_flap"),
        ("CUR_STRB", "cur_strb"),
        ("CUR_SRVO_O", "cur_srvo_o"),
        ("CUR_SRVO_M", "cur_srvo_m"),
        ("CUR_SRVO_I", "cur_srvo_i"),
        ("CUR_IHTR", "cur_heat"),
        ("CUR_ACPWR", "cur_acpwr"),
        ("CUR_OUTPWR", "cur_outpwr"),
        ("CUR_BAT1", "cur_bat_1"),
        ("CUR_BAT2", "cur_bat_2"),
        ("V_ACPWR", "vol_acpwr"),
        ("V_OUTPWR", "vol_outpwr"),
        ("V_BAT1", "vol_bat_1"),
        ("V_BAT2", "vol_bat_2"),
        ("V_RESp", "vol_res_p"),
        ("V_RESn", "vol_res_n"),
        ("V_BACKp", "vol_back_p"),
        ("V_BACKn", "vol_back_n"),
        ("V_GYRO1", "vol_gyro_1"),
        ("V_GYRO2", "vol_gyro_2"),
        ("V_ACCp", "vol_acc_p"),
        ("V_ACCn", "vol_acc_n"),
        ("V_BLOCK", "vol_block"),
        ("V_BACK", "vol_back"),
        ("V_SERVO", "vol_srvo"),
        ("V_CABT", "vol_cabt"),
        ("V_FAN", "vol_fan"),
        // Later flights and numbering beyond the 2020 list.
        ("COMPMAG2", "mag_2_c"),
        ("COMPMAG5", "mag_5_c"),
        ("DCMAG3", "mag_3_dc"),
        ("IGRFMAG4", "mag_4_igrf"),
        ("UNCOMPMAG12", "mag_12_uc"),
        ("FLUXB_T", "flux_b_t"),
    ];

    #[test]
    fn sgl_xyz_field_names_map_to_the_hdf5_names() {
        for &(upper, lower) in SGL_2020_XYZ_TO_HDF5 {
            assert_eq!(sgl_uppercase_alias(upper).as_deref(), Some(lower), "{upper}");
        }
    }

    /// Spellings that are not in the SGL 2020 XYZ list but that users write
    /// for the same fields: the generic rules give the HDF5 name.
    #[test]
    fn other_uppercase_spellings_follow_the_rules() {
        let cases = [
            ("COMPMAG3", "mag_3_c"),
            ("COMPMAG4", "mag_4_c"),
            ("DCMAG2", "mag_2_dc"),
            ("IGRF", "igrf"),
            ("FLIGHT", "flight"),
            ("LON", "lon"),
            ("MSL", "msl"),
            ("WGS-Z", "wgs_z"),
            ("CUR_HEAT", "cur_heat"),
            ("CUR_BAT_1", "cur_bat_1"),
            ("VOL_BAT1", "vol_bat_1"),
            ("VOL_BAT2", "vol_bat_2"),
            ("VOL_BLOCK", "vol_block"),
            ("VOL_BACK", "vol_back"),
            ("VOL_SRVO", "vol_srvo"),
            ("VOL_CABT", "vol_cabt"),
            ("VOL_FAN", "vol_fan"),
            ("VOL_BUS", "vol_bus"),
            ("INS_PITCH", "ins_pitch"),
            ("INS_ROLL", "ins_roll"),
            ("INS_AZIM", "ins_yaw"),
            ("INS_ALT", "ins_alt"),
            ("INS_VN", "ins_vn"),
            ("INS_VE", "ins_ve"),
            ("INS_VW", "ins_vw"),
            ("INS_VU", "ins_vu"),
            ("OGS_ALT", "ogs_alt"),
            ("TEMP_2", "temp_2"),
            ("X-1", "x_1"),
        ];
        for (upper, lower) in cases {
            assert_eq!(sgl_uppercase_alias(upper).as_deref(), Some(lower), "{upper}");
        }
    }

    /// Near misses of the patterns fall through to plain lowercasing
    /// instead of producing a wrong CONTRACT name.
    #[test]
    fn near_misses_of_the_patterns_are_only_lowercased() {
        let cases = [
            ("UNCOMPMAG", "uncompmag"),
            ("COMPMAGX", "compmagx"),
            ("MAG1", "mag1"),
            ("TOTALMAG1", "totalmag1"),
            ("FLUXBB_X", "fluxbb_x"),
            ("FLUXB_W", "fluxb_w"),
            ("FLUX_X", "flux_x"),
            ("CUR_", "cur_"),
            ("V_", "v_"),
            ("V_1", "v_1"),
            ("FOO1", "foo1"),
        ];
        for (upper, lower) in cases {
            assert_eq!(sgl_uppercase_alias(upper).as_deref(), Some(lower), "{upper}");
        }
    }

    #[test]
    fn names_that_are_not_uppercase_are_kept_as_written() {
        for name in [
            "", "-", "_", "_1", "1", "Ä", "MAGÄ1", "CUR_Ä", "V_RESÄ", "CUR_p", "mag_1_uc", "Cur_Strb", "flux_b_x",
            "cur_ACHi", "Time",
        ] {
            assert_eq!(sgl_uppercase_alias(name), None, "{name:?}");
        }
    }

    #[test]
    fn uppercase_sgl_names_get_their_roles() {
        let names = ColumnNames::default();
        let role = |upper: &str| names.role_of(&sgl_uppercase_alias(upper).unwrap());
        let vector = |sensor: &str, axis| {
            Some(ChannelRole::VectorMagnetometer {
                sensor: sensor.into(),
                axis,
            })
        };
        assert_eq!(role("TIME"), None);
        assert_eq!(role("LINE"), Some(ChannelRole::Line));
        assert_eq!(role("UNCOMPMAG3"), Some(ChannelRole::ScalarMagnetometer));
        for vendor_product in ["COMPMAG1", "LAGMAG1", "DCMAG1", "IGRFMAG1"] {
            assert_eq!(role(vendor_product), Some(ChannelRole::Auxiliary), "{vendor_product}");
        }
        assert_eq!(role("FLUXC_X"), vector("flux_c", VectorAxis::X));
        assert_eq!(role("FLUXC_Y"), vector("flux_c", VectorAxis::Y));
        assert_eq!(role("FLUXB_Z"), vector("flux_b", VectorAxis::Z));
        assert_eq!(
            role("FLUXD_TOT"),
            Some(ChannelRole::VectorTotal {
                sensor: "flux_d".into()
            })
        );
        assert_eq!(role("PITCH"), Some(ChannelRole::Attitude(AttitudeAngle::Pitch)));
        assert_eq!(role("ROLL"), Some(ChannelRole::Attitude(AttitudeAngle::Roll)));
        assert_eq!(role("AZIMUTH"), Some(ChannelRole::Attitude(AttitudeAngle::Yaw)));
        for position in ["LAT", "LONG", "UTM-Z", "MSL-Z"] {
            assert_eq!(role(position), Some(ChannelRole::Position), "{position}");
        }
        assert_eq!(role("DIURNAL"), Some(ChannelRole::BaseStation));
        for auxiliary in [
            "CUR_ACHi",
            "CUR_COM1",
            "V_BAT1",
            "V_RESp",
            "INS_ACC_X",
            "PITCHRT",
            "OGS_MAG",
        ] {
            assert_eq!(role(auxiliary), Some(ChannelRole::Auxiliary), "{auxiliary}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::test_runner::Config {
            cases: 2000,
            rng_seed: proptest::test_runner::RngSeed::Fixed(7),
            ..proptest::test_runner::Config::default()
        })]

        /// Any name, ASCII or not, maps without panicking, and a mapped name
        /// is a lowercase SGL-style name.
        #[test]
        fn any_name_maps_to_a_lowercase_name_or_none(name in "[A-Za-z0-9_Ää-]{0,12}|\\PC{0,8}") {
            if let Some(alias) = sgl_uppercase_alias(&name) {
                proptest::prop_assert!(!alias.is_empty());
                proptest::prop_assert!(
                    alias.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_'),
                    "{name:?} -> {alias:?}"
                );
            }
        }
    }

    #[test]
    fn explicit_mapping_overrides_patterns() {
        let names = ColumnNames {
            scalar: Some(vec!["tail_mag".into()]),
            vector: vec![VectorColumns {
                prefix: "fg".into(),
                x: "bx".into(),
                y: "by".into(),
                z: "bz".into(),
            }],
            ..ColumnNames::default()
        };
        assert_eq!(names.role_of("tail_mag"), Some(ChannelRole::ScalarMagnetometer));
        assert_eq!(names.role_of("mag_1_uc"), Some(ChannelRole::Auxiliary));
        assert_eq!(
            names.role_of("bz"),
            Some(ChannelRole::VectorMagnetometer {
                sensor: "fg".into(),
                axis: VectorAxis::Z
            })
        );
    }
}
