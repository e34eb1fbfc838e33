//! `magcomp plan`: what a planned calibration would achieve.

use std::path::Path;

use magcomp::config::Pipeline;
use magcomp::formats::{prepare, Destination, OutputKind};

use super::{print_notes, spinner};

/// Predicts what the plan would achieve and writes the plan report.
pub fn plan_calibration(plan_path: &Path, out: &Path, config: Option<&Path>) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let plan = magcomp::plan::Plan::load(plan_path)?;
    let mut inputs: Vec<&Path> = vec![plan_path];
    inputs.extend(config);
    inputs.extend(plan.settings.installation.as_deref());
    print_notes(&prepare(&inputs, &[Destination::new(out, OutputKind::Json, "--out")])?);
    let bar = spinner(format!(
        "flying {} simulated flights of {}",
        plan.settings.realisations,
        plan_path.display()
    ));
    let report = magcomp::plan::predict(&plan, &pipeline.settings);
    bar.finish_and_clear();
    let report = report?;
    magcomp::formats::write_json(out, "the plan report", &report)?;
    for line in &report.summary {
        println!("  {line}");
    }
    for warning in &report.warnings {
        println!("  warning: {warning}");
    }
    println!("wrote {}", out.display());
    Ok(())
}
