//! The compensated channels reduced for levelling and gridding, on
//! request (`[output] dc`, `[output] igrf`; `compensate --dc --igrf`),
//! with the SGL 2020 meanings:
//!
//! - `mag_<n>_dc`: compensated, the base station's variation removed;
//! - `mag_<n>_igrf`: compensated, the base station's variation and the
//!   IGRF-14 main field at the aircraft's position and the flight's day
//!   removed (the residual field).
//!
//! The base station's variation is its record about a datum: a station
//! that records the total field (tens of thousands of nT) is taken about
//! its median over the flight, so `_dc` keeps the survey's level; one that
//! records the variation already (a column near zero, |median| below
//! [`VARIATION_LIMIT_NT`]) is taken as recorded. The note says which.
//!
//! A row without a base-station reading (or, for `_igrf`, a position) has
//! no reduced value: the cell is empty and the row is flagged
//! `missing_source:<column>`, never filled in.

use serde::Serialize;

use crate::compensate::{Compensation, ReducedChannel};
use crate::error::{Error, Result};
use crate::ingest::flags::FlagKind;
use crate::ingest::flight_log::{ChannelRole, FlightLog};
use crate::messages::Note;
use crate::model::igrf::{decimal_year, Igrf};

/// A base-station column whose median is within this of zero records the
/// variation, not the total field, nT.
pub const VARIATION_LIMIT_NT: f64 = 1_000.0;

/// Which reduced columns to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct ReducedColumns {
    /// `mag_<n>_dc`.
    pub dc: bool,
    /// `mag_<n>_igrf`.
    pub igrf: bool,
}

impl ReducedColumns {
    /// Whether any is asked for.
    pub fn any(self) -> bool {
        self.dc || self.igrf
    }
}

/// The reduced column's name for the compensated channel `channel`:
/// `mag_<n>_<suffix>` for `mag_<n>_uc` (or `_c`), else `<channel>_<suffix>`.
fn column_name(channel: &str, suffix: &str) -> String {
    let stem = channel
        .strip_suffix("_uc")
        .or_else(|| channel.strip_suffix("_c"))
        .unwrap_or(channel);
    format!("{stem}_{suffix}")
}

/// The flight's base station, its variation on every row (the recorded
/// values less their median when the station records the total field),
/// and a note saying which; an error when there is no station or it has
/// no reading.
fn station_variation(log: &FlightLog) -> Result<(&str, Vec<f64>, Note)> {
    let missing = |looked_for: String, hint: &str| Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "base-station (for dc and igrf)",
        looked_for,
        hint: hint.into(),
    };
    let station = (log.channels().iter())
        .find(|c| c.role == ChannelRole::BaseStation)
        .ok_or_else(|| {
            missing(
                "`diurnal`, or the column `[columns] base_station` names; mag_<n>_dc and mag_<n>_igrf remove its variation".into(),
                "Add the base station's record to the flight (resampled to its times), or leave out dc and igrf",
            )
        })?;
    let mut recorded: Vec<f64> = station.values.iter().copied().filter(|v| v.is_finite()).collect();
    if recorded.is_empty() {
        return Err(missing(
            format!("'{}' with a reading (every row is blank)", station.name),
            "Check the base station's export, or leave out dc and igrf",
        ));
    }
    let middle = recorded.len() / 2;
    let median = *recorded.select_nth_unstable_by(middle, f64::total_cmp).1;
    let datum = match median.abs() < VARIATION_LIMIT_NT {
        true => 0.0,
        false => median,
    };
    let note = Note::BaseStationRemoved {
        station: station.name.clone(),
        median_nt: median,
        total_field: datum != 0.0,
    };
    let variation: Vec<f64> = station.values.iter().map(|v| v - datum).collect();
    Ok((&station.name, variation, note))
}

/// Adds the reduced columns `wanted` of every compensated channel of
/// `compensation` (each channel's `_dc`, then its `_igrf`), flagging the
/// rows that have none; returns the notes that say how they were made.
/// No base station, or for IGRF no latitude and longitude or no date, is
/// an error naming what is missing.
pub fn add_reduced(log: &FlightLog, compensation: &mut Compensation, wanted: ReducedColumns) -> Result<Vec<Note>> {
    if !wanted.any() || compensation.channels.is_empty() {
        return Ok(Vec::new());
    }
    let (station, variation, note) = station_variation(log)?;
    let mut notes = vec![note];
    let main_field = match wanted.igrf {
        true => {
            let (field, note) = main_field(log)?;
            notes.push(note);
            Some(field)
        }
        false => None,
    };
    let mut reduced = Vec::new();
    for channel in &compensation.channels {
        let dc: Vec<f64> = (channel.values.iter().zip(&variation)).map(|(c, v)| c - v).collect();
        if let Some(field) = &main_field {
            let igrf = dc.iter().zip(&field.total_nt).map(|(d, f)| d - f).collect();
            if wanted.dc {
                reduced.push(ReducedChannel {
                    column: column_name(&channel.channel, "dc"),
                    values: dc,
                });
            }
            reduced.push(ReducedChannel {
                column: column_name(&channel.channel, "igrf"),
                values: igrf,
            });
        } else {
            reduced.push(ReducedChannel {
                column: column_name(&channel.channel, "dc"),
                values: dc,
            });
        }
    }
    // A row the compensated channel has but a reduction lacks says why.
    for (row, flags) in compensation.flags.iter_mut().enumerate() {
        let compensated = compensation.channels.iter().any(|c| c.values[row].is_finite());
        if !compensated {
            continue;
        }
        if !variation[row].is_finite() {
            flags.raise(FlagKind::MissingSource, station);
        }
        if let Some(field) = &main_field {
            if !field.total_nt[row].is_finite() {
                flags.raise(FlagKind::MissingSource, &field.position);
            }
        }
    }
    compensation.reduced = reduced;
    Ok(notes)
}

/// IGRF-14's total field on every row, and the position columns it reads.
struct MainFieldColumn {
    total_nt: Vec<f64>,
    /// The position columns, for a row's flag (`lat/lon/msl`).
    position: String,
}

/// The main field at every row's latitude, longitude and height (above
/// mean sea level, 0 m without a height column) on the flight's day.
fn main_field(log: &FlightLog) -> Result<(MainFieldColumn, Note)> {
    let column = |names: &[&str]| {
        names
            .iter()
            .find_map(|n| log.channel(n).filter(|c| c.role == ChannelRole::Position))
    };
    let missing = |looked_for: &str, hint: &str| Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "position (for igrf)",
        looked_for: looked_for.into(),
        hint: hint.into(),
    };
    let (Some(latitude), Some(longitude)) = (column(&["lat", "ins_lat"]), column(&["lon", "ins_lon"])) else {
        return Err(missing(
            "latitude and longitude columns ('lat'/'ins_lat' and 'lon'/'ins_lon', degrees)",
            "Add the aircraft's position, or leave out igrf",
        ));
    };
    let height = column(&["msl", "alt", "utm_z", "ins_alt"]);
    let undated = |message: String| Error::Config {
        source_name: log.source().display().to_string(),
        message,
    };
    let date = log.date().ok_or_else(|| {
        undated("igrf: the flight has no date, and IGRF-14 changes by tens of nT a year; give it with --date YYYY-MM-DD (or a [[flight]] or manifest date), or leave out igrf".into())
    })?;
    let model = Igrf::fourteenth();
    let (first, last) = model.valid_years();
    let year = decimal_year(date.year, date.month, date.day, 43_200.0);
    if !(first..=last).contains(&year) {
        return Err(undated(format!(
            "igrf: the flight is dated {date}, outside the years IGRF-14 covers ({first:.0} to {last:.0}); check the flight's date, or leave out igrf"
        )));
    }
    let epoch = model.at_year(year);
    let total_nt = (0..log.len())
        .map(|row| {
            let h = height.map_or(0.0, |h| h.values[row]);
            let (lat, lon) = (latitude.values[row], longitude.values[row]);
            match lat.is_finite() && lon.is_finite() && h.is_finite() && lat.abs() <= 90.0 {
                true => epoch.field(lat, lon, h).total_nt(),
                false => f64::NAN,
            }
        })
        .collect();
    let position = [Some(latitude), Some(longitude), height]
        .iter()
        .flatten()
        .map(|c| c.name.as_str())
        .collect::<Vec<_>>()
        .join("/");
    let note = Note::MainFieldRemoved {
        day: date.to_string(),
        position: position.clone(),
        height: height.is_some(),
    };
    Ok((MainFieldColumn { total_nt, position }, note))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reduced_names_follow_the_sgl_convention() {
        assert_eq!(column_name("mag_3_uc", "dc"), "mag_3_dc");
        assert_eq!(column_name("mag_3_c", "igrf"), "mag_3_igrf");
        assert_eq!(column_name("tail", "dc"), "tail_dc");
    }
}
