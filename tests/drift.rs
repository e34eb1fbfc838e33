//! Drift between calibrations: one aircraft flown on two days, through
//! two different random boxes at two different places. An unchanged
//! aircraft is called steady; one whose permanent field at a sensor
//! changed between the flights is called changed on that sensor, and
//! the change it states matches the one made. Over 40 seeds
//! (`MAGCOMP_DRIFT_SEEDS=40`): no false alarm in 80 unchanged
//! comparisons, every one of 40 moved wing fields flagged (the smallest
//! T² 1.8 times its limit), the largest unchanged statistic 0.92 of its
//! limit.

mod common;

use std::path::Path;

use magcomp::campaign::drift::{compare, Calibration, Verdict};
use magcomp::config::FlightJob;
use magcomp::formats::write_flight_log;
use magcomp::ingest::flight_date::FlightDate;
use magcomp::simulate::random::Random;
use magcomp::simulate::scenario::{RawScenario, Scenario};
use magcomp::simulate::simulate;
use magcomp::simulate::truth::Truth;

/// A random box and site for `seed`, with a tail and a wing magnetometer.
fn raw_scenario(seed: u64) -> RawScenario {
    let mut draw = Random::new(seed).fork("drift test flight");
    let opening = common::random_box(seed, &mut draw);
    let text = format!(
        r#"
        {opening}
        line_count = 1
        line_length_m = 4000.0
        {}
        "#,
        common::TAIL_AND_WING
    );
    toml::from_str(&text).unwrap()
}

/// Flies `raw`, compensates it, and returns each channel's model as the
/// campaign summary reads it from the model JSON, and the truth.
fn fly(folder: &Path, raw: RawScenario, name: &str) -> (Vec<Calibration>, Truth) {
    let date = raw.date.clone();
    let simulated = simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let input = folder.join(format!("{name}.csv"));
    write_flight_log(&simulated.log, &input).unwrap();
    let mut job = FlightJob::new(&input);
    job.date = FlightDate::parse(&date);
    let run = magcomp::pipeline::run(&job, &common::plain(), &folder.join(format!("{name}_c.csv"))).unwrap();
    let calibrations = (run.result.models.iter())
        .map(|model| Calibration::from_model_json(&serde_json::to_value(model).unwrap()))
        .collect();
    (calibrations, simulated.truth)
}

/// The later flight of the aircraft flown in `earlier`: another seed's
/// box and site, the same aircraft field at every sensor.
fn same_aircraft(seed: u64, earlier: &Truth) -> RawScenario {
    let mut raw = raw_scenario(seed);
    raw.date = "2026-09-02".into();
    for sensor in &mut raw.scalar {
        let truth = earlier.sensors.iter().find(|s| s.channel == sensor.name).unwrap();
        sensor.aircraft = Some(truth.aircraft.clone());
    }
    for fluxgate in &mut raw.fluxgate {
        let truth = earlier.fluxgates.iter().find(|f| f.sensor == fluxgate.name).unwrap();
        fluxgate.aircraft = Some(truth.aircraft.clone());
    }
    raw
}

/// Seeds from `MAGCOMP_DRIFT_SEEDS=N` (the first N), six by default.
fn seeds() -> std::ops::Range<u64> {
    let n = std::env::var("MAGCOMP_DRIFT_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(6);
    300..300 + n
}

/// The permanent field at the wing sensor moved by this, nT, body axes.
const MOVED_NT: [f64; 3] = [4.0, -3.0, 2.0];

#[test]
fn an_unchanged_aircraft_is_steady_and_a_moved_permanent_field_is_flagged() {
    let folder = tempfile::tempdir().unwrap();
    let mut false_alarms = Vec::new();
    let mut missed = Vec::new();
    for seed in seeds() {
        let (before, truth) = fly(folder.path(), raw_scenario(seed), &format!("before_{seed}"));
        let (steady, _) = fly(
            folder.path(),
            same_aircraft(seed + 1000, &truth),
            &format!("steady_{seed}"),
        );
        let mut moved = same_aircraft(seed + 1000, &truth);
        let wing = moved.scalar.iter_mut().find(|s| s.name == "mag_2_uc").unwrap();
        let field = wing.aircraft.as_mut().unwrap();
        for (axis, change) in MOVED_NT.iter().enumerate() {
            field.permanent_nt[axis] += change;
        }
        let (changed, _) = fly(folder.path(), moved, &format!("moved_{seed}"));
        for (a, (b, c)) in before.iter().zip(steady.iter().zip(&changed)) {
            let unchanged = compare(a, b);
            let after_move = compare(a, c);
            println!(
                "seed {seed} {}: unchanged: ratio {:.2} (limit {:.2}), T² {:.2}; moved: ratio {:.2}, T² {:.2} (limit {:.2})",
                a.channel,
                unchanged.ratio,
                unchanged.limit,
                unchanged.permanent_t2,
                after_move.ratio,
                after_move.permanent_t2,
                after_move.permanent_limit
            );
            assert_ne!(unchanged.verdict, Verdict::Unknown, "{}", unchanged.note);
            if unchanged.verdict == Verdict::Changed {
                false_alarms.push(format!("seed {seed} {}: {}", a.channel, unchanged.describe()));
            }
            let expect_change = a.channel == "mag_2_uc";
            if (after_move.verdict == Verdict::Changed) != expect_change {
                missed.push(format!("seed {seed} {}: {}", a.channel, after_move.describe()));
            }
            if expect_change {
                // The stated change of the permanent field is the one made,
                // within four of its sigmas and 1 nT (the spread between
                // boxes has a heavier tail than a Gaussian's: over 40 seeds
                // 2 of 120 axes lay beyond three sigmas, none beyond four).
                let (change, sigma) = after_move.permanent_change_nt.unwrap();
                for axis in 0..3 {
                    let off = (change[axis] - MOVED_NT[axis]).abs();
                    if off >= 4.0 * sigma[axis] + 1.0 {
                        missed.push(format!(
                            "seed {seed}: axis {axis}: stated {:.2} ± {:.2} nT against {:.2} nT made",
                            change[axis], sigma[axis], MOVED_NT[axis]
                        ));
                    }
                }
            }
        }
    }
    assert!(
        false_alarms.is_empty(),
        "an unchanged aircraft flagged:\n{}",
        false_alarms.join("\n")
    );
    assert!(
        missed.is_empty(),
        "verdicts wrong after the move:\n{}",
        missed.join("\n")
    );
}

/// The whole path a user takes: three flights of one aircraft in a
/// campaign manifest, `magcomp run` with the default settings (diagnosis
/// applied, vector compensation on), then `magcomp summarize`. The wing
/// sensor's permanent field moves before the third flight:
/// `campaign_drift.csv` calls the first two steady and the move changed
/// on the wing channel only, stdout warns of it, and the page shows it.
#[test]
fn summarize_flags_the_moved_installation_in_a_campaign() {
    let folder = tempfile::tempdir().unwrap();
    let root = folder.path();
    let seed = 307;
    let first = simulate(&Scenario::try_from(raw_scenario(seed)).unwrap()).unwrap();
    write_flight_log(&first.log, &root.join("june01.csv")).unwrap();
    let second = simulate(&Scenario::try_from(same_aircraft(seed + 1000, &first.truth)).unwrap()).unwrap();
    write_flight_log(&second.log, &root.join("june10.csv")).unwrap();
    let mut moved = same_aircraft(seed + 2000, &first.truth);
    let wing = moved.scalar.iter_mut().find(|s| s.name == "mag_2_uc").unwrap();
    for (axis, change) in MOVED_NT.iter().enumerate() {
        wing.aircraft.as_mut().unwrap().permanent_nt[axis] += change;
    }
    let third = simulate(&Scenario::try_from(moved).unwrap()).unwrap();
    write_flight_log(&third.log, &root.join("june20.csv")).unwrap();
    std::fs::write(
        root.join("manifest.csv"),
        "input,aircraft,date\n\
         june20.csv,C-FMAG,2026-06-20\n\
         june01.csv,C-FMAG,2026-06-01\n\
         june10.csv,C-FMAG,2026-06-10\n",
    )
    .unwrap();
    std::fs::write(
        root.join("pipeline.toml"),
        "[output]\ndirectory = \"out\"\n\n[campaign]\nmanifest = \"manifest.csv\"\n",
    )
    .unwrap();
    let magcomp = |args: &[&str]| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_magcomp"));
        command.current_dir(root).args(args);
        for variable in magcomp::campaign::SCHEDULER_INDEX_VARIABLES {
            command.env_remove(variable);
        }
        let output = command.output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
        assert!(output.status.success(), "magcomp {args:?} failed: {stderr}");
        String::from_utf8_lossy(&output.stdout).into_owned()
    };
    magcomp(&["run", "pipeline.toml"]);
    let stdout = magcomp(&["summarize", "out"]);
    let table = std::fs::read_to_string(root.join("out/campaign_drift.csv")).unwrap();
    println!("{stdout}\n{table}");
    let mut reader = csv::Reader::from_reader(table.as_bytes());
    let header = reader.headers().unwrap().clone();
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
    // Two channels, two consecutive pairs, in date order.
    assert_eq!(rows.len(), 4, "{table}");
    for row in &rows {
        let pair = (&row[column("flight_before")], &row[column("flight_after")]);
        assert!(pair == ("june01", "june10") || pair == ("june10", "june20"), "{pair:?}");
        let expected = match (pair.1, &row[column("channel")]) {
            ("june20", "mag_2_uc") => "changed",
            _ => "steady",
        };
        assert_eq!(&row[column("verdict")], expected, "{table}");
        assert!(!row[column("fom_before_flight_nt")].is_empty() && !row[column("fom_after_flight_nt")].is_empty());
    }
    let moved_row = rows.iter().find(|r| &r[column("verdict")] == "changed").unwrap();
    for (axis, name) in ["x", "y", "z"].iter().enumerate() {
        let change: f64 = moved_row[column(&format!("permanent_change_{name}_nt"))]
            .parse()
            .unwrap();
        let sigma: f64 = moved_row[column(&format!("permanent_sigma_{name}_nt"))]
            .parse()
            .unwrap();
        assert!(
            (change - MOVED_NT[axis]).abs() < 4.0 * sigma + 1.0,
            "{name}: {change} ± {sigma} against {}",
            MOVED_NT[axis]
        );
    }
    assert!(
        stdout.contains("warning: installation changed: C-FMAG, mag_2_uc: june10 → june20"),
        "{stdout}"
    );
    let warnings = stdout
        .lines()
        .filter(|l| l.starts_with("  warning: installation changed"))
        .count();
    assert_eq!(warnings, 1, "{stdout}");
    let page = std::fs::read_to_string(root.join("out/campaign_summary.html")).unwrap();
    assert!(page.contains("Drift between calibrations") && page.contains("changed"));
}
