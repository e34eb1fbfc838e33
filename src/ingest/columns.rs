//! Mapping column names to channel roles.
//!
//! The defaults are the SGL 2020 field names used by MagNav.jl and the public
//! MagNav challenge data (CONTRACT §1): `tt`, `line`, `mag_<n>_uc`,
//! `flux_<s>_{x,y,z,t}`, `ins_pitch`/`ins_roll`/`ins_yaw`, `lat`/`lon`/
//! `utm_z`/`msl`/`alt` and `diurnal`. A `[columns]` table in pipeline.toml
//! replaces any of them.

use serde::Deserialize;

use crate::flight_log::{AttitudeAngle, ChannelRole, VectorAxis};

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
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields, default)]
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
        }
    }
}

impl ColumnNames {
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

/// The CONTRACT name of an uppercase SGL Geosoft field name, as used in the
/// XYZ deliveries of the MagNav challenge data: `TIME` → `tt`, `LINE` →
/// `line`, `UNCOMPMAG1` → `mag_1_uc`, `FLUXB_X` → `flux_b_x`, `FLUXB_TOT` →
/// `flux_b_t`, `PITCH`/`ROLL`/`AZIMUTH` → `ins_pitch`/`ins_roll`/`ins_yaw`,
/// `LAT`/`LONG` → `lat`/`lon`, `DIURNAL` → `diurnal`; any other all-uppercase
/// name (`CUR_STRB`) is lowercased. `None` for names that are not uppercase.
pub fn sgl_uppercase_alias(name: &str) -> Option<String> {
    let is_upper = name.bytes().any(|b| b.is_ascii_uppercase())
        && name
            .bytes()
            .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_');
    if !is_upper {
        return None;
    }
    let fixed = match name {
        "TIME" => Some("tt"),
        "PITCH" => Some("ins_pitch"),
        "ROLL" => Some("ins_roll"),
        "AZIMUTH" => Some("ins_yaw"),
        "LONG" => Some("lon"),
        _ => None,
    };
    if let Some(fixed) = fixed {
        return Some(fixed.into());
    }
    if let Some(n) = name
        .strip_prefix("UNCOMPMAG")
        .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    {
        return Some(format!("mag_{n}_uc"));
    }
    if let Some(rest) = name.strip_prefix("FLUX") {
        if let Some((letter, component)) = rest.split_once('_') {
            let component = match component {
                "X" | "Y" | "Z" => component.to_ascii_lowercase(),
                "TOT" => "t".into(),
                _ => String::new(),
            };
            if letter.len() == 1 && !component.is_empty() {
                return Some(format!("flux_{}_{component}", letter.to_ascii_lowercase()));
            }
        }
    }
    Some(name.to_ascii_lowercase())
}

/// `mag_<n>_uc` with n one or more digits.
fn is_sgl_scalar(name: &str) -> bool {
    name.strip_prefix("mag_")
        .and_then(|rest| rest.strip_suffix("_uc"))
        .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
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

    #[test]
    fn uppercase_sgl_names_map_to_contract_names() {
        let cases = [
            ("TIME", "tt"),
            ("LINE", "line"),
            ("UNCOMPMAG1", "mag_1_uc"),
            ("FLUXB_X", "flux_b_x"),
            ("FLUXD_TOT", "flux_d_t"),
            ("AZIMUTH", "ins_yaw"),
            ("CUR_STRB", "cur_strb"),
            ("LONG", "lon"),
        ];
        for (upper, lower) in cases {
            assert_eq!(sgl_uppercase_alias(upper).as_deref(), Some(lower), "{upper}");
        }
        assert_eq!(sgl_uppercase_alias("mag_1_uc"), None);
        assert_eq!(sgl_uppercase_alias("Cur_Strb"), None);
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
