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
