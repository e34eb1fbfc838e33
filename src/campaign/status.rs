//! The status JSON each flight of a run leaves beside its outputs, and
//! whether a flight's outputs are current.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::config::{FlightJob, Settings};
use crate::error::{Error, Result};
use crate::quality::verdict::Verdict;

/// How a flight of a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FlightState {
    /// Every output was written.
    Done,
    /// Processing stopped with an error; `error` says why. The flight's
    /// outputs are those of an earlier run, if any.
    Failed,
}

/// `<output name>_status.json`: how one flight of a run ended, what it
/// was made from and what it wrote. Written last, after the outputs, so
/// a status that says done means every output it lists is complete.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlightStatus {
    /// The name the flight's outputs carry.
    pub flight: String,
    /// The input file.
    pub input: PathBuf,
    /// SHA-256 of the input's bytes.
    pub input_sha256: String,
    /// SHA-256 of everything else the outputs depend on ([`settings_sha256`]).
    pub settings_sha256: String,
    /// The magcomp version that ran.
    pub magcomp_version: String,
    /// Done or failed.
    pub state: FlightState,
    /// Why it failed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The output files, named within the output folder.
    pub outputs: Vec<String>,
    /// Rows read and written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<usize>,
    /// The run's warnings (also in the quality JSON and the report).
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Each channel's verdict, in channel order (also in the quality JSON
    /// and the report).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub verdicts: Vec<ChannelVerdict>,
    /// The airframe, when the campaign names it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aircraft: Option<String>,
    /// The flight's day, `YYYY-MM-DD`, when the campaign gives it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub date: Option<String>,
    /// Wall time of the flight's processing, s (differs run to run).
    pub elapsed_s: f64,
    /// The shard that processed it, `K/N` (differs with the split).
    pub shard: String,
}

/// One channel's verdict, as a status keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelVerdict {
    /// The scalar channel.
    pub channel: String,
    /// Its verdict.
    pub verdict: Verdict,
}

/// `<folder>/<output name>_status.json`.
pub fn status_path(folder: &Path, output_name: &str) -> PathBuf {
    folder.join(format!("{output_name}_status.json"))
}

/// SHA-256 over what a flight's outputs depend on besides its input's
/// bytes: the magcomp version, every validated setting, the flight's own
/// choices (windows, channels, fluxgate, date, output name) and the bytes
/// of the diagnosis it applies, the plan report it is set against and the
/// saved model it is compensated with. Neither where the input, diagnosis,
/// plan and model files are (a campaign folder may move) nor `--force`
/// count.
pub fn settings_sha256(job: &FlightJob, settings: &Settings) -> Result<String> {
    let mut hasher = Sha256::new();
    hasher.update(concat!("magcomp ", env!("CARGO_PKG_VERSION"), "\n").as_bytes());
    hasher.update(format!("{settings:?}\n").as_bytes());
    let choices = FlightJob {
        input: PathBuf::new(),
        diagnosis: None,
        force_diagnosis: false,
        plan: None,
        model: None,
        ..job.clone()
    };
    hasher.update(format!("{choices:?}\n").as_bytes());
    if let Some(diagnosis) = &job.diagnosis {
        hasher.update(crate::ingest::flight_identity::hash_file(diagnosis)?.as_bytes());
    }
    if let Some(plan) = &job.plan {
        hasher.update(b"plan\n");
        hasher.update(crate::ingest::flight_identity::hash_file(plan)?.as_bytes());
    }
    if let Some(model) = &job.model {
        hasher.update(b"model\n");
        hasher.update(crate::ingest::flight_identity::hash_file(model)?.as_bytes());
    }
    Ok(hasher.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

impl FlightStatus {
    /// Reads the status at `path`; `None` when there is none or it cannot
    /// be read (a flight to do again, not an error).
    pub fn read(path: &Path) -> Option<Self> {
        let text = crate::ingest::read_text(path).ok()?;
        serde_json::from_str(&text).ok()
    }

    /// Whether this status vouches for the outputs in `folder`: the flight
    /// was done from the same input bytes and settings, and every output
    /// it lists is still there.
    pub fn is_current(&self, folder: &Path, input_sha256: &str, settings_sha256: &str) -> bool {
        self.state == FlightState::Done
            && self.input_sha256 == input_sha256
            && self.settings_sha256 == settings_sha256
            && self.outputs.iter().all(|name| folder.join(name).is_file())
    }

    /// Writes the status to `path` atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        crate::formats::stage_json(path, "the flight's status", self)?
            .commit()
            .map(drop)
    }

    /// The one-line outcome for a run's table.
    pub fn outcome(&self) -> String {
        match (self.state, &self.error) {
            (FlightState::Failed, error) => {
                let text = error.as_deref().unwrap_or("no reason recorded");
                let first: String = text.chars().take(100).collect();
                match first.len() < text.len() {
                    true => format!("FAILED: {first}…"),
                    false => format!("FAILED: {first}"),
                }
            }
            (FlightState::Done, _) => {
                let rows = self.rows.unwrap_or(0);
                let done = match self.warnings.len() {
                    0 => format!("ok, {rows} rows"),
                    1 => format!("ok with 1 warning, {rows} rows"),
                    n => format!("ok with {n} warnings, {rows} rows"),
                };
                match self.verdict() {
                    Some(Verdict::Pass) | None => done,
                    Some(worst) => {
                        let channels: Vec<&str> = (self.verdicts.iter())
                            .filter(|c| c.verdict == worst)
                            .map(|c| c.channel.as_str())
                            .collect();
                        format!("{worst} ({}); {done}", channels.join(", "))
                    }
                }
            }
        }
    }

    /// The flight's verdict: its worst channel's; `None` without channels.
    pub fn verdict(&self) -> Option<Verdict> {
        self.verdicts.iter().map(|c| c.verdict).max()
    }
}

/// An error reading or parsing a status file, for `summarize`.
pub(crate) fn unreadable(path: &Path, problem: String) -> Error {
    Error::NotOurFile {
        path: path.to_path_buf(),
        expected: "a flight status JSON written by magcomp run",
        problem,
        hint: "Remove it, or run magcomp run again to rewrite it.",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn done(verdicts: &[(&str, Verdict)], warnings: usize) -> FlightStatus {
        FlightStatus {
            flight: "f".into(),
            input: "f.csv".into(),
            input_sha256: String::new(),
            settings_sha256: String::new(),
            magcomp_version: String::new(),
            state: FlightState::Done,
            error: None,
            outputs: Vec::new(),
            rows: Some(100),
            warnings: vec!["w".into(); warnings],
            verdicts: (verdicts.iter())
                .map(|(channel, verdict)| ChannelVerdict {
                    channel: channel.to_string(),
                    verdict: *verdict,
                })
                .collect(),
            aircraft: None,
            date: None,
            elapsed_s: 0.0,
            shard: "0/1".into(),
        }
    }

    /// A flight with a channel at FAIL says FAIL first in the run's table,
    /// whatever else its channels are; a CHECK says CHECK; PASS says ok.
    #[test]
    fn the_table_leads_with_the_worst_verdict() {
        let status = done(
            &[
                ("mag_1_uc", Verdict::Pass),
                ("mag_2_uc", Verdict::Fail),
                ("mag_3_uc", Verdict::Check),
            ],
            4,
        );
        assert_eq!(status.verdict(), Some(Verdict::Fail));
        assert_eq!(status.outcome(), "FAIL (mag_2_uc); ok with 4 warnings, 100 rows");
        let status = done(&[("mag_1_uc", Verdict::Check), ("mag_2_uc", Verdict::Pass)], 0);
        assert_eq!(status.outcome(), "CHECK (mag_1_uc); ok, 100 rows");
        let status = done(&[("mag_1_uc", Verdict::Pass)], 1);
        assert_eq!(status.outcome(), "ok with 1 warning, 100 rows");
        assert_eq!(done(&[], 0).verdict(), None);
    }
}
