//! A flight set against the plan it was flown to.
//!
//! `magcomp plan` predicts, before the flight, the FOM and the survey
//! uncertainty a planned calibration would achieve (`PLAN_REPORT.json`).
//! Given that report (`compensate --plan PLAN_REPORT.json`, or `plan =` on
//! a `[[flight]]`), the compensation of the flight flown to it says, per
//! channel, whether each predicted figure held:
//!
//! - the FOM after compensation;
//! - the survey uncertainty the excitation analysis states (its
//!   coefficient part with the compensated noise);
//! - the RMS of the `mag_<n>_c_sigma` column over the survey lines.
//!
//! The plan states its medians within a factor (`stated_factor`); one
//! flight is one more draw of what the plan's simulated flights drew, and
//! its coefficients' uncertainty has a long tail (λ chosen by PRESS on a
//! few minutes of manoeuvres). So a figure holds when it lies inside the
//! range of the plan's simulated flights widened by the stated factor: on
//! random plans flown as planned, the figures hold and a sensor thirty
//! times noisier than planned does not (`tests/plan.rs`). One beyond that,
//! either way, is a warning: the prediction rested on an
//! installation or a box this flight did not have, and a plan made again
//! from this flight's model would be better founded. The manoeuvres flown
//! are matched with the planned ones by kind and heading; one the plan
//! counted on and the flight lacks is a warning too, since the prediction
//! assumed it. A flight that also flew the additions the plan proposed is
//! compared with the plan's prediction with the additions.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::calibration::headings::angle_apart;
use crate::calibration::windows::ManoeuvreKind;
use crate::error::{Error, Result};
use crate::messages::Note;

/// The factor within which the plan's medians are expected to hold on
/// flights of the plan (FOM and survey figures); `tests/plan.rs` measures it.
pub const STATED_FACTOR: f64 = 2.0;

/// A flown manoeuvre matches a planned one of its kind whose heading is
/// within this, degrees (on the circle).
const HEADING_TOLERANCE_DEG: f64 = 25.0;

/// A figure of the plan: median and range over its simulated flights.
/// `null` in the JSON (a figure the plan could not measure) reads as
/// `None`.
#[derive(Debug, Clone, Copy, Default, Deserialize)]
struct PlannedFigure {
    median: Option<f64>,
    low: Option<f64>,
    high: Option<f64>,
}

/// One channel's prediction, as `PLAN_REPORT.json` holds it.
#[derive(Debug, Clone, Deserialize)]
struct PlannedChannel {
    channel: String,
    fom_nt: PlannedFigure,
    survey_sigma_nt: PlannedFigure,
    #[serde(default)]
    sigma_column_nt: PlannedFigure,
}

/// A manoeuvre of the plan's box.
#[derive(Debug, Clone, Copy, Deserialize)]
struct PlannedManoeuvre {
    kind: ManoeuvreKind,
    heading_deg: f64,
}

/// A manoeuvre the plan proposed adding.
#[derive(Debug, Clone, Copy, Deserialize)]
struct PlannedAddition {
    kind: ManoeuvreKind,
    heading_deg: f64,
    count: usize,
}

/// What `compensate` needs of a `PLAN_REPORT.json`.
#[derive(Debug, Clone, Deserialize)]
pub struct PlanPrediction {
    /// The plan file the report was made from.
    plan: PathBuf,
    /// The factor the plan states for its medians.
    stated_factor: f64,
    /// The planned box's manoeuvres (absent from reports older than this
    /// comparison: then the manoeuvres are not compared).
    #[serde(default)]
    planned_manoeuvres: Vec<PlannedManoeuvre>,
    channels: Vec<PlannedChannel>,
    #[serde(default)]
    additions: Vec<PlannedAddition>,
    #[serde(default)]
    with_additions: Vec<PlannedChannel>,
    /// The report file.
    #[serde(skip)]
    path: PathBuf,
}

impl PlanPrediction {
    /// Reads a `PLAN_REPORT.json` as `magcomp plan` writes it.
    pub fn read(path: &Path) -> Result<PlanPrediction> {
        let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
        let not_ours = |problem: String| {
            Error::NotOurFile {
            path: path.to_path_buf(),
            expected: "a PLAN_REPORT.json as `magcomp plan` writes it",
            problem,
            hint: "Give the report `magcomp plan PLAN.toml --out PLAN_REPORT.json` wrote for the plan this flight was flown to.",
        }
        };
        let mut prediction: PlanPrediction = serde_json::from_str(&text).map_err(|e| not_ours(e.to_string()))?;
        if !(prediction.stated_factor.is_finite() && prediction.stated_factor > 1.0) {
            return Err(not_ours(format!(
                "its stated_factor is {}, not a number above 1",
                prediction.stated_factor
            )));
        }
        if prediction.channels.is_empty() {
            return Err(not_ours("it predicts no channel".into()));
        }
        prediction.path = path.to_path_buf();
        Ok(prediction)
    }
}

/// What one compensated channel achieved on the flight.
#[derive(Debug, Clone, PartialEq)]
pub struct FlownChannel {
    /// Scalar channel.
    pub channel: String,
    /// FOM after compensation, nT.
    pub fom_nt: Option<f64>,
    /// The survey uncertainty the excitation analysis states, with the
    /// compensated noise, nT.
    pub survey_sigma_nt: Option<f64>,
    /// RMS of the sigma column over the survey lines, nT.
    pub sigma_column_nt: Option<f64>,
}

/// How a flown figure stands against the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Inside the simulated range widened by the stated factor.
    AsPlanned,
    /// Above both: worse than planned.
    Worse,
    /// Below both: better than planned.
    Better,
    /// The flight or the plan has no such figure.
    NotCompared,
}

/// One figure of one channel, flown against planned.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FigureAgainstPlan {
    /// `fom_nt`, `survey_sigma_nt` or `sigma_column_nt`.
    pub figure: &'static str,
    /// The plan's median, nT.
    pub planned_nt: Option<f64>,
    /// The plan's simulated range, nT.
    pub planned_low_nt: Option<f64>,
    /// The plan's simulated range, nT.
    pub planned_high_nt: Option<f64>,
    /// This flight's, nT.
    pub flown_nt: Option<f64>,
    /// Flown over the planned median.
    pub ratio: Option<f64>,
    /// How it stands.
    pub verdict: Verdict,
}

/// One channel against the plan.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelAgainstPlan {
    /// Scalar channel.
    pub channel: String,
    /// Its figures.
    pub figures: Vec<FigureAgainstPlan>,
}

/// The quality JSON's `plan` section.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanComparison {
    /// The `PLAN_REPORT.json` given.
    pub report: PathBuf,
    /// The plan file it was made from.
    pub plan: PathBuf,
    /// The factor the plan states.
    pub stated_factor: f64,
    /// Whether the flight flew the plan's proposed additions, so that it
    /// is compared with the prediction with them.
    pub with_additions: bool,
    /// Planned manoeuvres, as flown or not.
    pub planned_manoeuvres: usize,
    /// The planned manoeuvres the flight lacks ("roll on heading 127°").
    pub missing: Vec<String>,
    /// Flown manoeuvres the plan did not have.
    pub unplanned: Vec<String>,
    /// Each channel both the flight and the plan have.
    pub channels: Vec<ChannelAgainstPlan>,
    /// What the user must know (also in the run's warnings).
    pub warnings: Vec<crate::messages::Warning>,
    /// The comparison in words (also in the run's notes).
    pub notes: Vec<Note>,
}

fn manoeuvre_words(kind: ManoeuvreKind, heading_deg: f64) -> String {
    format!("{} on heading {:.0}°", kind.name(), heading_deg.rem_euclid(360.0))
}

/// Matches `flown` (kind, heading) with `planned`, one to one, each
/// planned manoeuvre with the nearest free flown one of its kind within
/// the tolerance. Returns the planned indices unmatched and the flown
/// indices unmatched.
fn match_manoeuvres(planned: &[(ManoeuvreKind, f64)], flown: &[(ManoeuvreKind, f64)]) -> (Vec<usize>, Vec<usize>) {
    let mut used = vec![false; flown.len()];
    let mut missing = Vec::new();
    for (p, &(kind, heading)) in planned.iter().enumerate() {
        let nearest = (flown.iter().enumerate())
            .filter(|&(f, m)| !used[f] && m.0 == kind)
            .map(|(f, m)| (f, angle_apart(m.1, heading)))
            .filter(|&(_, gap)| gap <= HEADING_TOLERANCE_DEG)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match nearest {
            Some((f, _)) => used[f] = true,
            None => missing.push(p),
        }
    }
    let unplanned = (0..flown.len()).filter(|&f| !used[f]).collect();
    (missing, unplanned)
}

/// How `flown` stands against `planned` with the stated `factor`.
fn judge(figure: &'static str, planned: PlannedFigure, flown: Option<f64>, factor: f64) -> FigureAgainstPlan {
    let finite = |v: Option<f64>| v.filter(|v| v.is_finite());
    let (median, flown) = (finite(planned.median).filter(|m| *m > 0.0), finite(flown));
    let (low, high) = (finite(planned.low), finite(planned.high));
    let (ratio, verdict) = match (median, flown) {
        (Some(median), Some(flown)) => {
            let lower = low.unwrap_or(median).min(median) / factor;
            let upper = high.unwrap_or(median).max(median) * factor;
            let verdict = match flown {
                f if f > upper => Verdict::Worse,
                f if f < lower => Verdict::Better,
                _ => Verdict::AsPlanned,
            };
            (Some(flown / median), verdict)
        }
        _ => (None, Verdict::NotCompared),
    };
    FigureAgainstPlan {
        figure,
        planned_nt: median,
        planned_low_nt: low,
        planned_high_nt: high,
        flown_nt: flown,
        ratio,
        verdict,
    }
}

fn figure_words(figure: &str) -> &'static str {
    match figure {
        "fom_nt" => "FOM",
        "survey_sigma_nt" => "stated survey uncertainty",
        _ => "sigma column over the survey lines",
    }
}

/// Sets a flight's channels and manoeuvres against `prediction`.
/// `flown_manoeuvres` is `None` when the flight's windows carry no kind
/// and heading (given by hand without labels): then the manoeuvres are
/// not compared, and the notes say so.
pub fn compare(
    prediction: &PlanPrediction,
    flown_manoeuvres: Option<&[(ManoeuvreKind, f64)]>,
    channels: &[FlownChannel],
) -> PlanComparison {
    let factor = prediction.stated_factor;
    let mut said = Said::default();
    let manoeuvres = compare_manoeuvres(prediction, flown_manoeuvres, &mut said);
    let predictions = match manoeuvres.with_additions && !prediction.with_additions.is_empty() {
        true => &prediction.with_additions,
        false => &prediction.channels,
    };
    let mut compared = Vec::new();
    for channel in channels {
        let Some(planned) = predictions.iter().find(|p| p.channel == channel.channel) else {
            said.notes.push(Note::PlanLacksChannel {
                channel: channel.channel.clone(),
                report: prediction.path.clone(),
            });
            continue;
        };
        compared.push(compare_channel(planned, channel, (factor, &prediction.path), &mut said));
    }
    for planned in predictions {
        if !channels.iter().any(|c| c.channel == planned.channel) {
            said.notes.push(Note::PlanChannelNotCompensated {
                channel: planned.channel.clone(),
                report: prediction.path.clone(),
            });
        }
    }
    PlanComparison {
        report: prediction.path.clone(),
        plan: prediction.plan.clone(),
        stated_factor: factor,
        with_additions: manoeuvres.with_additions,
        planned_manoeuvres: prediction.planned_manoeuvres.len(),
        missing: manoeuvres.missing,
        unplanned: manoeuvres.unplanned,
        channels: compared,
        warnings: said.warnings,
        notes: said.notes,
    }
}

/// What a comparison says, as it goes.
#[derive(Default)]
struct Said {
    warnings: Vec<crate::messages::Warning>,
    notes: Vec<Note>,
}

/// The manoeuvres flown against the plan's: those it lacks and those it
/// did not have, in words, and whether the flight flew the plan's
/// proposed additions too.
struct ManoeuvresAgainstPlan {
    missing: Vec<String>,
    unplanned: Vec<String>,
    with_additions: bool,
}

/// Sets the manoeuvres flown against the plan's (and its additions'),
/// saying what differs.
fn compare_manoeuvres(
    prediction: &PlanPrediction,
    flown_manoeuvres: Option<&[(ManoeuvreKind, f64)]>,
    said: &mut Said,
) -> ManoeuvresAgainstPlan {
    let planned: Vec<(ManoeuvreKind, f64)> = (prediction.planned_manoeuvres.iter())
        .map(|m| (m.kind, m.heading_deg))
        .collect();
    let additions: Vec<(ManoeuvreKind, f64)> = (prediction.additions.iter())
        .flat_map(|a| std::iter::repeat_n((a.kind, a.heading_deg), a.count))
        .collect();
    let mut compared = ManoeuvresAgainstPlan {
        missing: Vec::new(),
        unplanned: Vec::new(),
        with_additions: false,
    };
    let flown = match flown_manoeuvres {
        Some(flown) if !planned.is_empty() => flown,
        _ => {
            said.notes.push(Note::PlanManoeuvresNotCompared {
                report: prediction.path.clone(),
                no_plan: planned.is_empty(),
            });
            return compared;
        }
    };
    let (lacking, extra) = match_manoeuvres(&planned, flown);
    let extra_flown: Vec<(ManoeuvreKind, f64)> = extra.iter().map(|&f| flown[f]).collect();
    // The extras are the proposed additions when they hold all of them
    // (and the box is whole); what is left is unplanned.
    let (additions_lacking, beyond_additions) = match_manoeuvres(&additions, &extra_flown);
    let with_additions = lacking.is_empty() && !additions.is_empty() && additions_lacking.is_empty();
    compared.with_additions = with_additions;
    compared.missing = lacking
        .iter()
        .map(|&p| manoeuvre_words(planned[p].0, planned[p].1))
        .collect();
    compared.unplanned = match with_additions {
        true => beyond_additions,
        false => (0..extra_flown.len()).collect(),
    }
    .into_iter()
    .map(|f| manoeuvre_words(extra_flown[f].0, extra_flown[f].1))
    .collect();
    if !compared.missing.is_empty() {
        said.warnings.push(crate::messages::Warning::PlanManoeuvresMissing {
            report: prediction.path.clone(),
            missing: compared.missing.clone(),
            planned: planned.len(),
        });
    }
    if !compared.unplanned.is_empty() {
        said.notes.push(Note::PlanUnplannedManoeuvres {
            report: prediction.path.clone(),
            manoeuvres: compared.unplanned.clone(),
        });
    }
    if with_additions {
        said.notes.push(Note::PlanWithAdditions {
            report: prediction.path.clone(),
            additions: additions.len(),
        });
    }
    compared
}

/// One channel's figures against its prediction: a note of each, and a
/// warning for each outside the plan's range widened by `factor`.
fn compare_channel(
    planned: &PlannedChannel,
    channel: &FlownChannel,
    (factor, report): (f64, &std::path::Path),
    said: &mut Said,
) -> ChannelAgainstPlan {
    let figures = vec![
        judge("fom_nt", planned.fom_nt, channel.fom_nt, factor),
        judge(
            "survey_sigma_nt",
            planned.survey_sigma_nt,
            channel.survey_sigma_nt,
            factor,
        ),
        judge(
            "sigma_column_nt",
            planned.sigma_column_nt,
            channel.sigma_column_nt,
            factor,
        ),
    ];
    let mut words = Vec::new();
    for figure in &figures {
        let what = figure_words(figure.figure);
        let (Some(planned), Some(flown), Some(ratio)) = (figure.planned_nt, figure.flown_nt, figure.ratio) else {
            words.push(format!("{what} not compared (the flight or the plan has none)"));
            continue;
        };
        let range = match (figure.planned_low_nt, figure.planned_high_nt) {
            (Some(low), Some(high)) => format!(" (range {low:.3}–{high:.3})"),
            _ => String::new(),
        };
        words.push(format!("{what} {flown:.3} nT, planned {planned:.3}{range}"));
        let worse = match figure.verdict {
            Verdict::Worse => true,
            Verdict::Better => false,
            _ => continue,
        };
        said.warnings.push(crate::messages::Warning::PlanFigureOutside {
            channel: channel.channel.clone(),
            figure: what,
            flown_nt: flown,
            planned_nt: planned,
            range: figure.planned_low_nt.zip(figure.planned_high_nt),
            ratio,
            factor,
            worse,
        });
    }
    let holds = figures
        .iter()
        .all(|f| matches!(f.verdict, Verdict::AsPlanned | Verdict::NotCompared));
    said.notes.push(Note::PlanChannelFigures {
        channel: channel.channel.clone(),
        report: report.to_path_buf(),
        figures: words,
        as_planned: holds,
    });
    ChannelAgainstPlan {
        channel: channel.channel.clone(),
        figures,
    }
}

/// RMS of `values` over the survey lines (rows whose `line` is positive),
/// missing values left out; `None` without such a row.
pub fn survey_rms(values: &[f64], line: &[f64]) -> Option<f64> {
    let (sum, count) = (values.iter().zip(line))
        .filter(|(v, l)| **l > 0.0 && v.is_finite())
        .fold((0.0, 0usize), |(s, n), (v, _)| (s + v * v, n + 1));
    (count > 0).then(|| (sum / count as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn figure(median: f64, low: f64, high: f64) -> PlannedFigure {
        PlannedFigure {
            median: Some(median),
            low: Some(low),
            high: Some(high),
        }
    }

    fn prediction() -> PlanPrediction {
        let channel = |name: &str, fom: f64| PlannedChannel {
            channel: name.into(),
            fom_nt: figure(fom, 0.8 * fom, 1.3 * fom),
            survey_sigma_nt: figure(0.02, 0.015, 0.03),
            sigma_column_nt: figure(0.03, 0.02, 0.05),
        };
        PlanPrediction {
            plan: "plan.toml".into(),
            stated_factor: 2.0,
            planned_manoeuvres: [0.0, 90.0, 180.0, 270.0]
                .iter()
                .flat_map(|&h| {
                    [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw].map(|kind| PlannedManoeuvre {
                        kind,
                        heading_deg: h + 7.0,
                    })
                })
                .collect(),
            channels: vec![channel("mag_1_uc", 1.0), channel("mag_2_uc", 2.0)],
            additions: vec![PlannedAddition {
                kind: ManoeuvreKind::Roll,
                heading_deg: 7.0,
                count: 2,
            }],
            with_additions: vec![channel("mag_1_uc", 0.5)],
            path: "plan_report.json".into(),
        }
    }

    fn box_flown(skip: Option<usize>) -> Vec<(ManoeuvreKind, f64)> {
        let kinds = [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw];
        (0..12)
            .filter(|&k| Some(k) != skip)
            // Headings flown a few degrees off, one across north.
            .map(|k| {
                (
                    kinds[k % 3],
                    (359.0 + 90.0 * (k / 3) as f64 + 3.0 * (k % 3) as f64) % 360.0,
                )
            })
            .collect()
    }

    fn flown(name: &str, fom: f64, sigma: f64) -> FlownChannel {
        FlownChannel {
            channel: name.into(),
            fom_nt: Some(fom),
            survey_sigma_nt: Some(sigma),
            sigma_column_nt: Some(0.03),
        }
    }

    #[test]
    fn figures_within_the_factor_or_the_range_hold_and_others_warn() {
        // The range 0.6–1.5 widened ×2: 0.3–3.0.
        let f = figure(1.0, 0.6, 1.5);
        assert_eq!(judge("fom_nt", f, Some(2.99), 2.0).verdict, Verdict::AsPlanned);
        assert_eq!(judge("fom_nt", f, Some(3.01), 2.0).verdict, Verdict::Worse);
        assert_eq!(judge("fom_nt", f, Some(0.31), 2.0).verdict, Verdict::AsPlanned);
        assert_eq!(judge("fom_nt", f, Some(0.29), 2.0).verdict, Verdict::Better);
        assert_eq!(judge("fom_nt", f, None, 2.0).verdict, Verdict::NotCompared);
        // Without a range, the median's factor.
        let bare = PlannedFigure {
            low: None,
            high: None,
            ..f
        };
        assert_eq!(judge("fom_nt", bare, Some(2.01), 2.0).verdict, Verdict::Worse);
        assert_eq!(judge("fom_nt", bare, Some(0.51), 2.0).verdict, Verdict::AsPlanned);
        let nan = PlannedFigure { median: None, ..f };
        assert_eq!(judge("fom_nt", nan, Some(1.0), 2.0).verdict, Verdict::NotCompared);
        assert_eq!(judge("fom_nt", f, Some(2.5), 2.0).ratio, Some(2.5));
    }

    #[test]
    fn a_box_flown_as_planned_holds_and_a_missing_manoeuvre_is_named() {
        let prediction = prediction();
        let channels = [flown("mag_1_uc", 1.2, 0.025), flown("mag_2_uc", 2.5, 0.02)];
        let held = compare(&prediction, Some(&box_flown(None)), &channels);
        assert!(held.warnings.is_empty(), "{:?}", held.warnings);
        assert!(held.missing.is_empty() && held.unplanned.is_empty());
        assert!(!held.with_additions);
        assert_eq!(held.channels.len(), 2);
        let as_planned = (held.notes.iter())
            .filter(|n| matches!(n, Note::PlanChannelFigures { as_planned: true, .. }))
            .count();
        assert_eq!(as_planned, 2, "{:?}", held.notes);
        assert!(held.notes.iter().any(|n| n.to_string().ends_with("; as planned")));
        // The roll on the second leg (heading 97°) left out.
        let lacking = compare(&prediction, Some(&box_flown(Some(4))), &channels);
        assert_eq!(lacking.missing, vec!["roll on heading 97°".to_string()]);
        assert_eq!(lacking.warnings.len(), 1);
        assert!(
            matches!(
                &lacking.warnings[0],
                crate::messages::Warning::PlanManoeuvresMissing { missing, planned: 12, .. } if *missing == lacking.missing
            ),
            "{}",
            lacking.warnings[0]
        );
        assert!(lacking.warnings[0]
            .to_string()
            .contains("the flight lacks 1 of the plan's 12 manoeuvres (roll on heading 97°); the plan's prediction counted on them"));
    }

    #[test]
    fn a_figure_beyond_the_factor_warns_on_its_channel() {
        let prediction = prediction();
        // mag_1_uc's range 0.8–1.3 widens to 0.4–2.6; the survey sigma's
        // 0.015–0.03 to 0.0075–0.06.
        let channels = [
            flown("mag_1_uc", 3.1, 0.025),
            flown("mag_2_uc", 2.0, 0.005),
            flown("mag_3_uc", 1.0, 0.1),
        ];
        let result = compare(&prediction, Some(&box_flown(None)), &channels);
        let verdicts: Vec<Vec<Verdict>> = (result.channels.iter())
            .map(|c| c.figures.iter().map(|f| f.verdict).collect())
            .collect();
        use Verdict::*;
        assert_eq!(
            verdicts,
            vec![vec![Worse, AsPlanned, AsPlanned], vec![AsPlanned, Better, AsPlanned]]
        );
        assert_eq!(result.warnings.len(), 2, "{:?}", result.warnings);
        let outside = |w: &crate::messages::Warning| match w {
            crate::messages::Warning::PlanFigureOutside {
                channel, figure, worse, ..
            } => Some((channel.clone(), *figure, *worse)),
            _ => None,
        };
        assert_eq!(
            result.warnings.iter().map(outside).collect::<Vec<_>>(),
            vec![
                Some(("mag_1_uc".to_string(), "FOM", true)),
                Some(("mag_2_uc".to_string(), "stated survey uncertainty", false))
            ]
        );
        assert!(result.warnings[0].to_string().starts_with(
            "mag_1_uc: FOM 3.100 nT against the plan's 1.000 nT (range 0.800–1.300), 3.10×, outside the plan's range widened by its stated factor of 2: worse than planned: "
        ));
        assert!(result.warnings[1]
            .to_string()
            .starts_with("mag_2_uc: stated survey uncertainty 0.005 nT"));
        assert!(result.notes.iter().any(|n| matches!(
            n,
            Note::PlanLacksChannel { channel, .. } if channel == "mag_3_uc"
        )));
        assert!(result
            .notes
            .iter()
            .any(|n| n.to_string().starts_with("mag_3_uc: not in the plan")));
    }

    #[test]
    fn a_flight_with_the_additions_is_compared_with_the_prediction_with_them() {
        let prediction = prediction();
        let mut manoeuvres = box_flown(None);
        manoeuvres.push((ManoeuvreKind::Roll, 5.0));
        let once = compare(&prediction, Some(&manoeuvres), &[flown("mag_1_uc", 0.5, 0.02)]);
        // One of the two proposed rolls flown: the plan as it was, and one
        // roll is unplanned (the planned roll on 7° takes the nearer, 5°).
        assert!(!once.with_additions);
        assert_eq!(once.unplanned, vec!["roll on heading 2°".to_string()]);
        assert_eq!(once.channels[0].figures[0].planned_nt, Some(1.0));
        manoeuvres.push((ManoeuvreKind::Roll, 10.0));
        let both = compare(&prediction, Some(&manoeuvres), &[flown("mag_1_uc", 0.5, 0.02)]);
        assert!(both.with_additions && both.unplanned.is_empty());
        assert_eq!(both.channels[0].figures[0].planned_nt, Some(0.5));
        assert_eq!(both.channels[0].figures[0].verdict, Verdict::AsPlanned);
    }

    #[test]
    fn the_survey_rms_counts_only_line_rows_with_values() {
        let values = [3.0, 1.0, f64::NAN, 1.0, 7.0];
        let line = [0.0, 1.0, 1.0, 2.0, f64::NAN];
        assert_eq!(survey_rms(&values, &line), Some(1.0));
        assert_eq!(survey_rms(&values, &[0.0; 5]), None);
    }
}
