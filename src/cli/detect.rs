//! `magcomp detect`: the calibration boxes and their manoeuvres.

use std::path::Path;

use magcomp::config::Pipeline;
use magcomp::formats::{prepare, Destination, OutputKind};

use super::{print_notes, read_screened};

/// Detects the boxes and manoeuvres of `flight` and writes DETECT.json.
pub fn detect(flight: &Path, out: &Path, config: Option<&Path>, lines: Option<&str>) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let lines = lines.map(magcomp::calibration::windows::parse_lines).transpose()?;
    let inputs: Vec<&Path> = std::iter::once(flight).chain(config).collect();
    print_notes(&prepare(&inputs, &[Destination::new(out, OutputKind::Json, "--out")])?);
    let log = read_screened(flight, &pipeline)?;
    let mut detection = magcomp::calibration::detect::detect_manoeuvres(&log, &pipeline.settings.detect)?;
    if let Some(lines) = lines {
        let spans = magcomp::calibration::windows::line_spans(&log, &lines)?;
        detection = detection.on_lines(&spans);
    }
    /// DETECT.json: the detection and the flight it was made on.
    #[derive(serde::Serialize)]
    struct DetectJson<'a> {
        #[serde(flatten)]
        detection: &'a magcomp::calibration::detect::Detection,
        flight: magcomp::ingest::flight_identity::FlightIdentity,
    }
    let file = DetectJson {
        detection: &detection,
        flight: magcomp::ingest::flight_identity::FlightIdentity::of(&log)?,
    };
    magcomp::formats::write_json(out, "the detected manoeuvres", &file)?;
    print_detection(&detection);
    println!("wrote {}", out.display());
    Ok(())
}

/// The detection on the terminal: its notes, its warnings and a line per
/// manoeuvre (kind, heading, span, cycles, period and amplitude).
fn print_detection(detection: &magcomp::calibration::detect::Detection) {
    for note in magcomp::pipeline::detection_notes(detection) {
        println!("  {note}");
    }
    for warning in magcomp::pipeline::detection_warnings(detection) {
        println!("  warning: {warning}");
    }
    for manoeuvre in &detection.manoeuvres {
        println!(
            "  {:<5} heading {:>5.1}: {:.1}–{:.1} s, {} cycles of {:.1} s, ±{:.1}°{}",
            format!("{:?}", manoeuvre.kind).to_lowercase(),
            manoeuvre.heading_deg,
            manoeuvre.t_start,
            manoeuvre.t_end,
            manoeuvre.cycles,
            manoeuvre.period_s,
            manoeuvre.amplitude_deg,
            manoeuvre
                .could_be
                .map(|other| format!(" (or a {}: uncertain)", format!("{other:?}").to_lowercase()))
                .unwrap_or_default()
        );
    }
}
