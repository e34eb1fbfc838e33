//! Does the calibration transfer? Coefficients often fit one box and fail
//! the next, so the FOM is also measured on manoeuvres the fit did not see.
//!
//! - Two boxes or more: fit on the first box, measure the FOM of the second
//!   (held out), and compare with the FOM of the second box fitted on
//!   itself (in sample).
//! - One box: leave one heading out: for each heading, fit on the other
//!   headings and measure that heading's manoeuvres; the held-out FOM sums
//!   those cells, the in-sample FOM is the ordinary fit's.
//!
//! A held-out FOM more than `warning_factor` times the in-sample one is a
//! warning: the model explains the calibration it saw better than it will
//! explain the survey.

use serde::Serialize;

use crate::calibration::headings::{heading_splits, same_heading};
use crate::calibration::windows::CalibrationWindow;
use crate::error::Result;
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::model::{FitOptions, FittedModel, Prepared, WindowFit};
use crate::numerics::stacked::StorePool;
use crate::quality::{figure_of_merit, fom_table, window_quality};
pub use crate::quality::{TransferCheck, TransferMethod};

/// `[quality]` settings of the transfer check.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TransferOptions {
    /// Warn when the held-out FOM exceeds the in-sample FOM by this factor.
    pub warning_factor: f64,
}

impl Default for TransferOptions {
    fn default() -> Self {
        TransferOptions { warning_factor: 2.0 }
    }
}

/// Groups labelled windows into boxes: in time order, a heading flown
/// again starts the next box.
pub fn group_into_boxes(windows: &[CalibrationWindow]) -> Vec<Vec<CalibrationWindow>> {
    let mut ordered: Vec<&CalibrationWindow> = windows.iter().filter(|w| w.heading_deg.is_some()).collect();
    ordered.sort_by(|a, b| a.t_start.total_cmp(&b.t_start));
    let mut boxes: Vec<Vec<CalibrationWindow>> = Vec::new();
    let mut current_heading: Option<f64> = None;
    for window in ordered {
        let heading = window.heading_deg.unwrap_or(0.0);
        let new_leg = current_heading.is_none_or(|h| !same_heading(h, heading));
        let repeated = new_leg
            && boxes
                .last()
                .is_some_and(|b| b.iter().any(|w| same_heading(w.heading_deg.unwrap_or(0.0), heading)));
        if boxes.is_empty() || repeated {
            boxes.push(Vec::new());
        }
        current_heading = Some(heading);
        if let Some(current) = boxes.last_mut() {
            current.push(window.clone());
        }
    }
    boxes
}

/// The compensated FOM of a set of held-out or fitted windows.
fn compensated_fom(fits: &[WindowFit]) -> Option<(f64, usize)> {
    let qualities: Vec<_> = fits.iter().map(window_quality).collect();
    figure_of_merit(&fom_table(&qualities, fits)).map(|(_, after, count)| (after, count))
}

/// Runs the transfer check of one channel on its labelled calibration
/// windows; `None` when there are too few headings to leave one out.
pub fn check_transfer(
    log: &FlightLog,
    sensor: &VectorSensor,
    model: &FittedModel,
    windows: &[CalibrationWindow],
    (options, transfer): (&FitOptions, &TransferOptions),
    stores: &StorePool,
) -> Result<Option<TransferCheck>> {
    let boxes = group_into_boxes(windows);
    // Every fit of the check is of the model's kind on the same prepared
    // flight; the stacked data's memory comes from `stores`.
    let prepared = Prepared::new(log, sensor, &model.channel, &model.spec)?;
    let (method, in_sample, held_out) = match boxes.as_slice() {
        [first, second, ..] => {
            let trained = prepared.fit(first, options, stores)?;
            let own = prepared.fit(second, options, stores)?;
            let held = prepared.held_out(&trained, second, options, stores)?;
            (
                TransferMethod::SecondBox,
                compensated_fom(&own.windows),
                compensated_fom(&held),
            )
        }
        [only] => {
            let held = leave_one_heading_out(&prepared, only, options, stores)?;
            let Some(held) = held else { return Ok(None) };
            let own: Vec<WindowFit> = model
                .windows
                .iter()
                .filter(|w| only.iter().any(|o| o.t_start == w.window.t_start))
                .cloned()
                .collect();
            (
                TransferMethod::LeaveOneHeadingOut,
                compensated_fom(&own),
                compensated_fom(&held),
            )
        }
        [] => return Ok(None),
    };
    let (Some((in_sample_fom_nt, manoeuvres)), Some((held_out_fom_nt, _))) = (in_sample, held_out) else {
        return Ok(None);
    };
    let ratio = held_out_fom_nt / in_sample_fom_nt;
    let warning = (ratio > transfer.warning_factor).then(|| {
        let what = match method {
            TransferMethod::SecondBox => "fitted on the first box, the model gives the second box",
            TransferMethod::LeaveOneHeadingOut => "fitted without each heading in turn, the model gives those headings",
        };
        format!(
            "{}: {what} a FOM of {held_out_fom_nt:.2} nT against {in_sample_fom_nt:.2} nT fitted on them ({ratio:.1}×): the calibration may not transfer to the survey",
            model.channel
        )
    });
    Ok(Some(TransferCheck {
        method,
        in_sample_fom_nt,
        held_out_fom_nt,
        manoeuvres,
        ratio,
        warning,
    }))
}

/// Each heading's windows measured with a fit of `model`'s kind (plain
/// or augmented) on the other headings; `None` with fewer than three
/// headings.
fn leave_one_heading_out(
    prepared: &Prepared,
    windows: &[CalibrationWindow],
    options: &FitOptions,
    stores: &StorePool,
) -> Result<Option<Vec<WindowFit>>> {
    let Some(splits) = heading_splits(windows) else {
        return Ok(None);
    };
    let mut held = Vec::new();
    for (out, rest) in splits {
        let trained = prepared.fit(&rest, options, stores)?;
        held.extend(prepared.held_out(&trained, &out, options, stores)?);
    }
    Ok(Some(held))
}

/// Another fluxgate whose plain Tolles-Lawson holds out better than the
/// one used by this factor matters: below it the choice is immaterial.
pub const FLUXGATE_MATERIAL: f64 = 1.25;

/// One fluxgate's plain Tolles-Lawson held out on a channel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FluxgateFigure {
    /// The fluxgate's prefix.
    pub fluxgate: String,
    /// Held-out FOM of plain Tolles-Lawson built from it, nT.
    pub held_out_fom_nt: f64,
}

/// Which fluxgate a channel's terms are built from, and whether it
/// matters: plain Tolles-Lawson with each fluxgate of the flight, held out
/// as the transfer check holds out (second box, or each heading fitted on
/// the others), side by side.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FluxgateComparison {
    /// The fluxgate used (named with `--vector`, or the first found).
    pub used: String,
    /// How the held-out figures were made.
    pub method: TransferMethod,
    /// Each fluxgate's held-out FOM, in the flight's order.
    pub held_out: Vec<FluxgateFigure>,
    /// The flight's fluxgates that could not be fitted on the windows (a
    /// gap, a dead axis): not compared, and said so.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub not_compared: Vec<String>,
}

impl FluxgateComparison {
    /// The fluxgate whose plain fit holds out best, and its figure.
    pub fn best(&self) -> Option<&FluxgateFigure> {
        self.held_out
            .iter()
            .min_by(|a, b| a.held_out_fom_nt.total_cmp(&b.held_out_fom_nt))
    }

    /// The used fluxgate's figure.
    pub fn used_figure(&self) -> Option<&FluxgateFigure> {
        self.held_out.iter().find(|f| f.fluxgate == self.used)
    }

    /// The fluxgate to use instead, when one holds out better than the
    /// used one by more than [`FLUXGATE_MATERIAL`].
    pub fn better(&self) -> Option<&FluxgateFigure> {
        let (best, used) = (self.best()?, self.used_figure()?);
        (best.held_out_fom_nt * FLUXGATE_MATERIAL < used.held_out_fom_nt).then_some(best)
    }

    /// "fluxgate flux_a used (--vector chooses); plain Tolles-Lawson with
    /// each, held out (each heading fitted on the other three): flux_a
    /// 0.68, flux_b 0.70 nT: the choice is immaterial (every one within
    /// ×1.25)".
    pub fn describe(&self) -> String {
        let figures: Vec<String> = (self.held_out.iter())
            .map(|f| format!("{} {:.2}", f.fluxgate, f.held_out_fom_nt))
            .collect();
        let used = self.used_figure().map_or(f64::NAN, |f| f.held_out_fom_nt);
        let worst = (self.held_out.iter()).max_by(|a, b| a.held_out_fom_nt.total_cmp(&b.held_out_fom_nt));
        let verdict = match (self.better(), worst) {
            (Some(better), _) => format!(
                "{} holds out better by more than ×{FLUXGATE_MATERIAL}: compensate with --vector {}",
                better.fluxgate, better.fluxgate
            ),
            (None, Some(worst)) if worst.held_out_fom_nt > FLUXGATE_MATERIAL * used => format!(
                "the one used is the best or within ×{FLUXGATE_MATERIAL} of it, and the choice matters: {} would hold out ×{:.1} worse",
                worst.fluxgate,
                worst.held_out_fom_nt / used
            ),
            (None, _) => format!("the choice is immaterial (every one within ×{FLUXGATE_MATERIAL})"),
        };
        let mut words = format!(
            "fluxgate {} used (--vector chooses); plain Tolles-Lawson with each, held out ({}): {} nT: {verdict}",
            self.used,
            self.method.describe(),
            figures.join(", ")
        );
        if !self.not_compared.is_empty() {
            words += &format!(
                "; not compared, as they cannot be fitted on the windows: {}",
                self.not_compared.join(", ")
            );
        }
        words
    }
}

/// [`FluxgateComparison`] of `model`'s channel on a flight with more than
/// one fluxgate (`used` the one its terms come from, `own` the model's
/// transfer check, reused when the model is plain); `None` with one, or
/// where the used fluxgate and one other cannot both be held out (too few
/// headings). A fluxgate whose readings cannot be fitted on the windows
/// (a gap, a dead axis) is named as not compared.
pub fn compare_fluxgates(
    log: &FlightLog,
    (used, own): (&VectorSensor, Option<&TransferCheck>),
    model: &FittedModel,
    windows: &[CalibrationWindow],
    (options, transfer): (&FitOptions, &TransferOptions),
    stores: &StorePool,
) -> Option<FluxgateComparison> {
    let sensors = log.vector_sensors();
    if sensors.len() < 2 {
        return None;
    }
    let plain = crate::model::ModelSpec::plain(model.spec.terms);
    let held_out_with = |sensor: &VectorSensor| -> Option<TransferCheck> {
        // A plain model's own transfer check is the used fluxgate's figure.
        if sensor.prefix == used.prefix && model.spec == plain {
            if let Some(own) = own {
                return Some(own.clone());
            }
        }
        let prepared = Prepared::new(log, sensor, &model.channel, &plain).ok()?;
        let fitted = prepared.fit(windows, options, stores).ok()?;
        check_transfer(log, sensor, &fitted, windows, (options, transfer), stores).ok()?
    };
    let (mut checks, mut not_compared) = (Vec::new(), Vec::new());
    for sensor in &sensors {
        match held_out_with(sensor) {
            Some(check) => checks.push((sensor.prefix.clone(), check)),
            None => not_compared.push(sensor.prefix.clone()),
        }
    }
    let method = checks.iter().find(|(prefix, _)| *prefix == used.prefix)?.1.method;
    (checks.len() >= 2).then(|| FluxgateComparison {
        used: used.prefix.clone(),
        method,
        not_compared,
        held_out: (checks.into_iter())
            .map(|(fluxgate, check)| FluxgateFigure {
                fluxgate,
                held_out_fom_nt: check.held_out_fom_nt,
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::headings::tests::window;

    #[test]
    fn a_heading_flown_again_starts_the_next_box() {
        let windows: Vec<CalibrationWindow> = [0.0, 90.0, 180.0, 270.0, 0.0, 90.0]
            .iter()
            .enumerate()
            .flat_map(|(leg, h)| (0..3).map(move |k| window(leg as f64 * 100.0 + k as f64 * 20.0, *h)))
            .collect();
        let boxes = group_into_boxes(&windows);
        assert_eq!(boxes.iter().map(Vec::len).collect::<Vec<_>>(), vec![12, 6]);
    }
}

/// One calibration box's model on another box of the same flight
/// (quality JSON `box_transfer`): how the calibration carries to flight it
/// did not see, with no truth needed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxTransfer {
    /// The box the model was fitted on ("box 1", in flying order).
    pub fit: String,
    /// The box it was measured on.
    pub test: String,
    /// Standard deviation of the band-passed residual on `test`'s
    /// calibration windows, nT.
    pub band_std_nt: f64,
    /// The same on `test` fitted on `test` itself, nT: what the model
    /// could do there had it seen it.
    pub own_fit_band_std_nt: f64,
}

/// Every box's model of `model`'s kind measured on every other box:
/// `boxes` are the calibration boxes' time spans (detected, the
/// calibration lines, or the hulls of given windows), and each window
/// belongs to the box its middle lies in. A box with fewer than three
/// windows neither fits nor tests (`None` for a flight without two such
/// boxes); a fit that fails is named in the returned notes.
pub fn box_transfer(
    log: &FlightLog,
    sensor: &VectorSensor,
    model: &FittedModel,
    windows: &[CalibrationWindow],
    boxes: &[(f64, f64)],
    options: &FitOptions,
    stores: &StorePool,
) -> Result<(Vec<BoxTransfer>, Vec<crate::messages::Note>)> {
    let grouped: Vec<(usize, Vec<CalibrationWindow>)> = (boxes.iter().enumerate())
        .map(|(k, (start, end))| {
            let inside = (windows.iter())
                .filter(|w| (*start..=*end).contains(&(0.5 * (w.t_start + w.t_end))))
                .cloned()
                .collect::<Vec<_>>();
            (k, inside)
        })
        .filter(|(_, inside)| inside.len() >= 3)
        .collect();
    if grouped.len() < 2 {
        return Ok((Vec::new(), Vec::new()));
    }
    let prepared = Prepared::new(log, sensor, &model.channel, &model.spec)?;
    let mut notes = Vec::new();
    let fits: Vec<Option<FittedModel>> = (grouped.iter())
        .map(|(k, inside)| match prepared.fit(inside, options, stores) {
            Ok(fitted) => Some(fitted),
            Err(error) => {
                notes.push(crate::messages::Note::NoBoxTransfer {
                    channel: model.channel.clone(),
                    number: k + 1,
                    why: error.to_string(),
                });
                None
            }
        })
        .collect();
    let band_std = |fits: &[WindowFit]| {
        let values: Vec<f64> = fits.iter().flat_map(|w| w.band_after_nt.iter().copied()).collect();
        let mean = values.iter().sum::<f64>() / values.len().max(1) as f64;
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len().max(1) as f64).sqrt()
    };
    let mut transfers = Vec::new();
    for (i, (fit_box, _)) in grouped.iter().enumerate() {
        for (j, (test_box, test_windows)) in grouped.iter().enumerate() {
            let (Some(trained), Some(own)) = (&fits[i], &fits[j]) else {
                continue;
            };
            if i == j {
                continue;
            }
            let held = prepared.held_out(trained, test_windows, options, stores)?;
            transfers.push(BoxTransfer {
                fit: format!("box {}", fit_box + 1),
                test: format!("box {}", test_box + 1),
                band_std_nt: band_std(&held),
                own_fit_band_std_nt: band_std(&own.windows),
            });
        }
    }
    Ok((transfers, notes))
}
