//! Detection on flight plans drawn at random: 240 simulated flights whose
//! heading order, box position (before, between or after the survey
//! lines), repeats, partial boxes, forgotten manoeuvres, clover-leaf
//! turns, a climb into the first leg, a last leg that runs straight on
//! into the descent and a survey line on its heading, sample rate (1 to
//! 50 Hz), pilot, turbulence and attitude source (INS, or the fluxgate
//! alone) all vary.
//!
//! The plans are drawn from what crews fly, not from the detector's
//! thresholds: the pilot's cycles (2–4), periods (3–10 s), amplitudes
//! (±20 % about 5°, 10°, 5°), lead-ins (10–40 s) and pauses (5–20 s) come
//! from the FOM procedure's usual ranges.
//!
//! Thresholds, each stated and justified (with INS attitude; the fluxgate
//! fallback's measured figures are held as floors, see the constants):
//! 1. **Every flown manoeuvre is found at IoU ≥ 0.9, and none is
//!    spurious** (a detected window that matches no flown one at IoU ≥ 0.9,
//!    a fragment included). At the lowest rates a manoeuvre's ends are
//!    known to a sample only: each zero crossing lies between two samples,
//!    the truth's and the detector's each round it to one, so the two ends
//!    together may differ by three samples, and the bound is
//!    min(0.9, 1 − 3/(rate × duration)). At 10 Hz and above that is 0.9
//!    for manoeuvres of 30 samples or more (every one here); at 1 Hz a
//!    15 s manoeuvre is bounded at 0.8.
//! 2. **Every incomplete box is named**: each detected box lists exactly
//!    the headings and manoeuvres its plan left out, the headings within
//!    5° of where the four-heading pattern puts them (and within the
//!    declination for magnetic headings from the fluxgate). A manoeuvre
//!    left out of a leg the box names missing ("no leg near 270°") is named.
//! 3. **No silent fault, with INS attitude or the fluxgate alone.** With
//!    the fluxgate alone two rotations can turn the field direction alike
//!    (pitch and yaw on east and west headings, roll and yaw on north and
//!    south): the detector then names the manoeuvre by its size and flags
//!    the other kind it could be (`could_be`). A manoeuvre found under the
//!    flagged name counts as found, as a fault of accuracy.

use magcomp::calibration::detect::{detect_manoeuvres, DetectOptions, Detection};
use magcomp::ingest::flight_log::FlightLog;
use magcomp::simulate::random::Random;
use magcomp::simulate::scenario::{BoxPosition, RawScenario, Scenario};
use magcomp::simulate::simulate;
use magcomp::simulate::truth::TrueManoeuvre;
use rayon::prelude::*;

/// Flights in the campaign.
const FLIGHTS: u64 = 240;

/// A plan and what it leaves out, for the truth.
struct Plan {
    raw: RawScenario,
    /// Attitude from the fluxgate alone (the INS columns removed).
    fluxgate_only: bool,
    /// The four-heading pattern's heading no leg was flown on, if any.
    dropped_heading: Option<f64>,
    /// Manoeuvres forgotten, (kind, heading).
    omitted: Vec<(&'static str, f64)>,
    /// The IoU every flown manoeuvre must be found at (before the
    /// quantisation of its ends at the lowest rates).
    iou: f64,
}

/// Draws a flight plan.
fn random_plan(seed: u64) -> Plan {
    let mut random = Random::new(0x9E37_79B9 ^ seed);
    let mut chance = |p: f64| random.uniform(0.0, 1.0) < p;
    let (three_headings, omits, clover, climb, continues, fluxgate_only, two_boxes) = (
        chance(0.15),
        chance(0.2),
        chance(0.25),
        chance(0.35),
        chance(0.35),
        chance(0.15),
        chance(0.12),
    );
    let mut raw = RawScenario {
        seed,
        ..RawScenario::default()
    };
    let base = random.uniform(0.0, 360.0).round();
    let mut headings: Vec<f64> = (0..4).map(|k| (base + 90.0 * k as f64).rem_euclid(360.0)).collect();
    // Any flying order.
    for k in (1..4).rev() {
        headings.swap(k, random.integer(0, k));
    }
    let dropped_heading = three_headings.then(|| headings.remove(random.integer(0, 3)));
    let rates = [1.0, 2.0, 5.0, 10.0, 10.0, 20.0, 50.0];
    raw.sample_rate_hz = rates[random.integer(0, rates.len() - 1)];
    raw.oversampling = (100.0 / raw.sample_rate_hz).round().max(1.0) as usize;
    let box_ = &mut raw.calibration;
    box_.repeats = if two_boxes { 2 } else { 1 };
    box_.position = [BoxPosition::Start, BoxPosition::Middle, BoxPosition::End][random.integer(0, 2)];
    box_.clover_leaf = clover;
    box_.climb_before = climb;
    box_.continue_into_survey = continues;
    let low = random.integer(2, 3);
    box_.cycles = [low, random.integer(low, 4)];
    let shortest = random.uniform(3.0, 7.0);
    box_.period_s = [shortest, random.uniform(shortest, 10.0)];
    box_.pitch_deg = random.uniform(4.0, 6.0);
    box_.roll_deg = random.uniform(8.0, 12.0);
    box_.yaw_deg = random.uniform(4.0, 6.0);
    box_.turbulence_deg = random.uniform(0.02, 0.4);
    box_.heading_wander_deg = random.uniform(0.0, 1.0);
    let lead = random.uniform(10.0, 40.0);
    box_.lead_in_s = [lead, random.uniform(lead, 40.0)];
    let pause = random.uniform(5.0, 12.0);
    box_.pause_s = [pause, random.uniform(pause, 20.0)];
    let omitted = match omits {
        true => omit_one(&mut random, &mut raw, &headings),
        false => Vec::new(),
    };
    finish_plan(&mut random, &mut raw, headings);
    Plan {
        raw,
        fluxgate_only,
        dropped_heading,
        omitted,
        iou: 0.9,
    }
}

/// Draws a box flown the way a real survey crew flies it, from ranges
/// wider than those measured on a real survey aircraft (10 Hz, two boxes
/// back to back on a calibration line): pitch, roll and yaw back to back
/// (gaps 0–1 s measured, 0–1.5 s here), about three cycles of 5–6.4 s
/// (2–4 of 4.5–7.5 s), pitch ±3.4–4° (±2.4–5.5°), roll ±7–8° (±5–10°) and
/// yaw ±3.4–4.5° (±2.8–6°), each ±20 % per manoeuvre; roll 0.2× a pitch
/// (0.1–0.3×), adverse yaw 0.25–0.3× a roll (0.2–0.4×), roll 0.4–0.46× a
/// yaw (0.3–0.55×) lagging by up to 60°; the first manoeuvre 0–4 s after
/// the turn's roll-out on half the plans (two pitches of the real flight
/// began within a few seconds of it), 5–45 s on the others; the turn to
/// the next leg 0–4 s after the yaw (three real yaws ran on into it); turns banked up to 24° (18–27°), the bank rolling
/// in over 1.5–6 s with the heading's rate; two boxes back to
/// back (or one), headings clockwise from any base, as crews fly them.
/// These plans share nothing with the detector but the flight it reads.
fn crew_plan(seed: u64) -> Plan {
    let mut random = Random::new(0xC0FF_EE00 ^ seed);
    let mut raw = RawScenario {
        seed: 10_000 + seed,
        ..RawScenario::default()
    };
    let base = random.uniform(0.0, 360.0).round();
    let sense = if random.uniform(0.0, 1.0) < 0.8 { 90.0 } else { -90.0 };
    let headings: Vec<f64> = (0..4).map(|k| (base + sense * k as f64).rem_euclid(360.0)).collect();
    let rates = [5.0, 10.0, 10.0, 10.0, 20.0, 50.0];
    raw.sample_rate_hz = rates[random.integer(0, rates.len() - 1)];
    raw.oversampling = (100.0 / raw.sample_rate_hz).round().max(1.0) as usize;
    let box_ = &mut raw.calibration;
    box_.repeats = if random.uniform(0.0, 1.0) < 0.7 { 2 } else { 1 };
    box_.position = [BoxPosition::Start, BoxPosition::Middle, BoxPosition::End][random.integer(0, 2)];
    let low = random.integer(2, 3);
    box_.cycles = [low, random.integer(low, 4)];
    let shortest = random.uniform(4.5, 6.5);
    box_.period_s = [shortest, random.uniform(shortest, 7.5)];
    box_.pitch_deg = random.uniform(3.0, 4.6);
    box_.roll_deg = random.uniform(6.2, 8.4);
    box_.yaw_deg = random.uniform(3.5, 5.0);
    box_.turbulence_deg = random.uniform(0.02, 0.3);
    box_.heading_wander_deg = random.uniform(0.0, 1.0);
    // Half the crews begin the pitch within 0–4 s of the roll-out, as on
    // two legs of the real flight; the others after 5–45 s.
    let lead = match random.uniform(0.0, 1.0) < 0.5 {
        true => [0.0, random.uniform(0.0, 4.0)],
        false => {
            let lead = random.uniform(5.0, 30.0);
            [lead, random.uniform(lead, 45.0)]
        }
    };
    box_.lead_in_s = lead;
    box_.pause_s = [0.0, random.uniform(0.0, 1.5)];
    // The turn to the next leg begins 0–4 s after the yaw.
    let soonest = random.uniform(0.0, 2.0);
    box_.turn_after_s = Some([soonest, random.uniform(soonest, 4.0)]);
    let slowest = random.uniform(2.3, 3.3);
    box_.turn_rate_deg_s = [slowest, random.uniform(slowest, 3.9)];
    // The bank rolls in over 1.5–6 s, the heading's rate with it.
    let quickest = random.uniform(1.5, 4.0);
    box_.turn_entry_s = [quickest, random.uniform(quickest, 6.0)];
    let coupling = &mut box_.coupling;
    let mut range = |low: f64, high: f64| {
        let a = random.uniform(low, high);
        [a, random.uniform(a, high)]
    };
    coupling.pitch_roll = range(0.1, 0.3);
    coupling.roll_pitch = range(0.0, 0.1);
    coupling.roll_yaw = range(0.2, 0.4);
    coupling.yaw_roll = range(0.3, 0.55);
    coupling.lag_deg = [0.0, 60.0];
    let omitted = match random.uniform(0.0, 1.0) < 0.15 {
        true => omit_one(&mut random, &mut raw, &headings),
        false => Vec::new(),
    };
    finish_plan(&mut random, &mut raw, headings);
    Plan {
        raw,
        fluxgate_only: false,
        dropped_heading: None,
        omitted,
        iou: 0.8,
    }
}

/// Leaves one manoeuvre out of the box: its kind and its leg drawn.
fn omit_one(random: &mut Random, raw: &mut RawScenario, headings: &[f64]) -> Vec<(&'static str, f64)> {
    let kind = ["pitch", "roll", "yaw"][random.integer(0, 2)];
    let heading = headings[random.integer(0, headings.len() - 1)];
    raw.calibration.omit = vec![format!("{kind}@{heading}")];
    vec![(kind, heading)]
}

/// The box on `headings`, then two or three short survey lines on a drawn
/// heading, over a light crust, with one scalar sensor.
fn finish_plan(random: &mut Random, raw: &mut RawScenario, headings: Vec<f64>) {
    raw.calibration.headings_deg = headings;
    raw.survey.line_count = random.integer(2, 3);
    raw.survey.line_length_m = random.uniform(3000.0, 6000.0);
    raw.survey.line_heading_deg = random.uniform(0.0, 360.0).round();
    raw.survey.turbulence_deg = random.uniform(0.5, 1.5);
    raw.crust.dipole_count = 2;
    raw.scalar.truncate(1);
}

/// Intersection over union of two time windows.
fn overlap(a: (f64, f64), b: (f64, f64), dt: f64) -> f64 {
    let inter = (a.1.min(b.1) - a.0.max(b.0) + dt).max(0.0);
    let union = a.1.max(b.1) - a.0.min(b.0) + dt;
    inter / union
}

/// The IoU a manoeuvre must reach: the plan's, less the quantisation of
/// its two ends to the sample interval.
fn iou_bound(plan: &Plan, m: &TrueManoeuvre, dt: f64) -> f64 {
    plan.iou.min(1.0 - 3.0 * dt / (m.t_end - m.t_start + dt))
}

fn without_ins(log: &FlightLog) -> FlightLog {
    let channels = log
        .channels()
        .iter()
        .filter(|c| !c.name.starts_with("ins_"))
        .cloned()
        .collect();
    FlightLog::new(log.source(), log.time_column(), log.time_s().to_vec(), channels).unwrap()
}

/// What went wrong on one flight, in words: faults of accuracy (a
/// manoeuvre found at a lower IoU than the bound, or lost and named
/// missing), and silent faults (a manoeuvre lost without being named, a
/// window where none was flown, a left-out heading or manoeuvre not named,
/// the wrong number of boxes).
#[derive(Default)]
struct Faults {
    accuracy: Vec<String>,
    silent: Vec<String>,
    /// Flown manoeuvres found with their kind at IoU ≥ 0.5, and of those at the plan's IoU.
    found: usize,
    timed: usize,
    /// Flown manoeuvres overlapped (IoU ≥ 0.5) by a detection of another kind only.
    misnamed: usize,
    /// Detections that match no flown manoeuvre.
    spurious: usize,
}

fn judge(plan: &Plan, detection: &Detection, truth: &[TrueManoeuvre], dt: f64, declination: f64) -> Faults {
    let mut faults = Faults::default();
    // Headings as detection reports them: magnetic from the fluxgate.
    let reported = |heading: f64| (heading - declination).rem_euclid(360.0);
    // Magnetic headings from the fluxgate also carry the aircraft's own
    // field at it (several degrees): they are matched within the
    // detector's same-heading tolerance, INS headings within 5°.
    let tolerance = if plan.fluxgate_only { 15.0 } else { 5.0 };
    let near = |a: f64, b: f64| ((a - b + 540.0).rem_euclid(360.0) - 180.0).abs() < tolerance;
    let named: Vec<(String, f64)> = detection
        .boxes
        .iter()
        .flat_map(|b| b.missing.iter().filter_map(|text| parse_missing(text)))
        .collect();
    let kind_name = |kind: magcomp::calibration::windows::ManoeuvreKind| format!("{kind:?}").to_lowercase();
    // A name the detector flagged as uncertain (`could_be`) counts as found,
    // but as a fault of accuracy, never as silent.
    let names = |k: &str, kind: magcomp::calibration::windows::ManoeuvreKind| {
        k == "leg" || k.split('|').any(|part| part == kind_name(kind))
    };
    for m in truth {
        let best_of = |flagged: bool| {
            detection
                .manoeuvres
                .iter()
                .filter(|d| match flagged {
                    false => d.kind == m.kind,
                    true => d.could_be == Some(m.kind),
                })
                .map(|d| overlap((d.t_start, d.t_end), (m.t_start, m.t_end), dt))
                .fold(0.0, f64::max)
        };
        let (best, flagged) = (best_of(false), best_of(true));
        faults.found += usize::from(best >= 0.5);
        faults.timed += usize::from(best >= iou_bound(plan, m, dt));
        let other = detection
            .manoeuvres
            .iter()
            .filter(|d| d.kind != m.kind)
            .any(|d| overlap((d.t_start, d.t_end), (m.t_start, m.t_end), dt) >= 0.5);
        faults.misnamed += usize::from(best < 0.5 && other);
        if best < 0.5 && flagged >= 0.5 {
            faults.accuracy.push(format!(
                "{:?} at {:.0}° ({:.1}–{:.1}) named the other kind, flagged uncertain",
                m.kind, m.heading_deg, m.t_start, m.t_end
            ));
            continue;
        }
        let said_missing = named
            .iter()
            .any(|(k, h)| names(k, m.kind) && near(*h, reported(m.heading_deg)));
        let what = format!(
            "{:?} at {:.0}° ({:.1}–{:.1})",
            m.kind, m.heading_deg, m.t_start, m.t_end
        );
        match (best >= iou_bound(plan, m, dt), best >= 0.5, said_missing) {
            (true, _, _) => {}
            (false, true, _) => faults.accuracy.push(format!("{what} found at IoU {best:.3}")),
            (false, false, true) => faults.accuracy.push(format!("{what} lost, and named missing")),
            (false, false, false) => faults.silent.push(format!("{what} lost without a word")),
        }
    }
    for d in &detection.manoeuvres {
        let flown = truth.iter().any(|m| {
            (m.kind == d.kind || d.could_be == Some(m.kind))
                && overlap((d.t_start, d.t_end), (m.t_start, m.t_end), dt) >= 0.5
        });
        if !flown {
            faults.spurious += 1;
            faults.silent.push(format!(
                "{:?} detected at {:.1}–{:.1}, where none was flown",
                d.kind, d.t_start, d.t_end
            ));
        }
    }
    let boxes = plan.raw.calibration.repeats;
    if detection.boxes.len() != boxes {
        faults
            .silent
            .push(format!("{} boxes detected, {boxes} flown", detection.boxes.len()));
    }
    for found in &detection.boxes {
        let mut expected: Vec<(String, f64)> = Vec::new();
        if let Some(h) = plan.dropped_heading {
            expected.push(("leg".into(), reported(h)));
        }
        for (kind, h) in &plan.omitted {
            expected.push((kind.to_string(), reported(*h)));
        }
        let named: Vec<(String, f64)> = found.missing.iter().filter_map(|text| parse_missing(text)).collect();
        let unnamed: Vec<&(String, f64)> = expected
            .iter()
            .filter(|(k, h)| {
                !named
                    .iter()
                    .any(|(nk, nh)| (nk == k || nk == "leg" || nk.split('|').any(|part| part == k)) && near(*nh, *h))
            })
            .collect();
        if named.len() != found.missing.len() || !unnamed.is_empty() {
            faults
                .silent
                .push(format!("box missing {:?}, left out {expected:?}", found.missing));
        }
    }
    faults
}

/// ("leg", 270) from "no leg near 270°"; ("yaw", 290) from "no yaw on
/// heading 290"; ("pitch|yaw", 90) from "one of pitch and yaw missing on
/// heading 90" (the fluxgate could not tell the two apart).
fn parse_missing(text: &str) -> Option<(String, f64)> {
    if let Some(rest) = text.strip_prefix("no leg near ") {
        return Some(("leg".into(), rest.trim_end_matches('°').parse().ok()?));
    }
    if let Some(rest) = text.strip_prefix("one of ") {
        let (kinds, heading) = rest.split_once(" missing on heading ")?;
        let (a, b) = kinds.split_once(" and ")?;
        return Some((format!("{a}|{b}"), heading.parse().ok()?));
    }
    let rest = text.strip_prefix("no ")?;
    let (kind, heading) = rest.split_once(" on heading ")?;
    Some((kind.to_string(), heading.parse().ok()?))
}

/// Flights allowed an accuracy fault (a manoeuvre found below the IoU
/// bound, lost and named missing, or named the other of two kinds the
/// fluxgate flagged it could be), of 240: the figure measured on plans
/// 0..240, held as a floor so that detection can only get better
/// (measured figures and their history: docs/measurements.md, section
/// tests::flight_plans).
const ACCURACY_FAULTS_ALLOWED: usize = 14;

/// Flights with a fault of each kind over one campaign.
struct Campaign {
    inaccurate: usize,
    silent: usize,
    silent_ins: usize,
}

/// Flies and detects the plans `draw` gives for `seeds`, prints every
/// fault and the totals, and counts the flights with faults.
fn fly_campaign(name: &str, draw: fn(u64) -> Plan, seeds: std::ops::Range<u64>) -> Campaign {
    let declination = magcomp::simulate::igrf::Igrf::fourteenth()
        .field(45.3, -75.7, 3080.0, 2026.45)
        .declination_deg();
    let flights = seeds.end - seeds.start;
    let outcomes: Vec<(u64, Plan, Faults)> = seeds
        .into_par_iter()
        .map(|seed| {
            let plan = draw(seed);
            let flight = simulate(&Scenario::try_from(plan.raw.clone()).unwrap()).unwrap();
            let log = match plan.fluxgate_only {
                true => without_ins(&flight.log),
                false => flight.log.clone(),
            };
            let detection = detect_manoeuvres(&log, &DetectOptions::default()).unwrap();
            let dt = 1.0 / plan.raw.sample_rate_hz;
            let offset = if plan.fluxgate_only { declination } else { 0.0 };
            let faults = judge(&plan, &detection, &flight.truth.manoeuvres, dt, offset);
            (seed, plan, faults)
        })
        .collect();
    let (mut inaccurate, mut silent, mut inaccurate_ins, mut silent_ins) = (0, 0, 0, 0);
    let (mut manoeuvres, mut faultless) = (0, 0);
    let (found, timed, misnamed, spurious) = outcomes.iter().fold((0, 0, 0, 0), |sum, (_, _, f)| {
        (sum.0 + f.found, sum.1 + f.timed, sum.2 + f.misnamed, sum.3 + f.spurious)
    });
    for (seed, plan, faults) in &outcomes {
        manoeuvres += (3 * plan.raw.calibration.headings_deg.len() - plan.omitted.len()) * plan.raw.calibration.repeats;
        if faults.accuracy.is_empty() && faults.silent.is_empty() {
            faultless += 1;
            continue;
        }
        inaccurate += usize::from(!faults.accuracy.is_empty());
        inaccurate_ins += usize::from(!faults.accuracy.is_empty() && !plan.fluxgate_only);
        silent += usize::from(!faults.silent.is_empty());
        silent_ins += usize::from(!faults.silent.is_empty() && !plan.fluxgate_only);
        println!("{name} seed {seed}: {}", describe(plan));
        for fault in faults
            .silent
            .iter()
            .map(|f| format!("SILENT: {f}"))
            .chain(faults.accuracy.clone())
        {
            println!("    {fault}");
        }
    }
    println!(
        "{name}: {flights} flights, {manoeuvres} manoeuvres flown: {faultless} without fault; {inaccurate} with an accuracy fault ({inaccurate_ins} with INS attitude); {silent} with a silent fault ({silent_ins} with INS attitude)"
    );
    println!(
        "{name}: manoeuvres found with the right kind (IoU ≥ 0.5) {found} of {manoeuvres}, at the plan's IoU {timed}; named another kind {misnamed}; detections where none was flown {spurious}"
    );
    Campaign {
        inaccurate,
        silent,
        silent_ins,
    }
}

/// The first seed of a campaign: `MAGCOMP_PLAN_FIRST=N` draws plans N..
/// instead, to look beyond the campaign's own (the floors hold for the
/// campaign's own plans).
fn first_seed() -> u64 {
    std::env::var("MAGCOMP_PLAN_FIRST")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

#[test]
fn detection_on_random_flight_plans() {
    let first = first_seed();
    let found = fly_campaign("plans", random_plan, first..first + FLIGHTS);
    assert_eq!(
        found.silent_ins, 0,
        "with INS attitude a manoeuvre, a window or a lack went unreported"
    );
    assert_eq!(
        found.silent, 0,
        "with the fluxgate alone a manoeuvre, a window or a lack went unreported"
    );
    assert!(
        found.inaccurate <= ACCURACY_FAULTS_ALLOWED,
        "{} flights with an accuracy fault",
        found.inaccurate
    );
}

/// Boxes flown as real crews fly them ([`crew_plan`]).
const CREW_FLIGHTS: u64 = 120;

/// Every manoeuvre of boxes flown back to back, with the airframe's
/// coupled motion, short legs and steep turns, is found, named right and
/// timed at IoU ≥ 0.8, and no box is called incomplete that is not (a box
/// lacking only what its plan left out is named with exactly that).
#[test]
fn detection_on_boxes_flown_as_real_crews_fly_them() {
    let first = first_seed();
    let found = fly_campaign("crew", crew_plan, first..first + CREW_FLIGHTS);
    assert_eq!(found.silent, 0, "a manoeuvre, a window or a lack went unreported");
    assert_eq!(found.inaccurate, 0, "flights with an accuracy fault");
}

fn describe(plan: &Plan) -> String {
    let raw = &plan.raw;
    format!(
        "{} Hz, headings {:?}{}, {:?}{}{}{}{}, {} box(es), omit {:?}",
        raw.sample_rate_hz,
        raw.calibration.headings_deg,
        plan.dropped_heading.map(|h| format!(" (no {h})")).unwrap_or_default(),
        raw.calibration.position,
        if raw.calibration.clover_leaf {
            ", clover leaf"
        } else {
            ""
        },
        if raw.calibration.climb_before {
            ", climb before"
        } else {
            ""
        },
        if raw.calibration.continue_into_survey {
            ", runs on into a line"
        } else {
            ""
        },
        if plan.fluxgate_only { ", fluxgate only" } else { "" },
        raw.calibration.repeats,
        raw.calibration.omit
    )
}

/// `MAGCOMP_PLAN_SEED=N cargo test --test flight_plans one_plan -- --nocapture`
/// (with `MAGCOMP_PLAN_CREW=1`, the crew plan N) writes plan N's flight to the temporary folder and prints its truth and
/// detection, to look at one failure closely.
#[test]
fn one_plan() {
    let Ok(seed) = std::env::var("MAGCOMP_PLAN_SEED") else {
        println!("MAGCOMP_PLAN_SEED not set: no plan written");
        return;
    };
    let seed: u64 = seed.parse().unwrap();
    let plan = match std::env::var("MAGCOMP_PLAN_CREW").is_ok() {
        true => crew_plan(seed),
        false => random_plan(seed),
    };
    let flight = simulate(&Scenario::try_from(plan.raw.clone()).unwrap()).unwrap();
    let log = match plan.fluxgate_only {
        true => without_ins(&flight.log),
        false => flight.log.clone(),
    };
    let path = std::env::temp_dir().join(format!("plan_{seed}.csv"));
    magcomp::formats::write_flight_log(&log, &path).unwrap();
    println!("wrote {}", path.display());
    for m in &flight.truth.manoeuvres {
        println!(
            "truth {:?} {:.0}: {:.1}–{:.1}",
            m.kind, m.heading_deg, m.t_start, m.t_end
        );
    }
    let detection = detect_manoeuvres(&log, &DetectOptions::default()).unwrap();
    for leg in &detection.legs {
        println!("leg {:.1}: {:.1}–{:.1}", leg.heading_deg, leg.t_start, leg.t_end);
    }
    for m in &detection.manoeuvres {
        println!(
            "found {:?} {:.0}: {:.1}–{:.1}",
            m.kind, m.heading_deg, m.t_start, m.t_end
        );
    }
}
