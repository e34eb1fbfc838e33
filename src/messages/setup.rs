//! What setting up a run tells its user before any flight is processed:
//! the output folders it made, and what reading a campaign decided about
//! its flights. Printed as `note:` lines.

use std::fmt;
use std::path::PathBuf;

/// A note of a run's setup.
#[derive(Debug, Clone, PartialEq)]
pub enum Setup {
    /// A missing output folder was created.
    FolderCreated {
        /// The folder.
        folder: PathBuf,
        /// What named the output that goes in it (`--out`, `[output]`).
        named_by: String,
    },
    /// A campaign's input pattern also matches files in its output folder,
    /// which are left out.
    InputsInOutputFolder {
        /// The pattern, as written.
        pattern: String,
        /// Files it matches in the output folder.
        files: usize,
        /// The output folder.
        folder: PathBuf,
    },
    /// A campaign's input pattern also matches the run's own settings
    /// (the pipeline file or its manifest), which are left out.
    SettingsMatched {
        /// The pattern, as written.
        pattern: String,
        /// The settings files it matches.
        files: Vec<PathBuf>,
    },
    /// An aircraft's flights compensated with the model of its
    /// calibration flight.
    CompensatedWithCalibration {
        /// The aircraft.
        aircraft: String,
        /// The calibration flight.
        calibration: PathBuf,
        /// The model it writes.
        model: PathBuf,
        /// The flights' output names.
        flights: Vec<String>,
    },
    /// A flight flown before any calibration flight of its aircraft,
    /// compensated with the first one's model.
    FlownBeforeCalibration {
        /// The flight.
        flight: PathBuf,
    },
    /// An aircraft with no calibration flight in a campaign that marks
    /// them: its flights are fitted on their own boxes.
    NoCalibrationFlight {
        /// The aircraft.
        aircraft: String,
        /// The flights' output names.
        flights: Vec<String>,
    },
}

impl fmt::Display for Setup {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Setup::FolderCreated { folder, named_by } => {
                write!(f, "created the folder {} for {named_by}", folder.display())
            }
            Setup::InputsInOutputFolder { pattern, files, folder } => write!(
                f,
                "[campaign] inputs: {pattern:?} matches {files} file(s) in the output folder {}; they are outputs of earlier runs, not flights, and are left out",
                folder.display()
            ),
            Setup::SettingsMatched { pattern, files } => write!(
                f,
                "[campaign] inputs: {pattern:?} matches the run's own settings ({}); they are not flights, and are left out",
                listed(&files.iter().map(|p| p.display().to_string()).collect::<Vec<_>>())
            ),
            Setup::CompensatedWithCalibration {
                aircraft,
                calibration,
                model,
                flights,
            } => write!(
                f,
                "aircraft '{aircraft}': {} flight(s) compensated with the model of its calibration flight {} ({}): {}",
                flights.len(),
                calibration.display(),
                model.display(),
                listed(flights)
            ),
            Setup::FlownBeforeCalibration { flight } => write!(
                f,
                "{} was flown before any calibration flight of its aircraft: it is compensated with the first one's model",
                flight.display()
            ),
            Setup::NoCalibrationFlight { aircraft, flights } => write!(
                f,
                "aircraft '{aircraft}' has no calibration flight in this campaign (calibration = true): its {} flight(s) are fitted on their own boxes: {}",
                flights.len(),
                listed(flights)
            ),
        }
    }
}

/// Names for a note: all of them up to eight, else the first eight and a
/// count.
fn listed(names: &[String]) -> String {
    const SHOWN: usize = 8;
    match names.len() {
        0..=SHOWN => names.join(", "),
        n => format!("{} and {} more", names[..SHOWN].join(", "), n - SHOWN),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_setup_notes_read_as_the_run_has_always_said_them() {
        let flights: Vec<String> = (1..=10).map(|k| format!("f{k}")).collect();
        assert_eq!(
            Setup::FolderCreated {
                folder: "out/new".into(),
                named_by: "--out".into()
            }
            .to_string(),
            "created the folder out/new for --out"
        );
        assert_eq!(
            Setup::InputsInOutputFolder {
                pattern: "f/**/*.csv".into(),
                files: 1,
                folder: "f/out".into()
            }
            .to_string(),
            "[campaign] inputs: \"f/**/*.csv\" matches 1 file(s) in the output folder f/out; they are outputs of earlier runs, not flights, and are left out"
        );
        assert_eq!(
            Setup::CompensatedWithCalibration {
                aircraft: "VH-ABC".into(),
                calibration: "cal.csv".into(),
                model: "out/cal.model.json".into(),
                flights: flights[..2].to_vec()
            }
            .to_string(),
            "aircraft 'VH-ABC': 2 flight(s) compensated with the model of its calibration flight cal.csv (out/cal.model.json): f1, f2"
        );
        assert_eq!(
            Setup::FlownBeforeCalibration { flight: "early.csv".into() }.to_string(),
            "early.csv was flown before any calibration flight of its aircraft: it is compensated with the first one's model"
        );
        assert_eq!(
            Setup::NoCalibrationFlight {
                aircraft: "VH-XYZ".into(),
                flights
            }
            .to_string(),
            "aircraft 'VH-XYZ' has no calibration flight in this campaign (calibration = true): its 10 flight(s) are fitted on their own boxes: f1, f2, f3, f4, f5, f6, f7, f8 and 2 more"
        );
    }
}
