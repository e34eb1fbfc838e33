//! Replays every sample flight of pipeline.toml and fails on drift from
//! `sample_flights/expected/<name>.json`.
//!
//! The figures: per channel the FOM before and after, the improvement
//! ratio, the survey-line error against the simulation's truth (when a
//! `<name>.truth.csv` sits beside the flight), and the fitted λ and method,
//! with plain Tolles-Lawson; and with the default (`[diagnose] apply =
//! "auto"`, run as `magcomp run` runs it: only the findings its evidence
//! rule applies) the effects applied, the FOM after and the survey-line
//! error. The guide's table of them (docs/guide/src/sample-flights.md) is
//! checked against these figures.
//! `MAGCOMP_BLESS=1 cargo test --test sample_flights` rewrites the
//! expected files (see sample_flights/regenerate.sh).
//!
//! Tolerances: the pipeline is deterministic, but the SVD and the filter
//! may round differently on another CPU's SIMD path. Figures are sums over
//! thousands of samples, so 1e-6 relative bounds that rounding by orders
//! of magnitude while catching any change of method, data or physics; λ
//! is a grid point and must match to 1e-9 relative.

mod common;

use std::path::{Path, PathBuf};

use magcomp::calibration::detect::detect_manoeuvres;
use magcomp::compensate::compensate;
use magcomp::config::Pipeline;
use magcomp::formats::read_flight_log;
use magcomp::pipeline::{choose_channels, choose_vector_sensor};
use magcomp::quality::assess_quality;
use magcomp::simulate::truth::survey_line_error_nt;
use serde::{Deserialize, Serialize};

#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct Expected {
    flight: String,
    channels: Vec<ChannelFigures>,
}

#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct ChannelFigures {
    channel: String,
    fom_before_nt: f64,
    fom_after_nt: f64,
    improvement_ratio: f64,
    survey_line_error_nt: Option<f64>,
    lambda: Option<f64>,
    method: String,
    /// With the default `[diagnose] apply = "auto"`: the effects applied to
    /// this channel, its FOM after and its survey-line error.
    default: DefaultFigures,
}

#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct DefaultFigures {
    effects: Vec<String>,
    fom_after_nt: f64,
    survey_line_error_nt: Option<f64>,
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Column `name` of a truth CSV.
fn truth_column(path: &Path, name: &str) -> Vec<f64> {
    let mut reader = csv::Reader::from_path(path).unwrap();
    let index = reader.headers().unwrap().iter().position(|h| h == name).unwrap();
    reader
        .records()
        .map(|r| r.unwrap()[index].parse::<f64>().unwrap())
        .collect()
}

fn replay(pipeline: &Pipeline, job: &magcomp::config::FlightJob) -> Expected {
    let log = read_flight_log(&job.input, &pipeline.settings.ingest).unwrap();
    let sensor = choose_vector_sensor(&log, job.vector.as_deref()).unwrap();
    let channels = choose_channels(&log, job.channels.as_deref()).unwrap();
    let windows = if job.windows.is_empty() {
        let detection = detect_manoeuvres(&log, &pipeline.settings.detect).unwrap();
        detection.calibration_windows(pipeline.settings.detect.window_margin_s)
    } else {
        job.windows.clone()
    };
    let models = common::fit_channels(&log, &sensor, (&channels, &windows), pipeline, &Default::default());
    let compensated = compensate(&log, &models, pipeline.settings.level).unwrap();
    // The default, as `run` makes it: the diagnosis, and only the findings
    // its evidence rule applies.
    let folder = tempfile::tempdir().unwrap();
    let run = magcomp::pipeline::run(job, &pipeline.settings, &folder.path().join("out.csv")).unwrap();
    let truth = job.input.with_extension("truth.csv");
    let line_error = |channel: &str, values: &[f64]| {
        truth.exists().then(|| {
            let earth = truth_column(&truth, &format!("{channel}_earth_nt"));
            survey_line_error_nt(values, &earth, &log.channel("line").unwrap().values)
        })
    };
    let figures = models
        .iter()
        .zip(&compensated.channels)
        .map(|(model, channel)| {
            let quality = assess_quality(&log, model, channel);
            let plain_line_error = line_error(&model.channel, &channel.values);
            let default_quality = (run.result.channels.iter())
                .find(|q| q.channel == model.channel)
                .unwrap();
            let default_values = &(run.compensation.channels.iter())
                .find(|c| c.channel == model.channel)
                .unwrap()
                .values;
            let default = DefaultFigures {
                effects: (run.result.diagnosis.iter())
                    .flat_map(|d| d.findings.iter())
                    .filter(|f| f.channel == model.channel && f.effect.name() != "unexplained")
                    .filter(|f| f.not_applied.is_none())
                    .map(|f| match &f.source {
                        Some(source) => format!("{} ({source})", f.effect.name()),
                        None => f.effect.name().to_string(),
                    })
                    .collect(),
                fom_after_nt: default_quality.fom_after_nt.unwrap_or(f64::NAN),
                survey_line_error_nt: line_error(&model.channel, default_values),
            };
            ChannelFigures {
                channel: model.channel.clone(),
                fom_before_nt: quality.fom_before_nt.unwrap_or(f64::NAN),
                fom_after_nt: quality.fom_after_nt.unwrap_or(f64::NAN),
                improvement_ratio: quality.improvement_ratio,
                survey_line_error_nt: plain_line_error,
                lambda: model.solution.lambda,
                method: format!("{:?}", model.solution.method),
                default,
            }
        })
        .collect();
    Expected {
        flight: job.input.file_name().unwrap().to_string_lossy().into_owned(),
        channels: figures,
    }
}

fn close(name: &str, got: f64, want: f64, relative: f64) {
    let scale = want.abs().max(1e-12);
    assert!(
        ((got - want) / scale).abs() <= relative,
        "{name}: {got} drifted from the expected {want} (tolerance {relative:e} relative)"
    );
}

/// Where the guide's table of the sample flights' figures lies.
const TABLE_START: &str = "<!-- figures: generated from sample_flights/expected by tests/sample_flights.rs -->\n";
const TABLE_END: &str = "<!-- end of figures -->\n";

/// The guide's table of every sample flight's channels: what the default
/// applies, and the FOM after and the survey-line error against truth,
/// plain Tolles-Lawson → the default.
fn guide_table(flights: &[Expected]) -> String {
    let mut table = String::from(
        "| flight | channel | the default applies | FOM after, nT | survey-line error, nT |\n|---|---|---|---|---|\n",
    );
    for flight in flights {
        for channel in &flight.channels {
            let applied = match channel.default.effects.is_empty() {
                true => "nothing (plain Tolles-Lawson)".to_string(),
                false => channel.default.effects.join(", "),
            };
            let error = match (channel.survey_line_error_nt, channel.default.survey_line_error_nt) {
                (Some(plain), Some(default)) => format!("{plain:.3} → {default:.3}"),
                _ => "no truth".to_string(),
            };
            table += &format!(
                "| {} | {} | {applied} | {:.2} → {:.2} | {error} |\n",
                flight.flight, channel.channel, channel.fom_after_nt, channel.default.fom_after_nt
            );
        }
    }
    table
}

/// The guide's page with its table of figures made from `flights`.
fn guide_with_table(page: &str, flights: &[Expected]) -> String {
    let start = page
        .find(TABLE_START)
        .expect("the sample flights' page marks its table")
        + TABLE_START.len();
    let end = start + page[start..].find(TABLE_END).expect("the table's end is marked");
    format!("{}{}{}", &page[..start], guide_table(flights), &page[end..])
}

#[test]
fn every_sample_flight_replays_to_its_expected_figures() {
    let pipeline = Pipeline::load(&root().join("pipeline.toml")).unwrap();
    let bless = std::env::var_os("MAGCOMP_BLESS").is_some();
    assert!(pipeline.flights.len() >= 7, "pipeline.toml lists every sample flight");
    let mut flights = Vec::new();
    for job in &pipeline.flights {
        let got = replay(&pipeline, job);
        let stem = job.input.file_stem().unwrap().to_string_lossy().into_owned();
        let path = root().join("sample_flights/expected").join(format!("{stem}.json"));
        if bless {
            std::fs::write(&path, serde_json::to_string_pretty(&got).unwrap() + "\n").unwrap();
            flights.push(got);
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap_or_else(|_| {
            panic!(
                "{}: no expected figures; run sample_flights/regenerate.sh",
                path.display()
            )
        });
        let want: Expected = serde_json::from_str(&text).unwrap();
        assert_eq!(got.channels.len(), want.channels.len(), "{stem}: channels");
        for (g, w) in got.channels.iter().zip(&want.channels) {
            let name = |figure: &str| format!("{stem} {} {figure}", g.channel);
            assert_eq!((&g.channel, &g.method), (&w.channel, &w.method), "{stem}");
            close(&name("FOM before"), g.fom_before_nt, w.fom_before_nt, 1e-6);
            close(&name("FOM after"), g.fom_after_nt, w.fom_after_nt, 1e-6);
            close(&name("IR"), g.improvement_ratio, w.improvement_ratio, 1e-6);
            match (g.survey_line_error_nt, w.survey_line_error_nt) {
                (Some(a), Some(b)) => close(&name("survey-line error"), a, b, 1e-6),
                (a, b) => assert_eq!(a.is_some(), b.is_some(), "{}", name("survey-line error")),
            }
            // The default's figures come through the diagnosis's choices
            // (a parameter refined at a flat held-out minimum moves more
            // with rounding than a sum does): 1e-4 relative.
            assert_eq!(g.default.effects, w.default.effects, "{}", name("default effects"));
            close(
                &name("default FOM after"),
                g.default.fom_after_nt,
                w.default.fom_after_nt,
                1e-4,
            );
            match (g.default.survey_line_error_nt, w.default.survey_line_error_nt) {
                (Some(a), Some(b)) => close(&name("default survey-line error"), a, b, 1e-4),
                (a, b) => assert_eq!(a.is_some(), b.is_some(), "{}", name("default survey-line error")),
            }
            match (g.lambda, w.lambda) {
                (Some(a), Some(b)) => close(&name("λ"), a, b, 1e-9),
                (a, b) => assert_eq!(a.is_some(), b.is_some(), "{}", name("λ")),
            }
        }
        flights.push(want);
    }
    // The guide's table is the expected figures' (rewritten when blessed).
    let page_path = root().join("docs/guide/src/sample-flights.md");
    let page = std::fs::read_to_string(&page_path).unwrap();
    let made = guide_with_table(&page, &flights);
    if bless {
        std::fs::write(&page_path, made).unwrap();
        return;
    }
    assert!(
        page == made,
        "docs/guide/src/sample-flights.md's table differs from the sample flights' figures; run sample_flights/regenerate.sh (or MAGCOMP_BLESS=1 cargo test --test sample_flights). The table should read:\n{}",
        guide_table(&flights)
    );
}
