//! The data a model is fitted on: band-passed, trimmed and stacked.
//!
//! For every calibration window, the rows where both the scalar channel and
//! the vector magnetometer are valid are split into contiguous runs (never
//! across a gap). Each run's design columns and scalar readings are
//! band-passed on their own, `trim_samples` are dropped at each end, and
//! the runs are stacked, one fold of the blocked PRESS per window.

use std::ops::Range;

use rayon::prelude::*;
use serde::Serialize;

use crate::calibration::windows::CalibrationWindow;
use crate::error::{Error, Number, Result};
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::model::terms::TermSet;
use crate::numerics::filter::{EdgePadding, FilterBand, FilterError, ZeroPhaseFilter, LANES};
use crate::numerics::segments::valid_runs;
use crate::numerics::solve::SolveOptions;
use crate::numerics::stacked::{Stacked, StackedBuilder, StorePool};

/// Settings of the band-pass applied before fitting.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct FilterSettings {
    /// Pass band.
    pub band: FilterBand,
    /// Butterworth poles.
    pub poles: usize,
    /// Edge extension convention.
    pub padding: EdgePadding,
    /// Samples dropped at each end of every filtered run.
    pub trim_samples: usize,
    /// The field strength the fit's design is built with.
    pub magnitude: FitMagnitude,
}

/// The field strength the fit's Tolles-Lawson columns are built with.
///
/// The induced and eddy terms scale with |B|, and |B| as the fluxgate
/// reads it carries the Earth's own variation (pulsations, the crustal
/// field under the box) into the band, where the scalar reads it too. A
/// fit free to weight it subtracts part of the Earth's field. The
/// traceless terms leave out the two isotropic directions that carry most
/// of it ([`crate::model::terms::TermSet`]); built with each run's mean
/// strength and the recorded direction, the design holds the aircraft's
/// attitude alone, and the fitted coefficients still predict with the
/// field as recorded. That is not recommended: a miscalibrated fluxgate's
/// field is then no longer a linear image of the true one, which the
/// coefficients would otherwise absorb (a cabin sensor's FOM 0.98 → 2.9 nT
/// on a fluxgate with 1.5 % scale errors).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FitMagnitude {
    /// The direction as recorded at the run's mean strength.
    RunMean,
    /// The field as recorded (MagNav.jl's convention).
    Measured,
}

impl Default for FilterSettings {
    /// 4-pole Butterworth band-pass, 0.1–0.9 Hz, 20 samples trimmed, the
    /// design from the field as measured.
    fn default() -> Self {
        FilterSettings {
            band: FilterBand::Bandpass {
                low_hz: 0.1,
                high_hz: 0.9,
            },
            poles: 4,
            padding: EdgePadding::Scipy,
            trim_samples: 20,
            magnitude: FitMagnitude::Measured,
        }
    }
}

/// How a model is fitted, whatever its terms: the band-pass and the
/// regularised solve.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FitOptions {
    /// Band-pass before fitting.
    pub filter: FilterSettings,
    /// Regularised solve.
    pub solve: SolveOptions,
    /// The estimator (`[fit] solver`); ridge by PRESS by default.
    pub solver: crate::numerics::estimators::Solver,
}

/// A window that lost more than this fraction of its samples to gaps in
/// the recording is a manoeuvre cut by gaps: its FOM cell and its share
/// of the fit count only what was kept, and the run says so.
pub const CUT_BY_GAPS: f64 = 0.1;

/// How one window contributed to the fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WindowFit {
    /// The window.
    pub window: CalibrationWindow,
    /// Rows of the stacked (filtered, trimmed) matrix from this window.
    #[serde(skip)]
    pub stacked_rows: Range<usize>,
    /// Samples used after trimming.
    pub samples_used: usize,
    /// Samples of the window left out (gaps, fragments too short to filter, trims).
    pub samples_dropped: usize,
    /// Samples of the flight inside the window.
    pub samples_in_window: usize,
    /// Samples of the window lost to gaps in the recording: invalid
    /// samples, and fragments between gaps too short to filter (the trims
    /// at the ends of the runs kept are not counted).
    pub samples_lost_to_gaps: usize,
    /// Rows of the flight the used samples come from, run by run (trimmed),
    /// in stacked order.
    #[serde(skip)]
    pub flight_rows: Vec<Range<usize>>,
    /// Band-passed uncompensated signal in the window, nT (trimmed runs).
    #[serde(skip)]
    pub band_before_nt: Vec<f64>,
    /// Band-passed residual after compensation in the window, nT.
    #[serde(skip)]
    pub band_after_nt: Vec<f64>,
}

impl WindowFit {
    /// Whether gaps in the recording took more than [`CUT_BY_GAPS`] of
    /// the window's samples.
    pub fn cut_by_gaps(&self) -> bool {
        self.samples_lost_to_gaps as f64 > CUT_BY_GAPS * self.samples_in_window as f64
    }
}

/// The band-passed, trimmed, stacked data of a set of windows.
pub(crate) struct BandData {
    /// Design columns and scalar readings.
    pub stacked: Stacked,
    /// How each window contributed (band-passed signal filled in).
    pub windows: Vec<WindowFit>,
    /// Sample rate the filter was designed for, Hz.
    pub sample_rate_hz: f64,
}

impl BandData {
    /// The band data of some of these windows (indices, in the order
    /// given): bit for bit what [`band_data`] gives on those windows alone,
    /// each window being band-passed on its own rows only.
    pub(crate) fn windows_subset(&self, indices: &[usize], stores: &StorePool) -> BandData {
        let mut start = 0;
        let windows = (indices.iter())
            .map(|&k| {
                let fit = &self.windows[k];
                let rows = start..start + fit.stacked_rows.len();
                start = rows.end;
                WindowFit {
                    stacked_rows: rows,
                    ..fit.clone()
                }
            })
            .collect();
        BandData {
            stacked: self.stacked.folds_subset(indices, stores),
            windows,
            sample_rate_hz: self.sample_rate_hz,
        }
    }
}

/// Band-passes and stacks `windows` of one channel: the columns of
/// `terms`, then `extra` (one value per row of the flight each), then the
/// channel's readings `scalar` (one per row: the recorded ones, or those
/// a model reads, advanced by a lag or less its second-order term).
pub(crate) fn band_data(
    log: &FlightLog,
    sensor: &VectorSensor,
    (channel, scalar): (&str, &[f64]),
    windows: &[CalibrationWindow],
    (terms, settings): (TermSet, &FilterSettings),
    extra: &[&[f64]],
    stores: &StorePool,
) -> Result<BandData> {
    let (filter, needed) = band_pass(log, (channel, scalar), settings)?;
    let sample_rate_hz = 1.0 / log.median_interval_s();
    let trim = settings.trim_samples;
    let plans: Vec<WindowPlan> = windows
        .iter()
        .map(|window| WindowPlan::new(log, sensor, (scalar, extra), window, needed, trim))
        .collect::<Result<_>>()?;
    let field = log.vector_components(sensor);
    let stacked = stack_filtered(
        (field, extra),
        scalar,
        &plans,
        (&filter, settings.magnitude),
        (terms, trim),
        stores,
    )
    .map_err(|e| Error::Fit {
        path: log.source().to_path_buf(),
        channel: channel.into(),
        source: e.into(),
    })?;
    Ok(BandData {
        windows: window_fits(&plans, trim, &stacked),
        stacked,
        sample_rate_hz,
    })
}

/// How each window of `plans` went into `stacked`: its rows there and in
/// the flight, and its band-passed signal.
fn window_fits(plans: &[WindowPlan], trim: usize, stacked: &Stacked) -> Vec<WindowFit> {
    let mut fits: Vec<WindowFit> = Vec::with_capacity(plans.len());
    let mut start = 0;
    for plan in plans {
        let used = plan.used(trim);
        let stacked_rows = start..start + used;
        fits.push(WindowFit {
            window: plan.window.clone(),
            band_before_nt: stacked.column_range(stacked.columns(), stacked_rows.clone()),
            stacked_rows,
            samples_used: used,
            samples_dropped: plan.rows - used,
            samples_in_window: plan.rows,
            samples_lost_to_gaps: plan.rows - plan.runs.iter().map(Range::len).sum::<usize>(),
            flight_rows: plan.runs.iter().map(|r| r.start + trim..r.end - trim).collect(),
            band_after_nt: Vec::new(),
        });
        start += used;
    }
    fits
}

/// The band-pass of `settings` for `log`, and the fewest samples a run
/// needs to be filtered and trimmed; an error when `scalar` (the channel's
/// readings) is not one value per row.
fn band_pass(
    log: &FlightLog,
    (channel, scalar): (&str, &[f64]),
    settings: &FilterSettings,
) -> Result<(ZeroPhaseFilter, usize)> {
    if scalar.len() != log.len() {
        return Err(Error::LengthMismatch {
            column: channel.to_string(),
            found: scalar.len(),
            expected: log.len(),
        });
    }
    let filter = design_filter(log, settings)?;
    let needed = filter.min_samples().max(2 * settings.trim_samples + 1);
    Ok((filter, needed))
}

/// Replaces `band`'s target by `scalar` band-passed over the same windows,
/// the design columns as they are: bit for bit what [`band_data`] gives
/// with `scalar`, since each column is band-passed in its own lane. False,
/// with `band` untouched, when `scalar` is not valid on the very runs the
/// band was made from (then only [`band_data`] will do).
pub(crate) fn replace_target(
    band: &mut BandData,
    log: &FlightLog,
    (sensor, extra): (&VectorSensor, &[&[f64]]),
    (channel, scalar): (&str, &[f64]),
    settings: &FilterSettings,
    stores: &StorePool,
) -> Result<bool> {
    let (filter, needed) = band_pass(log, (channel, scalar), settings)?;
    let trim = settings.trim_samples;
    let mut plans = Vec::with_capacity(band.windows.len());
    for fit in &band.windows {
        let Ok(plan) = WindowPlan::new(log, sensor, (scalar, extra), &fit.window, needed, trim) else {
            return Ok(false);
        };
        let runs = plan.runs.iter().map(|r| r.start + trim..r.end - trim);
        if !runs.eq(fit.flight_rows.iter().cloned()) {
            return Ok(false);
        }
        plans.push(plan);
    }
    let target = filter_target(scalar, &plans, (&filter, trim), stores).map_err(|e| Error::Fit {
        path: log.source().to_path_buf(),
        channel: channel.into(),
        source: e.into(),
    })?;
    if !band.stacked.take_target(&target) {
        stores.recycle(target);
        return Ok(false);
    }
    stores.recycle(target);
    let columns = band.stacked.columns();
    for fit in &mut band.windows {
        fit.band_before_nt = band.stacked.column_range(columns, fit.stacked_rows.clone());
    }
    Ok(true)
}

/// `scalar` band-passed and stacked alone, over every run of `plans`, as
/// [`stack_filtered`] stacks a target: a store with no design columns.
fn filter_target(
    scalar: &[f64],
    plans: &[WindowPlan],
    (filter, trim): (&ZeroPhaseFilter, usize),
    stores: &StorePool,
) -> std::result::Result<Stacked, FilterError> {
    let fold_lengths: Vec<usize> = plans.iter().map(|p| p.used(trim)).collect();
    let mut builder = StackedBuilder::new(&fold_lengths, 0, stores);
    let runs: Vec<Range<usize>> = plans.iter().flat_map(|p| p.runs.iter().cloned()).collect();
    let stacked_rows = stacked_rows(&runs, trim);
    let panel = builder
        .segments_mut(&stacked_rows)
        .into_iter()
        .next()
        .unwrap_or_default();
    panel.into_par_iter().enumerate().try_for_each(|(index, mut output)| {
        let run = runs[index].clone();
        let source = |rows: Range<usize>, out: &mut [[f64; LANES]]| {
            let rows = run.start + rows.start..run.start + rows.end;
            for (row, &value) in out.iter_mut().zip(&scalar[rows]) {
                *row = [0.0; LANES];
                row[0] = value;
            }
        };
        filter.apply_panel(run.len(), source, &mut output, trim)
    })?;
    Ok(builder.finish())
}

/// Whether `window` of `log` holds a run long enough to band-pass and
/// trim as `settings` ask, on which every one of `columns` is valid; false
/// too when the band cannot be designed for the flight's rate.
pub fn window_filterable(
    log: &FlightLog,
    window: &CalibrationWindow,
    columns: &[&[f64]],
    settings: &FilterSettings,
) -> bool {
    let Ok(filter) = design_filter(log, settings) else {
        return false;
    };
    let needed = filter.min_samples().max(2 * settings.trim_samples + 1);
    let rows = window.rows(log.time_s());
    let valid: Vec<bool> = rows
        .clone()
        .map(|row| {
            columns
                .iter()
                .all(|column| column.get(row).is_some_and(|v| v.is_finite()))
        })
        .collect();
    let runs = valid_runs(
        &log.time_s()[rows.clone()],
        &valid,
        0..rows.len(),
        log.median_interval_s(),
    );
    runs.iter().any(|run| run.len() >= needed)
}

/// The runs of one window that are long enough to filter and trim.
struct WindowPlan<'w> {
    window: &'w CalibrationWindow,
    /// Rows of the flight inside the window.
    rows: usize,
    runs: Vec<Range<usize>>,
}

impl<'w> WindowPlan<'w> {
    fn new(
        log: &FlightLog,
        sensor: &VectorSensor,
        (scalar, extra): (&[f64], &[&[f64]]),
        window: &'w CalibrationWindow,
        needed: usize,
        trim: usize,
    ) -> Result<Self> {
        let field = log.vector_components(sensor);
        let rows = window.rows(log.time_s());
        if rows.is_empty() {
            return Err(outside_the_flight(log, window));
        }
        let mut valid: Vec<bool> = scalar[rows.clone()].iter().map(|v| v.is_finite()).collect();
        for column in field.iter().chain(extra) {
            for (ok, value) in valid.iter_mut().zip(&column[rows.clone()]) {
                *ok &= value.is_finite();
            }
        }
        let runs = valid_runs(
            &log.time_s()[rows.clone()],
            &valid,
            0..rows.len(),
            log.median_interval_s(),
        );
        let kept: Vec<Range<usize>> = runs
            .iter()
            .filter(|r| r.len() >= needed)
            .map(|r| rows.start + r.start..rows.start + r.end)
            .collect();
        if kept.is_empty() {
            let longest = runs.iter().map(Range::len).max().unwrap_or(0);
            let problem = format!("its longest run of valid samples has {longest} samples, but filtering and trimming {trim} samples at each end need at least {needed}");
            let missing = valid.iter().filter(|ok| !**ok).count();
            if rows.len() < needed || missing == 0 {
                return Err(too_short(window, problem));
            }
            return Err(broken_by_missing(
                log,
                (sensor, scalar, extra),
                window,
                (&valid, problem),
            ));
        }
        Ok(WindowPlan {
            window,
            rows: rows.len(),
            runs: kept,
        })
    }

    /// Samples this window contributes after trimming.
    fn used(&self, trim: usize) -> usize {
        self.runs.iter().map(|r| r.len() - 2 * trim).sum()
    }
}

/// The run (its index), the panel filled and the panel rows it receives.
type FilterTask<'a> = (usize, usize, Vec<&'a mut [[f64; LANES]]>);

/// Builds the stacked, filtered, trimmed design columns and target: every
/// run of every window, one panel of [`LANES`] columns per filter pass, the
/// passes in parallel. Each pass fills and filters its own panel rows in
/// place, so the result does not depend on the number of threads.
fn stack_filtered(
    (field, extra): ([&[f64]; 3], &[&[f64]]),
    scalar: &[f64],
    plans: &[WindowPlan],
    (filter, magnitude): (&ZeroPhaseFilter, FitMagnitude),
    (terms, trim): (TermSet, usize),
    stores: &StorePool,
) -> std::result::Result<Stacked, FilterError> {
    let count = terms.len();
    let design = count + extra.len();
    let fold_lengths: Vec<usize> = plans.iter().map(|p| p.used(trim)).collect();
    let mut builder = StackedBuilder::new(&fold_lengths, design, stores);
    let runs: Vec<Range<usize>> = plans.iter().flat_map(|p| p.runs.iter().cloned()).collect();
    // Each run's field at its mean strength, indexed from the run's start.
    let steady: Vec<[Vec<f64>; 3]> = match magnitude {
        FitMagnitude::RunMean => runs.iter().map(|run| at_mean_strength(field, run.clone())).collect(),
        FitMagnitude::Measured => Vec::new(),
    };
    let stacked_rows = stacked_rows(&runs, trim);
    // One task per (run, panel), each owning its panel rows.
    let mut tasks: Vec<FilterTask> = Vec::new();
    for (panel, per_run) in builder.segments_mut(&stacked_rows).into_iter().enumerate() {
        for (index, segments) in per_run.into_iter().enumerate() {
            tasks.push((index, panel, segments));
        }
    }
    tasks.into_par_iter().try_for_each(|(index, panel, mut output)| {
        let run = runs[index].clone();
        let group = panel * LANES..(panel + 1) * LANES;
        let term_part = group.start.min(count)..group.end.min(count);
        let sources: Vec<(usize, &[f64])> = (group.start.max(count)..group.end.min(design))
            .map(|column| (column - group.start, extra[column - count]))
            .chain(group.contains(&design).then_some((design - group.start, scalar)))
            .collect();
        let source = |rows: Range<usize>, out: &mut [[f64; LANES]]| {
            let rows = run.start + rows.start..run.start + rows.end;
            if term_part.len() < LANES {
                out.iter_mut().for_each(|row| *row = [0.0; LANES]);
            }
            if !term_part.is_empty() {
                match steady.get(index) {
                    Some(local) => {
                        let local = [local[0].as_slice(), local[1].as_slice(), local[2].as_slice()];
                        let within = rows.start - run.start..rows.end - run.start;
                        terms.fill_lanes(local, 0..run.len(), within, term_part.clone(), out);
                    }
                    None => terms.fill_lanes(field, run.clone(), rows.clone(), term_part.clone(), out),
                }
            }
            for &(lane, source) in &sources {
                for (row, &value) in out.iter_mut().zip(&source[rows.clone()]) {
                    row[lane] = value;
                }
            }
        };
        filter.apply_panel(run.len(), source, &mut output, trim)
    })?;
    Ok(builder.finish())
}

/// The rows of the stack each run fills once trimmed, in order.
fn stacked_rows(runs: &[Range<usize>], trim: usize) -> Vec<Range<usize>> {
    let mut start = 0;
    (runs.iter())
        .map(|run| {
            let rows = start..start + run.len() - 2 * trim;
            start = rows.end;
            rows
        })
        .collect()
}

/// The field over `run` in its recorded direction at the run's mean
/// strength ([`FitMagnitude::RunMean`]).
fn at_mean_strength(field: [&[f64]; 3], run: Range<usize>) -> [Vec<f64>; 3] {
    let strength: Vec<f64> = run
        .clone()
        .map(|k| (field[0][k] * field[0][k] + field[1][k] * field[1][k] + field[2][k] * field[2][k]).sqrt())
        .collect();
    let mean = strength.iter().sum::<f64>() / strength.len().max(1) as f64;
    [0, 1, 2].map(|axis| {
        (run.clone().zip(&strength))
            .map(|(k, total)| field[axis][k] * (mean / total))
            .collect()
    })
}

/// The fit's band-pass filter for `log`'s sample rate (the reciprocal of
/// its median sample interval).
pub fn design_filter(log: &FlightLog, settings: &FilterSettings) -> Result<ZeroPhaseFilter> {
    let interval_s = log.median_interval_s();
    ZeroPhaseFilter::butterworth(settings.band, settings.poles, 1.0 / interval_s, settings.padding).map_err(|source| {
        let hint = match log.len() {
            0 | 1 => format!(
                "The flight has {} row(s); a fit needs minutes of flight at a steady rate, with a calibration box.",
                log.len()
            ),
            _ => format!(
                "The flight is sampled every {} s ({} Hz); set [filter] low_hz and high_hz below half that rate, or resample the flight.",
                Number(interval_s),
                Number(1.0 / interval_s)
            ),
        };
        Error::FilterDesign {
            path: log.source().to_path_buf(),
            source,
            hint,
        }
    })
}

/// A window with no row of the flight: most often windows of another
/// flight, or in another time unit.
fn outside_the_flight(log: &FlightLog, window: &CalibrationWindow) -> Error {
    let time = log.time_s();
    let span = match (time.first(), time.last()) {
        (Some(first), Some(last)) => format!("{} to {} s", Number(*first), Number(*last)),
        _ => "no time at all".into(),
    };
    Error::BadWindow {
        label: window.display_label(),
        t_start: window.t_start,
        t_end: window.t_end,
        problem: format!(
            "it holds no row of {}, whose time column '{}' runs {span}",
            log.source().display(),
            log.time_column()
        ),
        hint: "Windows are in the flight's own time unit: check that the windows (--window, --windows-file or [[flight]] windows) were made for this flight.".into(),
    }
}

/// A window long enough to fit but broken into short runs by missing
/// readings (`valid`, over its rows): whose readings are missing, in gaps
/// how long, and that filling them is the fix.
fn broken_by_missing(
    log: &FlightLog,
    (sensor, scalar, extra): (&VectorSensor, &[f64], &[&[f64]]),
    window: &CalibrationWindow,
    (valid, problem): (&[bool], String),
) -> Error {
    let rows = window.rows(log.time_s());
    let field = log.vector_components(sensor);
    let mut whose = vec![("the scalar".to_string(), &scalar[rows.clone()])];
    for (&axis, column) in sensor.axes.iter().zip(field) {
        whose.push((log.channels()[axis].name.clone(), &column[rows.clone()]));
    }
    whose.extend(
        extra
            .iter()
            .map(|column| ("another column fitted".to_string(), &column[rows.clone()])),
    );
    let counts: Vec<String> = (whose.iter())
        .map(|(name, values)| (name, values.iter().filter(|v| !v.is_finite()).count()))
        .filter(|(_, count)| *count > 0)
        .map(|(name, count)| format!("{name} at {count}"))
        .collect();
    let missing = valid.iter().filter(|ok| !**ok).count();
    let widest = (valid.split(|ok| *ok)).map(<[bool]>::len).max().unwrap_or(0);
    let samples = |n: usize| match n {
        1 => "1 sample".to_string(),
        _ => format!("{n} samples"),
    };
    let fill = match widest <= MOST_INTERPOLATED_GAP {
        true => format!(
            "Fill the missing cells in the file (gaps of {} can be interpolated)",
            samples(widest)
        ),
        false => "Fill the missing cells in the file".to_string(),
    };
    Error::BadWindow {
        label: window.display_label(),
        t_start: window.t_start,
        t_end: window.t_end,
        problem: format!(
            "in {}, {missing} of its {} samples miss a reading ({}), in gaps of up to {}, so that {problem}",
            log.source().display(),
            rows.len(),
            counts.join(", "),
            samples(widest)
        ),
        hint: format!("{fill}, lower trim_samples in [filter], or remove the window."),
    }
}

/// Longest gap a missing-cells error calls fit to interpolate, samples.
const MOST_INTERPOLATED_GAP: usize = 5;

fn too_short(window: &CalibrationWindow, problem: String) -> Error {
    Error::BadWindow {
        label: window.display_label(),
        t_start: window.t_start,
        t_end: window.t_end,
        problem,
        hint: "Lengthen the window, lower trim_samples in [filter], or remove the window.".into(),
    }
}
