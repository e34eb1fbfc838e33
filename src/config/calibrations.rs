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
use crate::messages::Setup;

/// Aircraft compared as [`crate::pipeline::apply`] compares them: without
/// case or surrounding spaces.
fn aircraft_key(aircraft: &str) -> String {
    aircraft.trim().to_lowercase()
}

/// The calibration flights (`calibration = true`) of each aircraft, by
/// [`aircraft_key`]; an error for a flight whose aircraft is empty, and for
/// a calibration flight that names no aircraft or gives a
/// model of its own.
fn calibration_flights(flights: &[FlightJob]) -> std::result::Result<BTreeMap<String, Vec<usize>>, String> {
    if let Some(flight) = (flights.iter()).find(|f| f.aircraft.as_deref().is_some_and(|a| a.trim().is_empty())) {
        return Err(format!(
            "{}: aircraft is empty; name the airframe (aircraft = \"C-GMAG\", say), or leave the key out",
            flight.input.display()
        ));
    }
    let mut by_aircraft: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (index, flight) in flights.iter().enumerate().filter(|(_, f)| f.calibration) {
        let Some(aircraft) = &flight.aircraft else {
            return Err(format!(
                "{}: calibration = true, but the flight names no aircraft; name it (aircraft = \"...\"): its model compensates that aircraft's other flights",
                flight.input.display()
            ));
        };
        if let Some(model) = &flight.model {
            return Err(format!(
                "{}: calibration = true and model = {:?}: a calibration flight is fitted on its own box; give it one or the other",
                flight.input.display(),
                model.display().to_string()
            ));
        }
        by_aircraft.entry(aircraft_key(aircraft)).or_default().push(index);
    }
    Ok(by_aircraft)
}

/// The notes on the flights not simply given their aircraft's calibration:
/// those `flown_before_any` of its calibration flights (given the first
/// one's model), and those of an aircraft with none, by aircraft
/// (`uncalibrated`, fitted on their own boxes).
fn notes_on_the_rest(
    flights: &[FlightJob],
    flown_before_any: &[usize],
    uncalibrated: &BTreeMap<String, Vec<usize>>,
) -> Vec<Setup> {
    let mut notes = Vec::new();
    for &index in flown_before_any {
        notes.push(Setup::FlownBeforeCalibration {
            flight: flights[index].input.clone(),
        });
    }
    for indices in uncalibrated.values() {
        notes.push(Setup::NoCalibrationFlight {
            aircraft: flights[indices[0]]
                .aircraft
                .as_deref()
                .unwrap_or_default()
                .trim()
                .to_string(),
            flights: indices.iter().map(|&i| flights[i].output_name.clone()).collect(),
        });
    }
    notes
}

/// Whether `flight` names its own calibration data, diagnosis or plan: it
/// is fitted on its own box.
fn names_its_own(flight: &FlightJob) -> bool {
    flight.calibration
        || flight.model.is_some()
        || !flight.windows.is_empty()
        || !flight.lines.is_empty()
        || flight.diagnosis.is_some()
        || flight.plan.is_some()
}

/// Gives each flight of an aircraft with calibration flights the model of
/// one of them (see the module documentation), as the path that flight's
/// run writes in `output_directory`. Returns one note per calibration
/// flight that compensates others.
pub(super) fn assign_calibrations(
    flights: &mut [FlightJob],
    output_directory: &Path,
    source_name: &str,
) -> Result<Vec<Setup>> {
    let bad = |message: String| Error::Config {
        source_name: source_name.into(),
        message,
    };
    let by_aircraft = calibration_flights(flights).map_err(bad)?;
    let mut uses: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    let mut flown_before_any = Vec::new();
    let mut uncalibrated: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    let mut unassigned: Vec<(usize, Option<String>)> = Vec::new();
    for (index, flight) in flights.iter().enumerate() {
        if names_its_own(flight) || by_aircraft.is_empty() {
            continue;
        }
        let Some(aircraft) = flight.aircraft.as_deref() else {
            unassigned.push((index, None));
            continue;
        };
        let Some(calibrations) = by_aircraft.get(&aircraft_key(aircraft)) else {
            uncalibrated.entry(aircraft_key(aircraft)).or_default().push(index);
            unassigned.push((index, Some(aircraft.to_string())));
            continue;
        };
        let (chosen, before_any) = choose(flights, flight, calibrations).map_err(bad)?;
        uses.entry(chosen).or_default().push(index);
        if before_any {
            flown_before_any.push(index);
        }
    }
    for (index, aircraft) in unassigned {
        flights[index].no_calibration_because = Some(why_no_calibration(flights, &by_aircraft, aircraft.as_deref()));
    }
    let mut notes = Vec::new();
    for (calibration, users) in &uses {
        let model = flights[*calibration].model_json_in(output_directory);
        for &user in users {
            flights[user].model = Some(model.clone());
            flights[user].assigned_model = Some(crate::messages::Note::AssignedModel {
                calibration: flights[*calibration].input.clone(),
                before_any: flown_before_any.contains(&user),
            });
        }
        notes.push(Setup::CompensatedWithCalibration {
            aircraft: flights[*calibration]
                .aircraft
                .as_deref()
                .unwrap_or_default()
                .trim()
                .to_string(),
            calibration: flights[*calibration].input.clone(),
            model: model.clone(),
            flights: users.iter().map(|&u| flights[u].output_name.clone()).collect(),
        });
    }
    notes.extend(notes_on_the_rest(flights, &flown_before_any, &uncalibrated));
    Ok(notes)
}

/// Why a flight of `aircraft` (or of none) took no calibration flight's
/// model: the campaign's calibration flights by aircraft, and the closest
/// aircraft name to the flight's.
fn why_no_calibration(
    flights: &[FlightJob],
    by_aircraft: &BTreeMap<String, Vec<usize>>,
    aircraft: Option<&str>,
) -> String {
    let listed: Vec<String> = (by_aircraft.values())
        .map(|indices| {
            let name = flights[indices[0]].aircraft.as_deref().unwrap_or_default().trim();
            let paths: Vec<String> = indices
                .iter()
                .map(|&i| flights[i].input.display().to_string())
                .collect();
            format!("{name}: {}", paths.join(", "))
        })
        .collect();
    let has = format!(
        "the campaign's calibration flights are, by aircraft, {}",
        listed.join("; ")
    );
    match aircraft {
        None => format!(
            "the flight names no aircraft, and {has}; name its aircraft (aircraft = \"...\") to take that aircraft's model, or give it a model, windows or lines of its own"
        ),
        Some(aircraft) => {
            let key = aircraft_key(aircraft);
            let closest = (by_aircraft.iter())
                .min_by_key(|(other, _)| edit_distance(&key, other))
                .map(|(_, indices)| flights[indices[0]].aircraft.as_deref().unwrap_or_default().trim());
            format!(
                "no calibration flight names its aircraft \"{}\", and {has}; the closest name is \"{}\": correct the flight's aircraft if it is that one, or give the flight a model, windows or lines of its own",
                aircraft.trim(),
                closest.unwrap_or_default()
            )
        }
    }
}

/// The Levenshtein distance between `a` and `b`, by characters.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let substituted = diagonal + usize::from(ca != cb);
            diagonal = row[j + 1];
            row[j + 1] = substituted.min(row[j] + 1).min(diagonal + 1);
        }
    }
    row[b.len()]
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
    let dated: Option<Vec<(crate::ingest::flight_date::FlightDate, usize)>> =
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
    let (chosen, before_any) = match dated.iter().rev().find(|(d, _)| *d <= day) {
        Some(&(d, c)) => ((d, c), false),
        None => (dated[0], true),
    };
    // Two boxes on one day: which one the flight followed is not in the
    // dates.
    let same_day: Vec<String> = (dated.iter())
        .filter(|(d, _)| *d == chosen.0)
        .map(|&(_, c)| flights[c].input.display().to_string())
        .collect();
    if same_day.len() > 1 {
        return Err(format!(
            "{} would take the model of a calibration flight of {}, and its aircraft flew {} then ({}); magcomp cannot tell which the flight followed: name the flight's model",
            flight.input.display(),
            chosen.0,
            same_day.len(),
            same_day.join(", ")
        ));
    }
    Ok((chosen.1, before_any))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_date::FlightDate;

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
        let mut diagnosed = flight("s8", Some("C-GMAG"), Some("2026-06-05"), false);
        diagnosed.diagnosis = Some("s8_diagnosis.json".into());
        flights.push(diagnosed);
        let notes = assign_calibrations(&mut flights, Path::new("/out"), "pipeline.toml").unwrap();
        let m = |name: &str| Some(format!("/out/{name}_model.json"));
        let expected = [
            None,
            None,
            None,
            m("cal_a1"),
            m("cal_a2"),
            m("cal_a1"),
            m("cal_b"),
            None,
            None,
            None,
            None,
        ];
        assert_eq!(models(&flights), expected);
        assert_eq!(notes.len(), 5, "{notes:?}");
        assert!(
            matches!(&notes[0], Setup::CompensatedWithCalibration { aircraft, flights, .. }
                if aircraft == "C-GMAG" && flights.len() == 2 && flights.join(", ").contains("s1, s3")),
            "{notes:?}"
        );
        assert!(
            matches!(&notes[1], Setup::CompensatedWithCalibration { aircraft, flights, .. }
                if aircraft == "c-gmag" && flights.len() == 1),
            "{notes:?}"
        );
        assert!(
            matches!(&notes[3], Setup::FlownBeforeCalibration { flight } if flight.ends_with("s3.csv")),
            "{notes:?}"
        );
        assert_eq!(
            notes[4],
            Setup::NoCalibrationFlight {
                aircraft: "C-OTHR".into(),
                flights: vec!["s6".into()]
            }
        );
        // Each flight given a model says why, in its own files.
        let said = |k: usize| flights[k].assigned_model.as_ref().map(|note| note.to_string());
        assert_eq!(
            flights[3].assigned_model,
            Some(crate::messages::Note::AssignedModel {
                calibration: "/season/cal_a1.csv".into(),
                before_any: false
            })
        );
        assert_eq!(
            said(3).as_deref(),
            Some("compensated with the model of its aircraft's calibration flight /season/cal_a1.csv (calibration = true)")
        );
        assert!(matches!(
            flights[5].assigned_model,
            Some(crate::messages::Note::AssignedModel { before_any: true, .. })
        ));
        let before_any = said(5).unwrap();
        assert!(before_any.ends_with("flown before any calibration flight of its aircraft, so the first one's"));
        assert!(flights[0].assigned_model.is_none() && flights[9].assigned_model.is_none());
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
        // Two boxes flown on the flight's day: which it followed is unknown.
        let mut same_day = vec![
            flight("cal_am", Some("C-GMAG"), Some("2026-06-05"), true),
            flight("cal_pm", Some("C-GMAG"), Some("2026-06-05"), true),
            flight("s1", Some("C-GMAG"), Some("2026-06-07"), false),
        ];
        let text = assign_calibrations(&mut same_day, Path::new("/out"), "p")
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("its aircraft flew 2 then (/season/cal_am.csv, /season/cal_pm.csv)"),
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
        // An empty name is no name: refused, whatever the flight.
        for calibration in [true, false] {
            let mut empty = vec![flight("cal", Some(" "), None, calibration)];
            let text = assign_calibrations(&mut empty, Path::new("/out"), "p")
                .unwrap_err()
                .to_string();
            assert!(text.contains("cal.csv: aircraft is empty"), "{text}");
        }
    }
}
