//! Manoeuvre detection against the simulator's truth: accuracy over many
//! pilots, headings, turbulence levels and seeds, and each edge case of the
//! detection on its own (gaps, no INS, steep fields, missing manoeuvres).

use magcomp::calibration::detect::{detect_manoeuvres, AttitudeSource, DetectOptions, Detection, STEEP_DIP_DEG};
use magcomp::calibration::windows::ManoeuvreKind;
use magcomp::ingest::flight_log::{Channel, FlightLog};
use magcomp::messages::Warning;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::truth::TrueManoeuvre;
use magcomp::simulate::{simulate, SimulatedFlight};
use rayon::prelude::*;

mod common;

/// Intersection over union of two time windows on a 0.1 s grid.
fn overlap(a: (f64, f64), b: (f64, f64)) -> f64 {
    let dt = 0.1;
    let inter = (a.1.min(b.1) - a.0.max(b.0) + dt).max(0.0);
    let union = a.1.max(b.1) - a.0.min(b.0) + dt;
    inter / union
}

/// How detection did against the truth.
#[derive(Debug, Default)]
struct Score {
    truth: usize,
    found: usize,
    worst_iou: f64,
    spurious: usize,
    wrong_kind: usize,
}

/// Each true manoeuvre is found when a detected window of the same kind
/// overlaps it with IoU ≥ 0.9; a detected window that matches no true
/// manoeuvre at IoU ≥ 0.9 is spurious (a fragment counts as spurious).
fn score(detection: &Detection, truth: &[TrueManoeuvre]) -> Score {
    let mut result = Score {
        truth: truth.len(),
        worst_iou: 1.0,
        ..Score::default()
    };
    for m in truth {
        let best = detection
            .manoeuvres
            .iter()
            .map(|d| (overlap((d.t_start, d.t_end), (m.t_start, m.t_end)), d.kind))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        let (iou, kind) = best.unwrap_or((0.0, m.kind));
        result.worst_iou = result.worst_iou.min(iou);
        if iou >= 0.9 && kind == m.kind {
            result.found += 1;
        } else if iou >= 0.9 {
            result.wrong_kind += 1;
        }
    }
    result.spurious = detection
        .manoeuvres
        .iter()
        .filter(|d| {
            !truth
                .iter()
                .any(|m| overlap((d.t_start, d.t_end), (m.t_start, m.t_end)) >= 0.9)
        })
        .count();
    result
}

fn fly(seed: u64, edit: impl FnOnce(&mut RawScenario)) -> SimulatedFlight {
    let mut raw = RawScenario {
        seed,
        ..RawScenario::default()
    };
    raw.survey.line_count = 2;
    raw.survey.line_length_m = 5000.0;
    edit(&mut raw);
    simulate(&Scenario::try_from(raw).unwrap()).unwrap()
}

fn detect(flight: &SimulatedFlight) -> Detection {
    detect_manoeuvres(&flight.log, &DetectOptions::default()).unwrap()
}

fn assert_perfect(name: &str, flight: &SimulatedFlight, detection: &Detection) -> Score {
    let result = score(detection, &flight.truth.manoeuvres);
    assert_eq!(
        (result.found, result.spurious, result.wrong_kind),
        (result.truth, 0, 0),
        "{name}: {result:?}\n{:#?}",
        detection.manoeuvres
    );
    result
}

#[test]
fn detection_finds_every_manoeuvre_across_pilots_headings_and_turbulence() {
    // 48 flights: the seed draws the pilot's cycle counts, periods and
    // amplitudes; headings, period ranges, turbulence and survey
    // turbulence vary with the index.
    let outcomes: Vec<(u64, Score)> = (0..48u64)
        .into_par_iter()
        .map(|index| {
            let flight = fly(100 + index, |raw| {
                let start = (index * 37 % 90) as f64;
                raw.calibration.headings_deg = (0..4)
                    .map(|k| (start + 90.0 * k as f64 + (index % 3) as f64 * 7.0 * k as f64) % 360.0)
                    .collect();
                raw.calibration.period_s = [[4.0, 8.0], [3.0, 6.0], [6.0, 10.0]][index as usize % 3];
                raw.calibration.cycles = [[2, 4], [3, 3], [2, 2], [4, 4]][index as usize % 4];
                raw.calibration.turbulence_deg = [0.05, 0.2, 0.4][index as usize % 3];
                raw.calibration.heading_wander_deg = [0.0, 1.0][index as usize % 2];
                raw.survey.turbulence_deg = [0.8, 1.5][index as usize % 2];
            });
            let detection = detect(&flight);
            (index, score(&detection, &flight.truth.manoeuvres))
        })
        .collect();
    let (mut truth, mut found, mut spurious, mut worst) = (0, 0, 0, 1.0f64);
    for (index, result) in &outcomes {
        println!("flight {index:2}: {result:?}");
        truth += result.truth;
        found += result.found;
        spurious += result.spurious;
        worst = worst.min(result.worst_iou);
    }
    println!("{found}/{truth} manoeuvres found at IoU ≥ 0.9, {spurious} spurious, worst IoU {worst:.3}");
    assert_eq!((found, spurious), (truth, 0));
    assert!(worst >= 0.9);
}

#[test]
fn two_and_four_cycle_pilots() {
    for cycles in [2, 4] {
        let flight = fly(7, |raw| raw.calibration.cycles = [cycles, cycles]);
        let detection = detect(&flight);
        assert_perfect(&format!("{cycles} cycles"), &flight, &detection);
        assert!(detection.manoeuvres.iter().all(|m| m.cycles == cycles as f64));
    }
}

#[test]
fn periods_from_three_to_ten_seconds() {
    for period in [[3.0, 3.2], [9.5, 10.0]] {
        let flight = fly(8, |raw| raw.calibration.period_s = period);
        let detection = detect(&flight);
        assert_perfect(&format!("period {period:?}"), &flight, &detection);
        for (found, truth) in detection.manoeuvres.iter().zip(&flight.truth.manoeuvres) {
            // The mean period over whole cycles, measured between crossings
            // located to a sample (0.1 s) at each end.
            assert!(
                (found.period_s - truth.period_s).abs() < 0.2 / truth.cycles as f64 + 0.05,
                "{found:?} vs {truth:?}"
            );
            assert!((found.amplitude_deg - truth.amplitude_deg).abs() < 0.05 * truth.amplitude_deg + 0.3);
        }
    }
}

#[test]
fn headings_off_the_cardinal_points_are_reported_as_flown() {
    let headings = vec![37.0, 127.0, 217.0, 307.0];
    let flight = fly(9, |raw| raw.calibration.headings_deg = headings.clone());
    let detection = detect(&flight);
    assert_perfect("headings", &flight, &detection);
    assert_eq!(detection.boxes.len(), 1);
    for (found, flown) in detection.boxes[0].headings_deg.iter().zip(&headings) {
        // Turbulence of 0.05° on the legs: the leg's heading to 0.5°.
        assert!((found - flown).abs() < 0.5, "{found} vs {flown}");
    }
}

#[test]
fn a_box_flown_twice_is_two_boxes() {
    let flight = fly(10, |raw| raw.calibration.repeats = 2);
    let detection = detect(&flight);
    assert_perfect("two boxes", &flight, &detection);
    assert_eq!(detection.boxes.len(), 2);
    for (found, truth) in detection.boxes.iter().zip(&flight.truth.boxes) {
        assert!(overlap((found.t_start, found.t_end), (truth.t_start, truth.t_end)) > 0.9);
    }
}

#[test]
fn a_missing_manoeuvre_is_reported_not_invented() {
    let flight = fly(11, |raw| {
        raw.calibration.omit = vec!["yaw@290".into(), "pitch@110".into()]
    });
    let detection = detect(&flight);
    assert_perfect("omitted", &flight, &detection);
    assert_eq!(detection.manoeuvres.len(), 10);
    assert_eq!(
        detection.boxes[0].missing,
        vec!["no pitch on heading 110", "no yaw on heading 290"]
    );
    // The run warns of the box by number, with what it lacks.
    let warnings = magcomp::pipeline::detection_warnings(&detection);
    let named: Vec<_> = (warnings.iter())
        .filter_map(|w| match w {
            magcomp::messages::Warning::IncompleteBox { number, missing, .. } => Some((*number, missing.clone())),
            _ => None,
        })
        .collect();
    assert_eq!(
        named,
        [(
            1,
            vec!["no pitch on heading 110".to_string(), "no yaw on heading 290".into()]
        )],
        "{warnings:?}"
    );
}

#[test]
fn a_wandering_track_and_heavy_turbulence() {
    // A held heading drifting 1° rms (over ~30 s) under the manoeuvres,
    // 0.5° of turbulence on the legs and 2° over the survey lines: all found.
    let flight = fly(12, |raw| {
        raw.calibration.heading_wander_deg = 1.0;
        raw.calibration.turbulence_deg = 0.5;
        raw.survey.turbulence_deg = 2.0;
    });
    assert_perfect("wander", &flight, &detect(&flight));
    // Twice the drift: a 5° yaw can sink into it. What is lost is reported
    // missing, never replaced by a fragment.
    let flight = fly(12, |raw| {
        raw.calibration.heading_wander_deg = 2.0;
        raw.calibration.turbulence_deg = 0.6;
        raw.survey.turbulence_deg = 2.0;
    });
    let detection = detect(&flight);
    let result = score(&detection, &flight.truth.manoeuvres);
    println!("heavy wander: {result:?}");
    assert_eq!((result.spurious, result.wrong_kind), (0, 0));
    let missing: usize = detection.boxes.iter().map(|b| b.missing.len()).sum();
    assert_eq!(missing, result.truth - result.found);
}

#[test]
fn a_yaw_run_on_into_the_turn_and_a_pitch_begun_at_the_roll_out_are_found() {
    // As on the real flight's legs: the turn begins 0–1 s after the yaw
    // and the pitch 0–1 s after the roll-out, the bank rolling in and out
    // over 1.5–4 s, the three manoeuvres back to back, the airframe's
    // coupled motion and a held heading that drifts 0.5–1° under them
    // (the yaw's own level is then neither the leg's nor the turn's). 16
    // flights, each drawn from the test's own SplitMix64 stream.
    let draws = common::splitmix64(0x5EED_0068_0004, 16 * 8);
    let outcomes: Vec<(u64, Score)> = (0..16usize)
        .into_par_iter()
        .map(|flight| {
            let unit = |k: usize| (draws[flight * 8 + k] >> 11) as f64 / (1u64 << 53) as f64;
            let within = |k: usize, low: f64, high: f64| low + (high - low) * unit(k);
            let seed = draws[flight * 8 + 7] % 100_000;
            let flown = fly(seed, |raw| {
                let base = within(0, 0.0, 360.0).round();
                raw.calibration.headings_deg = (0..4).map(|k| (base + 90.0 * k as f64) % 360.0).collect();
                raw.calibration.repeats = 2;
                raw.calibration.cycles = [2, 4];
                raw.calibration.period_s = [4.5, 7.5];
                raw.calibration.pitch_deg = within(1, 3.0, 4.6);
                raw.calibration.roll_deg = within(2, 6.2, 8.4);
                raw.calibration.yaw_deg = within(3, 3.5, 5.0);
                raw.calibration.heading_wander_deg = within(4, 0.5, 1.0);
                raw.calibration.turbulence_deg = 0.1;
                raw.calibration.lead_in_s = [0.0, 1.0];
                raw.calibration.pause_s = [0.0, 1.0];
                raw.calibration.turn_after_s = Some([0.0, 1.0]);
                let quickest = within(5, 1.5, 3.0);
                raw.calibration.turn_entry_s = [quickest, quickest + 1.0];
                raw.calibration.turn_rate_deg_s = [2.5, 3.5];
                let coupling = &mut raw.calibration.coupling;
                coupling.pitch_roll = [0.1, 0.3];
                coupling.roll_yaw = [0.2, 0.4];
                coupling.yaw_roll = [0.3, 0.55];
                coupling.lag_deg = [0.0, 60.0];
                raw.sample_rate_hz = [10.0, 20.0][usize::from(unit(6) < 0.5)];
            });
            (seed, score(&detect(&flown), &flown.truth.manoeuvres))
        })
        .collect();
    for (seed, result) in &outcomes {
        println!("seed {seed}: {result:?}");
    }
    let faulty: Vec<u64> = (outcomes.iter())
        .filter(|(_, r)| (r.found, r.spurious, r.wrong_kind) != (r.truth, 0, 0))
        .map(|(seed, _)| *seed)
        .collect();
    assert!(
        faulty.is_empty(),
        "manoeuvres lost, misnamed or spurious on seeds {faulty:?}"
    );
}

/// The flight with `rows` of the INS set missing, or removed entirely.
fn with_gap(log: &FlightLog, rows: std::ops::Range<usize>, remove: bool) -> FlightLog {
    let keep = |k: &usize| !(remove && rows.contains(k));
    let time: Vec<f64> = (0..log.len()).filter(keep).map(|k| log.time_s()[k]).collect();
    let channels = log
        .channels()
        .iter()
        .map(|c| Channel {
            values: (0..log.len())
                .filter(keep)
                .map(|k| {
                    if c.name.starts_with("ins_") && rows.contains(&k) {
                        f64::NAN
                    } else {
                        c.values[k]
                    }
                })
                .collect(),
            ..c.clone()
        })
        .collect();
    FlightLog::new(log.source(), log.time_column(), time, channels).unwrap()
}

#[test]
fn gaps_and_dropouts_lose_at_most_the_manoeuvre_they_hit() {
    let flight = fly(13, |_| {});
    let truth = &flight.truth.manoeuvres;
    let row = |t: f64| flight.log.time_s().partition_point(|&x| x < t);
    // An INS dropout of 1 s inside the fourth manoeuvre, and 30 s of the
    // recording missing in the level flight after the seventh.
    let dropout = row(truth[3].t_start + 3.0)..row(truth[3].t_start + 4.0);
    let pause = row(truth[6].t_end + 2.0)..row(truth[6].t_end + 5.0);
    for (name, log) in [
        ("dropout", with_gap(&flight.log, dropout, false)),
        ("removed rows", with_gap(&flight.log, pause, true)),
    ] {
        let detection = detect_manoeuvres(&log, &DetectOptions::default()).unwrap();
        let result = score(&detection, truth);
        println!("{name}: {result:?}");
        // Never a fragment or a wrong kind; the manoeuvre under the gap may be
        // lost (and is then reported missing), no other.
        assert_eq!((result.spurious, result.wrong_kind), (0, 0), "{name}");
        assert!(result.found >= truth.len() - 1, "{name}: {result:?}");
        let missing: usize = detection.boxes.iter().map(|b| b.missing.len()).sum();
        assert_eq!(missing, truth.len() - result.found, "{name}");
    }
}

/// The INS attitude missing over a whole leg's manoeuvres (about 80 s):
/// the three are lost and reported missing, and the detection says the
/// attitude is missing over that span, where they may have been flown;
/// a 1 s dropout is no such span.
#[test]
fn an_attitude_gap_over_a_leg_is_named_with_what_is_missing() {
    let flight = fly(13, |_| {});
    let truth = &flight.truth.manoeuvres;
    let row = |t: f64| flight.log.time_s().partition_point(|&x| x < t);
    let gap = row(truth[3].t_start - 5.0)..row(truth[5].t_end + 5.0);
    let (first, last) = (flight.log.time_s()[gap.start], flight.log.time_s()[gap.end - 1]);
    let detection = detect_manoeuvres(&with_gap(&flight.log, gap, false), &DetectOptions::default()).unwrap();
    assert!(
        detection.manoeuvres.len() <= truth.len() - 3,
        "{}",
        detection.manoeuvres.len()
    );
    assert_eq!(detection.attitude_gaps, vec![(first, last)]);
    let warning = detection.attitude_gap_warning().expect("a warning");
    assert_eq!(
        warning,
        Warning::AttitudeGaps {
            spans: vec![(first, last)]
        }
    );
    assert!(
        warning.to_string().contains(&format!("{first:.1}–{last:.1} s")),
        "{warning}"
    );
    // A gap on the survey lines, far from a box that lacks a manoeuvre,
    // is listed but not blamed.
    let omitted = fly(13, |raw| {
        raw.calibration.headings_deg = vec![0.0, 90.0, 180.0, 270.0];
        raw.calibration.omit = vec!["yaw@270".into()];
    });
    let end = omitted.log.time_s()[omitted.log.len() - 1];
    let rows = |t: f64| omitted.log.time_s().partition_point(|&x| x < t);
    let far = rows(end - 120.0)..rows(end - 100.0);
    let detection = detect_manoeuvres(&with_gap(&omitted.log, far, false), &DetectOptions::default()).unwrap();
    assert!(detection.boxes[0].t_end < end - 400.0, "the gap is on the survey lines");
    assert!(!detection.boxes[0].missing.is_empty());
    assert_eq!(detection.attitude_gaps.len(), 1);
    assert!(detection.attitude_gap_warning().is_none());
    let short = row(truth[3].t_start + 3.0)..row(truth[3].t_start + 4.0);
    let detection = detect_manoeuvres(&with_gap(&flight.log, short, false), &DetectOptions::default()).unwrap();
    assert!(detection.attitude_gaps.is_empty());
    assert!(detection.attitude_gap_warning().is_none());
}

/// `log` without its INS columns: attitude from the fluxgate alone.
fn without_ins(log: &FlightLog) -> FlightLog {
    let channels: Vec<Channel> = log
        .channels()
        .iter()
        .filter(|c| !c.name.starts_with("ins_"))
        .cloned()
        .collect();
    FlightLog::new(log.source(), log.time_column(), log.time_s().to_vec(), channels).unwrap()
}

#[test]
fn without_an_ins_the_fluxgate_stands_in() {
    let flight = fly(14, |_| {});
    let detection = detect_manoeuvres(&without_ins(&flight.log), &DetectOptions::default()).unwrap();
    assert_eq!(detection.attitude_source, AttitudeSource::Fluxgate);
    assert!(detection.notes.contains(&magcomp::messages::Note::AttitudeFromFluxgate));
    assert_perfect("fluxgate", &flight, &detection);
    // Headings are magnetic: true heading minus the declination (about
    // −13° at the default site), within 1.5° for the fluxgate's own field.
    let declination = magcomp::simulate::igrf::Igrf::fourteenth()
        .field(45.3, -75.7, 3080.0, 2026.45)
        .declination_deg();
    for (found, flown) in detection.boxes[0].headings_deg.iter().zip([20.0, 110.0, 200.0, 290.0]) {
        let expected = (flown - declination) % 360.0;
        assert!(
            ((found - expected + 540.0) % 360.0 - 180.0).abs() < 1.5,
            "{found} vs {expected}"
        );
    }
}

/// Near the magnetic pole (78° N, 95° W: the field dips about 88°) the
/// fluxgate alone misses manoeuvres it cannot see; the detection says the
/// field is steep and that the missing ones may have been flown, where at
/// 45° N (a dip of about 70°, every manoeuvre found) it says nothing of it.
/// The dip it states is the site's inclination within 2° (IGRF-14).
#[test]
fn under_a_steep_field_the_fluxgate_says_what_it_cannot_see() {
    let site = |raw: &mut RawScenario| {
        raw.site.latitude_deg = 78.0;
        raw.site.longitude_deg = -95.0;
    };
    let flight = fly(62, site);
    let detection = detect_manoeuvres(&without_ins(&flight.log), &DetectOptions::default()).unwrap();
    let inclination = magcomp::simulate::igrf::Igrf::fourteenth()
        .field(78.0, -95.0, 3080.0, 2026.45)
        .inclination_deg();
    let dip = detection.fluxgate_dip_deg.unwrap();
    assert!((dip - inclination).abs() < 2.0, "dip {dip} against {inclination}");
    assert!(detection.manoeuvres.len() < 12, "{}", detection.manoeuvres.len());
    let warnings = magcomp::pipeline::detection_warnings(&detection);
    let steep = (warnings.iter()).find_map(|w| match w {
        Warning::SteepField { dip_deg } => Some(*dip_deg),
        _ => None,
    });
    assert_eq!(steep, Some(dip.abs()), "{warnings:?}");
    assert!(
        warnings
            .iter()
            .any(|w| w.to_string().contains("may have been flown and not seen")),
        "{warnings:?}"
    );
    // With the INS the same flight is whole and says nothing of the field.
    let with_ins = detect(&flight);
    assert_perfect("with the INS at 78° N", &flight, &with_ins);
    assert!(with_ins.steep_field_warning().is_none());

    let flight = fly(14, |_| {});
    let detection = detect_manoeuvres(&without_ins(&flight.log), &DetectOptions::default()).unwrap();
    assert!(detection.fluxgate_dip_deg.unwrap() < STEEP_DIP_DEG);
    assert!(detection.steep_field_warning().is_none());
}

#[test]
fn survey_lines_alone_give_no_manoeuvres() {
    let flight = fly(15, |raw| {
        raw.calibration.repeats = 0;
        raw.survey.line_count = 4;
        raw.survey.turbulence_deg = 2.0;
    });
    let detection = detect(&flight);
    assert!(
        detection.manoeuvres.is_empty() && detection.boxes.is_empty(),
        "{:#?}",
        detection.manoeuvres
    );
}

#[test]
fn a_last_leg_that_runs_on_into_the_survey_keeps_its_manoeuvres() {
    // Headings 90, 180, 270, 0; after the last manoeuvre on heading 0 the
    // aircraft holds the heading, descends and flies the first survey line
    // on it. Before, leg, descent and line made one 750 s "leg" whose
    // median pitch was the descent's, and its three manoeuvres were lost.
    let flight = fly(4, |raw| {
        raw.calibration.headings_deg = vec![90.0, 180.0, 270.0, 0.0];
        raw.calibration.continue_into_survey = true;
        raw.survey.line_length_m = 6000.0;
    });
    let detection = detect(&flight);
    assert_perfect("runs on", &flight, &detection);
    assert_eq!(detection.boxes.len(), 1);
    let found = &detection.boxes[0];
    assert!(found.missing.is_empty(), "{:?}", found.missing);
    assert_eq!(found.headings_deg.len(), 4);
    // The box ends where the manoeuvring stops (within the 30 s the leg
    // is allowed to run on, plus the pause after the last yaw), not at
    // the end of the survey line.
    let truth = &flight.truth.boxes[0];
    assert!(
        (found.t_end - truth.t_end).abs() < 30.0,
        "{} vs {}",
        found.t_end,
        truth.t_end
    );
}

#[test]
fn a_box_without_a_heading_names_it() {
    let flight = fly(4, |raw| raw.calibration.headings_deg = vec![90.0, 180.0, 270.0]);
    let detection = detect(&flight);
    assert_perfect("three headings", &flight, &detection);
    assert_eq!(detection.boxes[0].missing, vec!["no leg near 0°"]);
}

/// A box flown on three headings 120° apart lacks no heading of a
/// four-heading box: its manoeuvres are all found, and it says it has
/// three legs off the pattern instead of naming three headings it never
/// meant to fly (before: "no leg near 90°, 180°, 270°" for legs on 10°,
/// 130°, 250°). Four legs off the pattern by a crab angle are a box.
#[test]
fn a_box_off_the_four_heading_pattern_says_so() {
    let flight = fly(4, |raw| raw.calibration.headings_deg = vec![10.0, 130.0, 250.0]);
    let detection = detect(&flight);
    assert_perfect("three headings 120° apart", &flight, &detection);
    let missing = &detection.boxes[0].missing;
    assert_eq!(missing.len(), 1, "{missing:?}");
    assert!(
        missing[0].contains("it has 3 legs (10°, 130°, 250°), not four headings"),
        "{missing:?}"
    );
    assert!(!missing[0].contains("no leg near"), "{missing:?}");
    // Four legs crabbed into a 20 m/s wind (yaw 343.4°, 90°, 196.6°, 270°
    // for tracks north, east, south and west) are a whole box.
    let flight = fly(4, |raw| raw.calibration.headings_deg = vec![343.4, 90.0, 196.6, 270.0]);
    let detection = detect(&flight);
    assert_perfect("crabbed legs", &flight, &detection);
    assert!(
        detection.boxes[0].missing.is_empty(),
        "{:?}",
        detection.boxes[0].missing
    );
}

/// On magnetic headings 0, 90, 180 and 270 the fluxgate sees a pitch and
/// a yaw alike on the east and west legs, and a roll and a yaw alike on
/// the north and south ones (the field then lies in the plane of the two
/// axes). Every manoeuvre must be found under its own name or under the
/// name the detector flags it could be, those legs must carry the flag,
/// and the warning must say so; with the INS nothing is flagged.
#[test]
fn the_fluxgate_flags_the_kinds_it_cannot_tell_apart() {
    let declination = magcomp::simulate::igrf::Igrf::fourteenth()
        .field(45.3, -75.7, 3080.0, 2026.45)
        .declination_deg();
    for seed in [3, 8, 21] {
        let flight = fly(seed, |raw| {
            raw.calibration.headings_deg = [0.0, 90.0, 180.0, 270.0]
                .iter()
                .map(|h| (h + declination).rem_euclid(360.0))
                .collect();
        });
        let with_ins = detect(&flight);
        assert!(with_ins.manoeuvres.iter().all(|m| m.could_be.is_none()), "seed {seed}");
        let detection = detect_manoeuvres(&without_ins(&flight.log), &DetectOptions::default()).unwrap();
        for m in &flight.truth.manoeuvres {
            let matched = detection.manoeuvres.iter().any(|d| {
                (d.kind == m.kind || d.could_be == Some(m.kind))
                    && overlap((d.t_start, d.t_end), (m.t_start, m.t_end)) >= 0.9
            });
            assert!(matched, "seed {seed}: {m:?} not found\n{:#?}", detection.manoeuvres);
        }
        assert_eq!(detection.manoeuvres.len(), flight.truth.manoeuvres.len(), "seed {seed}");
        let flagged = |heading: f64, pair: [ManoeuvreKind; 2]| {
            detection.manoeuvres.iter().any(|d| {
                ((d.heading_deg - heading + 540.0) % 360.0 - 180.0).abs() < 15.0
                    && d.could_be
                        .is_some_and(|other| pair.contains(&d.kind) && pair.contains(&other))
            })
        };
        for heading in [90.0, 270.0] {
            assert!(
                flagged(heading, [ManoeuvreKind::Pitch, ManoeuvreKind::Yaw]),
                "seed {seed}, {heading}"
            );
        }
        for heading in [0.0, 180.0] {
            assert!(
                flagged(heading, [ManoeuvreKind::Roll, ManoeuvreKind::Yaw]),
                "seed {seed}, {heading}"
            );
        }
        let warnings = magcomp::pipeline::detection_warnings(&detection);
        assert!(
            warnings.iter().any(|w| w
                .to_string()
                .contains("a pitch and a yaw turn the field direction alike")),
            "seed {seed}: {warnings:?}"
        );
        assert!(
            warnings.iter().any(|w| w
                .to_string()
                .contains("a roll and a yaw turn the field direction alike")),
            "seed {seed}: {warnings:?}"
        );
    }
}
