//! Other sensors as interference sensors: the `cross_sensor` candidates.
//!
//! Each fluxgate's magnitude and each other scalar, less a reference
//! scalar (the channel with the least aircraft field of its own, not the
//! channel itself), less its attitude part, is a geology-free signal of
//! what the aircraft does independently of its attitude
//! ([`crate::model::cross_sensor`]). The search scores each as a source
//! column, under the same evidence rule as a recorded column; a recorded
//! column that pays is preferred (it holds the cause itself, where a
//! signal holds another sensor's share of it and that sensor's noise).
//! The synthetic columns live in the log the search reads only, named
//! [`CROSS_COLUMN_PREFIX`]`minuend|reference`; what the search finds on
//! one becomes a `cross_sensor` finding and a [`SourceTerm::CrossSensor`]
//! that rebuilds the signal from the recorded sensors.

use super::*;
use crate::ingest::flight_log::Channel;
use crate::model::cross_sensor::{cross_signal, fit_attitude_parts, CrossSignal, CROSS_COLUMN_PREFIX};

/// The search's log with the cross-sensor columns, their recipes, and
/// which of them each channel may take.
pub(super) struct CrossColumns {
    /// The flight with the synthetic columns added.
    pub(super) log: FlightLog,
    /// Each synthetic column's recipe, by column name.
    pub(super) signals: BTreeMap<String, CrossSignal>,
    /// The synthetic columns each channel may take: none that reads it.
    pub(super) allowed: BTreeMap<String, Vec<String>>,
    /// Why a channel has none.
    pub(super) notes: Vec<Note>,
    /// The channels, least aircraft field first; `None` where a plain fit
    /// failed (the fluxgate check then ranks them itself, and says why).
    pub(super) ranked: Option<Vec<(String, f64)>>,
    /// The channels' names in that order (none where they were not
    /// ranked): the quiet scalars a signal is judged against on the survey.
    pub(super) quietest: Vec<String>,
}

/// The cross-sensor columns of `calibration` ([`cross_columns`]), its
/// channels ranked by their plain fits.
pub(super) fn prepare(
    calibration: &Calibration,
    (terms, options): (&TermSet, &FitOptions),
    stores: &StorePool,
) -> Result<CrossColumns> {
    // A channel whose plain fit fails is said so by its own search; the
    // other sensors' signals are then not tried, in a note.
    let ranked = plain_models(calibration, (terms, options), stores).and_then(|plain| ranked_of(calibration, &plain));
    let ranked = match ranked {
        Ok(ranked) => ranked,
        Err(error) => {
            return Ok(CrossColumns {
                log: calibration.log.clone(),
                signals: BTreeMap::new(),
                allowed: BTreeMap::new(),
                notes: vec![Diagnosing::ChannelNotTested {
                    reason: format!("other sensors as interference sensors not tried: {error}"),
                }
                .into()],
                ranked: None,
                quietest: Vec::new(),
            });
        }
    };
    let mut cross = cross_columns(calibration, &ranked, (terms, options), stores)?;
    cross.quietest = ranked.iter().map(|(channel, _)| channel.clone()).collect();
    cross.ranked = Some(ranked);
    Ok(cross)
}

/// What the search returns: each channel's diagnosis, its findings, and
/// the notes of channels it could not test.
type Searched = (Vec<ChannelDiagnosis>, Vec<Vec<Finding>>, Vec<Note>);

impl CrossColumns {
    /// The search's results with their synthetic columns named as
    /// cross-sensor findings and terms ([`name_cross_sensor`]), and this
    /// preparation's notes added.
    pub(super) fn named(&self, (mut channels, mut findings, mut notes): Searched) -> Searched {
        for found in &mut findings {
            name_cross_sensor((&mut [], found), &self.signals);
        }
        name_cross_sensor((&mut channels, &mut []), &self.signals);
        notes.extend(self.notes.iter().cloned());
        (channels, findings, notes)
    }

    /// The source columns and levels each of `channels` may take: every
    /// one of `levels` but the synthetic columns it is not allowed.
    pub(super) fn levels_by_channel(
        &self,
        channels: &[String],
        levels: &BTreeMap<String, f64>,
    ) -> BTreeMap<String, BTreeMap<String, f64>> {
        (channels.iter())
            .map(|channel| {
                let allowed = self.allowed.get(channel).map(Vec::as_slice).unwrap_or_default();
                let mine = (levels.iter())
                    .filter(|(name, _)| !is_cross_column(name) || allowed.contains(name))
                    .map(|(name, level)| (name.clone(), *level))
                    .collect();
                (channel.clone(), mine)
            })
            .collect()
    }
}

/// No cross-sensor signals: a problem without the other sensors.
#[cfg(test)]
pub(super) static NO_SIGNALS: BTreeMap<String, CrossSignal> = BTreeMap::new();

/// Whether `name` is a synthetic cross-sensor column.
pub(super) fn is_cross_column(name: &str) -> bool {
    name.starts_with(CROSS_COLUMN_PREFIX)
}

/// Every scalar channel of `calibration` with its aircraft field's size
/// (the standard deviation over the windows of the interference plain
/// Tolles-Lawson fitted on them predicts, nT), least first.
pub(super) fn ranked_by_interference(
    calibration: &Calibration,
    (terms, options): (&TermSet, &FitOptions),
    stores: &StorePool,
) -> Result<Vec<(String, f64)>> {
    let models = plain_models(calibration, (terms, options), stores)?;
    ranked_of(calibration, &models)
}

/// Each channel of `calibration` fitted with plain Tolles-Lawson.
pub(super) fn plain_models(
    calibration: &Calibration,
    (terms, options): (&TermSet, &FitOptions),
    stores: &StorePool,
) -> Result<Vec<FittedModel>> {
    let Calibration {
        log,
        sensor,
        channels,
        windows,
    } = *calibration;
    let plain = ModelSpec::plain(*terms);
    channels
        .par_iter()
        .map(|channel| fit(log, sensor, channel, windows, &plain, options, stores))
        .collect()
}

/// [`ranked_by_interference`] from the channels' plain `models`.
pub(super) fn ranked_of(calibration: &Calibration, models: &[FittedModel]) -> Result<Vec<(String, f64)>> {
    let Calibration {
        log, channels, windows, ..
    } = *calibration;
    let compensation = crate::compensate::compensate(log, models, crate::compensate::LevelConvention::Absolute)?;
    let rows = window_rows(log.time_s(), windows);
    let mut ranked: Vec<(String, f64)> = (channels.iter().zip(&compensation.channels))
        .filter_map(|(channel, compensated)| {
            let raw = log.channel(channel)?;
            let interference: Vec<f64> = (rows.iter())
                .map(|&k| raw.values[k] - compensated.values[k])
                .filter(|v| v.is_finite())
                .collect();
            Some((channel.clone(), crate::quality::standard_deviation(&interference)))
        })
        .collect();
    ranked.sort_by(|a, b| a.1.total_cmp(&b.1));
    Ok(ranked)
}

/// The cross-sensor columns of `calibration`: for each channel, every
/// fluxgate and the [`WITNESSES`] other scalars with the most aircraft
/// field of their own (a source on board reaches the busiest sensors)
/// against each of the [`REFERENCES`] quietest other scalars, a pair of
/// scalars once. `ranked` is [`ranked_by_interference`]'s order.
pub(super) fn cross_columns(
    calibration: &Calibration,
    ranked: &[(String, f64)],
    (terms, options): (&TermSet, &FitOptions),
    stores: &StorePool,
) -> Result<CrossColumns> {
    let log = calibration.log;
    let fluxgates: Vec<String> = log.vector_sensors().into_iter().map(|s| s.prefix).collect();
    let scalars: Vec<&str> = ranked.iter().map(|(c, _)| c.as_str()).collect();
    let (wanted, notes) = wanted_signals(calibration.channels, (&fluxgates, &scalars));
    let mut pairs: Vec<(String, String)> = wanted.iter().map(|(_, m, r)| (m.clone(), r.clone())).collect();
    pairs.sort();
    pairs.dedup();
    // Each sensor's attitude part once, whatever the pairs it is in.
    let mut sensors: Vec<String> = pairs.iter().flat_map(|(m, r)| [m.clone(), r.clone()]).collect();
    sensors.sort();
    sensors.dedup();
    let (sensor, windows) = (calibration.sensor, calibration.windows);
    let parts = fit_attitude_parts(log, sensor, (&sensors, windows), (*terms, options, stores))?;
    let fitted: Vec<Option<CrossSignal>> = pairs
        .par_iter()
        .map(|(minuend, reference)| {
            let (Some(m), Some(r)) = (parts.get(minuend), parts.get(reference)) else {
                return Ok(None);
            };
            cross_signal(log, sensor, ((minuend, m), (reference, r)), windows).map(Some)
        })
        .collect::<Result<_>>()?;
    let mut signals: BTreeMap<String, CrossSignal> = BTreeMap::new();
    let mut columns = log.channels().to_vec();
    for signal in fitted.into_iter().flatten() {
        let values = signal.values(log)?;
        let name = format!("{CROSS_COLUMN_PREFIX}{}", signal.name());
        columns.push(Channel {
            name: name.clone(),
            role: ChannelRole::Auxiliary,
            values,
        });
        signals.insert(name, signal);
    }
    let mut allowed: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for (channel, minuend, reference) in &wanted {
        let name = format!("{CROSS_COLUMN_PREFIX}{minuend}|{reference}");
        if signals.contains_key(&name) {
            allowed.entry(channel.clone()).or_default().push(name);
        }
    }
    Ok(CrossColumns {
        log: log.with_channels(columns)?,
        signals,
        allowed,
        notes,
        ranked: None,
        quietest: Vec::new(),
    })
}

/// (channel, minuend, reference) of every signal each of `channels` may
/// take, `scalars` least aircraft field first; a note for each channel
/// that has none.
fn wanted_signals(
    channels: &[String],
    (fluxgates, scalars): (&[String], &[&str]),
) -> (Vec<(String, String, String)>, Vec<Note>) {
    let mut wanted = Vec::new();
    let mut notes = Vec::new();
    for channel in channels {
        let others: Vec<&str> = scalars.iter().copied().filter(|s| s != channel).collect();
        if others.is_empty() {
            notes.push(not_tried(channel, fluxgates.len()));
            continue;
        }
        for (rank, reference) in others.iter().take(REFERENCES).enumerate() {
            let busiest = (others.iter().enumerate().rev())
                .filter(|(k, _)| *k > rank)
                .take(WITNESSES)
                .map(|(_, s)| *s);
            for minuend in fluxgates.iter().map(String::as_str).chain(busiest) {
                wanted.push((channel.clone(), minuend.to_string(), reference.to_string()));
            }
        }
    }
    (wanted, notes)
}

/// The quietest scalars each channel's signals are taken against.
const REFERENCES: usize = 2;

/// The other scalars taken as witnesses besides the fluxgates.
const WITNESSES: usize = 3;

/// Why `channel` has no cross-sensor signal: the flight has no other
/// scalar to take as reference (with `fluxgates` fluxgates, each less
/// this channel would hold the channel's own interference).
fn not_tried(channel: &str, fluxgates: usize) -> Note {
    Diagnosing::CrossSensorNotTried {
        channel: channel.to_string(),
        fluxgates,
    }
    .into()
}

/// The diagnosis's findings and models on synthetic columns turned into
/// `cross_sensor` findings and [`SourceTerm::CrossSensor`] terms that
/// rebuild their signal from the recorded sensors.
pub(super) fn name_cross_sensor(
    (channels, findings): (&mut [ChannelDiagnosis], &mut [Finding]),
    signals: &BTreeMap<String, CrossSignal>,
) {
    for channel in channels {
        for source in &mut channel.model.sources {
            let SourceTerm::AuxCoupling { column, .. } = source else {
                continue;
            };
            if let Some(signal) = signals.get(column.as_str()) {
                *source = SourceTerm::CrossSensor {
                    name: signal.name(),
                    signal: signal.clone(),
                    survey_gain: None,
                };
            }
        }
        channel.model.sources.retain(|s| !is_cross_column(s.column()));
    }
    for finding in findings {
        let Some(signal) = finding.source.as_deref().and_then(|s| signals.get(s)) else {
            continue;
        };
        if let Effect::AuxCoupling(coupling) = &finding.effect {
            finding.effect = Effect::CrossSensor(CrossSensor {
                k: coupling.k_nt_per_unit.unwrap_or_default(),
                survey: None,
                survey_gain: None,
            });
        }
        finding.source = Some(signal.name());
        let survey = match &finding.effect {
            Effect::CrossSensor(cross) => cross.survey.clone(),
            _ => None,
        };
        finding.explanation = cross_explanation(signal, &finding.channel, survey.as_ref());
    }
}

/// A cross-sensor finding in words, with what the survey says of it.
fn cross_explanation(signal: &CrossSignal, channel: &str, survey: Option<&SurveyEvidence>) -> String {
    let mut words = format!(
        "{channel} carries interference its attitude terms cannot hold, and {} less {} (their attitude part taken out, the geology cancelling between sensors a metre or two apart) sees it too: a source on board that varies on its own, such as a current no column records. The signal of those sensors is coupled into {channel} through the field's direction.",
        signal.minuend, signal.reference
    );
    words += &match survey {
        Some(s) => format!(
            " On the survey lines, which the fit never saw, {channel}'s difference from {} falls from {:.3} to {:.3} nT RMS with it ({:+.0} %), lower on {} of {} lines{}.",
            s.reference,
            s.before_nt,
            s.after_nt,
            100.0 * (s.after_nt / s.before_nt - 1.0),
            s.lines_lower,
            s.lines,
            match s.holds() {
                true => "",
                false => ": the survey does not bear it out",
            }
        ),
        None => " The survey could not judge it: the flight has no survey lines outside the calibration, or no quiet scalar the signal does not read.".into(),
    };
    words
}
