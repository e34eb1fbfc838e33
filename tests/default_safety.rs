//! The default never makes a clean channel worse: clean simulated flights
//! drawn the way a new user would draw them (1–8 scalar sensors in the
//! tail, cabin, wings and nose; 5–50 Hz; 20–240 minutes; half the boxes
//! flown back to back with the airframe's coupled motion; the simulator's
//! auxiliary channels, which vary through the flight but couple to
//! nothing; a base station with 10–100 nT of diurnal variation), each
//! compensated by `compensate`'s default (`[diagnose] apply = "auto"`,
//! through the pipeline and its evidence rule) and plain (`--plain`).
//!
//! What is measured, on the survey lines against the simulator's true
//! Earth field (standard deviation of compensated − truth over the line
//! rows): the channels worse than plain by more than 10 % + 0.01 nT. The
//! 300 plans must show none, and none may be harmed with nothing said.
//! The figures of every channel whose default differs from plain are
//! printed, with the findings it applied and those it held back, a table
//! by what was applied, and the channels whose verdict is CHECK (the
//! default's move from plain beyond its stated uncertainty) by what moved
//! them.
//!
//! Flights: `cargo test` flies [`DEFAULT_FLIGHTS`];
//! `MAGCOMP_SAFETY_FLIGHTS=N` flies the first N of the same draw instead
//! (450: 150 more, drawn as those before them), and
//! `MAGCOMP_SAFETY_SEEDS=6,27` those plans alone, printing the figures
//! without asserting them; and
//! `MAGCOMP_SAFETY_KEEP=DIR` leaves each flight there as `clean_<seed>.csv`
//! (with `truth_<seed>.csv`, the true Earth field per sensor) to look at
//! with `magcomp diagnose`.

mod common;

use magcomp::config::{FlightJob, Settings};
use magcomp::messages::{HeldBack, MovedBy, Warning};
use magcomp::simulate::random::Random;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::simulate;
use magcomp::simulate::truth::survey_line_error_nt;
use rayon::prelude::*;

/// Flights in `cargo test`.
const DEFAULT_FLIGHTS: u64 = 300;

fn flights() -> u64 {
    std::env::var("MAGCOMP_SAFETY_FLIGHTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(DEFAULT_FLIGHTS)
}

/// The plans flown: the first [`flights`], or those of
/// `MAGCOMP_SAFETY_SEEDS` (seeds separated by commas) to look again at a
/// few.
fn seeds() -> Vec<u64> {
    match std::env::var("MAGCOMP_SAFETY_SEEDS") {
        Ok(list) => (list.split(','))
            .map(|s| {
                s.trim()
                    .parse()
                    .expect("MAGCOMP_SAFETY_SEEDS: seeds separated by commas")
            })
            .collect(),
        Err(_) => (0..flights()).collect(),
    }
}

/// One channel of a clean flight, compensated by default and plain.
struct ChannelOutcome {
    /// The channel with the diagnosis's figures.
    name: String,
    /// Survey-line error against truth, plain, nT.
    plain: f64,
    /// The same by default, nT.
    auto: f64,
    /// Findings applied.
    applied: Vec<String>,
    /// Findings held back.
    held: Vec<String>,
    /// Whether the default run warned of the channel.
    warned: bool,
    /// The default's stated uncertainty outside the calibration, nT.
    stated_sigma: Option<f64>,
    /// What moved the survey beyond that uncertainty, where something
    /// did: the verdict is CHECK.
    checked: Option<MovedBy>,
    /// Why the default's verdict is not PASS, in words.
    verdict_reasons: Vec<String>,
}

type Outcome = Vec<ChannelOutcome>;

fn fly(seed: u64) -> (String, Outcome) {
    let raw = common::clean_plan(seed);
    let describe = format!(
        "seed {seed}: {} sensors, {} Hz, {} lines, {} ties",
        raw.scalar.len(),
        raw.sample_rate_hz,
        raw.survey.line_count,
        raw.survey.tie_count
    );
    let flight = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let folder = tempfile::tempdir().unwrap();
    let csv = folder.path().join("clean.csv");
    magcomp::formats::write_flight_log(&flight.log, &csv).unwrap();
    if let Ok(keep) = std::env::var("MAGCOMP_SAFETY_KEEP") {
        keep_flight(std::path::Path::new(&keep), seed, &csv, &flight);
    }
    let job = FlightJob::new(&csv);
    let mut default = Settings::default();
    default.vector.enabled = false;
    let plain = common::plain();
    let out = folder.path().join("out.csv");
    let auto = magcomp::pipeline::run(&job, &default, &out).unwrap();
    let fitted_plain = magcomp::pipeline::run(&job, &plain, &out).unwrap();
    let line = &flight.log.channel("line").unwrap().values;
    let ties = magcomp::quality::crossovers::Crossovers::of(&flight.log);
    let outcome = (auto.compensation.channels.iter())
        .zip(&fitted_plain.compensation.channels)
        .zip(&auto.result.models)
        .map(|((a, p), model)| {
            let truth = flight.truth.earth_total_nt(&model.channel).unwrap();
            let applied: Vec<String> = (auto.result.applied_findings.iter())
                .filter(|f| f.channel == model.channel)
                .map(|f| f.describe())
                .collect();
            let held: Vec<String> = (auto.result.diagnosis.iter())
                .flat_map(|d| d.findings.iter())
                .filter(|f| f.channel == model.channel && f.not_applied.is_some())
                .map(|f| format!("{} {:?}", f.effect, f.source))
                .collect();
            // The diagnosis's held-out RMS, plain and with its findings,
            // both with λ as compensation picks it.
            let heldout = (auto.result.diagnosis.iter())
                .flat_map(|d| d.channels.iter())
                .find(|c| c.channel == model.channel)
                .map(|c| {
                    format!(
                        "held out {:.4} → {:.4} nT",
                        c.heldout_rms_baseline_nt, c.heldout_rms_final_nt
                    )
                })
                .unwrap_or_default();
            let departure = (auto.result.channels.iter())
                .find(|q| q.channel == model.channel)
                .and_then(|q| q.survey_departure_from_plain_nt)
                .map(|d| format!(", survey departure {d:.4} nT"))
                .unwrap_or_default();
            // Whether the default said so: a warning that names the
            // channel (an uncertainty, a transfer, a departure from plain).
            let warned = (auto.result.warnings.iter()).any(|w| {
                w.channel() == Some(&model.channel) || w.to_string().starts_with(&format!("{}:", model.channel))
            });
            let stated_sigma = (auto.result.channels.iter())
                .find(|q| q.channel == model.channel)
                .and_then(|q| q.uncertainty.as_ref())
                .map(|u| u.outside_calibration_sigma_nt);
            let stated = stated_sigma.map_or("; no stated σ".into(), |s| format!("; stated σ {s:.4} nT"));
            let crossovers =
                magcomp::quality::crossovers::compare_levels(&flight.log, &ties, (&p.values, &a.values), 1)
                    .map(|c| {
                        format!(
                            "; levelled at {} crossovers of {} lines: plain {:.4} default {:.4} nT (se {:.4})",
                            c.crossovers, c.lines, c.reference_nt, c.candidate_nt, c.standard_error_nt
                        )
                    })
                    .unwrap_or_else(|| "; no crossovers".into());
            let said = if warned { "; warned" } else { "; not warned" };
            let checked = (auto.result.warnings.iter()).find_map(|w| match w {
                Warning::SurveyDeparture { channel, moved_by, .. } if *channel == model.channel => Some(*moved_by),
                _ => None,
            });
            ChannelOutcome {
                name: format!("{} ({heldout}{departure}{stated}{said}{crossovers})", model.channel),
                plain: survey_line_error_nt(&p.values, truth, line),
                auto: survey_line_error_nt(&a.values, truth, line),
                applied,
                held,
                warned,
                stated_sigma,
                checked,
                verdict_reasons: (auto.result.channels.iter())
                    .find(|q| q.channel == model.channel)
                    .map(|q| q.verdict_reasons.clone())
                    .unwrap_or_default(),
            }
        })
        .collect();
    (describe, outcome)
}

/// Copies the flight's CSV into `folder` and writes beside it the true
/// Earth field at each scalar sensor and the external variation along
/// the main field.
fn keep_flight(
    folder: &std::path::Path,
    seed: u64,
    csv: &std::path::Path,
    flight: &magcomp::simulate::SimulatedFlight,
) {
    std::fs::create_dir_all(folder).unwrap();
    std::fs::copy(csv, folder.join(format!("clean_{seed}.csv"))).unwrap();
    let sensors: Vec<_> = flight.truth.sensors.iter().collect();
    let mut text = String::from("time,external");
    for sensor in &sensors {
        text += &format!(",{}", sensor.channel);
    }
    text.push('\n');
    let time = flight.log.time_s();
    for (row, t) in time.iter().enumerate() {
        text += &format!("{t},{}", flight.truth.external_nt[row]);
        for sensor in &sensors {
            text += &format!(",{}", sensor.earth_total_nt[row]);
        }
        text.push('\n');
    }
    std::fs::write(folder.join(format!("truth_{seed}.csv")), text).unwrap();
}

// Channels harmed (default worse than plain by more than 10 % + 0.01 nT)
// over the [`DEFAULT_FLIGHTS`] plans (1,344 channels): none. Before the
// base station's record was low-passed where its own noise takes over
// (`magcomp::model::station`): 2, plans 95 and 272, by the station's term
// alone (0.0068 → 0.0202 and 0.0088 → 0.0208 nT, within twice their
// stated uncertainty); low-passed, the term is applied on 247 channels
// (was 140) and helps 127 of them by more than 10 % (was 68), and harms
// none. Before lags whatever the survey check, and couplings where none
// could be made, were weighed against what they explain on the box
// (`pipeline::diagnosis::unchecked_moves`): 4, plan 267's lag (0.0205 →
// 0.0919 nT) and plan 135's coupling (0.0593 → 0.1070 nT) besides those
// two; the rule changes no other channel of the 300. 80 % of the
// plans fly 1–4 tie lines, and the evidence rule levels the lines at
// their crossovers. Over all 300 plans (1,344 channels): 28 harmed before
// the ties, 22 with them, 16 with the levelling at its first setting (8
// crossovers, 2 standard errors; 7 of the 16 on flights with no tie). At
// the setting kept (2 crossovers, half a standard error) it holds back 8
// of those 9 with crossovers and none of the 109 channels the findings
// helped. On plans 300–449, drawn after it was set, with plans 0–29: 3
// harmed of 844 channels, none on a flight with ties, worst 4.69× (plan
// 344, no tie: 0.19 → 0.89 nT). The first 30 plans: none (plans 7 and
// 15 were harmed before the levelling; it holds both back now). Where no
// ties cross, the rule compares neighbouring lines flown both ways: on
// the same 844 channels none harmed (worst 1.44×), with as many helped as
// before (21 by the base station's term, 42 by the second-order term); on
// plans 450–629, drawn after it was written, 1 harmed of 787 (plan 581, a
// sensor lag: 0.021 → 0.038 nT, warned; a lag moves the geology along the
// line, which the lines' levels do not show).

// No channel of the [`DEFAULT_FLIGHTS`] plans may be harmed with
// nothing said: no warning naming the channel and an error beyond twice
// the uncertainty it states (the sigma's coverage: 91.5 % of survey
// samples within 2σ, `tests/uncertainty.rs`). Right, or loudly uncertain.
// Over all 300 plans: 1 of the 28 harmed (plan 32, a lone tail sensor:
// 0.0152 → 0.0401 nT against a stated 0.0150 nT, the base station's
// variation subtracted); 23 of the 28 are warned of and 4 lie within twice
// their stated uncertainty. What harms is the level per heading: the error
// within a line is the same plain and by default, and lines flown the same
// way carry the same level (plan 295, mag_4_uc: 0.21 nT between the two
// line directions plain, 0.33 nT by default); a fit on a cleaner target
// still draws the heading terms with their own scatter.

#[test]
fn the_default_never_makes_a_clean_channel_worse_than_plain() {
    let outcomes: Vec<(String, Outcome)> = seeds().into_par_iter().map(fly).collect();
    let (mut channels, mut harmed, mut held_back, mut worst) = (0, Vec::new(), 0, 1.0f64);
    // Harmed with nothing said: no warning names the channel and its
    // error lies beyond twice the uncertainty the default states for it.
    let mut silent = Vec::new();
    // Per set of effects applied: channels, harmed, helped by more than 10 %.
    let mut by_effect: std::collections::BTreeMap<String, (usize, usize, usize)> = Default::default();
    // Per cause of a CHECK verdict: channels, harmed, helped by more than 10 %.
    let mut checks: std::collections::BTreeMap<String, (usize, usize, usize)> = Default::default();
    // A clean flight has no cause for a cross-sensor term, and a good
    // model is failed neither by its survey figures nor by its anomaly
    // gain.
    let mut wrongly = Vec::new();
    for (flight, outcome) in &outcomes {
        for outcome in outcome {
            if outcome.applied.iter().any(|a| a.starts_with("cross_sensor")) {
                wrongly.push(format!(
                    "{flight} {}: cross_sensor applied {:?}",
                    outcome.name, outcome.applied
                ));
            }
            let failed_good = |r: &&String| r.contains("this aircraft's") || r.contains("scales a crustal anomaly");
            if let Some(reason) = outcome.verdict_reasons.iter().find(failed_good) {
                wrongly.push(format!("{flight} {}: {reason}", outcome.name));
            }
            let (channel, plain, auto, applied, held) = (
                &outcome.name,
                &outcome.plain,
                &outcome.auto,
                &outcome.applied,
                &outcome.held,
            );
            channels += 1;
            held_back += held.len();
            worst = worst.max(auto / plain);
            if !applied.is_empty() || !held.is_empty() || auto != plain {
                println!("{flight} {channel}: plain {plain:.4} nT, default {auto:.4} nT; applied {applied:?}; held back {held:?}");
            }
            let mut effects: Vec<&str> = applied.iter().filter_map(|a| a.split(' ').next()).collect();
            effects.sort();
            effects.dedup();
            let entry = by_effect.entry(effects.join("+")).or_default();
            let check =
                (outcome.checked.map(|by| format!("{by:?}")).as_deref()).map(|by| checks.entry(by.into()).or_default());
            let (harm, help) = (*auto > 1.1 * plain + 0.01, *auto < 0.9 * plain);
            if let Some(check) = check {
                *check = (check.0 + 1, check.1 + usize::from(harm), check.2 + usize::from(help));
            }
            entry.0 += 1;
            if harm {
                harmed.push(format!("{flight} {channel}: {plain:.4} → {auto:.4} nT"));
                entry.1 += 1;
                let within_stated = outcome.stated_sigma.is_some_and(|sigma| *auto <= 2.0 * sigma);
                if !outcome.warned && !within_stated {
                    silent.push(format!("{flight} {channel}: {plain:.4} → {auto:.4} nT"));
                }
            } else if help {
                entry.2 += 1;
            }
        }
    }
    println!("| applied | channels | harmed | helped by > 10 % |\n|---|---|---|---|");
    for (effects, (count, worse, better)) in &by_effect {
        let name = if effects.is_empty() {
            "nothing"
        } else {
            effects.as_str()
        };
        println!("| {name} | {count} | {worse} | {better} |");
    }
    println!("| CHECK, moved by | channels | harmed | helped by > 10 % |\n|---|---|---|---|");
    for (by, (count, worse, better)) in &checks {
        println!("| {by} | {count} | {worse} | {better} |");
    }
    println!(
        "{} clean flights, {channels} channels: {} harmed (worst default/plain {worst:.2}); {held_back} findings held back by the evidence rule",
        outcomes.len(),
        harmed.len()
    );
    println!("{harmed:#?}");
    println!(
        "harmed with nothing said (no warning, error beyond twice the stated uncertainty): {}\n{silent:#?}",
        silent.len()
    );
    println!("on clean flights, cross_sensor applied or a good model failed: {wrongly:#?}");
    assert!(wrongly.is_empty(), "{wrongly:#?}");
    if flights() == DEFAULT_FLIGHTS && std::env::var("MAGCOMP_SAFETY_SEEDS").is_err() {
        assert!(
            harmed.is_empty(),
            "the aim, and the figure measured on the {DEFAULT_FLIGHTS} plans: none harmed {harmed:#?}"
        );
        assert!(silent.is_empty(), "harmed with nothing said: {silent:#?}");
    }
}

/// The clean flight of `raw`, compensated by default and plain.
fn default_and_plain(
    raw: RawScenario,
) -> (
    magcomp::simulate::SimulatedFlight,
    magcomp::pipeline::FlightRun,
    magcomp::pipeline::FlightRun,
) {
    let flight = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let folder = tempfile::tempdir().unwrap();
    let csv = folder.path().join("clean.csv");
    magcomp::formats::write_flight_log(&flight.log, &csv).unwrap();
    let job = FlightJob::new(&csv);
    let mut default = Settings::default();
    default.vector.enabled = false;
    let out = folder.path().join("out.csv");
    let auto = magcomp::pipeline::run(&job, &default, &out).unwrap();
    let plain = magcomp::pipeline::run(&job, &common::plain(), &out).unwrap();
    (flight, auto, plain)
}

/// The survey-line errors against truth of channel `index` (`name`),
/// plain and by default.
fn survey_errors(
    flight: &magcomp::simulate::SimulatedFlight,
    (auto, plain): (&magcomp::pipeline::FlightRun, &magcomp::pipeline::FlightRun),
    (index, name): (usize, &str),
) -> (f64, f64) {
    let line = &flight.log.channel("line").unwrap().values;
    let truth = flight.truth.earth_total_nt(name).unwrap();
    let (a, p) = (&auto.compensation.channels[index], &plain.compensation.channels[index]);
    assert_eq!(a.channel, name);
    (
        survey_line_error_nt(&p.values, truth, line),
        survey_line_error_nt(&a.values, truth, line),
    )
}

/// The default's channel `index` (`name`) is plain Tolles-Lawson's on the
/// survey lines: the same error against truth.
fn assert_compensated_plain(
    flight: &magcomp::simulate::SimulatedFlight,
    runs: (&magcomp::pipeline::FlightRun, &magcomp::pipeline::FlightRun),
    channel: (usize, &str),
) {
    let (plain_error, auto_error) = survey_errors(flight, runs, channel);
    assert!(
        (auto_error - plain_error).abs() < 1e-9,
        "{}: {plain_error} → {auto_error} nT",
        channel.1
    );
}

/// The default's channel `index` (`name`) is no worse than plain
/// Tolles-Lawson on the survey lines than the campaign allows (10 % +
/// 0.01 nT against truth): (plain, default) errors.
fn assert_not_harmed(
    flight: &magcomp::simulate::SimulatedFlight,
    runs: (&magcomp::pipeline::FlightRun, &magcomp::pipeline::FlightRun),
    channel: (usize, &str),
) -> (f64, f64) {
    let (plain_error, auto_error) = survey_errors(flight, runs, channel);
    assert!(
        auto_error <= 1.1 * plain_error + 0.01,
        "{}: {plain_error} → {auto_error} nT",
        channel.1
    );
    (plain_error, auto_error)
}

/// Plan 242 (two sensors, 10 Hz): the diagnosis finds a sensor lag on the
/// tail sensor from the fit with λ by PRESS (held out 0.0222 → 0.0136 nT),
/// but with λ as compensation picks it (blocked PRESS) the lag does not
/// lower the held-out RMS (0.0297 → 0.0310 nT). Applied, it made the
/// survey three times worse against truth (0.0205 → 0.0629 nT). The
/// evidence rule must hold it back, say why, and compensate plain.
#[test]
fn a_finding_that_does_not_pay_with_the_compensations_lambda_is_held_back() {
    let (flight, auto, plain) = default_and_plain(common::clean_plan(242));
    let diagnosis = auto.result.diagnosis.as_ref().expect("the default diagnoses");
    let lag = (diagnosis.findings.iter())
        .find(|f| f.channel == "mag_1_uc" && f.effect.kind() == magcomp::diagnose::EffectKind::SensorLag)
        .expect("the diagnosis finds the lag on mag_1_uc");
    let reason = lag.not_applied.as_deref().expect("the lag is held back");
    assert!(reason.contains("do not lower the held-out RMS"), "{reason}");
    assert!(
        (auto.result.warnings.iter()).any(|w| matches!(
            w,
            Warning::FindingsHeldBack { channel, findings, reason: HeldBack::NoGainHeldOut { .. } }
                if channel == "mag_1_uc" && findings.iter().any(|f| f.starts_with("sensor_lag"))
        )),
        "{:#?}",
        auto.result.warnings
    );
    assert_compensated_plain(&flight, (&auto, &plain), (0, "mag_1_uc"));
}

/// Plan 344 (four sensors, 10 Hz, eight lines flown back and forth, no
/// tie): the diagnosis finds the second-order term on mag_4_uc (held out
/// 0.2114 → 0.1357 nT), and it passes the departure check, but on the
/// survey it leaves the lines flown one way 1.8 nT from those flown the
/// other (plain: 0.36 nT), and made the survey 4.7 times worse against
/// truth (0.19 → 0.89 nT). With no crossover to level, the evidence rule
/// must compare the neighbouring lines, hold the term back, say why, and
/// compensate plain.
#[test]
fn a_finding_that_corrugates_a_survey_without_ties_is_held_back() {
    let raw = common::clean_plan(344);
    assert_eq!(
        (raw.survey.line_count, raw.survey.tie_count),
        (8, 0),
        "the plan as measured"
    );
    let (flight, auto, plain) = default_and_plain(raw);
    let HeldBack::WorseBetweenLines {
        plain_nt,
        diagnosed_nt,
        lines,
        ..
    } = held_between_lines(&auto, ("mag_4_uc", "second_order"))
    else {
        unreachable!()
    };
    assert_eq!(lines, 8);
    // What the lines show against truth's heading levels: plain's lines
    // flown one way sit 0.36 nT from the others, the term's 1.77 nT.
    assert!((plain_nt - 0.36).abs() < 0.1, "{plain_nt}");
    assert!((diagnosed_nt - 1.77).abs() < 0.2, "{diagnosed_nt}");
    // The channel's quality figures show the level the survey keeps: plain
    // Tolles-Lawson's, against the uncompensated lines'.
    let shown = (auto.result.channels.iter())
        .find(|q| q.channel == "mag_4_uc")
        .and_then(|q| q.heading_level)
        .expect("the lines' heading level is measured");
    assert_eq!((shown.lines, shown.triples), (8, 6), "{shown:?}");
    assert!((shown.after_nt - plain_nt).abs() < 0.01, "{shown:?} against {plain_nt}");
    assert!(shown.before_nt > 10.0 * shown.after_nt, "{shown:?}");
    assert_compensated_plain(&flight, (&auto, &plain), (3, "mag_4_uc"));
}

/// Plan 581 (four sensors, 10 Hz, nine lines 500 m apart flown back and
/// forth, no tie): the diagnosis finds a lag of −0.18 s on mag_1_uc (held
/// out 0.0314 → 0.0176 nT, better on 11 of 12 manoeuvres), where the
/// simulator has none. On the survey it moves the level between the
/// lines flown one way and the other by 0.083 nT (0.065 nT since
/// detection levels a manoeuvre flown back to back about its own cycles,
/// which moves the windows' ends by tenths of a second), while the geology's
/// curvature across lines 500 m apart leaves plain's own level uncertain
/// by 0.043 nT: compared on their estimates alone (0.040 nT plain, 0.043
/// nT with the lag) the two looked alike, and the lag nearly doubled the
/// survey's error against truth (0.021 → 0.038 nT). A move the lines
/// cannot show to be a correction must be held back.
#[test]
fn a_heading_level_move_the_lines_cannot_resolve_is_held_back() {
    let raw = common::clean_plan(581);
    assert_eq!(
        (raw.survey.line_count, raw.survey.tie_count),
        (9, 0),
        "the plan as measured"
    );
    let (flight, auto, plain) = default_and_plain(raw);
    let HeldBack::WorseBetweenLines {
        plain_nt,
        diagnosed_nt,
        moved_nt,
        standard_error_nt,
        ..
    } = held_between_lines(&auto, ("mag_1_uc", "sensor_lag"))
    else {
        unreachable!()
    };
    // Sizes alike, the move twice the standard error.
    assert!((diagnosed_nt - plain_nt).abs() < 0.01, "{plain_nt} → {diagnosed_nt}");
    println!("moved {moved_nt:.4} nT, standard error {standard_error_nt:.4} nT");
    assert!((moved_nt - 0.065).abs() < 0.01, "{moved_nt}");
    assert!((standard_error_nt - 0.043).abs() < 0.01, "{standard_error_nt}");
    assert_compensated_plain(&flight, (&auto, &plain), (0, "mag_1_uc"));
}

/// The reason the default's run gives for holding back `channel`'s
/// findings between lines, one of them `effect`; panics, listing the
/// warnings, when it gives none.
fn held_between_lines(auto: &magcomp::pipeline::FlightRun, (channel, effect): (&str, &str)) -> HeldBack {
    (auto.result.warnings.iter())
        .find_map(|w| match w {
            Warning::FindingsHeldBack {
                channel: held,
                findings,
                reason: reason @ HeldBack::WorseBetweenLines { .. },
            } if held == channel && findings.iter().any(|f| f.starts_with(effect)) => Some(reason.clone()),
            _ => None,
        })
        .unwrap_or_else(|| {
            panic!(
                "{channel}'s {effect} is not held back between lines: {:#?}",
                auto.result.warnings
            )
        })
}

/// Plan 733 (four sensors, three of them in the tail, 50 Hz, two survey
/// lines 500 m apart, no tie): the diagnosis finds a lag of 0.099 s on
/// mag_1_uc (held out 0.0302 → 0.0155 nT) on a box flown with the
/// airframe's coupled motion, where the simulator has none. It passes the
/// departure check, since a lag moves the box's record too, and two lines
/// neither cross nor form a block to compare. Applied, it moved the survey
/// 0.102 nT from plain against a stated uncertainty of 0.054 nT, and made
/// it 5.6 times worse against truth (0.017 → 0.096 nT), on box evidence of
/// 0.026 nT (on the windows detection finds since it levels a manoeuvre
/// flown back to back about its own cycles: 0.090 nT against 0.050 nT, on
/// 0.025 nT). A move beyond the stated uncertainty on evidence within it,
/// that nothing on the survey can check, must be held back, with its
/// figures.
#[test]
fn a_move_beyond_the_stated_uncertainty_that_no_survey_line_can_check_is_held_back() {
    let raw = common::clean_plan(733);
    assert_eq!(
        (
            raw.scalar.len(),
            raw.sample_rate_hz,
            raw.survey.line_count,
            raw.survey.tie_count
        ),
        (4, 50.0, 2, 0),
        "the plan as measured"
    );
    let (flight, auto, plain) = default_and_plain(raw);
    assert_held_unchecked(
        &auto,
        ("mag_1_uc", "sensor_lag"),
        Unchecked {
            levels_checked: false,
            survey_nt: (0.090, 0.01),
            stated_nt: (0.050, 0.01),
            // On the box the lag explains √(0.0302² − 0.0155²) nT held
            // out, under the stated uncertainty.
            explained_nt: (0.0259, 0.003),
        },
    );
    // The diagnosis keeps the lag as a candidate with the same reason.
    let diagnosis = auto.result.diagnosis.as_ref().expect("the default diagnoses");
    let lag = (diagnosis.findings.iter())
        .find(|f| f.channel == "mag_1_uc" && f.effect.kind() == magcomp::diagnose::EffectKind::SensorLag)
        .expect("the diagnosis finds the lag on mag_1_uc");
    let not_applied = lag.not_applied.as_deref().expect("the lag is not applied");
    assert!(
        not_applied.contains("nothing to check that move against"),
        "{not_applied}"
    );
    assert_compensated_plain(&flight, (&auto, &plain), (0, "mag_1_uc"));
}

/// The figures a move the survey cannot check is held back with, each as
/// (expected, tolerance), nT.
struct Unchecked {
    /// Whether the survey's line levels were compared.
    levels_checked: bool,
    survey_nt: (f64, f64),
    stated_nt: (f64, f64),
    explained_nt: (f64, f64),
}

/// Asserts that the default's run holds back `channel`'s findings, one of
/// them `effect`, as a move the survey cannot check, with the `expected`
/// figures; panics, listing the warnings, when it gives no such reason.
fn assert_held_unchecked(auto: &magcomp::pipeline::FlightRun, (channel, effect): (&str, &str), expected: Unchecked) {
    let reason = (auto.result.warnings.iter())
        .find_map(|w| match w {
            Warning::FindingsHeldBack {
                channel: held,
                findings,
                reason: reason @ HeldBack::UncheckedOnSurvey { .. },
            } if held == channel && findings.iter().any(|f| f.starts_with(effect)) => Some(reason.clone()),
            _ => None,
        })
        .unwrap_or_else(|| panic!("{channel}'s {effect} is not held back: {:#?}", auto.result.warnings));
    println!("{reason:?}");
    let HeldBack::UncheckedOnSurvey {
        survey_nt,
        stated_nt,
        explained_nt,
        levels_checked,
        ..
    } = reason
    else {
        unreachable!()
    };
    assert_eq!(levels_checked, expected.levels_checked);
    let near = |value: f64, (want, tolerance): (f64, f64)| (value - want).abs() < tolerance;
    assert!(near(survey_nt, expected.survey_nt), "survey move {survey_nt}");
    let stated = stated_nt.expect("a stated uncertainty");
    assert!(near(stated, expected.stated_nt), "stated {stated}");
    assert!(near(explained_nt, expected.explained_nt), "explained {explained_nt}");
}

/// Plan 267 (four sensors, 10 Hz, 23 lines flown back and forth, no tie):
/// the diagnosis finds a lag on the tail sensor, where the simulator has
/// none. Neighbouring lines can be compared, and their levels pass it: a
/// lag moves the geology along the lines, which their levels do not show.
/// Applied (beside the base station's term as recorded), it moved the
/// survey 0.149 nT from plain against a stated uncertainty of 0.105 nT,
/// and made it 4.5 times worse against truth (0.0205 → 0.0919 nT), on box
/// evidence of 0.036 nT. Beside the station's term low-passed
/// (`magcomp::model::station`) it moves the survey 0.100 nT against a
/// stated 0.081 nT, on box evidence of 0.019 nT. It must be held back as a
/// move the survey's levels cannot check, with its figures, leaving the
/// station's term alone.
#[test]
fn a_lag_the_line_levels_cannot_check_is_held_back() {
    let raw = common::clean_plan(267);
    assert_eq!(
        (raw.scalar.len(), raw.survey.line_count, raw.survey.tie_count),
        (4, 23, 0),
        "the plan as measured"
    );
    let (flight, auto, plain) = default_and_plain(raw);
    assert_held_unchecked(
        &auto,
        ("mag_1_uc", "sensor_lag"),
        Unchecked {
            // The neighbouring lines were compared.
            levels_checked: true,
            survey_nt: (0.0997, 0.01),
            stated_nt: (0.0808, 0.008),
            // √(before² − after²) over the lag's step, held out.
            explained_nt: (0.0193, 0.002),
        },
    );
    // Held back, the channel keeps the base station's term: 0.0205 →
    // 0.0283 nT against truth.
    let applied: Vec<String> = (auto.result.applied_findings.iter())
        .filter(|f| f.channel == "mag_1_uc")
        .map(|f| f.describe())
        .collect();
    assert!(applied.iter().all(|f| f.starts_with("external_field")), "{applied:?}");
    let (before, after) = assert_not_harmed(&flight, (&auto, &plain), (0, "mag_1_uc"));
    println!("mag_1_uc against truth: plain {before:.4} nT, default {after:.4} nT");
}

/// Plan 135 (six sensors, 5 Hz, two lines, no tie): the diagnosis finds a
/// coupling of a cabin sensor to the aileron servo's current (held out
/// 0.0530 → 0.0315 nT at its step), which the simulator couples to
/// nothing. With nothing on the survey to check it, it moved the survey
/// 0.079 nT from plain against a stated uncertainty of 0.0435 nT, and
/// made it worse against truth (0.059 → 0.107 nT), on box evidence of
/// 0.0426 nT (0.0395 nT on the windows detection finds since it levels a
/// manoeuvre flown back to back about its own cycles). It must be held
/// back, with its figures.
#[test]
fn a_coupling_nothing_on_the_survey_checks_is_held_back() {
    let raw = common::clean_plan(135);
    assert_eq!(
        (raw.scalar.len(), raw.survey.line_count, raw.survey.tie_count),
        (6, 2, 0),
        "the plan as measured"
    );
    let (flight, auto, plain) = default_and_plain(raw);
    assert_held_unchecked(
        &auto,
        ("mag_2_uc", "aux_coupling"),
        Unchecked {
            // Nothing on the survey could be compared.
            levels_checked: false,
            survey_nt: (0.079, 0.008),
            stated_nt: (0.0435, 0.004),
            // √(0.0530² − 0.0315²) nT on the windows found before, 0.0395
            // on today's.
            explained_nt: (0.0395, 0.003),
        },
    );
    assert_compensated_plain(&flight, (&auto, &plain), (1, "mag_2_uc"));
}

/// Plans 95 (six sensors, 20 Hz, four lines, no tie) and 272 (eight
/// sensors, 5 Hz, 18 lines, two ties): a base station with 0.020 nT of
/// white noise and an external field with nothing above 0.1 Hz. Its
/// term lowered every sensor's held-out RMS by a third or more, but the
/// record as recorded put the station's noise into the fit's band, and
/// that noise moved the poorly excited coefficients: mag_5_uc of plan 95
/// went from 0.0068 to 0.0202 nT against truth, mag_2_uc of plan 272 from
/// 0.0088 to 0.0208 nT. Low-passed where its noise takes over
/// (`magcomp::model::station`), the station's term must harm no channel of
/// either flight and still help more than half of those it is applied on
/// (5 of 6 sensors, and 7 of 8).
#[test]
fn a_base_stations_own_noise_does_not_harm_a_channel() {
    for seed in [95, 272] {
        let (flight, outcome) = fly(seed);
        let (mut applied, mut helped) = (0, 0);
        for channel in &outcome {
            println!(
                "{flight} {}: {:.4} → {:.4} nT",
                channel.name, channel.plain, channel.auto
            );
            applied += usize::from(channel.applied.iter().any(|a| a.starts_with("external_field")));
            assert!(
                channel.auto <= 1.1 * channel.plain + 0.01,
                "{flight} {}: {:.4} → {:.4} nT",
                channel.name,
                channel.plain,
                channel.auto
            );
            helped += usize::from(channel.auto < 0.9 * channel.plain);
        }
        assert!(
            applied >= 5,
            "{flight}: the station's term applied on {applied} channels"
        );
        assert!(
            2 * helped > applied,
            "{flight}: helped {helped} of the {applied} it is applied on"
        );
        // The report says where the station was low-passed: its pulsations
        // reach 0.1 Hz, in the octave 0.078–0.156 Hz.
        let (_, auto, _) = default_and_plain(common::clean_plan(seed));
        let corner = (auto.result.notes.iter())
            .find_map(|n| match n {
                magcomp::messages::Note::QuietStation { column, filter, .. } if column == "diurnal" => {
                    filter.corner_hz()
                }
                _ => None,
            })
            .unwrap_or_else(|| panic!("{flight}: no note of the station's corner: {:#?}", auto.result.notes));
        assert!((corner - 0.156_25).abs() < 1e-9, "{flight}: corner {corner} Hz");
    }
}

/// Plan 579 (three sensors, 5 Hz, 15 lines, no tie): the base station's
/// term alone took the cabin sensor mag_1_uc from 0.0069 to 0.0363 nT
/// against truth, moving the survey 0.051 nT from plain Tolles-Lawson
/// against a stated uncertainty of 0.011 nT, and the verdict was PASS.
/// The move beyond the stated uncertainty is the station's: the run
/// warns and names it, and the verdict is CHECK.
#[test]
fn a_base_station_term_that_moves_the_survey_beyond_its_uncertainty_is_no_plain_pass() {
    let (flight, auto, plain) = default_and_plain(common::clean_plan(579));
    let (plain_error, auto_error) = survey_errors(&flight, (&auto, &plain), (0, "mag_1_uc"));
    println!("plan 579 mag_1_uc: {plain_error:.4} → {auto_error:.4} nT against truth");
    let applied: Vec<String> = (auto.result.applied_findings.iter())
        .filter(|f| f.channel == "mag_1_uc")
        .map(|f| f.describe())
        .collect();
    assert!(
        applied.len() == 1 && applied[0].starts_with("external_field"),
        "the station's term alone: {applied:?}"
    );
    let (departure, stated) = (auto.result.warnings.iter())
        .find_map(|w| match w {
            Warning::SurveyDeparture {
                channel,
                moved_by: MovedBy::BaseStation,
                departure_nt,
                stated_nt,
                ..
            } if channel == "mag_1_uc" => Some((*departure_nt, *stated_nt)),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no departure warning naming the station: {:#?}", auto.result.warnings));
    let stated = stated.expect("a stated uncertainty");
    println!("moved {departure:.4} nT, stated {stated:.4} nT");
    // Measured on the flight, within 15 %.
    assert!((departure - 0.0507).abs() < 0.0076, "moved {departure} nT");
    assert!((stated - 0.0109).abs() < 0.0016, "stated {stated} nT");
    let quality = (auto.result.channels.iter()).find(|q| q.channel == "mag_1_uc").unwrap();
    assert_eq!(quality.unchecked_departure().map(|(d, _)| d), Some(departure));
    // The other two channels keep no station's term, or one within what
    // they state.
    for q in auto.result.channels.iter().filter(|q| q.channel != "mag_1_uc") {
        assert!(
            q.unchecked_departure().is_none(),
            "{}: {:?}",
            q.channel,
            q.unchecked_departure()
        );
    }
}

/// The anomaly gain a model states is what an anomaly injected on the
/// survey comes out at: on random clean plans, each channel by default
/// (its 16 terms and the findings applied) and with MagNav.jl's 18 terms,
/// an anomaly of 20–150 nT and 4–25 s on a survey line, at the rows near
/// its peak (where its rate is nil, so the eddy terms see only the field's
/// turn). The injected gain is $1 - ΔH/δ$ with ΔH the model's predicted
/// interference with the anomaly less without; it must match the stated
/// per-row gain within 0.002 (the eddy terms' response to the anomaly's
/// rate within a quarter width of the peak, and rounding). The default's
/// median gain is within the tolerance of 1 on every channel.
#[test]
fn the_stated_anomaly_gain_is_what_an_injected_anomaly_comes_out_at() {
    let seeds: Vec<u64> = (0..6).map(|k| 9_100 + 37 * k).collect();
    let results: Vec<Vec<String>> = seeds
        .par_iter()
        .map(|&seed| {
            let raw = common::clean_plan(seed);
            let flight = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
            let folder = tempfile::tempdir().unwrap();
            let csv = folder.path().join("clean.csv");
            magcomp::formats::write_flight_log(&flight.log, &csv).unwrap();
            let job = FlightJob::new(&csv);
            let mut default = Settings::default();
            default.vector.enabled = false;
            let mut eighteen = common::plain();
            eighteen.terms = magcomp::model::terms::TermSet::magnav();
            let mut draw = Random::new(seed).fork("anomaly");
            let lines = flight.log.survey_lines();
            let (_, rows) = &lines[draw.integer(0, lines.len() - 1)];
            let centre_row = rows[rows.len() / 2];
            let amplitude_nt = draw.uniform(20.0, 150.0);
            let width_s = draw.uniform(4.0, 25.0);
            let (injected, delta) = common::with_anomaly(&flight.log, (centre_row, amplitude_nt, width_s));
            let peak: Vec<usize> = (rows.iter().copied())
                .filter(|&r| (flight.log.time_s()[r] - flight.log.time_s()[centre_row]).abs() < width_s / 4.0)
                .collect();
            let mut failures = Vec::new();
            for (name, settings) in [("default", &default), ("18 terms", &eighteen)] {
                let out = folder.path().join("out.csv");
                let run = magcomp::pipeline::run(&job, settings, &out).unwrap();
                for (model, quality) in run.result.models.iter().zip(&run.result.channels) {
                    let stated = model.anomaly_gain_at(&flight.log, &[], &peak).unwrap();
                    let clean = model.predict(&flight.log).unwrap().interference_nt;
                    let with = model.predict(&injected).unwrap().interference_nt;
                    let injected_gain: Vec<f64> =
                        peak.iter().map(|&r| 1.0 - (with[r] - clean[r]) / delta[r]).collect();
                    let worst = (stated.iter().zip(&injected_gain))
                        .map(|(s, i)| (s - i).abs())
                        .fold(0.0, f64::max);
                    let median = quality.anomaly_gain.unwrap();
                    println!(
                        "seed {seed} {name} {}: stated {:.4}, injected {:.4} ({amplitude_nt:.0} nT, {width_s:.1} s), worst difference {worst:.5}; median over the survey {median:.4}",
                        model.channel, stated[0], injected_gain[0]
                    );
                    if worst > 0.002 {
                        failures.push(format!(
                            "seed {seed} {name} {}: stated gain off the injected by {worst}",
                            model.channel
                        ));
                    }
                    if name == "default" && (median - 1.0).abs() > magcomp::model::ANOMALY_GAIN_TOLERANCE {
                        failures.push(format!(
                            "seed {seed} {}: the default scales an anomaly by {median}",
                            model.channel
                        ));
                    }
                }
            }
            failures
        })
        .collect();
    let failures: Vec<String> = results.into_iter().flatten().collect();
    assert!(failures.is_empty(), "{failures:#?}");
}

/// A column that holds the answer (a vendor's compensated total field of
/// the same sensor, under a name magcomp does not know) is never applied
/// as a source: it carries the Earth's field, so a coupling to it scales
/// the geology. On random clean plans with `vendor_mag` (plain
/// Tolles-Lawson's compensation of `mag_1_uc`) added, the default applies
/// no finding from it, and every channel keeps its anomaly gain within
/// the tolerance.
#[test]
fn a_column_that_holds_the_earths_field_is_never_a_source() {
    let seeds: Vec<u64> = (0..4).map(|k| 9_300 + 41 * k).collect();
    let failures: Vec<String> = seeds
        .par_iter()
        .flat_map(|&seed| {
            let flight = simulate(&Scenario::try_from(common::clean_plan(seed)).unwrap()).unwrap();
            let folder = tempfile::tempdir().unwrap();
            let csv = folder.path().join("clean.csv");
            magcomp::formats::write_flight_log(&flight.log, &csv).unwrap();
            let out = folder.path().join("out.csv");
            let plain = magcomp::pipeline::run(&FlightJob::new(&csv), &common::plain(), &out).unwrap();
            let mut channels = flight.log.channels().to_vec();
            channels.push(magcomp::ingest::flight_log::Channel {
                name: "vendor_mag".into(),
                role: magcomp::ingest::flight_log::ChannelRole::Auxiliary,
                values: plain.compensation.channels[0].values.clone(),
            });
            let with_vendor = flight.log.with_channels(channels).unwrap();
            let csv = folder.path().join("vendor.csv");
            magcomp::formats::write_flight_log(&with_vendor, &csv).unwrap();
            let mut default = Settings::default();
            default.vector.enabled = false;
            let auto = magcomp::pipeline::run(&FlightJob::new(&csv), &default, &out).unwrap();
            let mut failures = Vec::new();
            for finding in (auto.result.diagnosis.iter()).flat_map(|d| d.findings.iter()) {
                println!(
                    "seed {seed}: {} {} from {:?}: applied {}, {:?}",
                    finding.channel,
                    finding.effect,
                    finding.source,
                    finding.not_applied.is_none(),
                    finding.not_applied
                );
                if finding.source.as_deref() == Some("vendor_mag") && finding.not_applied.is_none() {
                    failures.push(format!("seed {seed}: {} coupled to vendor_mag", finding.channel));
                }
            }
            for quality in &auto.result.channels {
                let gain = quality.anomaly_gain.unwrap();
                println!(
                    "seed {seed}: {} anomaly gain {gain:.4}, {}",
                    quality.channel, quality.verdict
                );
                if (gain - 1.0).abs() > magcomp::model::ANOMALY_GAIN_TOLERANCE {
                    failures.push(format!("seed {seed}: {} scales the geology by {gain}", quality.channel));
                }
            }
            failures
        })
        .collect();
    assert!(failures.is_empty(), "{failures:#?}");
}
