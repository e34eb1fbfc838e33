//! The HTML quality report: its content, its figures JSON, and (when
//! `MAGCOMP_CHROMIUM` names a browser, as `.ci/run` sets it) that headless
//! Chromium renders it with every plot and no script or page error.

use std::path::{Path, PathBuf};
use std::process::Command;

use magcomp::config::{FlightJob, Settings};
use magcomp::output::sink::{process_flight, FlightOutputs};

/// Each `<text>` of the page's figures whose anchor lies outside its
/// figure, with the figure's number: a label drawn off the plot.
fn labels_out_of_bounds(html: &str) -> Vec<String> {
    let number = |tag: &str, name: &str| -> Option<f64> {
        let start = tag.find(&format!(" {name}=\""))? + name.len() + 3;
        tag[start..].split('"').next()?.parse().ok()
    };
    let mut outside = Vec::new();
    for (figure, svg) in html.split("<svg").skip(1).enumerate() {
        let svg = svg.split("</svg>").next().unwrap();
        let head = svg.split('>').next().unwrap();
        let (width, height) = (number(head, "width").unwrap(), number(head, "height").unwrap());
        for text in svg.split("<text").skip(1) {
            let tag = text.split('>').next().unwrap();
            let (Some(x), Some(y)) = (number(tag, "x"), number(tag, "y")) else {
                continue;
            };
            if !(0.0..=width).contains(&x) || !(0.0..=height).contains(&y) {
                let label = text
                    .split('>')
                    .nth(1)
                    .unwrap_or_default()
                    .split('<')
                    .next()
                    .unwrap_or_default();
                outside.push(format!("figure {figure} ({width}×{height}): '{label}' at ({x}, {y})"));
            }
        }
    }
    outside
}

fn report_of_clean_flight(folder: &Path) -> (PathBuf, magcomp::pipeline::FlightResult) {
    let input = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sample_flights/clean.csv");
    let job = FlightJob::new(input.clone());
    let outputs = FlightOutputs::in_directory(folder, &input);
    // Plain Tolles-Lawson: the diagnosis's section has its own test below.
    let mut options = Settings::default();
    options.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    let result = process_flight(&job, &options, &outputs).unwrap();
    (outputs.report_html.unwrap(), result)
}

#[test]
fn the_report_holds_every_section_and_its_figures_match_the_quality() {
    let folder = tempfile::tempdir().unwrap();
    let (html_path, result) = report_of_clean_flight(folder.path());
    let html = std::fs::read_to_string(&html_path).unwrap();
    // The flight's and the box's attitude, and per channel 12 manoeuvres,
    // the PRESS curve, the singular values, the line map and the lines'
    // profiles.
    let per_channel = 12 + 4;
    assert_eq!(html.matches("<svg").count(), 2 + per_channel * result.channels.len());
    assert_eq!(
        html.matches("heading, °").count(),
        2,
        "a heading panel in both timelines"
    );
    assert_eq!(html.matches("Calibration box, ").count(), 1);
    let channels = result.channels.len();
    for label in [
        "east, m",
        "north, m",
        "anomaly, nT",
        "line 1002: time since its start, s",
    ] {
        assert_eq!(html.matches(label).count(), channels, "{label}");
    }
    assert_eq!(labels_out_of_bounds(&html), Vec::<String>::new());
    assert_eq!(html.matches("class=\"manoeuvre\"").count(), 12 * result.channels.len());
    // Four headings in each FOM table, and a PASS for this clean flight
    // (FOM 0.44 and 0.82 nT against the 1.5 nT limit).
    assert_eq!(
        html.matches("<td>20°</td>").count() + html.matches("<td>110°</td>").count(),
        2 * result.channels.len()
    );
    // The verdict twice per channel: in the summary table that opens the
    // page, which links each channel's section, and at the section's head.
    assert_eq!(html.matches(">PASS<").count(), 2 * result.channels.len());
    let summary_at = html.find("<table class=\"summary\">").expect("a summary table");
    let first_section = html.find("<section class=\"channel\"").unwrap();
    assert!(summary_at < first_section, "the summary opens the page");
    for quality in &result.channels {
        assert!(
            html.contains(&format!("<a href=\"#{0}\">{0}</a>", quality.channel)),
            "{}: linked from the summary",
            quality.channel
        );
    }
    let figures: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(html_path.with_extension("json")).unwrap()).unwrap();
    for (quality, channel) in result.channels.iter().zip(figures["channels"].as_array().unwrap()) {
        assert_eq!(channel["fom_after_nt"].as_f64(), quality.fom_after_nt);
        assert_eq!(channel["fom_pass"].as_bool(), Some(true));
        let lines = channel["line_noise"].as_array().unwrap();
        assert_eq!(lines.len(), 3);
        for line in lines {
            // Compensation does not add noise to the lines.
            assert!(
                line["after_nt"].as_f64().unwrap() <= 1.05 * line["before_nt"].as_f64().unwrap(),
                "{line}"
            );
        }
    }
}

#[test]
fn headless_chromium_renders_the_report() {
    let Some(browser) = std::env::var_os("MAGCOMP_CHROMIUM") else {
        eprintln!("MAGCOMP_CHROMIUM is not set: the browser check is skipped (.ci/run sets it)");
        return;
    };
    let folder = tempfile::tempdir().unwrap();
    let (html_path, result) = report_of_clean_flight(folder.path());
    let profile = folder.path().join("profile");
    let screenshot = folder.path().join("report.png");
    let common = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--enable-logging=stderr",
        "--v=0",
    ];
    let url = format!("file://{}", html_path.display());
    let output = Command::new(&browser)
        .args(common)
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--virtual-time-budget=2000")
        .arg("--dump-dom")
        .arg(&url)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let dom = String::from_utf8_lossy(&output.stdout);
    let log = String::from_utf8_lossy(&output.stderr);
    // The page's own messages: any console error or uncaught exception.
    let page_errors: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("CONSOLE") || l.contains("Uncaught"))
        .collect();
    assert!(page_errors.is_empty(), "{page_errors:?}");
    // The rendered document holds every plot.
    assert_eq!(dom.matches("<svg").count(), 2 + 16 * result.channels.len());
    assert!(dom.contains("id=\"timeline\"") && dom.contains("class=\"fom\""));
    let status = Command::new(&browser)
        .args(common)
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--window-size=1100,2400")
        .arg(format!("--screenshot={}", screenshot.display()))
        .arg(&url)
        .output()
        .unwrap()
        .status;
    assert!(status.success());
    let size = std::fs::metadata(&screenshot).unwrap().len();
    assert!(size > 20_000, "screenshot of {size} bytes: the page rendered blank");
    if let Some(keep) = std::env::var_os("MAGCOMP_KEEP_SCREENSHOT") {
        std::fs::copy(&screenshot, keep).unwrap();
    }
}

#[test]
fn a_diagnosed_flight_reports_its_findings_and_marks_where_they_helped() {
    // concealed_a with `[diagnose] apply`: the cabin sensor's lag.
    let folder = tempfile::tempdir().unwrap();
    let input = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sample_flights/concealed_a.csv");
    let job = FlightJob::new(input.clone());
    let mut options = Settings::default();
    options.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Always;
    let outputs = FlightOutputs::in_directory(folder.path(), &input);
    let result = process_flight(&job, &options, &outputs).unwrap();
    let diagnosis = result.diagnosis.as_ref().unwrap();
    let html = std::fs::read_to_string(outputs.report_html.unwrap()).unwrap();
    assert!(html.contains("id=\"diagnosis\""));
    assert_eq!(html.matches("class=\"finding\"").count(), diagnosis.findings.len());
    assert_eq!(diagnosis.findings.len(), 1);
    // Every manoeuvre of every channel plotted, on top of the usual plots.
    let manoeuvres = 12 * result.channels.len();
    assert_eq!(html.matches("class=\"diagnosis-manoeuvre\"").count(), manoeuvres);
    assert_eq!(
        html.matches("<svg").count(),
        2 + 16 * result.channels.len() + manoeuvres
    );
    // Each window the lag helped most is shaded in its manoeuvre's plot.
    let finding = &diagnosis.findings[0];
    assert_eq!(finding.located.len(), 3);
    for located in &finding.located {
        let marker = format!(
            "data-label=\"{}\" data-marked=\"{:.2}:{:.2}",
            located.label, located.t_start, located.t_end
        );
        let at = html.find("id=\"diagnosis\"").unwrap();
        assert!(html[at..].contains(&marker), "{marker} not in the report");
    }
    // The per-manoeuvre table quotes the diagnosis.
    let cabin = diagnosis.channels.iter().find(|c| c.channel == "mag_2_uc").unwrap();
    for window in &cabin.localisation.windows {
        let row = format!(
            "<tr><td>{}</td><td>{:.4}</td><td>{:.4}</td></tr>",
            window.label, window.heldout_rms_baseline_nt, window.heldout_rms_final_nt
        );
        assert!(html.contains(&row), "{row}");
        assert!(window.heldout_rms_final_nt < window.heldout_rms_baseline_nt);
    }
}

/// A 3-hour flight of five scalar sensors at 10 Hz, with thirteen survey
/// lines: its report stays within 2 MB, every label lies inside its
/// figure, the map is drawn at one scale with its colour bar, and six of
/// the lines' profiles are drawn (the page says which share).
#[test]
fn a_three_hour_five_sensor_report_stays_within_its_size_budget() {
    use magcomp::simulate::scenario::{RawScenario, ScalarSensor, Scenario, SensorLocation};
    let mut raw = RawScenario {
        seed: 31_000,
        ..RawScenario::default()
    };
    raw.sample_rate_hz = 10.0;
    raw.oversampling = 10;
    let locations = [
        SensorLocation::Tail,
        SensorLocation::Cabin,
        SensorLocation::Cabin,
        SensorLocation::Wing,
        SensorLocation::Wing,
    ];
    raw.scalar = (locations.iter().enumerate())
        .map(|(k, &location)| ScalarSensor::new(&format!("mag_{}_uc", k + 1), location, 0.01))
        .collect();
    raw.survey.speed_m_s = 65.0;
    raw.survey.line_length_m = 12.0 * 60.0 * 65.0;
    raw.survey.line_count = 13;
    let flight = magcomp::simulate::simulate(&Scenario::try_from(raw).unwrap()).unwrap();
    let hours = (flight.log.time_s().last().unwrap() - flight.log.time_s()[0]) / 3600.0;
    assert!(hours > 2.8, "{hours} h");
    let folder = tempfile::tempdir().unwrap();
    let input = folder.path().join("three_hours.csv");
    magcomp::formats::write_flight_log(&flight.log, &input).unwrap();
    let outputs = FlightOutputs::in_directory(folder.path(), &input);
    let mut options = Settings::default();
    options.diagnose.apply = magcomp::diagnose::ApplyDiagnosis::Never;
    let result = process_flight(&FlightJob::new(&input), &options, &outputs).unwrap();
    assert_eq!(result.channels.len(), 5);
    let html = std::fs::read_to_string(outputs.report_html.unwrap()).unwrap();
    println!(
        "{:.1} h, {} rows, 5 sensors: report of {} bytes",
        hours,
        flight.log.len(),
        html.len()
    );
    if let Some(keep) = std::env::var_os("MAGCOMP_KEEP_REPORT") {
        std::fs::write(keep, &html).unwrap();
    }
    assert!(html.len() <= 2_000_000, "{} bytes", html.len());
    // Ticks never read "-0", and every line's track is drawn under the
    // map's dots.
    assert!(!html.contains(">-0<") && !html.contains(">-0.0<"));
    assert_eq!(html.matches("tracks in grey").count(), 5);
    assert_eq!(labels_out_of_bounds(&html), Vec::<String>::new());
    assert_eq!(html.matches("6 of the flight's 13 lines").count(), 5);
    assert_eq!(html.matches("class=\"profiles\"").count(), 5);
    assert_eq!(html.matches("anomaly, nT").count(), 5);
}
