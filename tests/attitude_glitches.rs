//! Glitches in the INS attitude and a dead fluxgate axis, on flights drawn
//! at random (`common::paired_sensors_flight`: random site, box, rate and
//! sensor layout).
//!
//! A heading read as 0, 359.9, −180 or a subnormal in 2 % of the rows is a
//! sample no aircraft can record (it turns no faster than 90°/s): it is
//! masked and flagged like any other impossible sample, detection finds
//! the same box, and the compensation is what it is without the glitches.
//! No compensated value is ever written beyond what a magnetometer reads
//! without its row flagged. A fluxgate axis reading 0 throughout is named
//! as dead, a scalar repeating one value throughout as stuck, and nothing
//! is compensated through them.

mod common;

use magcomp::config::FlightJob;
use magcomp::formats::write_flight_log;
use magcomp::ingest::flags::FlagKind;
use magcomp::ingest::flight_date::FlightDate;
use magcomp::ingest::flight_log::FlightLog;
use magcomp::simulate::random::Random;
use magcomp::simulate::scenario::Scenario;
use magcomp::simulate::simulate;
use std::collections::BTreeMap;

/// The values a glitching INS writes for the heading.
const GLITCHES: [f64; 4] = [0.0, 359.9, -180.0, 5e-324];

/// `log` with `fraction` of its heading samples replaced by [`GLITCHES`],
/// and the rows replaced.
fn with_heading_glitches(log: &FlightLog, seed: u64, fraction: f64) -> (FlightLog, Vec<usize>) {
    let mut draw = Random::new(seed).fork("heading glitches");
    let mut yaw = log.channel("ins_yaw").unwrap().values.clone();
    let mut rows = Vec::new();
    for (row, value) in yaw.iter_mut().enumerate() {
        if draw.uniform(0.0, 1.0) < fraction {
            *value = GLITCHES[draw.integer(0, GLITCHES.len() - 1)];
            rows.push(row);
        }
    }
    (log.with_values("ins_yaw", yaw).unwrap(), rows)
}

/// The plans a test flies: `MAGCOMP_GLITCH_FLIGHTS`, or `default`.
fn flights_asked(default: usize) -> usize {
    std::env::var("MAGCOMP_GLITCH_FLIGHTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Runs the plain pipeline on `log` (detection included) in `folder`.
fn run(folder: &std::path::Path, log: &FlightLog, name: &str) -> magcomp::error::Result<magcomp::pipeline::FlightRun> {
    let input = folder.join(format!("{name}.csv"));
    write_flight_log(log, &input).unwrap();
    let mut job = FlightJob::new(&input);
    job.date = FlightDate::parse("2026-06-15");
    magcomp::pipeline::run(&job, &common::plain(), &folder.join(format!("{name}_c.csv")))
}

/// Standard deviation of compensated − truth over the survey lines, nT.
fn survey_error(run: &magcomp::pipeline::FlightRun, truth: &[f64], channel: usize) -> f64 {
    let line = &run.log().channel("line").unwrap().values;
    let values = &run.compensation.channels[channel].values;
    let errors: Vec<f64> = (0..line.len())
        .filter(|&i| line[i] > 0.0 && values[i].is_finite())
        .map(|i| values[i] - truth[i])
        .collect();
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt()
}

#[test]
fn heading_glitches_are_masked_and_change_nothing_else() {
    let folder = tempfile::tempdir().unwrap();
    for seed in [3, 7, 11] {
        let (simulated, layout, _) = common::paired_sensors_flight(seed);
        let (glitched, rows) = with_heading_glitches(&simulated.log, seed, 0.02);
        let clean = run(folder.path(), &simulated.log, &format!("clean_{seed}")).unwrap();
        let dirty = run(folder.path(), &glitched, &format!("glitched_{seed}")).unwrap();
        // The same box is found.
        let windows = |r: &magcomp::pipeline::FlightRun| r.result.models[0].windows.len();
        assert_eq!(windows(&dirty), windows(&clean), "seed {seed} {layout:?}");
        // Every glitch far from the true heading is masked and flagged,
        // and nothing else is.
        let flags = &dirty.compensation.flags;
        let flagged: Vec<usize> = (0..flags.len())
            .filter(|&k| flags[k].has(FlagKind::Spike, "ins_yaw"))
            .collect();
        // Far: more than three times what the aircraft can turn in one
        // interval (the screen masks beyond twice from most neighbours;
        // a fast turn moves the neighbours by up to three intervals' turn).
        let jump = (magcomp::ingest::screen::FASTEST_ATTITUDE_DEG_S * simulated.log.median_interval_s())
            .max(magcomp::ingest::screen::LEAST_ATTITUDE_GLITCH_DEG);
        let truth = &simulated.log.channel("ins_yaw").unwrap().values;
        let far: Vec<usize> = (rows.iter().copied())
            .filter(|&k| {
                let glitch = glitched.channel("ins_yaw").unwrap().values[k];
                ((glitch - truth[k] + 180.0).rem_euclid(360.0) - 180.0).abs() > 3.0 * jump
            })
            .collect();
        let g = &glitched.channel("ins_yaw").unwrap().values;
        for &k in flagged.iter().filter(|k| !rows.contains(k)).take(3) {
            println!("GOOD MASKED {k}: {:?}", &g[k.saturating_sub(3)..(k + 4).min(g.len())]);
        }
        assert!(
            flagged.iter().all(|k| rows.contains(k)),
            "seed {seed}: a good heading masked"
        );
        let found = far.iter().filter(|k| flagged.contains(k)).count();
        let g = &glitched.channel("ins_yaw").unwrap().values;
        for &k in far.iter().filter(|k| !flagged.contains(k)).take(5) {
            println!(
                "MISSED {k}: {:?} truth {:?} dt {}",
                &g[k.saturating_sub(3)..(k + 4).min(g.len())],
                &truth[k.saturating_sub(3)..(k + 4).min(g.len())],
                simulated.log.median_interval_s()
            );
        }
        println!(
            "seed {seed} {layout:?}: {} glitches, {} far from the heading, {found} of them masked, {} masked in all",
            rows.len(),
            far.len(),
            flagged.len()
        );
        assert!(
            found as f64 >= 0.99 * far.len() as f64,
            "seed {seed}: {found} of {}",
            far.len()
        );
        assert!(
            dirty
                .result
                .warnings
                .iter()
                .any(|w| w.to_string().contains("samples of ins_yaw (glitches")),
            "{:?}",
            dirty.result.warnings
        );
        // The compensation is what it is without them, and no value lies
        // beyond what a magnetometer reads.
        for (k, model) in dirty.result.models.iter().enumerate() {
            let truth = simulated.truth.earth_total_nt(&model.channel).unwrap();
            let (before, after) = (survey_error(&clean, truth, k), survey_error(&dirty, truth, k));
            println!(
                "  {}: survey error {before:.4} nT clean, {after:.4} nT glitched",
                model.channel
            );
            assert!(
                after <= before * 1.1 + 0.005,
                "seed {seed} {}: {before} → {after}",
                model.channel
            );
        }
        assert!((0..flags.len()).all(|k| flags[k].iter().all(|f| f.kind != FlagKind::OutputOutOfRange)));
    }
}

#[test]
fn a_dead_fluxgate_axis_is_named_and_nothing_is_compensated_through_it() {
    let folder = tempfile::tempdir().unwrap();
    let (simulated, _, _) = common::paired_sensors_flight(5);
    let rows = simulated.log.len();
    let dead = simulated.log.with_values("flux_a_y", vec![0.0; rows]).unwrap();
    let Err(error) = run(folder.path(), &dead, "dead_axis") else {
        panic!("no compensation through a dead axis");
    };
    let text = error.to_string();
    assert!(
        text.contains("every sample of 'flux_a_y' was masked on screening")
            && text.contains("stuck or its axis dead")
            && text.contains("--vector"),
        "{text}"
    );
    // A scalar stuck for the whole flight is named the same way.
    let value = simulated.log.channel("mag_4_uc").unwrap().values[0];
    let stuck = simulated.log.with_values("mag_4_uc", vec![value; rows]).unwrap();
    let Err(error) = run(folder.path(), &stuck, "stuck_scalar") else {
        panic!("a stuck scalar");
    };
    let text = error.to_string();
    assert!(
        text.contains("every sample of 'mag_4_uc' was masked on screening") && text.contains("--channels"),
        "{text}"
    );
}

/// The rows `screen_samples` masks in `column` of `log`.
fn masked_rows(log: &FlightLog, column: &str) -> Vec<usize> {
    let screened = magcomp::ingest::screen::screen_samples(log).unwrap();
    let Some(masked) = screened.log.as_ref() else {
        return Vec::new();
    };
    let values = &masked.channel(column).unwrap().values;
    let recorded = &log.channel(column).unwrap().values;
    (0..values.len())
        .filter(|&k| values[k].is_nan() && recorded[k].is_finite())
        .collect()
}

#[test]
fn glitches_of_many_samples_on_a_scalar_or_a_fluxgate_axis_are_masked_and_nothing_else() {
    // Runs of 2, 3, 10 and 50 samples, each placed at a row drawn from the
    // test's own SplitMix64 stream on flights drawn at random (any rate
    // from 5 to 50 Hz, box and survey): a scalar lowered by 20,000 nT, a
    // fluxgate axis read as zeros or subnormals, and one with its sign
    // flipped (2, 3 and 10 samples: a flip held for 5 s is an axis that
    // turned, as far as continuity can tell). The clean flight masks
    // nothing; each damaged one masks exactly the damaged rows.
    let draws = common::splitmix64(0x5EED_0070_0001, 64);
    let mut next = draws.into_iter();
    for seed in [5, 13, 21] {
        let (simulated, layout, _) = common::paired_sensors_flight(seed);
        let log = &simulated.log;
        assert!(
            masked_rows(log, "mag_1_uc").is_empty(),
            "seed {seed}: the clean flight is masked"
        );
        assert!(
            masked_rows(log, "flux_a_z").is_empty(),
            "seed {seed}: the clean flight is masked"
        );
        for length in [2usize, 3, 10, 50] {
            let start = 100 + (next.next().unwrap() % (log.len() as u64 - 300)) as usize;
            let rows: Vec<usize> = (start..start + length).collect();
            let damaged = |column: &str, change: &dyn Fn(f64) -> f64| {
                let mut values = log.channel(column).unwrap().values.clone();
                for &k in &rows {
                    values[k] = change(values[k]);
                }
                log.with_values(column, values).unwrap()
            };
            let case = format!(
                "seed {seed} ({layout:?}), {length} samples from row {start} ({:.3} s apart; z {:.0} nT)",
                log.median_interval_s(),
                log.channel("flux_a_z").unwrap().values[start]
            );
            let lowered = damaged("mag_1_uc", &|v| v - 20_000.0);
            assert_eq!(masked_rows(&lowered, "mag_1_uc"), rows, "scalar lowered, {case}");
            // Zeros and a flip on the axis with the largest reading there:
            // an axis near zero read as zero, or flipped, is within what
            // a turn does.
            let axis = ["flux_a_x", "flux_a_y", "flux_a_z"]
                .into_iter()
                .max_by(|a, b| {
                    let at = |c: &str| log.channel(c).unwrap().values[start].abs();
                    at(a).total_cmp(&at(b))
                })
                .unwrap();
            let zeros = damaged(axis, &|_| 0.0);
            assert_eq!(masked_rows(&zeros, axis), rows, "{axis} zeros, {case}");
            let subnormal = damaged("flux_a_x", &|_| 5e-324);
            assert_eq!(masked_rows(&subnormal, "flux_a_x"), rows, "subnormals, {case}");
            if length <= 10 {
                let flipped = damaged(axis, &|v| -v);
                assert_eq!(masked_rows(&flipped, axis), rows, "{axis} flipped, {case}");
            }
        }
    }
}

#[test]
fn glitches_held_too_long_for_continuity_are_masked_against_the_fluxgate_magnitude() {
    // Clean plans drawn as the default's safety campaign draws them (5–50
    // Hz, 1–8 scalars anywhere on the aircraft, cabin ones included,
    // fluxgates mounted any way round), shortened to three survey lines.
    // A scalar lowered by 20,000 or 2,000 nT, or a fluxgate axis raised by
    // 5,000 nT, for 20 s to 10 minutes from a row drawn from the test's
    // own SplitMix64 stream: continuity alone cannot tell such a run from
    // the field (it looks up to 10 s on a scalar, 2 s on an axis); the
    // scalar's departure from the fluxgate's magnitude can. The clean
    // flight masks nothing; each damaged one masks exactly the damaged
    // rows, in the damaged channel only. `MAGCOMP_GLITCH_FLIGHTS=N` flies
    // N plans instead of 4.
    let flights = flights_asked(4);
    let draws = common::splitmix64(0x5EED_0070_0004, 8 * flights);
    let mut next = draws.into_iter();
    let mut cases = 0;
    for _ in 0..flights {
        let seed = next.next().unwrap() % 1_000;
        let mut raw = common::clean_plan(seed);
        raw.survey.line_count = raw.survey.line_count.min(3);
        raw.survey.tie_count = 0;
        let log = &simulate(&Scenario::try_from(raw).unwrap()).unwrap().log;
        let hz = 1.0 / log.median_interval_s();
        let magnetometers: Vec<String> = (log.channels().iter())
            .filter(|c| c.name.starts_with("mag_") || c.name.starts_with("flux_"))
            .map(|c| c.name.clone())
            .collect();
        for column in &magnetometers {
            let masked = masked_rows(log, column);
            assert!(
                masked.is_empty(),
                "seed {seed}: the clean flight masks {column} at {masked:?}"
            );
        }
        let last_scalar = magnetometers.iter().rfind(|c| c.starts_with("mag_")).unwrap().clone();
        for (column, change, seconds) in [
            ("mag_1_uc".to_string(), -20_000.0, 20.0),
            ("mag_1_uc".to_string(), -20_000.0, 600.0),
            (last_scalar, -2_000.0, 60.0),
            ("flux_a".to_string(), 5_000.0, 30.0),
        ] {
            let length = (seconds * hz) as usize;
            assert!(
                log.len() > length + 300,
                "seed {seed}: {} rows, too few for {seconds} s",
                log.len()
            );
            let start = 100 + (next.next().unwrap() % (log.len() - length - 200) as u64) as usize;
            // On the fluxgate, the axis reading most at both ends of the
            // run: an offset across the field hardly changes its
            // magnitude (that is the INS agreement's to see).
            let column = match column.as_str() {
                "flux_a" => ["flux_a_x", "flux_a_y", "flux_a_z"]
                    .into_iter()
                    .max_by(|a, b| {
                        let ends = |c: &str| {
                            let values = &log.channel(c).unwrap().values;
                            values[start].abs().min(values[start + length - 1].abs())
                        };
                        ends(a).total_cmp(&ends(b))
                    })
                    .unwrap()
                    .to_string(),
                _ => column,
            };
            let rows: Vec<usize> = (start..start + length).collect();
            let mut values = log.channel(&column).unwrap().values.clone();
            for &k in &rows {
                values[k] += change;
            }
            let damaged = log.with_values(&column, values).unwrap();
            let case = format!("seed {seed} ({hz} Hz): {column} {change:+} nT for {seconds} s from row {start}");
            for other in &magnetometers {
                let masked = masked_rows(&damaged, other);
                match *other == column {
                    true => assert_eq!(masked, rows, "{case}"),
                    false => assert!(
                        masked.is_empty(),
                        "{case}: {other} masked at {:?}",
                        &masked[..masked.len().min(5)]
                    ),
                }
            }
            cases += 1;
        }
    }
    println!("{cases} damaged flights, each masked on exactly its damaged rows");
}

#[test]
fn a_heading_step_held_is_masked_until_it_steps_back() {
    // Clean plans drawn at random (5–50 Hz, crews' boxes, fluxgates
    // mounted any way round), shortened to two survey lines. The INS
    // heading realigned by 15° at a row drawn from the test's own
    // SplitMix64 stream, held to the end of the record, or for 60 s and
    // then back: the rate screen sees one step within what the aircraft
    // can turn, and no run comes back within 5 s. The heading is masked
    // (flagged `step:ins_yaw`) on exactly the rows it is off (held to the
    // end, on the shorter part of the flight: a heading off from the
    // start and realigned reads the same), and no other channel
    // anywhere. `MAGCOMP_GLITCH_FLIGHTS=N` flies N plans
    // instead of 4.
    let flights = flights_asked(4);
    let draws = common::splitmix64(0x5EED_0070_0005, 8 * flights);
    let mut next = draws.into_iter();
    let channels = ["ins_roll", "ins_pitch", "ins_yaw", "flux_a_x", "flux_a_y", "flux_a_z"];
    for _ in 0..flights {
        let seed = next.next().unwrap() % 1_000;
        let mut raw = common::clean_plan(seed);
        raw.survey.line_count = raw.survey.line_count.min(2);
        raw.survey.tie_count = 0;
        let log = &simulate(&Scenario::try_from(raw).unwrap()).unwrap().log;
        let hz = 1.0 / log.median_interval_s();
        let yaw = &log.channel("ins_yaw").unwrap().values;
        let signed = yaw.iter().any(|v| *v < 0.0);
        for held_s in [f64::INFINITY, 60.0] {
            let margin = (70.0 * hz) as u64;
            let start = (margin + next.next().unwrap() % (log.len() as u64 - 2 * margin)) as usize;
            let end = match held_s.is_finite() {
                true => start + (held_s * hz) as usize,
                false => log.len(),
            };
            let turned: Vec<f64> = (0..log.len())
                .map(|k| match (start..end).contains(&k) {
                    true if signed => (yaw[k] + 15.0 + 180.0).rem_euclid(360.0) - 180.0,
                    true => (yaw[k] + 15.0).rem_euclid(360.0),
                    false => yaw[k],
                })
                .collect();
            let damaged = log.with_values("ins_yaw", turned).unwrap();
            let case = format!(
                "seed {seed} ({hz} Hz): heading +15° from row {start} to {end} of {}",
                log.len()
            );
            // A step that never comes back leaves two parts, either of
            // which may be the turned one: the shorter is masked.
            let off = match end - start <= start || end < log.len() {
                true => start..end,
                false => 0..start,
            };
            for column in channels {
                let masked = masked_rows(&damaged, column);
                match column {
                    "ins_yaw" => assert_eq!(masked, off.clone().collect::<Vec<_>>(), "{case}"),
                    _ => assert!(
                        masked.is_empty(),
                        "{case}: {column} masked at {:?}",
                        &masked[..masked.len().min(5)]
                    ),
                }
            }
            let screened = magcomp::ingest::screen::screen_samples(&damaged).unwrap();
            let flags = screened.log.unwrap().row_flags().to_vec();
            assert!(flags[off.start].has(FlagKind::Step, "ins_yaw"), "{case}");
            println!("{case}: masked on exactly rows {off:?}");
        }
    }
}

/// The INS attitude as it would read `late` samples behind (a fraction
/// read as the line between samples; the heading across north).
fn ins_late(log: &FlightLog, late: f64) -> FlightLog {
    let mut out = log.clone();
    for column in ["ins_roll", "ins_pitch", "ins_yaw"] {
        let values = &log.channel(column).unwrap().values;
        let signed = values.iter().any(|v| *v < 0.0);
        let at = |k: usize| -> f64 {
            let position = (k as f64 - late).max(0.0);
            let (low, share) = (position.floor() as usize, position.fract());
            let (a, b) = (values[low], values[(low + 1).min(values.len() - 1)]);
            if column != "ins_yaw" {
                return a + share * (b - a);
            }
            let turned = a + share * ((b - a + 180.0).rem_euclid(360.0) - 180.0);
            match signed {
                true => (turned + 180.0).rem_euclid(360.0) - 180.0,
                false => turned.rem_euclid(360.0),
            }
        };
        out = out.with_values(column, (0..values.len()).map(at).collect()).unwrap();
    }
    out
}

/// Body axes to north-east-down for roll, pitch and yaw in degrees, as
/// CONTRACT §1 states it: yaw about down, then pitch about east, then roll
/// about north.
fn to_ned(roll: f64, pitch: f64, yaw: f64) -> nalgebra::Matrix3<f64> {
    let turn = |axis: nalgebra::Unit<nalgebra::Vector3<f64>>, deg: f64| {
        nalgebra::Rotation3::from_axis_angle(&axis, deg.to_radians()).into_inner()
    };
    turn(nalgebra::Vector3::z_axis(), yaw)
        * turn(nalgebra::Vector3::y_axis(), pitch)
        * turn(nalgebra::Vector3::x_axis(), roll)
}

/// The angle between two directions, degrees.
fn angle_deg(a: nalgebra::Vector3<f64>, b: nalgebra::Vector3<f64>) -> f64 {
    a.normalize().dot(&b.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
}

#[test]
fn attitude_glitches_inside_the_rate_screen_are_masked_on_the_damaged_rows_alone() {
    // Clean plans drawn as the default's safety campaign draws them (5–50
    // Hz, boxes flown by crews, fluxgates mounted any way round), shortened
    // to two survey lines. The clean flight, and its INS read one, two and
    // half a sample late, mask nothing. Each glitch the rate screen lets
    // through (90°/s) masks none but damaged rows, in the damaged channel
    // alone, and every damaged row that turns the field the sensors see by
    // more than 3° (1,000–2,600 nT in a vector component).
    const TURN_DEG: f64 = 3.0;
    let attitude = ["ins_roll", "ins_pitch", "ins_yaw"];
    let axes = ["flux_a_x", "flux_a_y", "flux_a_z"];
    let mut counts: BTreeMap<&str, [usize; 3]> = BTreeMap::new();
    // `MAGCOMP_GLITCH_FLIGHTS=N` flies N plans instead of 6.
    let flights = flights_asked(6);
    let draws = common::splitmix64(0x5EED_0070_0002, 16 * flights);
    let mut next = draws.into_iter();
    for _ in 0..flights {
        let seed = next.next().unwrap() % 1_000;
        let mut raw = common::clean_plan(seed);
        raw.survey.line_count = raw.survey.line_count.min(2);
        raw.survey.tie_count = 0;
        let simulated = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
        let log = &simulated.log;
        let hz = 1.0 / log.median_interval_s();
        for late in [0.0, 0.5, 1.0, 2.0] {
            let shifted = ins_late(log, late);
            for column in attitude.iter().chain(&axes) {
                let masked = masked_rows(&shifted, column);
                assert!(
                    masked.is_empty(),
                    "seed {seed} ({hz} Hz), INS {late} samples late: {column} masked at {:?}",
                    &masked[..masked.len().min(5)]
                );
            }
        }
        let truth = &simulated.truth.fluxgates[0];
        let field_ned = |k: usize| nalgebra::Vector3::from_fn(|i, _| truth.earth_ned_nt[i][k]);
        let recorded = |column: &str| log.channel(column).unwrap().values.clone();
        let body = |k: usize, angles: [f64; 3]| to_ned(angles[0], angles[1], angles[2]).transpose() * field_ned(k);
        let angles_at = |k: usize| attitude.map(|c| log.channel(c).unwrap().values[k]);
        let margin = (10.0 * hz) as u64;
        let row = |draw: u64| (margin + draw % (log.len() as u64 - 3 * margin)) as usize;
        let cases: [(&str, usize, usize, f64); 4] = [
            ("roll +17°, one row", 0, 1, 17.0),
            ("heading +15°, one row", 2, 1, 15.0),
            ("roll +3°, one row", 0, 1, 3.0),
            ("pitch read as zero, five rows", 1, 5, f64::NAN),
        ];
        let mut damaged_logs = Vec::new();
        // Pitch read as zero where the aircraft pitches (in the box), so
        // that the zeros turn the field.
        let pitched: Vec<usize> = (margin as usize..log.len() - 3 * margin as usize)
            .filter(|&k| recorded("ins_pitch")[k].abs() > 3.0)
            .collect();
        for (name, angle, length, change) in cases {
            let start = match (change.is_nan(), pitched.len()) {
                (true, n) if n > 0 => pitched[(next.next().unwrap() % n as u64) as usize],
                _ => row(next.next().unwrap()),
            };
            let rows: Vec<usize> = (start..start + length).collect();
            let mut values = recorded(attitude[angle]);
            let mut turned = Vec::new();
            for &k in &rows {
                let mut angles = angles_at(k);
                angles[angle] = match change.is_nan() {
                    true => 0.0,
                    false => angles[angle] + change,
                };
                values[k] = angles[angle];
                if angle_deg(body(k, angles), body(k, angles_at(k))) > TURN_DEG {
                    turned.push(k);
                }
            }
            let damaged = log.with_values(attitude[angle], values).unwrap();
            damaged_logs.push((name, attitude[angle], rows, turned, damaged));
        }
        // An axis of the fluxgate read with its sign flipped for 4 s: the
        // axis with the largest reading there.
        let (start, length) = (row(next.next().unwrap()), (4.0 * hz) as usize);
        let rows: Vec<usize> = (start..start + length).collect();
        let axis = *axes
            .iter()
            .max_by(|a, b| recorded(a)[start].abs().total_cmp(&recorded(b)[start].abs()))
            .unwrap();
        let mut values = recorded(axis);
        let reading = |k: usize| nalgebra::Vector3::from_fn(|i, _| log.channel(axes[i]).unwrap().values[k]);
        let mut turned = Vec::new();
        for &k in &rows {
            values[k] = -values[k];
            let mut flipped = reading(k);
            let i = axes.iter().position(|a| *a == axis).unwrap();
            flipped[i] = -flipped[i];
            if angle_deg(flipped, reading(k)) > TURN_DEG {
                turned.push(k);
            }
        }
        damaged_logs.push((
            "fluxgate axis flipped, 4 s",
            axis,
            rows,
            turned,
            log.with_values(axis, values).unwrap(),
        ));
        for (name, column, rows, turned, damaged) in damaged_logs {
            let case = format!("seed {seed} ({hz} Hz), {name} from row {}", rows[0]);
            for other in attitude.iter().chain(&axes) {
                let masked = masked_rows(&damaged, other);
                if *other != column {
                    assert!(masked.is_empty(), "{case}: {other} masked at {masked:?}");
                    continue;
                }
                assert!(
                    masked.iter().all(|k| rows.contains(k)),
                    "{case}: undamaged rows masked: {masked:?}"
                );
                let missed: Vec<&usize> = turned.iter().filter(|k| !masked.contains(k)).collect();
                assert!(
                    missed.is_empty(),
                    "{case}: rows turning the field > {TURN_DEG}° not masked: {missed:?}"
                );
                let count = counts.entry(name).or_default();
                count[0] += rows.len();
                count[1] += turned.len();
                count[2] += masked.len();
            }
        }
    }
    for (name, [damaged, turned, masked]) in counts {
        println!("{name}: {damaged} rows damaged, {turned} turn the field > {TURN_DEG}°, {masked} masked");
    }
}

/// Runs the pipeline on `log` in `folder` with vector compensation on and
/// no diagnosis.
fn run_vector(folder: &std::path::Path, log: &FlightLog, name: &str) -> magcomp::pipeline::FlightRun {
    let input = folder.join(format!("{name}.csv"));
    write_flight_log(log, &input).unwrap();
    let mut job = FlightJob::new(&input);
    job.date = FlightDate::parse("2026-06-15");
    let mut settings = common::plain();
    settings.vector.enabled = true;
    magcomp::pipeline::run(&job, &settings, &folder.join(format!("{name}_c.csv"))).unwrap()
}

#[test]
fn no_vector_value_turned_by_an_attitude_glitch_is_written_unflagged() {
    // Clean plans drawn at random, shortened to two survey lines, with
    // vector compensation on. Each glitch the rate screen lets through (a
    // roll or heading step on one row, pitch read as zero on five rows
    // where the aircraft pitches) may change the north-east-down vector
    // written on an unflagged row by no more than a 3° turn of the field
    // would; the clean run is the measure. `MAGCOMP_GLITCH_FLIGHTS=N`
    // flies N plans instead of 2.
    const TURN_DEG: f64 = 3.0;
    let flights = flights_asked(2);
    let draws = common::splitmix64(0x5EED_0070_0003, 8 * flights);
    let mut next = draws.into_iter();
    let folder = tempfile::tempdir().unwrap();
    let mut worst: BTreeMap<&str, (f64, usize)> = BTreeMap::new();
    for flight in 0..flights {
        let seed = next.next().unwrap() % 1_000;
        let mut raw = common::clean_plan(seed);
        raw.survey.line_count = raw.survey.line_count.min(2);
        raw.survey.tie_count = 0;
        let log = simulate(&Scenario::try_from(raw).unwrap()).unwrap().log;
        let hz = 1.0 / log.median_interval_s();
        let clean = run_vector(folder.path(), &log, &format!("clean_{flight}"));
        assert_eq!(
            clean.compensation.vectors.len(),
            1,
            "seed {seed}: {:?}",
            clean.result.warnings
        );
        let reference = &clean.compensation.vectors[0].ned_nt;
        let margin = 10.0 * hz;
        let row = |draw: u64| (margin as u64 + draw % (log.len() as u64 - 3 * margin as u64)) as usize;
        let pitch = &log.channel("ins_pitch").unwrap().values;
        let pitched: Vec<usize> = (margin as usize..log.len() - 3 * margin as usize)
            .filter(|&k| pitch[k].abs() > 3.0)
            .collect();
        let cases: [(&str, &str, usize, f64); 3] = [
            ("roll +17°, one row", "ins_roll", 1, 17.0),
            ("heading +15°, one row", "ins_yaw", 1, 15.0),
            ("pitch read as zero, five rows", "ins_pitch", 5, f64::NAN),
        ];
        for (name, column, length, change) in cases {
            let start = match (change.is_nan(), pitched.len()) {
                (true, n) if n > 0 => pitched[(next.next().unwrap() % n as u64) as usize],
                _ => row(next.next().unwrap()),
            };
            let mut values = log.channel(column).unwrap().values.clone();
            for value in &mut values[start..start + length] {
                *value = if change.is_nan() { 0.0 } else { *value + change };
            }
            let damaged = log.with_values(column, values).unwrap();
            let dirty = run_vector(folder.path(), &damaged, &format!("{flight}_{column}"));
            assert_eq!(dirty.compensation.vectors.len(), 1, "seed {seed}, {name}");
            let written = &dirty.compensation.vectors[0].ned_nt;
            let flags = &dirty.compensation.flags;
            let (mut turned, mut largest) = (0, 0.0f64);
            for k in 0..log.len() {
                let field = (0..3).map(|i| reference[i][k].powi(2)).sum::<f64>().sqrt();
                let change = (0..3)
                    .map(|i| (written[i][k] - reference[i][k]).abs())
                    .fold(0.0, f64::max);
                if !field.is_finite() || !change.is_finite() || !flags[k].is_empty() {
                    turned += usize::from((start..start + length).contains(&k));
                    continue;
                }
                let allowed = field * TURN_DEG.to_radians().sin();
                assert!(
                    change <= allowed,
                    "seed {seed} ({hz} Hz), {name} from row {start}: row {k} written unflagged {change:.0} nT off \
                     (a {TURN_DEG}° turn is {allowed:.0} nT)"
                );
                largest = largest.max(change);
            }
            let entry = worst.entry(name).or_default();
            entry.0 = entry.0.max(largest);
            entry.1 += turned;
        }
    }
    for (name, (largest, missing)) in worst {
        println!(
            "{name}: largest change on an unflagged row {largest:.1} nT; damaged rows missing or flagged {missing}"
        );
    }
}
