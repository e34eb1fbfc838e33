//! `magcomp summarize`: a run's flights in one campaign table.

use std::path::Path;

/// Writes the campaign table of the run whose output folder is `folder`.
pub fn summarize(folder: &Path) -> anyhow::Result<()> {
    let summary = magcomp::campaign::summary::summarize(folder)?;
    print!("{}", summary.describe());
    for path in summary.write(folder)? {
        println!("  wrote {}", path.display());
    }
    Ok(())
}
