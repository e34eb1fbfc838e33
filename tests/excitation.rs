//! The excitation analysis and the manoeuvre advice
//! (`magcomp::model::excitation`) on flight plans drawn at random: for
//! each seed a box (four headings 90° apart, random site, amplitudes and
//! rates; `common::random_box`) flown whole, and flown again with one
//! manoeuvre, drawn at random, left out (even seeds) or swung at a tenth
//! to a quarter of its amplitude (odd seeds).
//!
//! What is judged:
//! - the advice names the manoeuvre left out or weakened first, as a gap
//!   in the box, in at least 9 of 10 seeds, and flying it lowers the
//!   predicted survey uncertainty, and the run warns of it;
//! - a whole box has no gap (at least 9 of 10 seeds);
//! - the coefficients the analysis newly calls poorly pinned when a
//!   manoeuvre is missing are, by the fit's own blocked jackknife (an
//!   estimate that knows nothing of the analysis), less certain than with
//!   the whole box: their jackknife spread grows with the omission in at
//!   least three quarters of the cases.

mod common;

use magcomp::calibration::windows::ManoeuvreKind;
use magcomp::config::{FlightJob, Settings};
use magcomp::diagnose::ApplyDiagnosis;
use magcomp::formats::write_flight_log;
use magcomp::ingest::flight_date::FlightDate;
use magcomp::model::FittedModel;
use magcomp::simulate::random::Random;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::simulate;

/// A flight plan drawn from `seed`, with `change` added to its
/// `[calibration]` table.
fn plan(seed: u64, change: &str) -> RawScenario {
    let mut draw = Random::new(seed).fork("excitation test flight");
    let opening = common::random_box(seed, &mut draw).replace("[survey]", &format!("{change}\n        [survey]"));
    let text = format!(
        r#"
        {opening}
        line_count = 2
        line_length_m = 5000.0
        [[scalar]]
        name = "mag_1_uc"
        location = "tail"
        [[fluxgate]]
        name = "flux_a"
        "#
    );
    toml::from_str(&text).unwrap()
}

/// The plan flown and fitted by the pipeline (no diagnosis, no vector
/// compensation): the model of `mag_1_uc` and the run's warnings.
fn fitted(folder: &std::path::Path, name: &str, raw: RawScenario) -> (FittedModel, Vec<String>) {
    fitted_on(folder, name, raw, false)
}

/// [`fitted`]; with `given_windows`, on the simulation's own manoeuvre
/// windows, labelled with kind and heading (as a DETECT.json or a window
/// list would give them), instead of detected ones.
fn fitted_on(
    folder: &std::path::Path,
    name: &str,
    raw: RawScenario,
    given_windows: bool,
) -> (FittedModel, Vec<String>) {
    let simulated = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let input = folder.join(format!("{name}.csv"));
    write_flight_log(&simulated.log, &input).unwrap();
    let mut settings = Settings::default();
    settings.diagnose.apply = ApplyDiagnosis::Never;
    settings.vector.enabled = false;
    let mut job = FlightJob::new(&input);
    job.date = FlightDate::parse("2026-06-15");
    if given_windows {
        job.windows = simulated.truth.calibration_windows(settings.detect.window_margin_s);
    }
    let run = magcomp::pipeline::run(&job, &settings, &folder.join(format!("{name}_c.csv"))).unwrap();
    let warnings = run.result.warnings.iter().map(ToString::to_string).collect();
    (run.result.models.into_iter().next().unwrap(), warnings)
}

/// The blocked jackknife's standard deviation of each coefficient.
fn jackknife_spread(model: &FittedModel) -> Vec<f64> {
    let deviations = &model.solution.jackknife;
    (0..model.coefficients.len())
        .map(|j| deviations.iter().map(|d| d[j] * d[j]).sum::<f64>().sqrt())
        .collect()
}

#[test]
fn the_advice_names_a_manoeuvre_left_out_or_weakened_first() {
    let folder = tempfile::tempdir().unwrap();
    let seeds = 1..11u64;
    let (mut named, mut clean, mut grew, mut flagged) = (0, 0, 0, 0);
    for seed in seeds.clone() {
        let mut draw = Random::new(seed).fork("excitation test change");
        let heading = plan(seed, "").calibration.headings_deg[(draw.uniform(0.0, 4.0) as usize).min(3)];
        let (kind, kind_name) = [
            (ManoeuvreKind::Pitch, "pitch"),
            (ManoeuvreKind::Roll, "roll"),
            (ManoeuvreKind::Yaw, "yaw"),
        ][(draw.uniform(0.0, 3.0) as usize).min(2)];
        let change = match seed % 2 {
            0 => format!("omit = [\"{kind_name}@{heading}\"]"),
            _ => format!("weaken = [\"{kind_name}@{heading}={:.2}\"]", draw.uniform(0.1, 0.25)),
        };
        let (whole, _) = fitted(folder.path(), &format!("whole_{seed}"), plan(seed, ""));
        let (changed, warnings) = fitted(folder.path(), &format!("changed_{seed}"), plan(seed, &change));
        let analysis = changed.excitation.as_ref().expect("four headed windows: an analysis");
        let first = &analysis.additions[0];
        let hit = first.kind == kind && (first.heading_deg - heading).abs() < 1.0 && first.gap;
        println!(
            "seed {seed} ({change}): first advice {} (gap {}, survey uncertainty {:.4} → {:.4} nT)",
            first.label(),
            first.gap,
            analysis.survey_sigma_nt,
            first.survey_sigma_nt
        );
        for line in &analysis.summary {
            println!("    {line}");
        }
        if hit {
            named += 1;
            assert!(
                first.survey_sigma_nt < analysis.survey_sigma_nt,
                "seed {seed}: flying the gap lowers the predicted survey uncertainty"
            );
            assert!(
                analysis.summary.iter().any(|l| l.contains(&first.label())),
                "seed {seed}: the summary names the gap"
            );
            assert!(
                warnings
                    .iter()
                    .any(|w| w.starts_with("mag_1_uc: The box's") && w.contains(&first.label())),
                "seed {seed}: the gap is a warning on stdout: {warnings:?}"
            );
        }
        let whole_analysis = whole.excitation.as_ref().expect("an analysis of the whole box");
        let gaps: Vec<String> = whole_analysis
            .additions
            .iter()
            .filter(|c| c.gap)
            .map(|c| c.label())
            .collect();
        println!("    whole box: gaps {gaps:?}");
        if gaps.is_empty() {
            clean += 1;
        }
        // Coefficients newly poorly pinned: does the jackknife agree?
        let (before, after) = (jackknife_spread(&whole), jackknife_spread(&changed));
        for (j, term) in analysis.terms.iter().enumerate() {
            if term.poorly_pinned && !whole_analysis.terms[j].poorly_pinned {
                flagged += 1;
                let ratio = after[j] / before[j];
                println!(
                    "    {} newly poorly pinned (inflation {:.1} against {:.1}): jackknife spread ×{ratio:.2}",
                    term.term, term.inflation, whole_analysis.terms[j].inflation
                );
                if ratio > 1.0 {
                    grew += 1;
                }
            }
        }
    }
    let count = seeds.count();
    println!("gap named first in {named} of {count}; whole boxes without a gap {clean} of {count}; newly poorly pinned coefficients whose jackknife spread grew: {grew} of {flagged}");
    assert!(
        named * 10 >= count * 9,
        "the gap is named first in {named} of {count} seeds"
    );
    assert!(clean * 10 >= count * 9, "whole boxes without a gap: {clean} of {count}");
    assert!(flagged >= 5, "omissions leave coefficients poorly pinned: {flagged}");
    assert!(grew * 4 >= flagged * 3, "the jackknife agrees on {grew} of {flagged}");
}

/// A manoeuvre swung at a tenth to a quarter of its amplitude, given as a
/// labelled window (the detector drops such weak swings, so the windows
/// are the simulation's own, as a DETECT.json would give them): the
/// analysis calls it a gap although it was flown, says how much of a
/// typical one's excitation it had, advises flying it first, and the run
/// warns; in at least 9 of 10 random plans.
#[test]
fn a_weak_manoeuvre_among_the_windows_is_a_gap() {
    let folder = tempfile::tempdir().unwrap();
    let seeds = 21..31u64;
    let mut named = 0;
    for seed in seeds.clone() {
        let mut draw = Random::new(seed).fork("excitation test weakening");
        let heading = plan(seed, "").calibration.headings_deg[draw.integer(0, 3)];
        let kind = [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw][draw.integer(0, 2)];
        let fraction = draw.uniform(0.1, 0.25);
        let change = format!("weaken = [\"{}@{heading}={fraction:.2}\"]", kind.name());
        let (model, warnings) = fitted_on(folder.path(), &format!("weak_{seed}"), plan(seed, &change), true);
        assert!(
            (model.windows.iter()).any(|w| w.window.kind == Some(kind)
                && w.window
                    .heading_deg
                    .is_some_and(|h| magcomp::calibration::headings::same_heading(h, heading))),
            "seed {seed}: the weak manoeuvre is among the windows"
        );
        let analysis = model.excitation.as_ref().expect("labelled windows: an analysis");
        let first = &analysis.additions[0];
        println!(
            "seed {seed} ({change}): first advice {} (flown {}, gap {}, {:.1} % of a typical one's excitation)",
            first.label(),
            first.flown,
            first.gap,
            100.0 * first.excitation_flown
        );
        if first.kind == kind && magcomp::calibration::headings::same_heading(first.heading_deg, heading) && first.gap {
            named += 1;
            assert!(first.flown, "seed {seed}: the weak manoeuvre was flown");
            assert!(
                first.excitation_flown < magcomp::model::excitation::WEAK_EXCITATION,
                "seed {seed}"
            );
            let words = format!("{} was flown with", first.label());
            assert!(
                warnings.iter().any(|w| w.contains(&words)),
                "seed {seed}: the run warns that {words} …: {warnings:?}"
            );
        }
    }
    let count = seeds.count();
    println!("weak manoeuvre named first as a gap in {named} of {count}");
    assert!(named * 10 >= count * 9, "named first in {named} of {count}");
}
