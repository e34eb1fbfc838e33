//! `magcomp summarize OUTDIR`: a campaign's flights in one table.
//!
//! Reads every `<flight>_status.json` in the folder and, for each flight
//! done, its quality and model JSON; writes
//! - `campaign_summary.csv`: a row per flight and channel (a failed
//!   flight: one row with its reason): state, rows, warnings, the FOM
//!   before and after, the improvement ratio, the band residual and the
//!   diagnosed findings applied;
//! - `campaign_coefficients.csv`, when an aircraft has two calibrated
//!   flights or more: each coefficient of each channel, flight by flight
//!   in date order, with its one-sigma uncertainty;
//! - `campaign_drift.csv`, for the same aircraft: each channel's model
//!   compared with the aircraft's previous calibration ([`super::drift`]),
//!   with the FOM of both, and a change the uncertainties do not explain
//!   flagged (and warned of on stdout);
//! - `campaign_summary.html`: the same tables on one page.
//!
//! Only flights the campaign names an aircraft for (`aircraft = …` in a
//! `[[flight]]` or a manifest) are followed over time: flights of unnamed
//! aircraft may be of different airframes, whose coefficients side by side
//! would suggest a change that is none.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::Value;

use super::drift::{compare, Calibration, Drift, Verdict};
use super::status::unreadable;
use super::{FlightState, FlightStatus};
use crate::error::{Error, Result};
use crate::formats::{stage, OutputSet};

/// One scalar channel of a flight, from its quality JSON.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelFigures {
    /// The channel.
    pub channel: String,
    /// FOM before compensation, nT.
    pub fom_before_nt: Option<f64>,
    /// FOM after, nT.
    pub fom_after_nt: Option<f64>,
    /// Improvement ratio of the band-passed standard deviation.
    pub improvement_ratio: Option<f64>,
    /// Band-passed residual over the windows, nT.
    pub band_std_after_nt: Option<f64>,
    /// Diagnosed effects applied, `effect` or `effect from source`.
    pub findings: Vec<String>,
    /// The saved model the channel was compensated with (`--apply`), as
    /// the quality JSON names it; `None` when fitted on its own flight.
    pub model: Option<String>,
    /// The channel's verdict, `FAIL`, `CHECK` or `PASS`, as its quality
    /// JSON gives it ([`crate::quality::verdict`]); empty when the figures
    /// cannot be read.
    pub verdict: String,
}

/// One coefficient of one channel's model.
#[derive(Debug, Clone, PartialEq)]
pub struct Coefficient {
    /// The channel.
    pub channel: String,
    /// The term's name.
    pub term: String,
    /// Its value.
    pub value: f64,
    /// One sigma, when the fit gives one.
    pub sigma: Option<f64>,
}

/// A flight of the campaign: its status and, when done, its figures.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryFlight {
    /// The status the run left.
    pub status: FlightStatus,
    /// Per-channel figures (empty for a failed flight).
    pub channels: Vec<ChannelFigures>,
    /// The fitted coefficients (empty for a failed flight).
    pub coefficients: Vec<Coefficient>,
    /// Each channel's model, as the drift comparison reads it.
    pub calibrations: Vec<Calibration>,
    /// What could not be read for this flight.
    pub problems: Vec<String>,
}

/// One channel of a recurring aircraft compared with its previous
/// calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftRow {
    /// The aircraft.
    pub aircraft: String,
    /// The channel.
    pub channel: String,
    /// The earlier flight and its date.
    pub from: (String, Option<String>),
    /// The later flight and its date.
    pub to: (String, Option<String>),
    /// The channel's FOM after compensation on each, nT.
    pub fom_nt: (Option<f64>, Option<f64>),
    /// The comparison.
    pub drift: Drift,
}

impl DriftRow {
    /// The row's cells in `campaign_drift.csv`, in its header's order.
    fn csv_cells(&self) -> Vec<String> {
        let d = &self.drift;
        let number = |v: f64| match v.is_finite() {
            true => format!("{v:.6}"),
            false => String::new(),
        };
        let (change, sigma) = d.permanent_change_nt.unwrap_or(([f64::NAN; 3], [f64::NAN; 3]));
        let mut cells = vec![
            self.aircraft.clone(),
            self.channel.clone(),
            self.from.0.clone(),
            self.from.1.clone().unwrap_or_default(),
            self.to.0.clone(),
            self.to.1.clone().unwrap_or_default(),
            d.verdict.name().into(),
            number(d.change_rms_nt),
            number(d.expected_rms_nt),
            number(d.ratio),
            number(d.limit),
            number(d.degrees_of_freedom),
            d.compared_terms.to_string(),
        ];
        cells.extend(change.iter().chain(&sigma).map(|&v| number(v)));
        cells.extend([number(d.permanent_t2), number(d.permanent_limit)]);
        cells.extend([figure(self.fom_nt.0), figure(self.fom_nt.1), d.note.clone()]);
        cells
    }

    /// The row in the page's drift table, a change in red.
    fn html_row(&self) -> String {
        let escape = crate::output::report::escape;
        let d = &self.drift;
        let label = |(flight, date): &(String, Option<String>)| match date {
            Some(date) => format!("{flight} ({date})"),
            None => flight.clone(),
        };
        let class = match d.verdict {
            Verdict::Changed => " class=\"failed\"",
            _ => "",
        };
        let number = |v: f64| match v.is_finite() {
            true => format!("{v:.3}"),
            false => "–".into(),
        };
        format!(
            "<tr{class}><td class=\"text\">{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"text\">{}</td></tr>",
            escape(&self.aircraft),
            escape(&self.channel),
            escape(&label(&self.from)),
            escape(&label(&self.to)),
            d.verdict.name(),
            number(d.change_rms_nt),
            number(d.expected_rms_nt),
            number(d.ratio),
            number(d.limit),
            figure(self.fom_nt.0),
            figure(self.fom_nt.1),
            escape(&d.describe())
        )
    }

    /// The row in one sentence, for stdout and the page.
    pub fn describe(&self) -> String {
        let fom = match self.fom_nt {
            (Some(a), Some(b)) => format!("; FOM {a:.3} → {b:.3} nT"),
            _ => String::new(),
        };
        format!(
            "{}, {}: {} → {}: {}{fom}",
            self.aircraft,
            self.channel,
            self.from.0,
            self.to.0,
            self.drift.describe()
        )
    }
}

/// A campaign's flights, in output-name order.
#[derive(Debug, Clone, PartialEq)]
pub struct CampaignSummary {
    /// Every flight with a status in the folder.
    pub flights: Vec<SummaryFlight>,
}

/// Reads the statuses in `folder` and the JSON files they list.
pub fn summarize(folder: &Path) -> Result<CampaignSummary> {
    let entries = std::fs::read_dir(folder).map_err(|e| Error::io(folder, "listing", e))?;
    let mut paths: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.ends_with("_status.json"))
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(Error::Config {
            source_name: folder.display().to_string(),
            message: "holds no <flight>_status.json; give the [output] directory of a magcomp run".into(),
        });
    }
    let mut flights = paths
        .iter()
        .map(|path| summary_flight(folder, path))
        .collect::<Result<Vec<_>>>()?;
    name_repeated_inputs(&mut flights);
    Ok(CampaignSummary { flights })
}

/// Marks each flight whose input's content another flight of the folder
/// shares: one input under two output names (a run that named it
/// otherwise left its outputs) would otherwise count twice in the table.
fn name_repeated_inputs(flights: &mut [SummaryFlight]) {
    let names_of = |sha256: &str, flights: &[SummaryFlight]| -> Vec<String> {
        (flights.iter())
            .filter(|f| f.status.input_sha256 == sha256)
            .map(|f| f.status.flight.clone())
            .collect()
    };
    let repeated: Vec<(usize, Vec<String>)> = (0..flights.len())
        .filter(|&i| !flights[i].status.input_sha256.is_empty())
        .map(|i| (i, names_of(&flights[i].status.input_sha256, flights)))
        .filter(|(_, names)| names.len() > 1)
        .collect();
    for (i, names) in repeated {
        let others: Vec<&String> = names.iter().filter(|n| **n != flights[i].status.flight).collect();
        let others: Vec<String> = others.iter().map(|n| format!("'{n}'")).collect();
        flights[i].problems.push(format!(
            "its input ({}) has the same content as that of {}, so the table counts one flight {} times: remove the outputs an earlier run left under the name no longer used",
            flights[i].status.input.display(),
            others.join(", "),
            names.len()
        ));
    }
}

fn summary_flight(folder: &Path, path: &Path) -> Result<SummaryFlight> {
    let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
    let status: FlightStatus = serde_json::from_str(&text).map_err(|e| unreadable(path, e.to_string()))?;
    let mut flight = SummaryFlight {
        status,
        channels: Vec::new(),
        coefficients: Vec::new(),
        calibrations: Vec::new(),
        problems: Vec::new(),
    };
    if flight.status.state != FlightState::Done {
        return Ok(flight);
    }
    let name = flight.status.flight.clone();
    match read_json(&folder.join(format!("{name}_quality.json"))) {
        Ok(quality) => {
            flight.channels = channel_figures(&quality);
            report_verdicts(
                &read_json(&folder.join(format!("{name}_report.json"))).unwrap_or_default(),
                &mut flight.channels,
            );
            if flight.channels.is_empty() {
                flight.problems.push(format!(
                    "{name}_quality.json lists no compensated channel although the flight is done: its row has no figures; read the flight's warnings and run it again"
                ));
            }
        }
        Err(problem) => flight.problems.push(problem),
    }
    // A flight compensated with a saved model fitted nothing: its
    // coefficients are its calibration flight's, counted there.
    let applied = flight.channels.iter().any(|c| c.model.is_some());
    match read_json(&folder.join(format!("{name}_model.json"))) {
        _ if applied => {}
        Ok(model) => {
            flight.coefficients = coefficients(&model);
            flight.calibrations = (model["models"].as_array().into_iter().flatten())
                .map(Calibration::from_model_json)
                .collect();
        }
        Err(problem) => flight.problems.push(problem),
    }
    Ok(flight)
}

/// Each channel's verdict: the quality JSON's own (`verdict`), else, for
/// outputs of an earlier magcomp, as the report's figures (`report`) gave
/// it, FAIL by the FOM over CHECK over PASS.
fn report_verdicts(report: &Value, channels: &mut [ChannelFigures]) {
    let passes = report["channels"].as_array().cloned().unwrap_or_default();
    for channel in channels {
        if crate::quality::verdict::Verdict::from_word(&channel.verdict).is_some() {
            continue;
        }
        let pass = (passes.iter())
            .find(|c| c["channel"].as_str() == Some(&channel.channel))
            .map(|c| c["fom_pass"].as_bool());
        channel.verdict = match (channel.verdict.as_str(), pass) {
            (_, Some(Some(false))) => "FAIL".into(),
            ("unchecked", _) => "CHECK".into(),
            (_, Some(Some(true))) => "PASS".into(),
            (_, Some(None)) => "CHECK".into(),
            (_, None) => String::new(),
        };
    }
}

fn read_json(path: &Path) -> std::result::Result<Value, String> {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    let text = crate::ingest::read_text(path).map_err(|e| format!("{name}: {e}"))?;
    serde_json::from_str(&text).map_err(|e| format!("{name}: {e}"))
}

fn channel_figures(quality: &Value) -> Vec<ChannelFigures> {
    let findings = quality["applied_findings"].as_array().cloned().unwrap_or_default();
    let model = quality["model"]["file"].as_str().map(str::to_string);
    // Findings that moved the survey beyond the stated uncertainty
    // (`ChannelQuality::unchecked_departure`): no plain pass.
    let unchecked = |channel: &Value| {
        let departure = channel["survey_departure_from_plain_nt"].as_f64();
        let stated = channel["uncertainty"]["outside_calibration_sigma_nt"].as_f64();
        departure.is_some_and(|d| d > stated.unwrap_or(0.0).max(crate::quality::DEPARTURE_FLOOR_NT))
    };
    let number = |value: &Value| value.as_f64();
    quality["channels"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|channel| {
            let name = channel["channel"].as_str().unwrap_or_default().to_string();
            ChannelFigures {
                fom_before_nt: number(&channel["fom_before_nt"]),
                fom_after_nt: number(&channel["fom_after_nt"]),
                improvement_ratio: number(&channel["improvement_ratio"]),
                band_std_after_nt: number(&channel["band_std_after_nt"]),
                findings: findings
                    .iter()
                    .filter(|f| f["channel"].as_str() == Some(&name))
                    .map(|f| {
                        let effect = f["effect"].as_str().unwrap_or("?");
                        match f["source"].as_str() {
                            Some(source) => format!("{effect} from {source}"),
                            None => effect.to_string(),
                        }
                    })
                    .collect(),
                model: model.clone(),
                verdict: match (channel["verdict"].as_str(), unchecked(channel)) {
                    (Some(word), _) => word.to_string(),
                    (None, true) => "unchecked".into(),
                    (None, false) => String::new(),
                },
                channel: name,
            }
        })
        .collect()
}

fn coefficients(model: &Value) -> Vec<Coefficient> {
    let mut all = Vec::new();
    for fitted in model["models"].as_array().into_iter().flatten() {
        let channel = fitted["channel"].as_str().unwrap_or_default();
        let names = fitted["term_names"].as_array().cloned().unwrap_or_default();
        let values = fitted["coefficients"].as_array().cloned().unwrap_or_default();
        let sigmas = fitted["coefficient_uncertainty"]
            .as_array()
            .cloned()
            .unwrap_or_default();
        for (index, (term, value)) in names.iter().zip(&values).enumerate() {
            let (Some(term), Some(value)) = (term.as_str(), value.as_f64()) else {
                continue;
            };
            all.push(Coefficient {
                channel: channel.into(),
                term: term.into(),
                value,
                sigma: sigmas.get(index).and_then(Value::as_f64),
            });
        }
    }
    all
}

impl CampaignSummary {
    /// Flights done and failed.
    pub fn counts(&self) -> (usize, usize) {
        let done = self
            .flights
            .iter()
            .filter(|f| f.status.state == FlightState::Done)
            .count();
        (done, self.flights.len() - done)
    }

    /// The named aircraft with two calibrated flights done or more, each
    /// with its flights in date order (undated last, then by name). A
    /// flight compensated with a saved model is not a calibration.
    pub fn recurring_aircraft(&self) -> Vec<(String, Vec<&SummaryFlight>)> {
        let mut groups: std::collections::BTreeMap<String, Vec<&SummaryFlight>> = Default::default();
        let calibrated = |f: &&SummaryFlight| !f.channels.iter().any(|c| c.model.is_some());
        for flight in (self.flights.iter())
            .filter(|f| f.status.state == FlightState::Done)
            .filter(calibrated)
        {
            if let Some(aircraft) = &flight.status.aircraft {
                groups.entry(aircraft.clone()).or_default().push(flight);
            }
        }
        groups
            .into_iter()
            .filter(|(_, flights)| flights.len() >= 2)
            .map(|(aircraft, mut flights)| {
                flights.sort_by(|a, b| {
                    let key =
                        |f: &SummaryFlight| (f.status.date.is_none(), f.status.date.clone(), f.status.flight.clone());
                    key(a).cmp(&key(b))
                });
                (aircraft, flights)
            })
            .collect()
    }

    /// Each channel of each recurring aircraft compared with the
    /// aircraft's previous calibration, flight after flight in date order.
    pub fn drifts(&self) -> Vec<DriftRow> {
        let mut rows = Vec::new();
        for (aircraft, flights) in self.recurring_aircraft() {
            for pair in flights.windows(2) {
                let (earlier, later) = (pair[0], pair[1]);
                for b in &later.calibrations {
                    let drift = match earlier.calibrations.iter().find(|a| a.channel == b.channel) {
                        Some(a) => compare(a, b),
                        None => Drift::unknown(format!(
                            "not compared: the earlier flight has no model of {} (not compensated, or its model JSON unreadable)",
                            b.channel
                        )),
                    };
                    let fom = |flight: &SummaryFlight| {
                        (flight.channels.iter())
                            .find(|c| c.channel == b.channel)
                            .and_then(|c| c.fom_after_nt)
                    };
                    rows.push(DriftRow {
                        aircraft: aircraft.clone(),
                        channel: b.channel.clone(),
                        from: (earlier.status.flight.clone(), earlier.status.date.clone()),
                        to: (later.status.flight.clone(), later.status.date.clone()),
                        fom_nt: (fom(earlier), fom(later)),
                        drift,
                    });
                }
            }
        }
        rows
    }

    /// `campaign_drift.csv`, or `None` when no aircraft recurs.
    pub fn drift_csv(&self) -> Option<String> {
        if self.recurring_aircraft().is_empty() {
            return None;
        }
        let header = [
            "aircraft",
            "channel",
            "flight_before",
            "date_before",
            "flight_after",
            "date_after",
            "verdict",
            "change_rms_nt",
            "expected_rms_nt",
            "ratio",
            "limit",
            "degrees_of_freedom",
            "compared_terms",
            "permanent_change_x_nt",
            "permanent_change_y_nt",
            "permanent_change_z_nt",
            "permanent_sigma_x_nt",
            "permanent_sigma_y_nt",
            "permanent_sigma_z_nt",
            "permanent_t2",
            "permanent_limit",
            "fom_before_flight_nt",
            "fom_after_flight_nt",
            "note",
        ];
        let mut rows = vec![header.map(String::from).to_vec()];
        for row in self.drifts() {
            rows.push(row.csv_cells());
        }
        Some(csv_text(&rows))
    }

    /// `campaign_summary.csv`.
    pub fn flights_csv(&self) -> String {
        let header = [
            "flight",
            "input",
            "aircraft",
            "date",
            "state",
            "rows",
            "warnings",
            "channel",
            "verdict",
            "fom_before_nt",
            "fom_after_nt",
            "improvement_ratio",
            "band_std_after_nt",
            "findings",
            "model",
            "problem",
        ];
        let mut rows = vec![header.map(String::from).to_vec()];
        for flight in &self.flights {
            rows.extend(flight.csv_rows());
        }
        csv_text(&rows)
    }

    /// `campaign_coefficients.csv`, or `None` when no aircraft recurs.
    pub fn coefficients_csv(&self) -> Option<String> {
        let recurring = self.recurring_aircraft();
        if recurring.is_empty() {
            return None;
        }
        let header = ["aircraft", "date", "flight", "channel", "term", "coefficient", "sigma"];
        let mut rows = vec![header.map(String::from).to_vec()];
        for (aircraft, flights) in &recurring {
            for flight in flights {
                for c in &flight.coefficients {
                    rows.push(vec![
                        aircraft.clone(),
                        flight.status.date.clone().unwrap_or_default(),
                        flight.status.flight.clone(),
                        c.channel.clone(),
                        c.term.clone(),
                        format!("{:e}", c.value),
                        c.sigma.map(|s| format!("{s:e}")).unwrap_or_default(),
                    ]);
                }
            }
        }
        Some(csv_text(&rows))
    }

    /// The lines `summarize` prints.
    pub fn describe(&self) -> String {
        let (done, failed) = self.counts();
        let mut text = format!("{} flights: {done} done, {failed} failed\n", self.flights.len());
        for flight in self.flights.iter().filter(|f| f.status.state == FlightState::Failed) {
            let _ = writeln!(
                text,
                "  failed: {}: {}",
                flight.status.flight,
                flight.status.error.as_deref().unwrap_or("no reason recorded")
            );
        }
        for flight in self.flights.iter().filter(|f| !f.problems.is_empty()) {
            let _ = writeln!(
                text,
                "  warning: {}: {}",
                flight.status.flight,
                flight.problems.join("; ")
            );
        }
        for row in self.drifts() {
            let kind = match row.drift.verdict {
                Verdict::Changed => "warning: installation changed",
                Verdict::Unknown => "note: drift not compared",
                Verdict::Steady => continue,
            };
            let _ = writeln!(text, "  {kind}: {}", row.describe());
        }
        text
    }

    /// `campaign_summary.html`.
    pub fn html(&self) -> String {
        let (done, failed) = self.counts();
        let mut page = String::from(
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>magcomp campaign summary</title>\n<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}td.text,th.text{text-align:left}tr.failed td{background:#fdd}td.FAIL{background:#f8c6cc;font-weight:bold}td.CHECK{background:#ffe7a8;font-weight:bold}td.PASS{background:#cfeccf}</style></head><body>\n",
        );
        let _ = writeln!(
            page,
            "<h1>Campaign summary</h1>\n<p>{} flights: {done} done, {failed} failed.</p>",
            self.flights.len()
        );
        page += "<h2>Flights</h2>\n<table><tr><th class=\"text\">flight</th><th class=\"text\">aircraft</th><th class=\"text\">date</th><th class=\"text\">state</th><th>rows</th><th>warnings</th><th class=\"text\">channel</th><th class=\"text\">verdict</th><th>FOM before, nT</th><th>FOM after, nT</th><th>IR</th><th class=\"text\">findings applied</th><th class=\"text\">saved model applied</th><th class=\"text\">problem</th></tr>\n";
        for flight in &self.flights {
            page += &flight.html_rows();
        }
        page += "</table>\n";
        if self.flights.iter().all(|f| f.status.aircraft.is_none()) {
            page += "<p>No flight names its aircraft: name it (<code>aircraft = \"…\"</code> in a [[flight]] or a manifest column) to follow each aircraft's coefficients over time.</p>\n";
        }
        page += &self.drift_html();
        page += &self.coefficients_html();
        page += "</body></html>\n";
        page
    }

    /// The drift table: each channel against the aircraft's previous
    /// calibration, a change the uncertainties do not explain in red.
    fn drift_html(&self) -> String {
        let rows = self.drifts();
        if rows.is_empty() {
            return String::new();
        }
        let mut html = String::from(
            "<h2>Drift between calibrations</h2>\n<p>Each channel's model against the aircraft's previous calibration: the RMS of the two models' predictions' difference over the calibration manoeuvres, against what the two fits' blocked-jackknife uncertainties explain. A ratio above the limit (the χ² 0.999 quantile times 1.5) is a change of the installation.</p>\n<table><tr><th class=\"text\">aircraft</th><th class=\"text\">channel</th><th class=\"text\">before</th><th class=\"text\">after</th><th class=\"text\">verdict</th><th>change, nT</th><th>expected, nT</th><th>ratio</th><th>limit</th><th>FOM before, nT</th><th>FOM after, nT</th><th class=\"text\">in words</th></tr>\n",
        );
        for row in &rows {
            let _ = writeln!(html, "{}", row.html_row());
        }
        html += "</table>\n";
        html
    }

    /// One table per recurring aircraft and channel: a row per term, a
    /// column per flight in date order, value ± one sigma.
    fn coefficients_html(&self) -> String {
        let escape = crate::output::report::escape;
        let mut html = String::new();
        for (aircraft, flights) in self.recurring_aircraft() {
            let _ = writeln!(html, "<h2>Coefficients over time: {}</h2>", escape(&aircraft));
            let mut channels: Vec<&str> = flights
                .iter()
                .flat_map(|f| f.coefficients.iter().map(|c| c.channel.as_str()))
                .collect();
            channels.sort_unstable();
            channels.dedup();
            for channel in channels {
                html += &coefficient_history(channel, &flights);
            }
        }
        html
    }

    /// Writes the summary files into `folder`, all committed together;
    /// returns their paths.
    pub fn write(&self, folder: &Path) -> Result<Vec<PathBuf>> {
        let mut files = vec![
            ("campaign_summary.csv", self.flights_csv()),
            ("campaign_summary.html", self.html()),
        ];
        if let Some(text) = self.coefficients_csv() {
            files.push(("campaign_coefficients.csv", text));
        }
        if let Some(text) = self.drift_csv() {
            files.push(("campaign_drift.csv", text));
        }
        let mut set = OutputSet::new();
        for (name, text) in files {
            set.add(stage(&folder.join(name), |w| {
                std::io::Write::write_all(w, text.as_bytes())
            })?);
        }
        set.commit()
    }
}

fn state_name(state: FlightState) -> &'static str {
    match state {
        FlightState::Done => "done",
        FlightState::Failed => "failed",
    }
}

/// The terms of `channel`'s coefficients over `flights`, each once, in
/// the order they first appear.
fn terms_of<'a>(channel: &str, flights: &[&'a SummaryFlight]) -> Vec<&'a str> {
    let mut terms: Vec<&str> = Vec::new();
    for c in flights
        .iter()
        .flat_map(|f| &f.coefficients)
        .filter(|c| c.channel == channel)
    {
        if !terms.contains(&c.term.as_str()) {
            terms.push(&c.term);
        }
    }
    terms
}

/// One recurring aircraft's table for `channel`: a row per term, a column
/// per flight in date order, value ± one sigma.
fn coefficient_history(channel: &str, flights: &[&SummaryFlight]) -> String {
    let escape = crate::output::report::escape;
    let mut html = String::new();
    let _ = write!(
        html,
        "<h3>{}</h3>\n<table><tr><th class=\"text\">term</th>",
        escape(channel)
    );
    for flight in flights {
        let label = match &flight.status.date {
            Some(date) => format!("{} ({date})", flight.status.flight),
            None => flight.status.flight.clone(),
        };
        let _ = write!(html, "<th>{}</th>", escape(&label));
    }
    html += "</tr>\n";
    for term in terms_of(channel, flights) {
        let _ = write!(html, "<tr><td class=\"text\">{}</td>", escape(term));
        for flight in flights {
            let found = flight
                .coefficients
                .iter()
                .find(|c| c.channel == channel && c.term == term);
            let text = match found {
                Some(Coefficient {
                    value, sigma: Some(s), ..
                }) => format!("{value:.4e} ± {s:.1e}"),
                Some(c) => format!("{:.4e}", c.value),
                None => "–".into(),
            };
            let _ = write!(html, "<td>{text}</td>");
        }
        html += "</tr>\n";
    }
    html += "</table>\n";
    html
}

fn figure(value: Option<f64>) -> String {
    value.map(|v| format!("{v:.4}")).unwrap_or_default()
}

/// `rows` as CSV text, fields quoted where they need it.
fn csv_text(rows: &[Vec<String>]) -> String {
    let mut writer = csv::Writer::from_writer(Vec::new());
    for row in rows {
        // Writing to memory cannot fail.
        let _ = writer.write_record(row);
    }
    let bytes = writer.into_inner().unwrap_or_default();
    String::from_utf8_lossy(&bytes).into_owned()
}

impl SummaryFlight {
    /// The flight's rows in `campaign_summary.csv`: one per channel, or
    /// one without figures when it has none.
    fn csv_rows(&self) -> Vec<Vec<String>> {
        let mut rows = Vec::new();
        let status = &self.status;
        let head = [
            status.flight.clone(),
            status.input.display().to_string(),
            status.aircraft.clone().unwrap_or_default(),
            status.date.clone().unwrap_or_default(),
            state_name(status.state).into(),
            status.rows.map(|r| r.to_string()).unwrap_or_default(),
            status.warnings.len().to_string(),
        ];
        if self.channels.is_empty() {
            rows.push(
                head.iter()
                    .cloned()
                    .chain(vec![String::new(); 8])
                    .chain([self.problem()])
                    .collect(),
            );
        }
        for channel in &self.channels {
            let figures = [
                channel.channel.clone(),
                channel.verdict.clone(),
                figure(channel.fom_before_nt),
                figure(channel.fom_after_nt),
                figure(channel.improvement_ratio),
                figure(channel.band_std_after_nt),
                channel.findings.join("; "),
                channel.model.clone().unwrap_or_default(),
                self.problem(),
            ];
            rows.push(head.iter().cloned().chain(figures).collect());
        }
        rows
    }

    /// The flight's rows in the page's table of flights: one per channel,
    /// or one without figures when it has none; a failed flight in red.
    fn html_rows(&self) -> String {
        let escape = crate::output::report::escape;
        let mut page = String::new();
        let status = &self.status;
        let problem = self.problem();
        let class = match status.state {
            FlightState::Failed => " class=\"failed\"",
            FlightState::Done => "",
        };
        // The flight's name links its report, where it wrote one.
        let report = (status.outputs.iter()).find(|name| name.ends_with("_report.html"));
        let name = match report {
            Some(report) => format!("<a href=\"{}\">{}</a>", escape(report), escape(&status.flight)),
            None => escape(&status.flight),
        };
        let head = format!(
            "<td class=\"text\">{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td><td>{}</td><td>{}</td>",
            name,
            escape(status.aircraft.as_deref().unwrap_or("")),
            escape(status.date.as_deref().unwrap_or("")),
            state_name(status.state),
            status.rows.map(|r| r.to_string()).unwrap_or_default(),
            status.warnings.len()
        );
        if self.channels.is_empty() {
            let _ = writeln!(
                page,
                "<tr{class}>{head}<td></td><td></td><td></td><td></td><td></td><td></td><td></td><td class=\"text\">{}</td></tr>",
                escape(&problem)
            );
        }
        for channel in &self.channels {
            let verdict = escape(&channel.verdict);
            let _ = writeln!(
                page,
                "<tr{class}>{head}<td class=\"text\">{}</td><td class=\"text {verdict}\">{verdict}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td><td class=\"text\">{}</td></tr>",
                escape(&channel.channel),
                figure(channel.fom_before_nt),
                figure(channel.fom_after_nt),
                figure(channel.improvement_ratio),
                escape(&channel.findings.join("; ")),
                escape(channel.model.as_deref().unwrap_or("")),
                escape(&problem)
            );
        }
        page
    }

    /// Why the flight failed and what of it could not be read, in one
    /// cell (empty when nothing is wrong).
    fn problem(&self) -> String {
        let status = &self.status;
        status
            .error
            .iter()
            .chain(&self.problems)
            .cloned()
            .collect::<Vec<_>>()
            .join("; ")
    }
}

#[cfg(test)]
mod verdict_tests {
    use super::*;

    /// The summary takes each channel's verdict from its quality JSON;
    /// outputs of an earlier magcomp, which wrote none, get FAIL by the
    /// FOM before CHECK by the departure, never CHECK over FAIL.
    #[test]
    fn the_quality_jsons_verdict_is_the_summarys() {
        let quality = serde_json::json!({"channels": [
            {"channel": "mag_1_uc", "verdict": "FAIL", "survey_departure_from_plain_nt": 0.5},
            {"channel": "mag_2_uc", "survey_departure_from_plain_nt": 0.5,
             "uncertainty": {"outside_calibration_sigma_nt": 0.01}},
            {"channel": "mag_3_uc", "survey_departure_from_plain_nt": 0.5,
             "uncertainty": {"outside_calibration_sigma_nt": 0.01}},
        ]});
        let report = serde_json::json!({"channels": [
            {"channel": "mag_1_uc", "fom_pass": true},
            {"channel": "mag_2_uc", "fom_pass": false},
            {"channel": "mag_3_uc", "fom_pass": true},
        ]});
        let mut channels = channel_figures(&quality);
        report_verdicts(&report, &mut channels);
        let verdicts: Vec<&str> = channels.iter().map(|c| c.verdict.as_str()).collect();
        assert_eq!(verdicts, ["FAIL", "FAIL", "CHECK"]);
    }
}
