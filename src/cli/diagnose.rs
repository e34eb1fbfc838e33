//! `magcomp diagnose`: the physics the model leaves out, named and
//! scored held out.

use std::path::Path;

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::config::{FlightJob, Pipeline};
use magcomp::formats::{prepare, Destination, OutputKind, OutputSet};

use super::progress::FlightBar;
use super::{print_notes, read_prepared};

/// Diagnoses `flight` and writes DIAGNOSIS.json and its HTML page.
pub fn diagnose(
    flight: &Path,
    (out, html): (&Path, &Path),
    windows: &[String],
    config: Option<&Path>,
) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let inputs: Vec<&Path> = std::iter::once(flight).chain(config).collect();
    print_notes(&prepare(
        &inputs,
        &[
            Destination::new(out, OutputKind::Json, "--out"),
            Destination::new(html, OutputKind::Html, "--html"),
        ],
    )?);
    let job = FlightJob {
        diagnosis: None,
        force_diagnosis: false,
        windows: windows
            .iter()
            .map(|w| CalibrationWindow::parse(w))
            .collect::<Result<_, _>>()?,
        ..FlightJob::new(flight)
    };
    let prepared = read_prepared(&job, &pipeline)?;
    let bar = FlightBar::alone(flight, "diagnosing");
    let diagnosis = prepared.diagnose((&pipeline.settings, &pipeline.settings.diagnose), &bar);
    drop(bar);
    let diagnosis = diagnosis?;
    let mut set = OutputSet::new();
    set.add(magcomp::formats::stage_json(out, "the diagnosis", &diagnosis)?);
    set.add_last(magcomp::output::report::stage_diagnosis_report(
        html, flight, &diagnosis,
    )?);
    set.commit()?;
    print_diagnosis(&diagnosis, pipeline.settings.fit.solve.criterion);
    println!("wrote {} and {}", out.display(), html.display());
    if diagnosis.channels.iter().any(|c| !c.model.is_plain()) {
        println!(
            "to compensate with these models: magcomp compensate {} --out OUT.csv --diagnosis {}",
            flight.display(),
            out.display()
        );
    }
    Ok(())
}

/// One channel of the diagnosis on the terminal: its held-out RMS plain
/// and with the findings (λ by `criterion`), where the search started, and
/// the best candidate short of the threshold.
fn print_diagnosed_channel(
    channel: &magcomp::diagnose::ChannelDiagnosis,
    criterion: magcomp::numerics::solve::Criterion,
) {
    println!(
        "  {}: held-out RMS {:.4} nT with plain Tolles-Lawson, {:.4} nT with the findings and λ by {} as compensation picks it",
        channel.channel,
        channel.heldout_rms_baseline_nt,
        channel.heldout_rms_final_nt,
        criterion.describe()
    );
    if let (true, Some(start)) = (
        channel.search_criterion != criterion,
        channel.heldout_rms_other_criterion_nt,
    ) {
        println!(
            "    the search started from plain Tolles-Lawson with λ by {} ({start:.4} nT held out); its findings' figures are measured from there",
            channel.search_criterion.describe()
        );
    }
    if let Some(hint) = &channel.strongest_rejected {
        println!("    best candidate short of the threshold: {hint}");
    }
}

/// The diagnosis on the terminal: each channel's held-out RMS (λ by
/// `criterion`, as compensation picks it), the notes, and each finding
/// with what it means.
fn print_diagnosis(diagnosis: &magcomp::diagnose::Diagnosis, criterion: magcomp::numerics::solve::Criterion) {
    for channel in &diagnosis.channels {
        print_diagnosed_channel(channel, criterion);
    }
    for note in &diagnosis.notes {
        println!("  note: {note}");
    }
    if diagnosis.findings.is_empty() {
        println!("  no finding: nothing in the library explains the residual better than plain Tolles-Lawson");
    }
    for finding in &diagnosis.findings {
        println!(
            "  {} on {}{}: held-out RMS {:.4} → {:.4} nT",
            finding.effect,
            finding.channel,
            finding
                .source
                .as_ref()
                .map(|s| format!(" from {s}"))
                .unwrap_or_default(),
            finding.heldout_rms_before_nt,
            finding.heldout_rms_after_nt
        );
        println!("    {}", finding.explanation);
    }
}
