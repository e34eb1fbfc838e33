//! A flight made ready for one channel's model: the fluxgate calibrated,
//! the scalar read `lag_s` earlier, and the extension columns built. The
//! fit, the held-out residual and the prediction all start here, so they
//! see the same data.

use std::borrow::Cow;
use std::ops::Range;

use crate::calibration::headings::{distinct_headings, same_heading};
use crate::calibration::windows::{merged_rows, CalibrationWindow};
use crate::error::{Error, Result};
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::numerics::estimators::{compare, compare_families, Decomposed, Factor, Scored, Solver};
use crate::numerics::solve::{solve_again, solve_keeping, DesignFactor, Solution};
use crate::numerics::stacked::{Stacked, StorePool};

use super::band::{band_data, replace_target, BandData, FitOptions, WindowFit};
use super::extensions::{advanced, advanced_on, field_directions, lagged_rate, rate_at, second_order_term, SourceTerm};
use super::{FittedModel, ModelSpec, SolverUse, SECOND_ORDER_PASSES};

/// One extension column: a regressor beside the Tolles-Lawson terms.
#[derive(Debug, Clone)]
pub(crate) struct ExtraColumn {
    /// Name, appended to the term names.
    pub name: String,
    /// One value per row of the flight.
    pub values: Vec<f64>,
}

/// What a model of one channel is fitted on and predicts from.
#[derive(Debug, Clone)]
pub(crate) struct Prepared<'a> {
    /// The flight with the fluxgate calibrated and the scalar advanced by
    /// the lag (borrowed when neither applies).
    pub log: Cow<'a, FlightLog>,
    /// The vector magnetometer the terms are built from.
    pub sensor: &'a VectorSensor,
    /// The scalar channel.
    pub channel: &'a str,
    /// The model.
    pub spec: &'a ModelSpec,
    /// Extension columns, in the order their coefficients follow the terms'.
    pub extra: Vec<ExtraColumn>,
    /// What the model is fitted to: the scalar channel's readings,
    /// advanced by the lag, less a base station's variation (borrowed when
    /// neither applies): the flight itself is never copied for it.
    pub scalar: Cow<'a, [f64]>,
    /// The rows the extension columns and a changed scalar hold values on
    /// (zero elsewhere), for a fit and its held-out residual on windows
    /// within them ([`Self::on_rows`]); `None`: every row.
    filled: Option<Vec<Range<usize>>>,
}

impl<'a> Prepared<'a> {
    /// Calibrates the fluxgate, advances the scalar and builds the
    /// extension columns of `spec`. A source column the flight lacks is an
    /// error.
    pub fn new(log: &'a FlightLog, sensor: &'a VectorSensor, channel: &'a str, spec: &'a ModelSpec) -> Result<Self> {
        let calibrated = match &spec.extensions.vector_calibration {
            Some(calibration) => Cow::Owned(calibration.apply(log, sensor)?),
            None => Cow::Borrowed(log),
        };
        // Only the extension columns use the field's direction.
        let extensions = &spec.extensions;
        let direction = match extensions.eddy_tau_s > 0.0 || !extensions.sources.is_empty() {
            true => field_directions(&calibrated, sensor),
            false => Default::default(),
        };
        Self::with_directions(calibrated, sensor, channel, spec, &direction)
    }

    /// [`Self::new`] on a flight whose fluxgate is already what the model
    /// uses (the spec's calibration is not applied again), with its unit
    /// field directions.
    pub fn with_directions(
        log: Cow<'a, FlightLog>,
        sensor: &'a VectorSensor,
        channel: &'a str,
        spec: &'a ModelSpec,
        direction: &[Vec<f64>; 3],
    ) -> Result<Self> {
        Self::build((log, sensor, channel), spec, direction, None)
    }

    /// [`Self::with_directions`] for fits and held-out residuals on windows
    /// within `rows` alone (the diagnosis scores hundreds of candidates on
    /// a box that is a fraction of the flight): the extension columns and
    /// a lagged or station-corrected scalar are computed on those rows,
    /// each value as on the whole flight, and are zero elsewhere. A fit or
    /// residual on a window beyond them is an error.
    pub fn on_rows(
        log: Cow<'a, FlightLog>,
        (sensor, channel): (&'a VectorSensor, &'a str),
        spec: &'a ModelSpec,
        direction: &[Vec<f64>; 3],
        rows: Vec<Range<usize>>,
    ) -> Result<Self> {
        Self::build((log, sensor, channel), spec, direction, Some(rows))
    }

    fn build(
        (log, sensor, channel): (Cow<'a, FlightLog>, &'a VectorSensor, &'a str),
        spec: &'a ModelSpec,
        direction: &[Vec<f64>; 3],
        filled: Option<Vec<Range<usize>>>,
    ) -> Result<Self> {
        let extensions = &spec.extensions;
        let scale = spec.terms.bt_scale_nt;
        let rows = filled.as_deref();
        let n = log.len();
        // Lagged eddy terms first: the newest source term stays last.
        let mut extra = match extensions.eddy_tau_s > 0.0 {
            true => lagged_eddy_columns(&log, sensor, direction, (extensions.eddy_tau_s, scale), rows),
            false => Vec::new(),
        };
        let mut push = |name: String, values: Vec<f64>| extra.push(ExtraColumn { name, values });
        for source in &extensions.sources {
            let columns = match source {
                SourceTerm::CrossSensor {
                    name,
                    signal,
                    survey_gain: None,
                } => cross_sensor_columns((name, signal), &log, direction, rows)?,
                // Subtracted from the scalar below: the station with gain
                // 1, a survey-fitted signal with its gain.
                SourceTerm::ExternalField { .. } | SourceTerm::CrossSensor { .. } => Vec::new(),
                SourceTerm::AuxCoupling { .. } | SourceTerm::AuxCouplingRate { .. } => {
                    recorded_source_columns(&log, (source, channel), direction, rows)?
                }
            };
            for column in columns {
                push(column.name, column.values);
            }
        }
        let scalar = match (&log, extensions.lag_s) {
            (_, lag_s) if lag_s != 0.0 => {
                let recorded = scalar_values(&log, channel)?;
                Cow::Owned(match rows {
                    None => advanced(recorded, log.time_s(), lag_s),
                    Some(rows) => advanced_on(recorded, log.time_s(), lag_s, rows),
                })
            }
            (Cow::Borrowed(flight), _) => Cow::Borrowed(scalar_values(flight, channel)?),
            (Cow::Owned(flight), _) => Cow::Owned(scalar_values(flight, channel)?.to_vec()),
        };
        let scalar = less_base_stations(scalar, &log, &extensions.sources, (n, rows));
        let scalar = less_survey_fitted(scalar, &log, &extensions.sources, (n, rows))?;
        Ok(Prepared {
            log,
            sensor,
            channel,
            spec,
            extra,
            scalar,
            filled,
        })
    }

    /// An error when `windows` reach beyond the rows this preparation
    /// holds values on ([`Self::on_rows`]).
    fn check_filled(&self, windows: &[CalibrationWindow]) -> Result<()> {
        let Some(filled) = &self.filled else {
            return Ok(());
        };
        let time = self.log.time_s();
        match windows.iter().map(|w| w.rows(time)).all(|r| {
            r.is_empty() || filled.iter().any(|f| f.start <= r.start && r.end <= f.end)
        }) {
            true => Ok(()),
            false => Err(Error::Fit {
                path: self.log.source().to_path_buf(),
                channel: self.channel.into(),
                source: crate::error::FitFailure::Other(
                    "a window reaches beyond the rows its columns were prepared on (a fault of magcomp's, not of the flight)".into(),
                ),
            }),
        }
    }

    /// Whether `windows` lie within the rows this preparation holds values
    /// on: what band data built from its columns outside [`Self::fit`] and
    /// [`Self::held_out`] must check.
    pub(crate) fn covers(&self, windows: &[CalibrationWindow]) -> bool {
        self.check_filled(windows).is_ok()
    }

    /// The extension columns as the band data takes them.
    pub(crate) fn extra_columns(&self) -> Vec<&[f64]> {
        self.extra.iter().map(|c| c.values.as_slice()).collect()
    }

    /// Fits the model on `windows`, refitting on the scalar less the
    /// second-order term when the model has it; the stacked data's stores
    /// come from and go back to `stores`.
    pub fn fit(&self, windows: &[CalibrationWindow], options: &FitOptions, stores: &StorePool) -> Result<FittedModel> {
        if windows.is_empty() {
            return Err(Error::NoCalibrationWindows {
                path: self.log.source().to_path_buf(),
            });
        }
        self.check_filled(windows)?;
        let band = self.band_with(&self.scalar, windows, options, stores)?;
        self.fit_passes(band, options, stores)
    }

    /// The fit on `band` (this model's columns and the scalar as prepared,
    /// over its windows), then each second-order pass: the same design
    /// columns fitted to the scalar less the term of the fit before, only
    /// that scalar band-passed again and the design's decomposition kept.
    /// The band's store goes back to `stores`.
    fn fit_passes(&self, mut band: BandData, options: &FitOptions, stores: &StorePool) -> Result<FittedModel> {
        let fitted = self.passes_on(&mut band, options, stores);
        stores.recycle(band.stacked);
        fitted
    }

    /// [`Self::fit_passes`] on a band it may change.
    fn passes_on(&self, band: &mut BandData, options: &FitOptions, stores: &StorePool) -> Result<FittedModel> {
        if !self.spec.extensions.second_order {
            // The only pass: the model takes the band's windows.
            let windows = std::mem::take(&mut band.windows);
            return Ok(self.fit_windows(band, windows, None, options)?.0);
        }
        let (mut fitted, mut factor) = self.fit_on(band, None, options)?;
        let windows: Vec<CalibrationWindow> = band.windows.iter().map(|w| w.window.clone()).collect();
        for _ in 0..SECOND_ORDER_PASSES {
            let corrected = self.corrected(&fitted, &windows);
            if !self.replace_target(band, &corrected, options, stores)? {
                // The corrected scalar is valid on other rows: band it afresh.
                let afresh = self.band_with(&corrected, &windows, options, stores)?;
                stores.recycle(std::mem::replace(band, afresh).stacked);
                factor = None;
            }
            let (next, made) = self.fit_on(band, factor.as_ref(), options)?;
            fitted = next;
            factor = made.or(factor);
        }
        Ok(fitted)
    }

    /// [`replace_target`] with this preparation's flight and columns.
    fn replace_target(
        &self,
        band: &mut BandData,
        scalar: &[f64],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<bool> {
        replace_target(
            band,
            &self.log,
            (self.sensor, &self.extra_columns()),
            (self.channel, scalar),
            &options.filter,
            stores,
        )
    }

    /// The fit on `band` of this preparation's columns, its design
    /// decomposed afresh or, given `factor` (of the same design columns),
    /// reused; with the decomposition made, if one was.
    fn fit_on(
        &self,
        band: &BandData,
        factor: Option<&DesignFactor>,
        options: &FitOptions,
    ) -> Result<(FittedModel, Option<DesignFactor>)> {
        self.fit_windows(band, band.windows.clone(), factor, options)
    }

    /// [`Self::fit_on`] with the band's `windows` given apart (the band's
    /// own, or a copy of them), for the model to keep.
    fn fit_windows(
        &self,
        band: &BandData,
        windows: Vec<WindowFit>,
        factor: Option<&DesignFactor>,
        options: &FitOptions,
    ) -> Result<(FittedModel, Option<DesignFactor>)> {
        let stacked = &band.stacked;
        let solve = self.spec.solve_options(&options.solve);
        let solved = match factor {
            Some(factor) => solve_again(stacked, factor, &solve).map(|solution| (solution, None)),
            None => solve_keeping(stacked, &solve).map(|(solution, made)| (solution, Some(made))),
        };
        let (mut solution, made) = solved.map_err(|e| Error::Fit {
            path: self.log.source().to_path_buf(),
            channel: self.channel.into(),
            source: e.into(),
        })?;
        let chosen = match options.solver {
            Solver::Ridge => None,
            requested => Some(solve_on_headings(stacked, &windows, requested, &mut solution)),
        };
        let model = self.fitted_model((windows, band.sample_rate_hz), (solution, chosen), options);
        Ok((model, made))
    }

    /// The model `solution` makes on the band's windows `fits` (sampled at
    /// `sample_rate_hz`): its coefficients, their uncertainty and each
    /// window's band-passed residual.
    fn fitted_model(
        &self,
        (mut fits, sample_rate_hz): (Vec<WindowFit>, f64),
        (solution, chosen): (Solution, Option<SolverUse>),
        options: &FitOptions,
    ) -> FittedModel {
        for fit in &mut fits {
            fit.band_after_nt = (fit.band_before_nt.iter())
                .zip(&solution.fitted[fit.stacked_rows.clone()])
                .map(|(y, f)| y - f)
                .collect();
        }
        // A residual of bandwidth B holds only 2B independent samples a
        // second (Nyquist): the white-noise standard errors are scaled by
        // √(f_s / 2B).
        let correlation = (sample_rate_hz / (2.0 * options.filter.band.bandwidth_hz(sample_rate_hz)))
            .max(1.0)
            .sqrt();
        FittedModel {
            solver: chosen,
            coefficient_uncertainty: solution.standard_errors.iter().map(|e| e * correlation).collect(),
            channel: self.channel.into(),
            vector_sensor: self.sensor.prefix.clone(),
            spec: self.spec.clone(),
            term_names: (self.spec.fitted_terms().names().into_iter())
                .chain(self.extra.iter().map(|c| c.name.clone()))
                .collect(),
            coefficients: solution.coefficients.clone(),
            filter: options.filter,
            sample_rate_hz,
            solution,
            windows: fits,
            estimators: None,
            excitation: None,
            calibration_level: None,
        }
    }

    /// Every estimator of the family ([`crate::numerics::estimators`]) on
    /// this model's band-passed design over `windows`, each held out
    /// heading by heading: one R factor per heading, each heading predicted
    /// from the others'. `None` when the windows span fewer than three
    /// headings or one has none. The design is the first-order one (the
    /// flight as recorded, without the second-order term's correction).
    pub fn compare_estimators(
        &self,
        windows: &[CalibrationWindow],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<Option<Vec<Scored>>> {
        let headings = distinct_headings(windows);
        if headings.len() < 3 || windows.iter().any(|w| w.heading_deg.is_none()) {
            return Ok(None);
        }
        self.check_filled(windows)?;
        let BandData {
            stacked, windows: fits, ..
        } = self.band_with(&self.scalar, windows, options, stores)?;
        let factors = heading_factors(&stacked, &fits);
        stores.recycle(stacked);
        Ok(factors.map(|f| compare(&f)))
    }

    /// The band-passed residual of `fitted` (a model of this spec) on
    /// `windows`, which it need not have been fitted on.
    pub fn held_out(
        &self,
        fitted: &FittedModel,
        windows: &[CalibrationWindow],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<Vec<WindowFit>> {
        self.check_filled(windows)?;
        let corrected = self.corrected(fitted, windows);
        let data = self.band_with(&corrected, windows, options, stores)?;
        Ok(Self::residual_on(data, fitted, stores))
    }

    /// Band data of `windows` with the scalar as prepared: each window
    /// band-passed once, for [`Self::fit_within`] and
    /// [`Self::held_out_within`] on any part of them.
    pub(crate) fn band(
        &self,
        windows: &[CalibrationWindow],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<BandData> {
        self.check_filled(windows)?;
        self.band_with(&self.scalar, windows, options, stores)
    }

    /// Band data of `windows` with `scalar` as the target.
    fn band_with(
        &self,
        scalar: &[f64],
        windows: &[CalibrationWindow],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<BandData> {
        band_data(
            &self.log,
            self.sensor,
            (self.channel, scalar),
            windows,
            (self.spec.fitted_terms(), &options.filter),
            &self.extra_columns(),
            stores,
        )
    }

    /// What the model is fitted to on `windows` once fitted there: the
    /// scalar as prepared, or with the second-order term the scalar less
    /// the term of the fit on `windows` (its last pass's target).
    pub(crate) fn fitted_target(
        &self,
        windows: &[CalibrationWindow],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<Cow<'_, [f64]>> {
        if !self.spec.extensions.second_order {
            return Ok(Cow::Borrowed(&self.scalar));
        }
        let fitted = self.fit(windows, options, stores)?;
        Ok(self.corrected(&fitted, windows))
    }

    /// [`Self::fit`] on the windows `indices` of `band`: the same fit, bit
    /// for bit, without band-passing their design columns again (the
    /// second-order passes band-pass only their scalar).
    pub(crate) fn fit_within(
        &self,
        band: &BandData,
        indices: &[usize],
        options: &FitOptions,
        stores: &StorePool,
    ) -> Result<FittedModel> {
        if indices.is_empty() {
            return Err(Error::NoCalibrationWindows {
                path: self.log.source().to_path_buf(),
            });
        }
        self.fit_passes(band.windows_subset(indices, stores), options, stores)
    }

    /// [`Self::held_out`] on the windows `indices` of `band`, bit for bit.
    pub(crate) fn held_out_within(
        &self,
        band: &BandData,
        fitted: &FittedModel,
        (indices, options): (&[usize], &FitOptions),
        stores: &StorePool,
    ) -> Result<Vec<WindowFit>> {
        let mut data = band.windows_subset(indices, stores);
        if self.spec.extensions.second_order {
            let windows: Vec<CalibrationWindow> = data.windows.iter().map(|w| w.window.clone()).collect();
            let corrected = self.corrected(fitted, &windows);
            if !self.replace_target(&mut data, &corrected, options, stores)? {
                let afresh = self.band_with(&corrected, &windows, options, stores)?;
                stores.recycle(std::mem::replace(&mut data, afresh).stacked);
            }
        }
        Ok(Self::residual_on(data, fitted, stores))
    }

    /// Each window's band-passed residual from `fitted`'s prediction.
    fn residual_on(data: BandData, fitted: &FittedModel, stores: &StorePool) -> Vec<WindowFit> {
        let mut fits = data.windows;
        let predicted = data.stacked.predict(&fitted.coefficients);
        stores.recycle(data.stacked);
        for fit in &mut fits {
            fit.band_after_nt = (fit.band_before_nt.iter().zip(&predicted[fit.stacked_rows.clone()]))
                .map(|(y, f)| y - f)
                .collect();
        }
        fits
    }

    /// The prepared flight with the channel less the second-order term of
    /// `fitted`'s aircraft field over the rows of `windows` (the only rows
    /// a fit or its residual reads; the rest unchanged), or unchanged
    /// without the term. Each stretch of window rows is computed with one
    /// row either side, so the field's rate at its ends is what the whole
    /// flight gives.
    fn corrected(&self, fitted: &FittedModel, windows: &[CalibrationWindow]) -> Cow<'_, [f64]> {
        if !self.spec.extensions.second_order {
            return Cow::Borrowed(&self.scalar);
        }
        let merged = merged_rows(windows, self.log.time_s());
        let field = self.log.vector_components(self.sensor);
        let terms = self.spec.fitted_terms();
        let mut corrected = self.scalar.to_vec();
        for rows in merged {
            let (from, to) = (rows.start.saturating_sub(1), (rows.end + 1).min(corrected.len()));
            let term = second_order_term(field.map(|axis| &axis[from..to]), &terms, &fitted.coefficients);
            for (row, q) in (from..to).zip(term).filter(|(row, _)| rows.contains(row)) {
                corrected[row] = self.scalar[row] - q;
            }
        }
        Cow::Owned(corrected)
    }
}

/// The nine eddy terms with the field's rate lagged by `tau_s`:
/// $u_i \dot B_j^{(\tau)} / s$ for the `direction` cosines u, on `rows`
/// (every row without).
fn lagged_eddy_columns(
    log: &FlightLog,
    sensor: &VectorSensor,
    direction: &[Vec<f64>; 3],
    (tau_s, scale): (f64, f64),
    rows: Option<&[Range<usize>]>,
) -> Vec<ExtraColumn> {
    let dt = log.median_interval_s();
    let lagged: Vec<Vec<f64>> = (log.vector_components(sensor).iter())
        .map(|b| lagged_rate(b, dt, tau_s))
        .collect();
    let mut columns = Vec::with_capacity(9);
    for (i, axis_i) in ["x", "y", "z"].iter().enumerate() {
        for (j, axis_j) in ["x", "y", "z"].iter().enumerate() {
            columns.push(ExtraColumn {
                name: format!("eddy_lagged_{axis_i}{axis_j}"),
                values: column_on(log.len(), rows, |k| direction[i][k] * lagged[j][k] / scale),
            });
        }
    }
    columns
}

/// The scalar less each base station's variation among `sources` (its
/// quiet record less its level: [`super::station`]), on `rows` of the
/// flight's `n` (all without).
/// A base station's variation is the Earth's field, which the aircraft's
/// sensor reads as the station does: the model is fitted on the scalar
/// less it, gain 1, so it cannot bias the aircraft's coefficients and no
/// fitted gain can take up the aircraft's own field in its place. The
/// compensated channel keeps it (removing it is the survey's diurnal
/// correction, a step of its own).
fn less_base_stations<'s>(
    scalar: Cow<'s, [f64]>,
    log: &FlightLog,
    sources: &[SourceTerm],
    (n, rows): (usize, Option<&[Range<usize>]>),
) -> Cow<'s, [f64]> {
    let stations: Vec<(std::sync::Arc<super::station::QuietStation>, f64)> = (sources.iter())
        .filter_map(|source| match source {
            SourceTerm::ExternalField { column, level } => {
                super::station::shared_quiet_station(log, column).map(|values| (values, *level))
            }
            _ => None,
        })
        .collect();
    match stations.is_empty() {
        true => scalar,
        false => Cow::Owned(column_on(n, rows, |row| {
            scalar[row] - stations.iter().map(|(c, level)| c.values[row] - level).sum::<f64>()
        })),
    }
}

/// The scalar less each survey-fitted cross-sensor term among `sources`
/// ([`survey_fitted_part`]), on `rows` of the `n` (every row when `None`).
/// The box's fit then holds the rest of the aircraft's field, as with a
/// base station's record.
fn less_survey_fitted<'s>(
    scalar: Cow<'s, [f64]>,
    log: &FlightLog,
    sources: &[SourceTerm],
    (n, rows): (usize, Option<&[Range<usize>]>),
) -> Result<Cow<'s, [f64]>> {
    let Some(part) = survey_fitted_part(log, sources)? else {
        return Ok(scalar);
    };
    Ok(Cow::Owned(column_on(n, rows, |row| scalar[row] - part[row])))
}

/// $\sum g\,s$ over the survey-fitted cross-sensor terms among `sources`
/// on every row of `log` (`NaN` where a signal is); `None` where there
/// is none.
pub(crate) fn survey_fitted_part(log: &FlightLog, sources: &[SourceTerm]) -> Result<Option<Vec<f64>>> {
    let mut part: Option<Vec<f64>> = None;
    for source in sources {
        let SourceTerm::CrossSensor {
            signal,
            survey_gain: Some(gain),
            ..
        } = source
        else {
            continue;
        };
        let values = signal.values(log)?;
        let sum = part.get_or_insert_with(|| vec![0.0; log.len()]);
        for (total, s) in sum.iter_mut().zip(&values) {
            *total += gain * s;
        }
    }
    Ok(part)
}

/// The error for a source column of the model of `channel` that `log`
/// lacks.
fn missing_source(log: &FlightLog, source: &SourceTerm, channel: &str) -> Error {
    Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "model source column",
        looked_for: format!("'{}', which the model of '{channel}' uses", source.column()),
        hint: "Compensate with a diagnosis made on a flight that records the same columns.".into(),
    }
}

/// The three regressors of a recorded source column of `channel`'s model:
/// $(c - \bar c)\,u_i$ for a coupling, $\dot c\,u_i$ for its rate; none for
/// the other terms.
fn recorded_source_columns(
    log: &FlightLog,
    (source, channel): (&SourceTerm, &str),
    direction: &[Vec<f64>; 3],
    rows: Option<&[Range<usize>]>,
) -> Result<Vec<ExtraColumn>> {
    let n = log.len();
    let Some(values) = log.channel(source.column()).map(|c| &c.values) else {
        return Err(missing_source(log, source, channel));
    };
    let each_axis = |name: &dyn Fn(&str) -> String, value: &dyn Fn(usize) -> f64| {
        (["x", "y", "z"].iter().zip(direction))
            .map(|(axis, u)| ExtraColumn {
                name: name(axis),
                values: column_on(n, rows, |k| value(k) * u[k]),
            })
            .collect()
    };
    Ok(match source {
        SourceTerm::AuxCoupling { column, level } => {
            each_axis(&|axis| format!("{column}_{axis}"), &|k| values[k] - level)
        }
        SourceTerm::AuxCouplingRate { column } => {
            let rate = column_on(n, rows, |k| rate_at(values, log.time_s(), k));
            each_axis(&|axis| format!("{column}_rate_{axis}"), &|k| rate[k])
        }
        SourceTerm::ExternalField { .. } | SourceTerm::CrossSensor { .. } => Vec::new(),
    })
}

/// The three regressors $s\,u_i$ of a cross-sensor signal.
fn cross_sensor_columns(
    (name, signal): (&str, &crate::model::cross_sensor::CrossSignal),
    log: &FlightLog,
    direction: &[Vec<f64>; 3],
    rows: Option<&[Range<usize>]>,
) -> Result<Vec<ExtraColumn>> {
    let values = signal.values(log)?;
    Ok((["x", "y", "z"].iter().zip(direction))
        .map(|(axis, u)| ExtraColumn {
            name: format!("{name}_{axis}"),
            values: column_on(log.len(), rows, |k| values[k] * u[k]),
        })
        .collect())
}

/// `value(k)` for every row of a column `n` long, or only for `rows`
/// with zero elsewhere.
fn column_on(n: usize, rows: Option<&[Range<usize>]>, value: impl Fn(usize) -> f64) -> Vec<f64> {
    match rows {
        None => (0..n).map(value).collect(),
        Some(rows) => {
            let mut column = vec![0.0; n];
            for row in rows.iter().flat_map(Clone::clone).filter(|&k| k < n) {
                column[row] = value(row);
            }
            column
        }
    }
}

pub(crate) fn scalar_values<'a>(log: &'a FlightLog, channel: &str) -> Result<&'a [f64]> {
    match log.channel(channel) {
        Some(scalar) => Ok(&scalar.values),
        None => Err(Error::MissingColumn {
            path: log.source().to_path_buf(),
            role: "scalar magnetometer",
            looked_for: format!("'{channel}'"),
            hint: "Name a scalar channel the flight records.".into(),
        }),
    }
}

/// One R factor of the band-passed design and scalar per heading of
/// `fits`' windows; `None` when they span fewer than three headings or a
/// window has none.
fn heading_factors(stacked: &Stacked, fits: &[WindowFit]) -> Option<Vec<Factor>> {
    if fits.iter().any(|f| f.window.heading_deg.is_none()) {
        return None;
    }
    let windows: Vec<CalibrationWindow> = fits.iter().map(|f| f.window.clone()).collect();
    let headings = distinct_headings(&windows);
    if headings.len() < 3 {
        return None;
    }
    let factors = headings
        .iter()
        .map(|&heading| {
            let ranges: Vec<_> = fits
                .iter()
                .filter(|f| f.window.heading_deg.is_some_and(|h| same_heading(h, heading)))
                .map(|f| f.stacked_rows.clone())
                .collect();
            // Columns 0..p are the design, column p the scalar.
            let gather = |column: usize| -> Vec<f64> {
                ranges
                    .iter()
                    .flat_map(|r| stacked.column_range(column, r.clone()))
                    .collect()
            };
            let columns: Vec<Vec<f64>> = (0..stacked.columns()).map(gather).collect();
            let target = gather(stacked.columns());
            let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
            Factor::of_columns(&views, &target)
        })
        .collect();
    Some(factors)
}

/// Fits by `requested` (not ridge) on the heading folds of `stacked`:
/// its family's rank or λ chosen leaving one heading out, the
/// coefficients fitted on every heading replacing `solution`'s, with its
/// fitted values, standard errors and reason. With fewer than three
/// headings, or when no estimator of the family can be fitted on every
/// split, `solution` (ridge by PRESS) stands and the returned use says why.
fn solve_on_headings(stacked: &Stacked, fits: &[WindowFit], requested: Solver, solution: &mut Solution) -> SolverUse {
    let fallback = |why: &str| SolverUse {
        requested,
        family: None,
        estimator: None,
        heldout_rms: None,
        reason: format!(
            "[fit] solver = \"{}\" was not used: {why}; fitted by ridge with λ by PRESS instead",
            requested.name()
        ),
    };
    let Some(folds) = heading_factors(stacked, fits) else {
        return fallback("the calibration windows span fewer than three headings (or one has no heading), so no estimator can be chosen leaving one heading out");
    };
    let scored = compare_families(&folds, requested.families());
    let Some(best) = scored.iter().min_by(|a, b| a.heldout_rms.total_cmp(&b.heldout_rms)) else {
        return fallback("no estimator of the family could be fitted on every split of the headings");
    };
    let all = Factor::combine(&folds).and_then(|f| Decomposed::new(&f));
    let fitted = stacked.predict(&best.coefficients);
    let rows = stacked.rows();
    let p = best.coefficients.len();
    let rss: f64 = (stacked.target_pieces().flatten().zip(&fitted))
        .map(|(y, f)| (y - f).powi(2))
        .sum();
    let noise = (rss / rows.saturating_sub(p).max(1) as f64).sqrt();
    let standard_errors = all
        .and_then(|d| d.standard_errors(best.estimator, noise))
        .unwrap_or_else(|| vec![f64::NAN; p]);
    let reason = format!(
        "Fitted by {} ([fit] solver = \"{}\"), scored leaving one heading out: held-out RMS {:.4} nT. The ridge figures beside it are for comparison: {}",
        best.estimator.describe(),
        requested.name(),
        best.heldout_rms,
        solution.reason
    );
    solution.coefficients = best.coefficients.clone();
    // The jackknife is ridge's (or TSVD's); it says nothing of these
    // coefficients.
    solution.jackknife.clear();
    solution.fitted = fitted;
    solution.standard_errors = standard_errors;
    solution.reason = reason.clone();
    SolverUse {
        requested,
        family: Some(best.family),
        estimator: Some(best.estimator),
        heldout_rms: Some(best.heldout_rms),
        reason,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_log::{Channel, ChannelRole};
    use crate::model::terms::TermSet;
    use crate::model::{Extensions, FitOptions};
    use crate::simulate::scenario::{RawScenario, Scenario};

    /// A simulated box and line with a current and a base station of its
    /// own, and the box's detected windows.
    fn flight() -> (FlightLog, Vec<CalibrationWindow>) {
        let raw: RawScenario = toml::from_str("[survey]\nline_count = 1\nline_length_m = 3000.0\n").unwrap();
        let flight = crate::simulate::simulate(&Scenario::try_from(raw).unwrap()).unwrap();
        let log = flight.log;
        let mut channels = log.channels().to_vec();
        let wave = |period: f64| -> Vec<f64> { log.time_s().iter().map(|t| 3.0 + (t / period).sin()).collect() };
        channels.push(Channel {
            name: "cur_test".into(),
            role: ChannelRole::Auxiliary,
            values: wave(7.0),
        });
        channels.push(Channel {
            name: "station".into(),
            role: ChannelRole::BaseStation,
            values: wave(300.0),
        });
        let log = FlightLog::new(log.source(), log.time_column(), log.time_s().to_vec(), channels).unwrap();
        let windows = crate::calibration::detect::detect_manoeuvres(&log, &Default::default())
            .unwrap()
            .calibration_windows(1.0);
        (log, windows)
    }

    /// The per-sample columns, decided from the spec, are the eddy and
    /// field-derivative terms by name, and the nine lagged eddy columns of
    /// an eddy τ; a source column named like one is not.
    #[test]
    fn per_sample_columns_are_the_eddy_and_derivative_terms() {
        for terms in [
            TermSet::default(),
            TermSet::magnav(),
            TermSet {
                field_derivative: true,
                bias: true,
                ..TermSet::default()
            },
            crate::vector::tolles_lawson::terms(),
        ] {
            for eddy_tau_s in [0.0, 0.4] {
                let spec = ModelSpec::new(
                    terms,
                    Extensions {
                        eddy_tau_s,
                        sources: vec![SourceTerm::AuxCoupling {
                            column: "eddy_pump".into(),
                            level: 0.0,
                        }],
                        ..Extensions::default()
                    },
                );
                let names = spec.fitted_terms().names();
                let mut expected: Vec<bool> = (names.iter())
                    .map(|n| n.starts_with("eddy_") || n.starts_with("dB_"))
                    .collect();
                if eddy_tau_s > 0.0 {
                    expected.extend([true; 9]);
                }
                let flags = crate::model::per_sample_columns(&spec);
                assert_eq!(flags, expected, "{terms:?} τ {eddy_tau_s}");
                assert!(flags.iter().any(|f| *f), "{terms:?}");
            }
        }
    }

    /// Prepared on the windows' rows alone, every extension column and the
    /// lagged, station-corrected scalar hold on those rows the bits the
    /// whole flight's preparation gives, and so does the fit; a window
    /// beyond those rows is refused.
    #[test]
    fn columns_prepared_on_the_windows_rows_are_the_whole_flights_there() {
        let (log, windows) = flight();
        let sensor = log.vector_sensor("flux_a").unwrap();
        let direction = field_directions(&log, &sensor);
        let spec = ModelSpec::new(
            TermSet::default(),
            Extensions {
                lag_s: 0.13,
                eddy_tau_s: 0.4,
                sources: vec![
                    SourceTerm::AuxCoupling {
                        column: "cur_test".into(),
                        level: 3.0,
                    },
                    SourceTerm::AuxCouplingRate {
                        column: "cur_test".into(),
                    },
                    SourceTerm::ExternalField {
                        column: "station".into(),
                        level: 3.0,
                    },
                ],
                ..Extensions::default()
            },
        );
        let channel = "mag_1_uc";
        let whole = Prepared::with_directions(Cow::Borrowed(&log), &sensor, channel, &spec, &direction).unwrap();
        let rows = merged_rows(&windows, log.time_s());
        assert!(
            rows.iter().map(Range::len).sum::<usize>() < log.len() / 2,
            "the box is not a part of the flight"
        );
        let part = Prepared::on_rows(Cow::Borrowed(&log), (&sensor, channel), &spec, &direction, rows.clone()).unwrap();
        assert_eq!(part.extra.len(), whole.extra.len());
        assert_eq!(part.extra.len(), 9 + 3 + 3);
        let bits = |values: &[f64]| -> Vec<u64> {
            rows.iter()
                .flat_map(Clone::clone)
                .map(|k| values[k].to_bits())
                .collect()
        };
        for (a, b) in part.extra.iter().zip(&whole.extra) {
            assert_eq!(a.name, b.name);
            assert_eq!(bits(&a.values), bits(&b.values), "{}", a.name);
        }
        assert_eq!(bits(&part.scalar), bits(&whole.scalar));
        let options = FitOptions::default();
        let stores = StorePool::new();
        let (fitted_part, fitted_whole) = (
            part.fit(&windows, &options, &stores).unwrap(),
            whole.fit(&windows, &options, &stores).unwrap(),
        );
        let coefficients = |m: &FittedModel| m.coefficients.iter().map(|c| c.to_bits()).collect::<Vec<_>>();
        assert_eq!(coefficients(&fitted_part), coefficients(&fitted_whole));
        let time = log.time_s();
        let beyond = CalibrationWindow::new(time[log.len() - 400], time[log.len() - 10]);
        assert!(part.fit(std::slice::from_ref(&beyond), &options, &stores).is_err());
        assert!(part
            .held_out(&fitted_part, std::slice::from_ref(&beyond), &options, &stores)
            .is_err());
        assert!(whole.fit(&[beyond], &options, &stores).is_ok());
    }

    #[test]
    fn a_fit_and_residual_on_part_of_one_band_data_are_those_made_afresh() {
        let (log, windows) = flight();
        let sensor = log.vector_sensor("flux_a").unwrap();
        let spec = ModelSpec::new(
            TermSet::default(),
            Extensions {
                sources: vec![SourceTerm::AuxCoupling {
                    column: "cur_test".into(),
                    level: 3.0,
                }],
                ..Extensions::default()
            },
        );
        let prepared = Prepared::new(&log, &sensor, "mag_1_uc", &spec).unwrap();
        let options = FitOptions::default();
        let stores = StorePool::new();
        let band = prepared.band(&windows, &options, &stores).unwrap();
        // Trained on every other window in reverse, held out on the rest.
        let trained: Vec<usize> = (0..windows.len()).rev().step_by(2).collect();
        let out: Vec<usize> = (0..windows.len()).filter(|k| !trained.contains(k)).collect();
        let pick = |indices: &[usize]| indices.iter().map(|&k| windows[k].clone()).collect::<Vec<_>>();
        let afresh = prepared.fit(&pick(&trained), &options, &stores).unwrap();
        let within = prepared.fit_within(&band, &trained, &options, &stores).unwrap();
        let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&within.coefficients), bits(&afresh.coefficients));
        assert_eq!(
            within.solution.lambda.map(f64::to_bits),
            afresh.solution.lambda.map(f64::to_bits)
        );
        assert_eq!(bits(&within.solution.fitted), bits(&afresh.solution.fitted));
        assert_eq!(within.windows, afresh.windows);
        let held_afresh = prepared.held_out(&afresh, &pick(&out), &options, &stores).unwrap();
        let held_within = (prepared.held_out_within(&band, &within, (&out, &options), &stores)).unwrap();
        assert!(held_within.iter().all(|w| !w.band_after_nt.is_empty()));
        assert_eq!(held_within, held_afresh);
        assert!(prepared.fit_within(&band, &[], &options, &stores).is_err());
    }

    /// The fit of a second-order model as each pass once made it: the
    /// scalar less the term of the pass before band-passed with every
    /// design column again, and the design decomposed again.
    fn second_order_afresh(prepared: &Prepared, windows: &[CalibrationWindow], stores: &StorePool) -> FittedModel {
        let options = FitOptions::default();
        let band = prepared.band_with(&prepared.scalar, windows, &options, stores).unwrap();
        let mut fitted = prepared.fit_on(&band, None, &options).unwrap().0;
        for _ in 0..SECOND_ORDER_PASSES {
            let corrected = prepared.corrected(&fitted, windows);
            let band = prepared.band_with(&corrected, windows, &options, stores).unwrap();
            fitted = prepared.fit_on(&band, None, &options).unwrap().0;
        }
        fitted
    }

    #[test]
    fn the_second_order_passes_refit_the_same_design_bit_for_bit() {
        let (log, windows) = flight();
        let sensor = log.vector_sensor("flux_a").unwrap();
        let second = ModelSpec::new(
            TermSet::default(),
            Extensions {
                second_order: true,
                ..Extensions::default()
            },
        );
        let prepared = Prepared::new(&log, &sensor, "mag_1_uc", &second).unwrap();
        let (options, stores) = (FitOptions::default(), StorePool::new());
        let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let afresh = second_order_afresh(&prepared, &windows, &stores);
        let kept = prepared.fit(&windows, &options, &stores).unwrap();
        assert_eq!(bits(&kept.coefficients), bits(&afresh.coefficients));
        assert_eq!(bits(&kept.solution.fitted), bits(&afresh.solution.fitted));
        assert_eq!(kept.windows, afresh.windows);
        // The passes matter: the first fit alone is another.
        let band = prepared.band(&windows, &options, &stores).unwrap();
        let first = prepared.fit_on(&band, None, &options).unwrap().0;
        assert_ne!(bits(&first.coefficients), bits(&kept.coefficients));
        // Part of one band data: trained on every other window, held out
        // on the rest.
        let trained: Vec<usize> = (0..windows.len()).step_by(2).collect();
        let out: Vec<usize> = (1..windows.len()).step_by(2).collect();
        let pick = |indices: &[usize]| indices.iter().map(|&k| windows[k].clone()).collect::<Vec<_>>();
        let within = prepared.fit_within(&band, &trained, &options, &stores).unwrap();
        let afresh = second_order_afresh(&prepared, &pick(&trained), &stores);
        assert_eq!(bits(&within.coefficients), bits(&afresh.coefficients));
        assert_eq!(within.windows, afresh.windows);
        let held_afresh = prepared.held_out(&afresh, &pick(&out), &options, &stores).unwrap();
        let held_within = (prepared.held_out_within(&band, &within, (&out, &options), &stores)).unwrap();
        assert!(held_within.iter().all(|w| !w.band_after_nt.is_empty()));
        assert_eq!(held_within, held_afresh);
    }
}
