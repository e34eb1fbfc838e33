//! What every stage after reading shares: the flight's vector sensor,
//! its channels and its calibration windows, chosen once.

use crate::calibration::detect::{detect_manoeuvres, Detection};
use crate::calibration::windows::CalibrationWindow;
use crate::config::{FlightJob, Settings};
use crate::error::{Error, Result};
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::ingest::screen::{Screened, Screening};
use crate::messages::progress::{Meter, Silent};
use crate::messages::{Note, Warning};
use crate::model::Calibration;

/// Warnings from detection: every incomplete box, and every leg whose
/// pitch and yaw the fluxgate could not tell apart.
pub fn detection_warnings(detection: &Detection) -> Vec<Warning> {
    let mut warnings: Vec<Warning> = detection
        .boxes
        .iter()
        .enumerate()
        .filter(|(_, b)| !b.missing.is_empty())
        .map(|(index, b)| Warning::IncompleteBox {
            number: index + 1,
            start: b.t_start,
            end: b.t_end,
            missing: b.missing.clone(),
        })
        .collect();
    warnings.extend(crate::calibration::detect::uncertain_kinds(detection));
    warnings.extend(detection.steep_field_warning());
    warnings.extend(detection.attitude_gap_warning());
    if !detection.left_out_in_gaps.is_empty() {
        warnings.push(Warning::ManoeuvresInGaps {
            manoeuvres: detection.left_out_in_gaps.clone(),
        });
    }
    warnings
}

/// The windows a flight is calibrated on, with the detection that gave
/// them and a note on their headings: the windows given; else the
/// manoeuvres detected (on the calibration lines only, when the job names
/// lines); else, on lines where none is detected, each line's whole span.
pub fn calibration_windows(
    log: &FlightLog,
    job: &FlightJob,
    options: &Settings,
) -> Result<(
    Vec<crate::calibration::windows::CalibrationWindow>,
    Option<Detection>,
    Option<Note>,
)> {
    let tolerance = options.detect.heading_tolerance_deg;
    if !job.windows.is_empty() {
        let (windows, note) = crate::calibration::windows::headings_from_ins(log, &job.windows, tolerance);
        return Ok((windows, None, note));
    }
    let detection = detect_manoeuvres(log, &options.detect)?;
    if job.lines.is_empty() {
        return Ok((
            detection.calibration_windows(options.detect.window_margin_s),
            Some(detection),
            None,
        ));
    }
    let spans = crate::calibration::windows::line_spans(log, &job.lines)?;
    let detection = detection.on_lines(&spans);
    if !detection.manoeuvres.is_empty() {
        return Ok((
            detection.calibration_windows(options.detect.window_margin_s),
            Some(detection),
            None,
        ));
    }
    // No manoeuvre seen on the lines: each line's span is a window, its
    // heading from the INS where it holds one.
    let whole: Vec<crate::calibration::windows::CalibrationWindow> = (spans.iter())
        .filter(|(_, start, end)| start < end)
        .map(|(line, start, end)| crate::calibration::windows::CalibrationWindow {
            label: format!("line {line}"),
            ..crate::calibration::windows::CalibrationWindow::new(*start, *end)
        })
        .collect();
    let (windows, note) = crate::calibration::windows::headings_from_ins(log, &whole, tolerance);
    let said = Note::LinesAsWindows {
        lines: job.lines.clone(),
        headings: note.map(Box::new),
    };
    Ok((windows, None, Some(said)))
}

/// Diagnoses a screened flight `log`: its vector sensor and channels and
/// its windows (given, or detected) chosen as `job` asks, then
/// [`crate::diagnose::diagnose`].
pub fn diagnose_flight(
    log: &FlightLog,
    job: &FlightJob,
    options: &Settings,
    settings: &crate::diagnose::DiagnoseOptions,
) -> Result<crate::diagnose::Diagnosis> {
    let chosen = Chosen::of(log, None, job, options)?;
    diagnose_calibration(&chosen.calibration(log), (options, settings), &Silent)
}

/// [`crate::diagnose::diagnose`] on `calibration`, the diagnosis naming
/// the flight it was made on; `meter` hears its channels done.
fn diagnose_calibration(
    calibration: &Calibration,
    (options, settings): (&Settings, &crate::diagnose::DiagnoseOptions),
    meter: &dyn Meter,
) -> Result<crate::diagnose::Diagnosis> {
    let settings = (&options.terms, &options.fit, settings);
    let mut diagnosis = crate::diagnose::diagnose_metered(calibration, settings, meter)?;
    diagnosis.flight = Some(crate::ingest::flight_identity::FlightIdentity::of(calibration.log)?);
    Ok(diagnosis)
}

/// A flight read and made ready for the stages, once for `run`,
/// `diagnose` and `simulate --replay`: its samples screened, its vector
/// sensor and scalar channels chosen, its calibration windows given or
/// detected.
#[derive(Debug)]
pub struct PreparedFlight {
    /// The flight as recorded: the compensated output copies it.
    pub recorded: FlightLog,
    /// The samples no instrument can record, masked: what every stage
    /// works on.
    pub screened: Screened,
    /// The vector magnetometer of the direction cosines.
    pub sensor: VectorSensor,
    /// The scalar channels to fit.
    pub channels: Vec<String>,
    /// The calibration windows.
    pub windows: Vec<CalibrationWindow>,
    /// The detection that gave the windows, when they were detected.
    pub detection: Option<Detection>,
    /// How the given windows' headings were found, when they were given.
    pub headings_note: Option<Note>,
}

impl PreparedFlight {
    /// Screens `recorded` and chooses its sensor, channels and windows as
    /// `job` asks. A fluxgate axis or a scalar channel that screening
    /// masked whole is refused by name.
    pub fn new(recorded: FlightLog, job: &FlightJob, options: &Settings) -> Result<Self> {
        let screened = crate::ingest::screen::screen_samples(&recorded)?;
        let log = screened.log_or(&recorded);
        let chosen = Chosen::of(log, Some(&screened.screening), job, options)?;
        Ok(PreparedFlight {
            sensor: chosen.sensor,
            channels: chosen.channels,
            windows: chosen.windows,
            detection: chosen.detection,
            headings_note: chosen.headings_note,
            recorded,
            screened,
        })
    }

    /// The log the stages work on (the screened samples).
    pub fn log(&self) -> &FlightLog {
        self.screened.log_or(&self.recorded)
    }

    /// The calibration on the screened samples.
    pub fn calibration(&self) -> Calibration<'_> {
        Calibration {
            log: self.log(),
            sensor: &self.sensor,
            channels: &self.channels,
            windows: &self.windows,
        }
    }

    /// What screening masked, as warnings.
    pub fn warnings(&self) -> Vec<Warning> {
        self.screened.warnings(&self.recorded)
    }

    /// The flight diagnosed on its calibration; `meter` hears its
    /// channels done.
    pub fn diagnose(
        &self,
        (options, settings): (&Settings, &crate::diagnose::DiagnoseOptions),
        meter: &dyn Meter,
    ) -> Result<crate::diagnose::Diagnosis> {
        diagnose_calibration(&self.calibration(), (options, settings), meter)
    }
}

/// The sensor, channels and windows `job` asks for on a screened log.
struct Chosen {
    sensor: VectorSensor,
    channels: Vec<String>,
    windows: Vec<CalibrationWindow>,
    detection: Option<Detection>,
    headings_note: Option<Note>,
}

impl Chosen {
    /// Chooses on `log`; with `screening`, a column it masked whole is
    /// refused by name first.
    fn of(log: &FlightLog, screening: Option<&Screening>, job: &FlightJob, options: &Settings) -> Result<Self> {
        let sensor = choose_vector_sensor(log, job.vector.as_deref())?;
        if let Some(screening) = screening {
            refuse_dead_columns(log, screening, &sensor, job.channels.as_deref())?;
        }
        let channels = choose_channels(log, job.channels.as_deref())?;
        let (mut windows, mut detection, headings_note) = calibration_windows(log, job, options)?;
        if let Some(detection) = &mut detection {
            detection.left_out_in_gaps = leave_out_gaps(log, (&sensor, &channels), &mut windows, options);
        }
        Ok(Chosen {
            sensor,
            channels,
            windows,
            detection,
            headings_note,
        })
    }

    fn calibration<'a>(&'a self, log: &'a FlightLog) -> Calibration<'a> {
        Calibration {
            log,
            sensor: &self.sensor,
            channels: &self.channels,
            windows: &self.windows,
        }
    }
}

/// Removes from detected `windows` those where gaps in `sensor`'s axes or
/// in one of `channels` leave no run long enough to band-pass (a
/// manoeuvre flown while a sensor dropped out), and returns their labels:
/// the fit goes on with the rest, and the run says what it lacks.
fn leave_out_gaps(
    log: &FlightLog,
    (sensor, channels): (&VectorSensor, &[String]),
    windows: &mut Vec<CalibrationWindow>,
    options: &Settings,
) -> Vec<String> {
    let mut columns: Vec<&[f64]> = log.vector_components(sensor).to_vec();
    columns.extend(
        channels
            .iter()
            .filter_map(|c| log.channel(c))
            .map(|c| c.values.as_slice()),
    );
    let filter = &options.fit.filter;
    let (kept, left_out): (Vec<CalibrationWindow>, Vec<CalibrationWindow>) = std::mem::take(windows)
        .into_iter()
        .partition(|w| crate::model::window_filterable(log, w, &columns, filter));
    // With nothing left, the fit's own error names the first window's gap.
    if kept.is_empty() {
        *windows = left_out;
        return Vec::new();
    }
    *windows = kept;
    left_out.iter().map(CalibrationWindow::display_label).collect()
}

/// What detection found, in a sentence per box and per lack.
pub fn detection_notes(detection: &Detection) -> Vec<Note> {
    let mut notes = vec![Note::Detected {
        manoeuvres: detection.manoeuvres.len(),
        boxes: detection.boxes.len(),
        from_fluxgate: detection.attitude_source == crate::calibration::detect::AttitudeSource::Fluxgate,
    }];
    notes.extend(detection.notes.iter().cloned());
    notes
}

/// An error naming what screening found when it masked every sample of
/// an axis of `sensor` or of a scalar channel to compensate (`wanted`, or
/// every scalar channel): a dead axis or a stuck sensor is named as such,
/// not as an empty column or a calibration window without samples.
pub(super) fn refuse_dead_columns(
    log: &FlightLog,
    screening: &crate::ingest::screen::Screening,
    sensor: &VectorSensor,
    wanted: Option<&[String]>,
) -> Result<()> {
    let fluxgate_hint = format!(
        "No Tolles-Lawson term can be built from '{}' without it. Repair the sensor or its export, or choose another fluxgate with --vector.",
        sensor.prefix
    );
    let scalar_hint = "Leave the channel out with --channels (or [columns] in pipeline.toml) to compensate the others.";
    let axes = sensor.axes.map(|axis| log.channels()[axis].name.clone());
    let scalars: Vec<String> = match wanted {
        Some(list) => list.to_vec(),
        None => log.scalar_channels().into_iter().map(String::from).collect(),
    };
    let needed = (axes.iter().map(|c| (c, fluxgate_hint.as_str()))).chain(scalars.iter().map(|c| (c, scalar_hint)));
    for (column, hint) in needed {
        if let Some(reason) = screening.took_all(log, column) {
            return Err(Error::AllMasked {
                path: log.source().to_path_buf(),
                column: column.clone(),
                reason,
                hint: hint.into(),
            });
        }
    }
    Ok(())
}

/// The vector magnetometer called `wanted`, or the first one found.
pub fn choose_vector_sensor(log: &FlightLog, wanted: Option<&str>) -> Result<VectorSensor> {
    let sensors = log.vector_sensors();
    let found = match wanted {
        Some(prefix) => sensors.iter().find(|s| s.prefix == prefix),
        None => sensors.first(),
    };
    found.cloned().ok_or_else(|| Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "vector magnetometer",
        looked_for: match wanted {
            Some(prefix) => format!("{prefix}_x, {prefix}_y and {prefix}_z"),
            None => "flux_<s>_x, flux_<s>_y and flux_<s>_z".into(),
        },
        hint: format!(
            "The Tolles-Lawson terms are built from a 3-axis fluxgate. {} Choose one with --vector, or map its columns in [[columns.vector]] in pipeline.toml.",
            match sensors.is_empty() {
                true => format!(
                    "The flight has no fluxgate of three such columns; its columns are {}.{}",
                    column_list(log),
                    lost_topics(log)
                ),
                false => format!(
                    "Fluxgates found: {}.",
                    sensors.iter().map(|s| s.prefix.as_str()).collect::<Vec<_>>().join(", ")
                ),
            }
        ),
    })
}

/// The recording's topics that could not be read, for a message about a
/// sensor the flight lacks: a fluxgate may be among them. Empty when none
/// was lost.
fn lost_topics(log: &FlightLog) -> String {
    use crate::messages::{Reading, Warning};
    let lost: Vec<String> = (log.reading_warnings().iter())
        .filter_map(|w| match w {
            Warning::Reading(Reading::McapTopicLost { topic, why }) => Some(format!("'{topic}' ({why})")),
            _ => None,
        })
        .collect();
    match lost.is_empty() {
        true => String::new(),
        false => format!(
            " The recording's topic(s) {} could not be read, and the fluxgate may be among them: write them in an encoding magcomp reads.",
            lost.join(", ")
        ),
    }
}

/// The flight's column names for a message: the first
/// [`LISTED_COLUMNS`], then how many more.
pub(super) fn column_list(log: &FlightLog) -> String {
    let names: Vec<&str> = std::iter::once(log.time_column())
        .chain(log.channels().iter().map(|c| c.name.as_str()))
        .collect();
    let shown: Vec<String> = names.iter().take(LISTED_COLUMNS).map(|n| format!("'{n}'")).collect();
    match names.len() > LISTED_COLUMNS {
        true => format!("{} and {} more", shown.join(", "), names.len() - LISTED_COLUMNS),
        false => shown.join(", "),
    }
}

/// Columns a message lists before "and N more".
pub(super) const LISTED_COLUMNS: usize = 20;

/// The scalar channels to compensate: `wanted`, or every scalar channel.
/// Channels with no valid sample are an error.
pub fn choose_channels(log: &FlightLog, wanted: Option<&[String]>) -> Result<Vec<String>> {
    let channels: Vec<String> = match wanted {
        Some(list) => list.to_vec(),
        None => log.scalar_channels().into_iter().map(String::from).collect(),
    };
    if let Some(twice) = (channels.iter().enumerate()).find_map(|(i, c)| channels[..i].contains(c).then_some(c)) {
        return Err(Error::Config {
            source_name: log.source().display().to_string(),
            message: format!("the channel '{twice}' is asked for twice; name each channel to compensate once"),
        });
    }
    if channels.is_empty() {
        return Err(Error::MissingColumn {
            path: log.source().to_path_buf(),
            role: "scalar magnetometer",
            looked_for: "mag_<n>_uc".into(),
            hint: "Name your scalar channels with --channels or [columns] scalar = [...] in pipeline.toml.".into(),
        });
    }
    for name in &channels {
        let channel = log.channel(name).ok_or_else(|| Error::MissingColumn {
            path: log.source().to_path_buf(),
            role: "scalar magnetometer",
            looked_for: format!("'{name}'"),
            hint: "Check the name given with --channels or in pipeline.toml.".into(),
        })?;
        if channel.values.iter().all(|v| v.is_nan()) {
            return Err(Error::AllMissing {
                path: log.source().to_path_buf(),
                column: name.clone(),
            });
        }
    }
    Ok(channels)
}
