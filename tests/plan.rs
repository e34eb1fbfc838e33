//! Planning a calibration before it is flown (`magcomp plan`): the
//! prediction against flights of the plan it has not seen.
//!
//! For each seed a plan is drawn at random (`common::random_box`: four
//! headings 90° apart from a random base, site, height, amplitudes and
//! sample rate; on odd seeds one manoeuvre left out), with a tail and a
//! wing magnetometer. `magcomp::plan::predict` flies it on its own
//! seeds; then four fresh flights of the same plan (other seeds) are
//! written to CSV and run through the pipeline as `compensate --plain`
//! does, manoeuvres detected. What is judged, per channel:
//! - the median FOM of the fresh flights lies within the plan's stated
//!   factor of the predicted median;
//! - so does the survey uncertainty compensate states (the excitation
//!   analysis's coefficient part with the compensated noise);
//! - so does the fresh flights' true survey-line error (against the
//!   simulation's truth, relative to the calibration level).
//!
//! A second test gives a plan a previous flight's model as its
//! installation and a survey target it misses: the additions proposed
//! meet the target when the plan is flown again with them.

mod common;

use std::path::Path;

use magcomp::config::FlightJob;
use magcomp::formats::write_flight_log;
use magcomp::ingest::flight_date::FlightDate;
use magcomp::messages::PlanWarning;
use magcomp::plan::{predict, Plan, PlanReport, STATED_FACTOR};
use magcomp::simulate::random::Random;
use magcomp::simulate::scenario::Scenario;
use magcomp::simulate::simulate;

/// One channel of a fresh flight: name, FOM after, stated survey sigma,
/// true survey error.
type Flown = (String, f64, f64, f64);

/// A random plan's TOML for `seed`, with `extra` appended.
fn plan_text(seed: u64, extra: &str) -> String {
    let mut draw = Random::new(seed).fork("plan test flight");
    let mut opening = common::random_box(seed, &mut draw);
    if seed % 2 == 1 {
        let heading: f64 = {
            let start = opening.find("headings_deg = [").unwrap() + "headings_deg = [".len();
            let end = opening[start..].find(',').unwrap() + start;
            opening[start..end].trim().parse().unwrap()
        };
        let kind = ["pitch", "roll", "yaw"][draw.integer(0, 2)];
        opening = opening.replace("[survey]", &format!("omit = [\"{kind}@{heading}\"]\n        [survey]"));
    }
    format!(
        r#"
        {opening}
        line_count = 2
        line_length_m = 6000.0
        {}
        {extra}
        "#,
        common::TAIL_AND_WING
    )
}

/// One fresh flight of `plan` with `seed`, through the pipeline with
/// detected windows: per channel, (FOM after, stated survey sigma, true
/// survey error).
fn fresh_flight(folder: &Path, plan: &Plan, seed: u64) -> Vec<Flown> {
    let mut scenario: Scenario = plan.scenario.clone();
    scenario.raw.seed = seed;
    let (simulated, run) = fly(folder, &scenario, &format!("fresh_{seed}"), None);
    let line = &run.log().channel("line").unwrap().values;
    (run.result.models.iter().zip(&run.compensation.channels))
        .map(|(model, channel)| {
            let quality = run.result.channels.iter().find(|q| q.channel == model.channel).unwrap();
            let noise = quality.white_noise_nt().unwrap();
            let stated = model
                .excitation
                .as_ref()
                .map_or(f64::NAN, |e| e.survey_sigma_nt.hypot(noise));
            let truth = simulated.truth.earth_total_nt(&model.channel).unwrap();
            let error = magcomp::plan::error_from_calibration_level(model, &channel.values, truth, line);
            (
                model.channel.clone(),
                quality.fom_after_nt.unwrap_or(f64::NAN),
                stated,
                error,
            )
        })
        .collect()
}

/// Simulates `scenario`, writes it to CSV as `<name>.csv` and runs it
/// through the pipeline as `compensate --plain [--plan plan]` does.
fn fly(
    folder: &Path,
    scenario: &Scenario,
    name: &str,
    plan: Option<&Path>,
) -> (magcomp::simulate::SimulatedFlight, magcomp::pipeline::FlightRun) {
    let simulated = simulate(scenario).unwrap();
    let input = folder.join(format!("{name}.csv"));
    write_flight_log(&simulated.log, &input).unwrap();
    let mut job = FlightJob::new(&input);
    job.date = FlightDate::parse(&scenario.raw.date);
    job.plan = plan.map(Path::to_path_buf);
    let run = magcomp::pipeline::run(&job, &common::plain(), &folder.join(format!("{name}_c.csv"))).unwrap();
    (simulated, run)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.retain(|v| v.is_finite());
    values.sort_by(f64::total_cmp);
    let n = values.len();
    assert!(n > 0, "no finite value");
    match n % 2 {
        1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

fn load(folder: &Path, name: &str, text: &str) -> Plan {
    let path = folder.join(name);
    std::fs::write(&path, text).unwrap();
    Plan::load(&path).unwrap()
}

/// Seeds from `MAGCOMP_PLAN_SEEDS=N` (the first N), four by default.
fn seeds() -> std::ops::Range<u64> {
    let n = std::env::var("MAGCOMP_PLAN_SEEDS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(4);
    1..1 + n
}

#[test]
fn the_prediction_holds_on_flights_of_the_plan_it_has_not_seen() {
    let folder = tempfile::tempdir().unwrap();
    let (mut judged, mut warned) = (0, 0);
    for seed in seeds() {
        let plan = load(
            folder.path(),
            &format!("plan_{seed}.toml"),
            &plan_text(seed, "[plan]\nrealisations = 6"),
        );
        let report: PlanReport = predict(&plan, &common::plain()).unwrap();
        assert_eq!(report.seeds.len(), 6);
        let fresh: Vec<Vec<Flown>> = (0..4)
            .map(|k| fresh_flight(folder.path(), &plan, 1000 + 10 * seed + k))
            .collect();
        for (c, predicted) in report.channels.iter().enumerate() {
            let of = |f: &dyn Fn(&Flown) -> f64| median(fresh.iter().map(|run| f(&run[c])).collect());
            let (fom, stated, error) = (of(&|r| r.1), of(&|r| r.2), of(&|r| r.3));
            println!(
                "seed {seed} {}: FOM predicted {:.3} ({:.3}–{:.3}) flown {fom:.3}; survey sigma predicted {:.4} flown {stated:.4}; true error predicted {:.4} ({:.4}–{:.4}) flown {error:.4}; uncertain in {} of 6",
                predicted.channel,
                predicted.fom_nt.median,
                predicted.fom_nt.low,
                predicted.fom_nt.high,
                predicted.survey_sigma_nt.median,
                predicted.survey_error_nt.median,
                predicted.survey_error_nt.low,
                predicted.survey_error_nt.high,
                predicted.uncertain_flights,
            );
            let within =
                |predicted: f64, flown: f64| (1.0 / STATED_FACTOR..=STATED_FACTOR).contains(&(flown / predicted));
            for (what, predicted, flown) in [
                ("FOM", predicted.fom_nt.median, fom),
                ("stated survey sigma", predicted.survey_sigma_nt.median, stated),
            ] {
                assert!(
                    within(predicted, flown),
                    "seed {seed} channel {c}: {what} predicted {predicted:.4} nT, flown {flown:.4} nT"
                );
            }
            // The true error lies in the plan's range widened by the
            // factor (its median is of a heavy-tailed few), unless the plan
            // warned that the compensation is uncertain on some of its
            // flights (a fragile box: on those the error is many times the
            // median).
            let range = predicted.survey_error_nt;
            match (range.low / STATED_FACTOR..=range.high * STATED_FACTOR).contains(&error) {
                true => judged += 1,
                false => {
                    assert!(
                        predicted.uncertain_flights > 0
                            && report.warnings.iter().any(|w| matches!(w, PlanWarning::UncertainAway { .. })
                                && w.names(&predicted.channel)),
                        "seed {seed} channel {c}: true survey error predicted {:.4} nT, flown {error:.4} nT, and the plan did not warn",
                        predicted.survey_error_nt.median
                    );
                    warned += 1;
                }
            }
        }
        // A plan that leaves a manoeuvre out says so.
        if seed % 2 == 1 {
            assert!(
                (report.warnings.iter()).any(|w| matches!(
                    w,
                    PlanWarning::Gap {
                        excitation_flown: None,
                        ..
                    }
                )),
                "seed {seed}: {:?}",
                report.warnings
            );
        }
    }
    println!("{judged} channels whose flown true error lies in the plan's range widened ×{STATED_FACTOR}, {warned} outside it on a plan that warned");
    assert!(judged >= 5, "{judged} channels within the factor");
}

#[test]
fn additions_proposed_for_a_target_meet_it_when_flown() {
    let folder = tempfile::tempdir().unwrap();
    // A previous flight of the aircraft: its model is the installation.
    let previous = load(folder.path(), "previous.toml", &plan_text(7, ""));
    let simulated = simulate(&previous.scenario).unwrap();
    let input = folder.path().join("previous.csv");
    write_flight_log(&simulated.log, &input).unwrap();
    let mut job = FlightJob::new(&input);
    job.date = FlightDate::parse(&previous.scenario.raw.date);
    let run = magcomp::pipeline::run(&job, &common::plain(), &folder.path().join("previous_c.csv")).unwrap();
    let models = serde_json::json!({"flight": "previous.csv", "models": run.result.models});
    std::fs::write(folder.path().join("previous_model.json"), models.to_string()).unwrap();

    // A three-leg plan without a roll: well above a target the full box
    // would meet.
    let mut text = plan_text(8, "");
    let start = text.find("headings_deg = [").unwrap();
    let end = text[start..].find(']').unwrap() + start + 1;
    let base: f64 = text[start + "headings_deg = [".len()..end - 1]
        .split(',')
        .next()
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    let legs = [base, base + 90.0, base + 180.0];
    text.replace_range(
        start..end,
        &format!("headings_deg = {legs:?}\n        omit = [\"roll@{}\"]", legs[1]),
    );
    let installed = format!("{text}\n[plan]\nrealisations = 6\ninstallation = \"previous_model.json\"\n");
    let untouched = predict(&load(folder.path(), "probe.toml", &installed), &common::plain()).unwrap();
    let tail = &untouched.channels[0];
    let target = 0.7 * tail.survey_sigma_nt.median;
    assert!(
        target > 1.5 * tail.noise_nt.median,
        "the target {target:.4} must lie above the noise {:.4}",
        tail.noise_nt.median
    );
    let plan_toml = format!("{installed}target_survey_sigma_nt = {target}\nmost_additions = 8\n");
    let plan = load(folder.path(), "plan.toml", &plan_toml);
    assert!(plan.installation.contains("mag_1_uc"), "{}", plan.installation);
    let report = predict(&plan, &common::plain()).unwrap();
    for line in &report.summary {
        println!("{line}");
    }
    for warning in &report.warnings {
        println!("{warning}");
    }
    let before = report.channels[0].survey_sigma_nt.median;
    assert!(before > target, "the plan already meets {target}: {before}");
    assert!(!report.additions.is_empty());
    assert_eq!(report.additions_meet_target, Some(true), "{:?}", report.additions);
    // Each manoeuvre is listed once (flown `count` times), and each
    // entry's figures include the entries before it.
    for (i, a) in report.additions.iter().enumerate() {
        let again = report.additions[i + 1..]
            .iter()
            .any(|b| b.kind == a.kind && b.heading_deg == a.heading_deg);
        assert!(!again, "listed twice: {:?}", report.additions);
    }
    // A warning is said once, naming the channels it concerns, not once
    // per channel.
    for warning in &report.warnings {
        assert_eq!(
            report.warnings.iter().filter(|w| *w == warning).count(),
            1,
            "{:?}",
            report.warnings
        );
        assert!(
            !report
                .channels
                .iter()
                .any(|c| warning.to_string().starts_with(&format!("{}: ", c.channel))),
            "a warning per channel: {warning}"
        );
    }
    // The gap (the roll left out) is among the additions.
    assert!(
        report
            .additions
            .iter()
            .any(|a| a.kind == magcomp::calibration::windows::ManoeuvreKind::Roll),
        "{:?}",
        report.additions
    );
    // Flown with the additions, the plan meets the target on the tail
    // sensor within the stated factor, and is better than without.
    let after = report.with_additions[0].survey_sigma_nt.median;
    println!("mag_1_uc: survey sigma {before:.4} nT; with the additions predicted {:.4}, flown {after:.4}; target {target:.4}", report.additions.last().unwrap().survey_sigma_nt["mag_1_uc"]);
    assert!(after < before, "{after} not below {before}");
    assert!(
        after <= target * 1.25,
        "flown with the additions: {after:.4} against the target {target:.4}"
    );
}

/// A plan that cannot be flown or read gets an error naming the table,
/// the value and what to give; the command never writes over its input.
#[test]
fn a_bad_plan_is_refused_with_what_to_fix() {
    let folder = tempfile::tempdir().unwrap();
    let refused = |name: &str, text: &str, expected: &str| {
        let path = folder.path().join(name);
        std::fs::write(&path, text).unwrap();
        let message = Plan::load(&path).unwrap_err().to_string();
        assert!(message.contains(expected), "{name}: {message}");
    };
    refused(
        "zero.toml",
        "[plan]\nrealisations = 0\n",
        "realisations = 0: give 1 to 64",
    );
    refused("typo.toml", "[plan]\nrealisation = 4\n", "unknown field `realisation`");
    refused(
        "target.toml",
        "[plan]\ntarget_fom_nt = -1.0\n",
        "target_fom_nt: give a positive number",
    );
    refused(
        "nobox.toml",
        "[calibration]\nrepeats = 0\n",
        "a plan needs a calibration box",
    );
    refused(
        "extra.toml",
        "[calibration]\nheadings_deg = [0.0, 90.0]\nextra = [\"roll@45\"]\n",
        "45 is not one of headings_deg",
    );
    std::fs::write(folder.path().join("not_a_model.json"), "{\"flight\": \"x.csv\"}").unwrap();
    refused(
        "installation.toml",
        "[plan]\ninstallation = \"not_a_model.json\"\n",
        "not a model JSON written by compensate --model: it has no \"models\" list",
    );
    // Written over its own input: refused, the plan unchanged.
    let plan = folder.path().join("plan.toml");
    std::fs::write(&plan, "[plan]\nrealisations = 1\n").unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["plan", plan.to_str().unwrap(), "--out", plan.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!output.status.success());
    assert_eq!(std::fs::read_to_string(&plan).unwrap(), "[plan]\nrealisations = 1\n");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.starts_with("magcomp: error:"), "{stderr}");
}

/// Seeds from `MAGCOMP_PLAN_COMPARE_SEEDS=N` (N even seeds), three by
/// default: plans that leave no manoeuvre out.
fn compare_seeds() -> Vec<u64> {
    let n = std::env::var("MAGCOMP_PLAN_COMPARE_SEEDS")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(3);
    (1..=n).map(|k| 2 * k).collect()
}

/// `scenario` with its raw tables changed by `change`, checked again.
fn changed(scenario: &Scenario, change: impl FnOnce(&mut magcomp::simulate::scenario::RawScenario)) -> Scenario {
    let mut raw = scenario.raw.clone();
    change(&mut raw);
    Scenario::try_from(raw).unwrap()
}

/// A flight flown to a plan, compensated with its PLAN_REPORT.json
/// (`compensate --plan`), on random plans:
/// - flown as planned, its figures hold (inside the plan's simulated
///   range widened by the stated factor) and no manoeuvre is missing;
/// - flown with one planned manoeuvre left out, exactly that manoeuvre is
///   named and warned of;
/// - flown with the tail magnetometer thirty times noisier than planned,
///   its FOM and stated survey uncertainty are worse than planned and
///   the run warns of it, while the wing magnetometer still holds.
#[test]
fn a_flight_is_set_against_the_plan_it_was_flown_to() {
    use magcomp::quality::against_plan::Verdict;
    let folder = tempfile::tempdir().unwrap();
    let (mut figures, mut held) = (0, 0);
    for seed in compare_seeds() {
        let plan = load(
            folder.path(),
            &format!("compare_{seed}.toml"),
            &plan_text(seed, "[plan]\nrealisations = 6"),
        );
        let report = predict(&plan, &common::plain()).unwrap();
        let report_path = folder.path().join(format!("compare_{seed}_report.json"));
        magcomp::formats::write_json(&report_path, "the plan report", &report).unwrap();
        assert_eq!(report.planned_manoeuvres.len(), report.manoeuvres);

        // As planned.
        let mut scenario = plan.scenario.clone();
        scenario.raw.seed = 2000 + seed;
        let (_, run) = fly(
            folder.path(),
            &scenario,
            &format!("as_planned_{seed}"),
            Some(&report_path),
        );
        let comparison = run.result.plan.as_ref().expect("a comparison with the plan");
        assert!(
            comparison.missing.is_empty() && comparison.unplanned.is_empty(),
            "seed {seed}: missing {:?}, unplanned {:?}",
            comparison.missing,
            comparison.unplanned
        );
        assert_eq!(comparison.channels.len(), 2);
        for channel in &comparison.channels {
            for figure in &channel.figures {
                println!(
                    "seed {seed} {} {}: planned {:?} ({:?}–{:?}) flown {:?}: {:?}",
                    channel.channel,
                    figure.figure,
                    figure.planned_nt,
                    figure.planned_low_nt,
                    figure.planned_high_nt,
                    figure.flown_nt,
                    figure.verdict
                );
                assert_ne!(figure.verdict, Verdict::NotCompared, "seed {seed}: {figure:?}");
                figures += 1;
                held += usize::from(figure.verdict == Verdict::AsPlanned);
            }
        }

        // One planned manoeuvre left out.
        let mut draw = Random::new(seed).fork("left out of the flown plan");
        let leg = scenario.raw.calibration.headings_deg[draw.integer(0, 3)];
        let kind = ["pitch", "roll", "yaw"][draw.integer(0, 2)];
        let lacking = changed(&scenario, |raw| raw.calibration.omit.push(format!("{kind}@{leg}")));
        let (_, run) = fly(folder.path(), &lacking, &format!("lacking_{seed}"), Some(&report_path));
        let comparison = run.result.plan.as_ref().unwrap();
        let expected = format!("{kind} on heading {:.0}°", leg.rem_euclid(360.0));
        assert_eq!(comparison.missing, vec![expected.clone()], "seed {seed}");
        assert!(
            run.result
                .warnings
                .iter()
                .map(ToString::to_string)
                .any(|w| w.contains("the flight lacks 1 of the plan's") && w.contains(&expected)),
            "seed {seed}: {:?}",
            run.result.warnings
        );

        // The tail magnetometer far noisier than the plan's.
        let noisy = changed(&scenario, |raw| raw.scalar[0].noise_nt *= 30.0);
        let (_, run) = fly(folder.path(), &noisy, &format!("noisy_{seed}"), Some(&report_path));
        let comparison = run.result.plan.as_ref().unwrap();
        let verdicts =
            |c: usize| -> Vec<Verdict> { comparison.channels[c].figures.iter().map(|f| f.verdict).collect() };
        let flown = |c: usize| -> Vec<String> {
            (comparison.channels[c].figures.iter())
                .map(|f| {
                    format!(
                        "{:.4}/{:.4}",
                        f.flown_nt.unwrap_or(f64::NAN),
                        f.planned_high_nt.unwrap_or(f64::NAN)
                    )
                })
                .collect()
        };
        println!(
            "seed {seed} noisy tail: {:?} (flown/planned high {:?}), wing: {:?}",
            verdicts(0),
            flown(0),
            verdicts(1)
        );
        assert_eq!(verdicts(0)[..2], [Verdict::Worse, Verdict::Worse], "seed {seed}");
        assert!(
            run.result
                .warnings
                .iter()
                .map(ToString::to_string)
                .any(|w| w.starts_with("mag_1_uc: FOM") && w.contains("worse than planned")),
            "seed {seed}: {:?}",
            run.result.warnings
        );
        assert!(
            !verdicts(1).contains(&Verdict::Worse),
            "seed {seed}: the wing {:?}",
            verdicts(1)
        );
        if seed == 2 {
            the_command_line_sets_the_flight_against_the_plan(folder.path(), &report_path);
        }
    }
    println!("{held} of {figures} figures of flights flown as planned hold");
    assert!(held as f64 >= 0.85 * figures as f64, "{held} of {figures} figures held");
}

/// `compensate --plan` on the noisy flight of seed 2: the warning on
/// stdout, the `plan` section in the quality JSON and the report page;
/// a file that is not a plan report is refused before any work.
fn the_command_line_sets_the_flight_against_the_plan(folder: &Path, report: &Path) {
    let magcomp = |args: &[&std::ffi::OsStr]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_magcomp"))
            .current_dir(folder)
            .args(args)
            .output()
            .unwrap()
    };
    let os = |s: &str| std::ffi::OsString::from(s);
    let output = magcomp(&[
        &os("compensate"),
        &os("noisy_2.csv"),
        &os("--out"),
        &os("noisy_2_cli.csv"),
        &os("--report"),
        &os("noisy_2_quality.json"),
        &os("--plain"),
        &os("--plan"),
        report.as_os_str(),
    ]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    // Exit 3 where a channel's verdict is FAIL, its outputs written.
    let expected = if stdout.contains(": FAIL") { 3 } else { 0 };
    assert_eq!(
        output.status.code(),
        Some(expected),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        stdout
            .lines()
            .any(|l| l.contains("warning: mag_1_uc: FOM") && l.contains("worse than planned")),
        "{stdout}"
    );
    let quality: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(folder.join("noisy_2_quality.json")).unwrap()).unwrap();
    let verdict = &quality["plan"]["channels"][0]["figures"][0];
    assert_eq!(verdict["figure"], "fom_nt");
    assert_eq!(verdict["verdict"], "worse");
    let page = std::fs::read_to_string(folder.join("noisy_2_cli_report.html")).unwrap();
    assert!(page.contains("Against the plan") && page.contains("worse than planned"));
    // The flight's own CSV is not a plan report.
    let output = magcomp(&[
        &os("compensate"),
        &os("noisy_2.csv"),
        &os("--out"),
        &os("refused.csv"),
        &os("--plan"),
        &os("noisy_2.csv"),
    ]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("not a PLAN_REPORT.json as `magcomp plan` writes it"),
        "{stderr}"
    );
    assert!(!folder.join("refused.csv").exists());
}
