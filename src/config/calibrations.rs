//! Calibrate once, apply everywhere, in a campaign: each aircraft's
//! calibration flights (`calibration = true`) are fitted on their own box,
//! and every other flight of that aircraft that names no model, windows or
//! lines of its own is compensated with a calibration flight's model.
//!
//! Which one: the only calibration flight of the aircraft; else, by the
//! flights' `date`, the latest flown on or before the flight (the first
//! after it when the flight was flown before any, which a note says).
//! Several calibration flights and a date missing to choose between them
//! is an error that names them: a guess would compensate with the wrong
//! box.

use std::collections::BTreeMap;
use std::path::Path;

use super::FlightJob;
use crate::error::{Error, Result};

/// Aircraft compared as [`crate::apply`] compares them: without case or
/// surrounding spaces.
fn aircraft_key(aircraft: &str) -> String {
    aircraft.trim().to_lowercase()
}

/// Gives each flight of an aircraft with calibration flights the model of
/// one of them (see the module documentation), as the path that flight's
/// run writes in `output_directory`. Returns one note per calibration
/// flight that compensates others.
pub(super) fn assign_calibrations(
    flights: &mut [FlightJob],
    output_directory: &Path,
    source_name: &str,
) -> Result<Vec<String>> {
    let bad = |message: String| Error::Config {
        source_name: source_name.into(),
        message,
    };
    let mut by_aircraft: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (index, flight) in flights.iter().enumerate().filter(|(_, f)| f.calibration) {
        let Some(aircraft) = &flight.aircraft else {
            return Err(bad(format!(
                "{}: calibration = true, but the flight names no aircraft; name it (aircraft = \"...\"): its model compensates that aircraft's other flights",
                flight.input.display()
            )));
        };
        if let Some(model) = &flight.model {
            return Err(bad(format!(
                "{}: calibration = true and model = {:?}: a calibration flight is fitted on its own box; give it one or the other",
                flight.input.display(),
                model.display().to_string()
            )));
        }
        by_aircraft.entry(aircraft_key(aircraft)).or_default().push(index);
    }
    let mut uses: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    let mut flown_before_any = Vec::new();
    for (index, flight) in flights.iter().enumerate() {
        let own =
            flight.calibration || flight.model.is_some() || !flight.windows.is_empty() || !flight.lines.is_empty();
        let Some(calibrations) = (flight.aircraft.as_deref()).and_then(|a| by_aircraft.get(&aircraft_key(a))) else {
            continue;
        };
        if own {
            continue;
        }
        let (chosen, before_any) = choose(flights, flight, calibrations).map_err(bad)?;
        uses.entry(chosen).or_default().push(index);
        if before_any {
            flown_before_any.push(index);
        }
    }
    let mut notes = Vec::new();
    for (calibration, users) in &uses {
        let model = flights[*calibration].model_json_in(output_directory);
        for &user in users {
            flights[user].model = Some(model.clone());
        }
        let names: Vec<&str> = users.iter().map(|&u| flights[u].output_name.as_str()).collect();
        notes.push(format!(
            "aircraft '{}': {} flight(s) compensated with the model of its calibration flight {} ({}): {}",
            flights[*calibration].aircraft.as_deref().unwrap_or_default(),
            users.len(),
            flights[*calibration].input.display(),
            model.display(),
            listed(&names)
        ));
    }
    for index in flown_before_any {
        notes.push(format!(
            "{} was flown before any calibration flight of its aircraft: it is compensated with the first one's model",
            flights[index].input.display()
        ));
    }
    Ok(notes)
}

/// The calibration flight (an index into `flights`) whose model compensates
/// `flight`, and whether it was flown after it.
fn choose(
    flights: &[FlightJob],
    flight: &FlightJob,
    calibrations: &[usize],
) -> std::result::Result<(usize, bool), String> {
    if let [only] = calibrations {
        return Ok((*only, false));
    }
    let dated: Option<Vec<(crate::flight_date::FlightDate, usize)>> =
        calibrations.iter().map(|&c| Some((flights[c].date?, c))).collect();
    let (Some(day), Some(mut dated)) = (flight.date, dated) else {
        let names: Vec<String> = calibrations
            .iter()
            .map(|&c| flights[c].input.display().to_string())
            .collect();
        return Err(format!(
            "{} could take the model of {} calibration flights of its aircraft ({}), and without the date of each (date = \"YYYY-MM-DD\") magcomp cannot tell which was flown last before it; give the dates, or name the flight's model",
            flight.input.display(),
            calibrations.len(),
            names.join(", ")
        ));
    };
    dated.sort();
    Ok(match dated.iter().rev().find(|(d, _)| *d <= day) {
        Some((_, c)) => (*c, false),
        None => (dated[0].1, true),
    })
}

/// Names for a note: all of them up to eight, else the first eight and a
/// count.
fn listed(names: &[&str]) -> String {
    const SHOWN: usize = 8;
    match names.len() {
        0..=SHOWN => names.join(", "),
        n => format!("{} and {} more", names[..SHOWN].join(", "), n - SHOWN),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight_date::FlightDate;

    fn flight(name: &str, aircraft: Option<&str>, date: Option<&str>, calibration: bool) -> FlightJob {
        FlightJob {
            aircraft: aircraft.map(String::from),
            date: date.map(|d| FlightDate::parse(d).unwrap()),
            calibration,
            ..FlightJob::new(format!("/season/{name}.csv"))
        }
    }

    fn models(flights: &[FlightJob]) -> Vec<Option<String>> {
        (flights.iter())
            .map(|f| f.model.as_ref().map(|m| m.display().to_string()))
            .collect()
    }

    #[test]
    fn each_flight_takes_its_aircraft_s_last_calibration_before_it() {
        let mut flights = vec![
            flight("cal_a1", Some("C-GMAG"), Some("2026-06-01"), true),
            flight("cal_a2", Some("c-gmag "), Some("2026-06-10"), true),
            flight("cal_b", Some("C-FTLL"), None, true),
            flight("s1", Some("C-GMAG"), Some("2026-06-05"), false),
            flight("s2", Some("C-GMAG"), Some("2026-06-10"), false),
            flight("s3", Some("C-GMAG"), Some("2026-05-20"), false),
            flight("s4", Some("C-FTLL"), None, false),
            flight("s5", None, Some("2026-06-05"), false),
            flight("s6", Some("C-OTHR"), Some("2026-06-05"), false),
        ];
        let mut own = flight("s7", Some("C-GMAG"), Some("2026-06-05"), false);
        own.lines = vec![1002.2];
        flights.push(own);
        let notes = assign_calibrations(&mut flights, Path::new("/out"), "pipeline.toml").unwrap();
        let m = |name: &str| Some(format!("/out/{name}_model.json"));
        assert_eq!(
            models(&flights),
            [
                None,
                None,
                None,
                m("cal_a1"),
                m("cal_a2"),
                m("cal_a1"),
                m("cal_b"),
                None,
                None,
                None
            ]
        );
        assert_eq!(notes.len(), 4, "{notes:?}");
        assert!(
            notes[0].contains("aircraft 'C-GMAG': 2 flight(s)") && notes[0].contains("s1, s3"),
            "{notes:?}"
        );
        assert!(
            notes[3].contains("s3.csv was flown before any calibration flight"),
            "{notes:?}"
        );
    }

    #[test]
    fn a_choice_the_dates_cannot_make_is_refused_by_name() {
        let mut flights = vec![
            flight("cal_1", Some("C-GMAG"), Some("2026-06-01"), true),
            flight("cal_2", Some("C-GMAG"), None, true),
            flight("s1", Some("C-GMAG"), Some("2026-06-05"), false),
        ];
        let error = assign_calibrations(&mut flights, Path::new("/out"), "pipeline.toml").unwrap_err();
        let text = error.to_string();
        assert!(
            text.contains("s1.csv could take the model of 2 calibration flights")
                && text.contains("cal_1.csv, /season/cal_2.csv")
                && text.contains("give the dates"),
            "{text}"
        );
        let mut unnamed = vec![flight("cal", None, None, true), flight("s", None, None, false)];
        let text = assign_calibrations(&mut unnamed, Path::new("/out"), "p")
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("cal.csv: calibration = true, but the flight names no aircraft"),
            "{text}"
        );
    }
}
