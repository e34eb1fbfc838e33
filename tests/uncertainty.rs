//! The per-sample uncertainty of the compensated output
//! (`mag_<n>_c_sigma`) and the uncertainty warning, judged against the
//! simulator's true Earth field on flight plans drawn at random
//! (`common::paired_sensors_flight`: a tail sensor and a wing-tip,
//! nose-and-tail or stacked pair, over magnetic ground, at a random site
//! with a random box, rate and survey height).
//!
//! The column is one sigma of the compensated value relative to its level
//! over the calibration windows (the level is `level_sigma_nt`, and a
//! sensor's constant offset is seen by no calibration), so each true
//! error is taken from the calibration windows' mean error before it is
//! compared with the column. Nor does any scalar fit see the isotropic
//! part of the aircraft's induced tensor M, $k = \mathrm{tr}(M)/3$: the
//! sensor reads it as $(1 + k)|B|$, a gain on the Earth's field (the
//! default terms leave it out; `tests/earth_field.rs`). The truth each
//! error is taken from is therefore $(1 + k)|B|$: on these plans k reaches
//! a few 10⁻⁴ on the wing tips, 0.1 nT over 500 nT of anomaly. Fitted with the plain settings (no diagnosis,
//! no vector stage): on seeds 1–40 the default diagnosis changed the model
//! of 6 of 120 channels, every change on a channel wrong by more than
//! 0.1 nT either way, and the pooled coverage moved from 0.719 / 0.896 to
//! 0.722 / 0.898; the plain runs keep the test to about a minute.

mod common;

use magcomp::config::FlightJob;
use magcomp::formats::write_flight_log;
use magcomp::ingest::flight_date::FlightDate;

/// A channel whose survey lines lie more than this from the truth
/// (RMS of the error from the calibration's level) is wrong: it must
/// carry the uncertainty warning.
const WRONG_NT: f64 = 0.1;
/// A channel within this is right: it should not.
const RIGHT_NT: f64 = 0.03;

/// Seeds from `UNCERTAINTY_SEEDS=a..b`, or 1–80 (240 channels).
fn seeds() -> std::ops::Range<u64> {
    match std::env::var("UNCERTAINTY_SEEDS") {
        Ok(text) => {
            let (a, b) = text.split_once("..").expect("UNCERTAINTY_SEEDS=a..b");
            a.parse().unwrap()..b.parse().unwrap()
        }
        Err(_) => 1..81,
    }
}

/// Over every plan, the channels without the uncertainty warning have a
/// calibrated sigma column, and the warning marks the wrong channels and
/// spares the right ones:
/// - pooled over the unwarned channels, sample by sample, the fraction of
///   survey-line samples whose true error lies within ±1σ is 0.60–0.76
///   and within ±2σ 0.90–0.98. The errors are correlated along a line
///   (the model's error is smooth), so the samples are far from
///   independent: the effective count is about the number of channels,
///   whose binomial spread on 0.68 is about ±0.04 for 150 of them. The
///   fractions are pooled by sample (long lines weigh more) and the
///   count of channels is asserted (at least 100 unwarned).
/// - at least 95 % of the channels wrong by more than [`WRONG_NT`] carry
///   the warning, and at most 5 % of those right within [`RIGHT_NT`] do.
///
/// What the column leaves out, and these flights show: a channel whose
/// model misses physics (the fit's bias, not its sampling spread) can be
/// off by a level between the box and the survey that no refit on the
/// box's own windows sees; the diagnosis adds such physics where the
/// residuals show it.
#[test]
fn the_sigma_column_is_calibrated_and_the_wrong_channels_are_warned_on_random_plans() {
    let folder = tempfile::tempdir().unwrap();
    let settings = common::plain();
    let (mut samples, mut within) = (0usize, [0usize; 2]);
    let (mut unwarned, mut wrong, mut wrong_warned, mut right, mut right_warned) = (0, 0, 0, 0, 0);
    let mut missed = Vec::new();
    let mut false_alarms = Vec::new();
    for seed in seeds() {
        let (simulated, layout, _) = common::paired_sensors_flight(seed);
        let input = folder.path().join(format!("plan_{seed}.csv"));
        write_flight_log(&simulated.log, &input).unwrap();
        let mut job = FlightJob::new(&input);
        job.date = FlightDate::parse("2026-06-15");
        let run = magcomp::pipeline::run(&job, &settings, &folder.path().join(format!("plan_{seed}_c.csv"))).unwrap();
        let line = &run.log().channel("line").unwrap().values;
        assert_eq!(run.result.models.len(), 3, "seed {seed}: {:?}", run.result.warnings);
        for (model, channel) in run.result.models.iter().zip(&run.compensation.channels) {
            // What a scalar compensation can know: the Earth's field times
            // (1 + k), k the aircraft's isotropic induced part (see the
            // module's comment).
            let sensor = (simulated.truth.sensors.iter())
                .find(|s| s.channel == model.channel)
                .unwrap();
            let m = &sensor.aircraft.induced;
            let gain = 1.0 + (m[0][0] + m[1][1] + m[2][2]) / 3.0;
            let truth: Vec<f64> = sensor.earth_total_nt.iter().map(|b| gain * b).collect();
            let truth = truth.as_slice();
            let quality = run.result.channels.iter().find(|q| q.channel == model.channel).unwrap();
            let stated = quality.uncertainty.as_ref().expect("twelve windows: a jackknife");
            let warned = run.result.warnings.iter().any(|w| {
                matches!(w, magcomp::messages::Warning::UncertainAwayFromCalibration { channel, .. } if *channel == model.channel)
            });
            assert_eq!(
                warned,
                magcomp::quality::is_uncertain(quality),
                "seed {seed} {}",
                model.channel
            );
            let column = common::SigmaColumn::of(model, channel, truth, line);
            let n = column.error_nt.len();
            assert!(n > 1000, "seed {seed} {}: {n} survey samples", model.channel);
            let error = common::SigmaColumn::rms(&column.error_nt);
            let fractions = [1.0, 2.0].map(|k| column.fraction_within(k));
            println!(
                "seed {seed:2} {layout:?} {}: error from the calibration level {error:.3} nT RMS, column {:.3} nT RMS (stated {:.3}), within 1σ {:.2}, 2σ {:.2}{}",
                model.channel,
                common::SigmaColumn::rms(&column.sigma_nt),
                stated.outside_calibration_sigma_nt,
                fractions[0],
                fractions[1],
                if warned { ", warned" } else { "" }
            );
            let name = format!(
                "seed {seed} {} ({error:.3} nT, stated {:.3})",
                model.channel, stated.outside_calibration_sigma_nt
            );
            if !warned {
                unwarned += 1;
                samples += n;
                within[0] += column.within(1.0);
                within[1] += column.within(2.0);
            }
            if error > WRONG_NT {
                wrong += 1;
                wrong_warned += usize::from(warned);
                if !warned {
                    missed.push(name);
                }
            } else if error < RIGHT_NT {
                right += 1;
                right_warned += usize::from(warned);
                if warned {
                    false_alarms.push(name);
                }
            }
        }
    }
    let [one, two] = within.map(|w| w as f64 / samples as f64);
    println!("sigma column over {unwarned} unwarned channels ({samples} survey samples): within 1σ {one:.3}, within 2σ {two:.3}");
    println!("wrong (> {WRONG_NT} nT): {wrong}, {wrong_warned} warned; missed: {missed:?}");
    println!("right (< {RIGHT_NT} nT): {right}, {right_warned} warned: {false_alarms:?}");
    let everything = std::env::var("UNCERTAINTY_SEEDS").is_err();
    if everything {
        assert!(unwarned >= 100, "{unwarned} unwarned channels");
        // With MagNav.jl's 18 terms about 45 of the channels were wrong:
        // most of them had the survey's anomalies scaled by the isotropic
        // terms. The default's 16 leave 11 wrong (0.10-0.19 nT), still
        // enough that one missed warning fails the 95 % below.
        assert!(
            wrong >= 10 && right >= 80,
            "{wrong} wrong and {right} right channels: the plans test both"
        );
    }
    assert!((0.60..=0.76).contains(&one), "within one sigma: {one}");
    assert!((0.90..=0.98).contains(&two), "within two sigma: {two}");
    assert!(
        wrong_warned as f64 >= 0.95 * wrong as f64,
        "{wrong_warned} of {wrong} wrong channels warned: {missed:?}"
    );
    assert!(
        right_warned as f64 <= 0.05 * right as f64,
        "{right_warned} of {right} right channels warned: {false_alarms:?}"
    );
}
