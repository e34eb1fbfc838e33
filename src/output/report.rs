//! The HTML quality report: one self-contained file with SVG plots, from
//! which a geophysicist can decide whether to accept the calibration.
//!
//! Sections: verdict per channel; attitude timeline with the calibration
//! windows shaded; each manoeuvre's band-passed signal before and after;
//! the FOM table with pass/fail against `fom_limit_nt`; the PRESS curve
//! with the chosen λ and the singular values; the coefficients; the survey
//! lines coloured by compensated anomaly; per-line noise; and, when the
//! flight was diagnosed, the findings and each manoeuvre's held-out
//! residual before and after them with the located stretches shaded. The
//! same figures go to a JSON file beside it.

use std::fmt::Write as _;
use std::path::Path;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use serde::Serialize;

use crate::diagnose::localise::ResidualTrace;
use crate::diagnose::{Diagnosis, Located};
use crate::error::{Error, Result};
use crate::formats::{stage, stage_json, Staged};
use crate::ingest::flight_log::{AttitudeAngle, ChannelRole, FlightLog};
use crate::model::FittedModel;
use crate::pipeline::{FlightResult, FlightRun};
use crate::quality::{fourth_difference_noise, ChannelQuality, FomCell};

/// Plot size, pixels.
const WIDE: (u32, u32) = (900, 260);
const SMALL: (u32, u32) = (290, 165);

/// Noise of one survey line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LineNoise {
    /// Line number.
    pub line: f64,
    /// Fourth-difference noise before, nT RMS.
    pub before_nt: f64,
    /// Fourth-difference noise after, nT RMS.
    pub after_nt: f64,
}

/// The report's figures per channel (also written as JSON).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelFigures {
    /// Scalar channel.
    pub channel: String,
    /// FOM after compensation, nT.
    pub fom_after_nt: Option<f64>,
    /// The FOM limit it is judged against, nT.
    pub fom_limit_nt: f64,
    /// FOM after within the limit.
    pub fom_pass: Option<bool>,
    /// The channel's verdict ([`crate::quality::verdict`]).
    pub verdict: crate::quality::verdict::Verdict,
    /// How the compensation scales a crustal anomaly (median over the
    /// survey's rows).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anomaly_gain: Option<f64>,
    /// Improvement ratio.
    pub improvement_ratio: f64,
    /// Per-line fourth-difference noise.
    pub line_noise: Vec<LineNoise>,
}

/// Everything the report shows, as numbers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReportFigures {
    /// Flight file.
    pub flight: String,
    /// Per channel.
    pub channels: Vec<ChannelFigures>,
}

fn plot_error(e: impl std::error::Error + Send + Sync + 'static) -> Error {
    Error::Serialise {
        path: Default::default(),
        what: "a report plot",
        source: Box::new(e),
    }
}

/// Renders an SVG of `size` with `draw`.
fn svg(
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend, plotters::coord::Shift>) -> Result<()>,
) -> Result<String> {
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        draw(&root)?;
        root.present().map_err(plot_error)?;
    }
    Ok(text)
}

/// The axis range of `values`: every finite value, padded by 5 %, never
/// empty. When a few wild values (under 0.5 % at either end) span more
/// than ten times the rest, the axis spans the 0.5th to 99.5th percentile
/// instead, so they neither flatten the plot nor push its axis past the
/// float range (where the axis labelling never ends); they are drawn at
/// the plot's edge. Samples that wild are screened out before the report
/// (and said so); what is left here is display, not data.
fn span(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    /// Axis ends beyond this are clamped: the axis width stays finite.
    const FARTHEST: f64 = 1e300;
    /// How much wider than the bulk the full range may be and still be shown.
    const WIDEST_TAILS: f64 = 10.0;
    let mut finite: Vec<f64> = values.filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return 0.0..1.0;
    }
    let trimmed = finite.len() / 200;
    let last = finite.len() - 1 - trimmed;
    let bulk_low = *finite.select_nth_unstable_by(trimmed, f64::total_cmp).1;
    let bulk_high = *finite.select_nth_unstable_by(last, f64::total_cmp).1;
    let (lowest, highest) = finite
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let bulk = bulk_high - bulk_low;
    let tame = (highest - lowest).is_finite() && highest - lowest <= WIDEST_TAILS * bulk.max(f64::MIN_POSITIVE);
    let (low, high) = match tame || bulk == 0.0 && highest - lowest < FARTHEST {
        true => (lowest, highest),
        false => (bulk_low, bulk_high),
    };
    let (low, high) = (low.clamp(-FARTHEST, FARTHEST), high.clamp(-FARTHEST, FARTHEST));
    let magnitude = low.abs().max(high.abs());
    let pad = ((high - low) * 0.05).max(magnitude * 1e-9).max(1e-12);
    low - pad..high + pad
}

/// An axis tick's label: the value rounded to a millionth, as short as
/// it reads (53156.2, 0.25, 12), and never "-0".
fn tick(value: &f64) -> String {
    let rounded = (value * 1e6).round() / 1e6;
    // -0.0 + 0.0 is 0.0.
    format!("{}", rounded + 0.0)
}

/// `value` brought within one axis width of `range`: a point off the plot
/// stays off it, but its pixel coordinate stays small (plotters adds pixel
/// coordinates as 32-bit integers, which 1e308 would overflow).
fn near(range: &std::ops::Range<f64>, value: f64) -> f64 {
    let width = range.end - range.start;
    value.clamp(range.start - width, range.end + width)
}

/// `points` with both coordinates [`near`] the plot's ranges.
fn on_canvas(
    points: impl IntoIterator<Item = (f64, f64)>,
    x: &std::ops::Range<f64>,
    y: &std::ops::Range<f64>,
) -> Vec<(f64, f64)> {
    points.into_iter().map(|(a, b)| (near(x, a), near(y, b))).collect()
}

/// Points a line plot draws at most: about two per pixel column.
const MOST_LINE_POINTS: usize = 2000;

/// `points` (in order of x) reduced for display to the first, the lowest
/// and the highest of each of `MOST_LINE_POINTS / 3` runs, in order, so
/// that every spike still shows; fewer points are kept as they are.
/// Non-finite points are dropped.
fn decimated(points: impl Iterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    decimated_to(points, MOST_LINE_POINTS)
}

/// [`decimated`] to at most `most` points.
fn decimated_to(points: impl Iterator<Item = (f64, f64)>, most: usize) -> Vec<(f64, f64)> {
    let points: Vec<(f64, f64)> = points.filter(|(x, y)| x.is_finite() && y.is_finite()).collect();
    if points.len() <= most {
        return points;
    }
    let run = points.len().div_ceil((most / 3).max(1));
    let mut kept = Vec::with_capacity(most);
    for chunk in points.chunks(run) {
        let lowest = chunk
            .iter()
            .enumerate()
            .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
            .map(|(k, _)| k);
        let highest = chunk
            .iter()
            .enumerate()
            .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
            .map(|(k, _)| k);
        let mut chosen = [Some(0), lowest, highest];
        chosen.sort();
        let mut previous = None;
        for k in chosen.into_iter().flatten() {
            if previous != Some(k) {
                kept.push(chunk[k]);
                previous = Some(k);
            }
        }
    }
    kept
}

/// The calibration windows of a flight's first model, as (start, end).
fn calibration_spans(result: &FlightResult) -> Vec<(f64, f64)> {
    (result.models.first())
        .map(|m| m.windows.iter().map(|w| (w.window.t_start, w.window.t_end)).collect())
        .unwrap_or_default()
}

/// The attitude over the whole flight: heading above, pitch and roll
/// below, the calibration windows shaded.
fn attitude_timeline(log: &FlightLog, result: &FlightResult) -> Result<String> {
    let time = span(log.time_s().iter().copied());
    let caption = "Flight: heading (top), pitch (blue) and roll (red) below, calibration windows shaded";
    attitude_panels(log, &calibration_spans(result), time, caption)
}

/// The calibration box on its own time axis (its first window's start to
/// its last window's end, 2 % either side), as [`attitude_timeline`]
/// draws the flight; `None` without windows.
fn box_timeline(log: &FlightLog, result: &FlightResult) -> Result<Option<String>> {
    let windows = calibration_spans(result);
    let (Some(start), Some(end)) = (
        windows.iter().map(|w| w.0).min_by(f64::total_cmp),
        windows.iter().map(|w| w.1).max_by(f64::total_cmp),
    ) else {
        return Ok(None);
    };
    let margin = 0.02 * (end - start).max(1.0);
    let caption = format!(
        "Calibration box, {start:.0} to {end:.0} s: heading (top), pitch (blue) and roll (red), its {} windows shaded",
        windows.len()
    );
    attitude_panels(log, &windows, (start - margin)..(end + margin), &caption).map(Some)
}

/// The heading panel over `time`: the `windows` shaded, the heading of
/// `rows` wrapped to 360° from [`heading_cut`] and broken where it
/// crosses the axis's ends.
fn heading_panel(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    (time, windows): (&std::ops::Range<f64>, &[(f64, f64)]),
    (t, rows, heading): (&[f64], &[usize], Option<&[f64]>),
    shade: &ShapeStyle,
) -> Result<()> {
    let cut = heading_cut(rows.iter().filter_map(|&k| heading.map(|h| h[k])));
    let axis = cut..cut + 360.0;
    let mut chart = ChartBuilder::on(area)
        .margin(6)
        .x_label_area_size(18)
        .y_label_area_size(45)
        .build_cartesian_2d(time.clone(), axis.clone())
        .map_err(plot_error)?;
    (chart.configure_mesh().x_label_formatter(&tick))
        .y_labels(0)
        .disable_y_mesh()
        .y_desc("heading, °")
        .draw()
        .map_err(plot_error)?;
    compass_ticks(area, &mut chart, (time, cut))?;
    chart
        .draw_series(
            windows
                .iter()
                .map(|&(a, b)| Rectangle::new([(near(time, a), axis.start), (near(time, b), axis.end)], *shade)),
        )
        .map_err(plot_error)?;
    if let Some(heading) = heading {
        let points = decimated(rows.iter().map(|&k| (t[k], cut + (heading[k] - cut).rem_euclid(360.0))));
        for piece in split_at_wraps(&points, cut) {
            chart.draw_series(LineSeries::new(piece, BLACK)).map_err(plot_error)?;
        }
    }
    Ok(())
}

/// Heading (0–360°) in a panel above pitch and roll, over `time`, with
/// `windows` shaded in both. Series are named in the caption, not in a
/// legend box drawn over the data.
fn attitude_panels(
    log: &FlightLog,
    windows: &[(f64, f64)],
    time: std::ops::Range<f64>,
    caption: &str,
) -> Result<String> {
    let t = log.time_s();
    let angle = |wanted: AttitudeAngle| {
        (log.channels().iter())
            .find(|c| c.role == ChannelRole::Attitude(wanted))
            .map(|c| c.values.as_slice())
    };
    let rows: Vec<usize> = (0..t.len()).filter(|&k| time.contains(&t[k])).collect();
    let series: Vec<(&[f64], RGBColor)> = [(AttitudeAngle::Pitch, BLUE), (AttitudeAngle::Roll, RED)]
        .into_iter()
        .filter_map(|(wanted, colour)| Some((angle(wanted)?, colour)))
        .collect();
    let heading = angle(AttitudeAngle::Yaw);
    svg((WIDE.0, 380), |root| {
        let root = root.titled(caption, ("sans-serif", 15)).map_err(plot_error)?;
        let (top, bottom) = root.split_vertically(150);
        let shade = RGBColor(255, 200, 60).mix(0.35).filled();
        heading_panel(&top, (&time, windows), (t, &rows, heading), &shade)?;
        pitch_roll_panel(&bottom, (&time, windows), (t, &rows, &series), &shade)
    })
}

/// An attitude angle's values over the flight, degrees, and its line's colour.
type Trace<'a> = (&'a [f64], RGBColor);

/// The lower panel of [`attitude_panels`]: pitch and roll, degrees, over
/// `time`, with `windows` shaded.
fn pitch_roll_panel(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    (time, windows): (&std::ops::Range<f64>, &[(f64, f64)]),
    (t, rows, series): (&[f64], &[usize], &[Trace]),
    shade: &ShapeStyle,
) -> Result<()> {
    let y = span(series.iter().flat_map(|(v, _)| rows.iter().map(|&k| v[k])));
    let mut chart = ChartBuilder::on(area)
        .margin(6)
        .x_label_area_size(30)
        .y_label_area_size(45)
        .build_cartesian_2d(time.clone(), y.clone())
        .map_err(plot_error)?;
    (chart.configure_mesh().x_label_formatter(&tick).y_label_formatter(&tick))
        .x_desc("time, s")
        .y_desc("pitch, roll, °")
        .draw()
        .map_err(plot_error)?;
    chart
        .draw_series(
            windows
                .iter()
                .map(|&(a, b)| Rectangle::new([(near(time, a), y.start), (near(time, b), y.end)], *shade)),
        )
        .map_err(plot_error)?;
    for (values, colour) in series {
        let points = on_canvas(decimated(rows.iter().map(|&k| (t[k], values[k]))), time, &y);
        chart.draw_series(LineSeries::new(points, colour)).map_err(plot_error)?;
    }
    Ok(())
}

/// The heading panel's grid and labels at every 90° from `cut` (its
/// axis's start), labelled as compass headings (0–360°), in `area`'s
/// label margin left of `chart`'s plot over `time`.
fn compass_ticks(
    area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    chart: &mut ChartContext<SVGBackend, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    (time, cut): (&std::ops::Range<f64>, f64),
) -> Result<()> {
    let levels: Vec<f64> = (0..5).map(|k| cut + 90.0 * f64::from(k)).collect();
    (chart.draw_series(
        levels
            .iter()
            .map(|&v| PathElement::new(vec![(time.start, v), (time.end, v)], RGBColor(200, 200, 200))),
    ))
    .map_err(plot_error)?;
    let base = area.get_base_pixel();
    let style = TextStyle::from(("sans-serif", 11).into_font()).pos(Pos::new(HPos::Right, VPos::Center));
    for &v in &levels {
        let (x, y) = chart.backend_coord(&(time.start, v));
        let at = (x - base.0 - 6, y - base.1);
        area.draw(&Text::new(tick(&v.rem_euclid(360.0)), at, style.clone()))
            .map_err(plot_error)?;
    }
    Ok(())
}

/// Where the heading panel's axis begins, degrees: the one of north,
/// east, south and west with the fewest of the `headings` within 15° of
/// it (north on a tie), so the lines flown are drawn whole, not along both
/// edges of the panel.
fn heading_cut(headings: impl Iterator<Item = f64>) -> f64 {
    let mut near = [0_usize; 4];
    for heading in headings.filter(|h| h.is_finite()) {
        for (k, count) in near.iter_mut().enumerate() {
            let apart = (heading - 90.0 * k as f64).rem_euclid(360.0);
            *count += usize::from(apart.min(360.0 - apart) < 15.0);
        }
    }
    let best = (0..4).min_by_key(|&k| (near[k], k)).unwrap_or(0);
    90.0 * best as f64
}

/// A heading trace on an axis from `cut` to `cut` + 360°, cut where it
/// wraps across the axis's ends (a step of more than 180°), each piece
/// carried to the panel's edge where it crosses, and no line drawn
/// across the panel.
fn split_at_wraps(points: &[(f64, f64)], cut: f64) -> Vec<Vec<(f64, f64)>> {
    let mut pieces = Vec::new();
    let mut piece: Vec<(f64, f64)> = Vec::new();
    for (k, &point) in points.iter().enumerate() {
        if let Some(&(t0, h0)) = k.checked_sub(1).map(|j| &points[j]) {
            let step = point.1 - h0;
            if step.abs() > 180.0 {
                // Unwrapped, the heading goes from h0 to h1 through north
                // (360° going up, 0° going down).
                let (edge, other, unwrapped) = match step < 0.0 {
                    true => (cut + 360.0, cut, point.1 + 360.0),
                    false => (cut, cut + 360.0, point.1 - 360.0),
                };
                let fraction = (edge - h0) / (unwrapped - h0);
                let t = t0 + fraction.clamp(0.0, 1.0) * (point.0 - t0);
                piece.push((t, edge));
                pieces.push(std::mem::take(&mut piece));
                piece.push((t, other));
            }
        }
        piece.push(point);
    }
    pieces.push(piece);
    pieces
}

/// One manoeuvre's band-passed signal before (grey) and after (blue).
fn manoeuvre_plot(model: &FittedModel, index: usize) -> Result<String> {
    let fit = &model.windows[index];
    let label = fit.window.display_label();
    let dt = 1.0 / model.sample_rate_hz;
    svg(SMALL, |root| {
        let n = fit.band_before_nt.len().max(1) as f64 * dt;
        let y = span(fit.band_before_nt.iter().chain(&fit.band_after_nt).copied());
        let mut chart = ChartBuilder::on(root)
            .caption(&label, ("sans-serif", 12))
            .margin(4)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .build_cartesian_2d(0.0..n, y.clone())
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .disable_x_mesh()
            .x_labels(3)
            .y_labels(4)
            .x_desc("s")
            .y_desc("nT")
            .draw()
            .map_err(plot_error)?;
        for (values, colour) in [
            (&fit.band_before_nt, RGBColor(150, 150, 150)),
            (&fit.band_after_nt, BLUE),
        ] {
            chart
                .draw_series(LineSeries::new(
                    on_canvas(
                        decimated(values.iter().enumerate().map(|(k, v)| (k as f64 * dt, *v))),
                        &(0.0..n),
                        &y,
                    ),
                    colour,
                ))
                .map_err(plot_error)?;
        }
        Ok(())
    })
}

fn press_plot(model: &FittedModel) -> Result<String> {
    let solution = &model.solution;
    let curve: Vec<(f64, f64)> = solution
        .ridge_curve
        .iter()
        .map(|p| (p.lambda.log10(), p.blocked_press.unwrap_or(p.press)))
        .filter(|(l, p)| l.is_finite() && p.is_finite() && *p > 0.0)
        .collect();
    svg((440, 240), |root| {
        let x = span(curve.iter().map(|p| p.0));
        let y = span(curve.iter().map(|p| p.1.log10()));
        let mut chart = ChartBuilder::on(root)
            .caption("PRESS against log10 λ (chosen λ marked)", ("sans-serif", 13))
            .margin(6)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d(x.clone(), y.clone())
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .x_desc("log10 λ")
            .y_desc("log10 PRESS, nT²")
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(LineSeries::new(
                on_canvas(curve.iter().map(|(l, p)| (*l, p.log10())), &x, &y),
                BLUE,
            ))
            .map_err(plot_error)?;
        if let Some(lambda) = solution.lambda.filter(|l| *l > 0.0) {
            let at = near(&x, lambda.log10());
            chart
                .draw_series(std::iter::once(PathElement::new(vec![(at, y.start), (at, y.end)], RED)))
                .map_err(plot_error)?;
        }
        Ok(())
    })
}

fn singular_value_plot(model: &FittedModel) -> Result<String> {
    let values: Vec<f64> = model
        .solution
        .singular_values
        .iter()
        .map(|s| s.max(1e-300).log10())
        .collect();
    svg((440, 240), |root| {
        let y = span(values.iter().copied());
        let mut chart = ChartBuilder::on(root)
            .caption("Singular values (log10, scaled design)", ("sans-serif", 13))
            .margin(6)
            .x_label_area_size(36)
            .y_label_area_size(45)
            .build_cartesian_2d(0.5..values.len() as f64 + 0.5, y.clone())
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .x_desc("index")
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(
                values
                    .iter()
                    .enumerate()
                    .map(|(k, v)| Circle::new(((k + 1) as f64, near(&y, *v)), 3, BLUE.filled())),
            )
            .map_err(plot_error)?;
        Ok(())
    })
}

/// Metres east and north of (`lat0`, `lon0`), degrees: the equirectangular
/// projection about `lat0`, within 0.1 % of the ground distance across a
/// survey block of 100 km at mid latitudes: a map, not geodesy.
fn local_metres((lat, lon): (f64, f64), (lat0, lon0): (f64, f64)) -> (f64, f64) {
    const EARTH_RADIUS_M: f64 = 6_371_000.0;
    let east = (lon - lon0).to_radians() * EARTH_RADIUS_M * lat0.to_radians().cos();
    let north = (lat - lat0).to_radians() * EARTH_RADIUS_M;
    (east, north)
}

/// The map's width, the width its colour bar takes from it, and the
/// least and most height of its plotting area, pixels: the height follows
/// the block's shape between them.
const MAP_WIDTH: u32 = 900;
const COLOUR_BAR_WIDTH: u32 = 120;
const MAP_PLOT_HEIGHT: (u32, u32) = (240, 640);

/// The anomaly's colour, blue (`low`) to red (`high`), nT.
fn anomaly_colour(v: f64, (low, high): (f64, f64)) -> RGBColor {
    let f = ((v - low) / (high - low).max(1e-9)).clamp(0.0, 1.0);
    RGBColor(
        (255.0 * f) as u8,
        (80.0 + 60.0 * (1.0 - (2.0 * f - 1.0).abs())) as u8,
        (255.0 * (1.0 - f)) as u8,
    )
}

/// A chart in metres east and north, drawn as SVG.
type MapChart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The map's chart over `x` × `y` (metres east, north) in `area`.
fn map_chart<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    stretch: f64,
) -> Result<MapChart<'a, 'b>> {
    let caption = match stretch > 1.0 {
        true => {
            format!("Survey lines: compensated anomaly (north stretched ×{stretch:.1} to show a long, narrow block)")
        }
        false => "Survey lines: compensated anomaly, tracks in grey".to_string(),
    };
    ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 13))
        .margin(6)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y)
        .map_err(plot_error)
}

/// `x` and `y` widened about their centres to one scale, metres per pixel,
/// for a plot of `pixels`, a kilometre north drawn `stretch` times as long
/// as one east (1: one scale).
fn stretched_scale(
    (x, y): (std::ops::Range<f64>, std::ops::Range<f64>),
    pixels: (u32, u32),
    stretch: f64,
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (width, height) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
    // Metres east per pixel; north, a stretch-th of that.
    let scale = ((x.end - x.start) / width).max(stretch * (y.end - y.start) / height);
    let about = |r: &std::ops::Range<f64>, half: f64| {
        let centre = (r.start + r.end) / 2.0;
        (centre - half)..(centre + half)
    };
    (
        about(&x, scale * width / 2.0),
        about(&y, scale / stretch * height / 2.0),
    )
}

/// The map's canvas for a block `east` × `north` metres across: its size,
/// pixels, and how much north is stretched (1 unless the block is so long
/// and narrow that at one scale its plot would be under
/// [`MAP_PLOT_HEIGHT`]'s least).
fn map_canvas(east: f64, north: f64) -> Result<((u32, u32), f64)> {
    // The caption, margins and east axis take the same pixels whatever
    // the canvas's height.
    let scratch_height = 2 * MAP_PLOT_HEIGHT.1;
    let (plot_width, plot_height) = map_pixels((MAP_WIDTH, scratch_height))?;
    let frame = scratch_height.saturating_sub(plot_height);
    let aspect = match east > 0.0 {
        true => north.max(0.0) / east,
        false => 1.0,
    };
    let wanted = aspect * f64::from(plot_width);
    let (least, most) = (f64::from(MAP_PLOT_HEIGHT.0), f64::from(MAP_PLOT_HEIGHT.1));
    let height = wanted.clamp(least, most);
    let stretch = match wanted > 0.0 && wanted < least {
        true => least / wanted,
        false => 1.0,
    };
    // A block taller than wide is drawn narrower, not with empty sides.
    let width = match wanted > most {
        true => {
            let frame_width = MAP_WIDTH - plot_width;
            ((most / aspect).round() as u32 + frame_width).max(MAP_WIDTH / 2)
        }
        false => MAP_WIDTH,
    };
    Ok(((width, height.round() as u32 + frame), stretch))
}

/// Metres east and north of the centre of `rows`' positions (latitude and
/// longitude, degrees), on every row of the flight; NaN off `rows`.
fn east_north(rows: &[usize], (lat, lon): (&[f64], &[f64])) -> (Vec<f64>, Vec<f64>) {
    let centre = (span(rows.iter().map(|&k| lat[k])), span(rows.iter().map(|&k| lon[k])));
    let centre = (
        (centre.0.start + centre.0.end) / 2.0,
        (centre.1.start + centre.1.end) / 2.0,
    );
    let (mut east, mut north) = (vec![f64::NAN; lat.len()], vec![f64::NAN; lat.len()]);
    for &k in rows {
        (east[k], north[k]) = local_metres((lat[k], lon[k]), centre);
    }
    (east, north)
}

/// The plotting area of a map of `size` in pixels. It does not depend on
/// the map's ranges: measured on a scratch canvas, it sets the one scale.
fn map_pixels(size: (u32, u32)) -> Result<(u32, u32)> {
    let mut scratch = String::new();
    let root = SVGBackend::with_string(&mut scratch, size).into_drawing_area();
    let (area, _) = root.split_horizontally(size.0 - COLOUR_BAR_WIDTH);
    let chart = map_chart(&area, 0.0..1.0, 0.0..1.0, 1.0)?;
    let pixels = chart.plotting_area().dim_in_pixel();
    Ok(pixels)
}

/// The anomaly's level (the `values`' median, which it is measured from)
/// and the range its colours span (its 2nd to 98th percentiles), nT;
/// `values` not empty, in any order.
fn anomaly_scale(values: Vec<f64>) -> (f64, (f64, f64)) {
    let mut sorted = values;
    sorted.sort_by(f64::total_cmp);
    let level = sorted[sorted.len() / 2];
    let range = (
        sorted[sorted.len() / 50] - level,
        sorted[sorted.len() - 1 - sorted.len() / 50] - level,
    );
    (level, range)
}

/// Survey-line samples coloured by compensated anomaly (value less the
/// lines' median), blue low to red high, in metres east and north of the
/// survey's centre at one scale, with a colour bar in nT.
fn line_map(log: &FlightLog, values: &[f64]) -> Result<Option<String>> {
    let (Some(lat), Some(lon), Some(line)) = (
        log.channel("lat"),
        log.channel("lon"),
        log.channels().iter().find(|c| c.role == ChannelRole::Line),
    ) else {
        return Ok(None);
    };
    let rows: Vec<usize> = (0..log.len())
        .filter(|&k| {
            line.values[k] != 0.0
                && line.values[k].is_finite()
                && values[k].is_finite()
                && lat.values[k].is_finite()
                && lon.values[k].is_finite()
        })
        .collect();
    if rows.is_empty() {
        return Ok(None);
    }
    let (level, range) = anomaly_scale(rows.iter().map(|&k| values[k]).collect());
    let (east, north) = east_north(&rows, (&lat.values, &lon.values));
    let extent = (
        span(rows.iter().map(|&k| east[k])),
        span(rows.iter().map(|&k| north[k])),
    );
    let (size, stretch) = map_canvas(extent.0.end - extent.0.start, extent.1.end - extent.1.start)?;
    let pixels = map_pixels(size)?;
    let (x, y) = stretched_scale(extent, pixels, stretch);
    // One dot (4 px across) for each 8 × 8 pixel cell a line crosses.
    let drawn = one_per_cell(&rows, (&east, &north), (&x, &y), (pixels.0 / 8, pixels.1 / 8));
    let tracks = line_tracks(log, (&east, &north));
    let map = svg(size, |root| {
        let (area, bar) = root.split_horizontally(size.0 - COLOUR_BAR_WIDTH);
        let mut chart = map_chart(&area, x.clone(), y.clone(), stretch)?;
        for track in &tracks {
            let points = on_canvas(track.iter().copied(), &x, &y);
            (chart.draw_series(LineSeries::new(points, RGBColor(170, 170, 170)))).map_err(plot_error)?;
        }
        draw_line_dots(&mut chart, (&drawn, &east, &north), (values, level, range))?;
        colour_bar(&bar, range)
    })?;
    Ok(Some(map))
}

/// The map's dots: each of the `drawn` samples at its metres east and
/// north, coloured by its anomaly (value less `level`) over `range`, nT.
fn draw_line_dots(
    chart: &mut MapChart,
    (drawn, east, north): (&[usize], &[f64], &[f64]),
    (values, level, range): (&[f64], f64, (f64, f64)),
) -> Result<()> {
    (chart.configure_mesh().x_label_formatter(&tick).y_label_formatter(&tick))
        .max_light_lines(0)
        .x_labels(6)
        .y_labels(8)
        .x_desc("east, m")
        .y_desc("north, m")
        .draw()
        .map_err(plot_error)?;
    chart
        .draw_series((drawn.iter()).map(|&k| {
            Circle::new(
                (east[k], north[k]),
                2,
                anomaly_colour(values[k] - level, range).filled(),
            )
        }))
        .map_err(plot_error)?;
    Ok(())
}

/// Points of each line's track (tie lines too) a map draws at most.
const TRACK_POINTS: usize = 60;

/// Each survey line's track, metres east and north, thinned to
/// [`TRACK_POINTS`]: drawn under the dots, so a line or a tie crossing
/// the block shows where the dots of others hide it.
fn line_tracks(log: &FlightLog, (east, north): (&[f64], &[f64])) -> Vec<Vec<(f64, f64)>> {
    (log.survey_lines().iter())
        .map(|(_, rows)| {
            let step = rows.len().div_ceil(TRACK_POINTS).max(1);
            (rows.iter().step_by(step))
                .map(|&k| (east[k], north[k]))
                .filter(|(e, n)| e.is_finite() && n.is_finite())
                .collect()
        })
        .collect()
}

/// The map's colour bar: the anomaly's colours from `low` to `high`, nT.
fn colour_bar(area: &DrawingArea<SVGBackend, plotters::coord::Shift>, (low, high): (f64, f64)) -> Result<()> {
    let high = if high > low { high } else { low + 1e-9 };
    let mut chart = ChartBuilder::on(area)
        .margin_top(30)
        .margin_bottom(36)
        .margin_right(8)
        .y_label_area_size(75)
        .build_cartesian_2d(0.0..1.0, low..high)
        .map_err(plot_error)?;
    (chart.configure_mesh().x_label_formatter(&tick).y_label_formatter(&tick))
        .disable_x_mesh()
        .disable_y_mesh()
        .disable_x_axis()
        .y_desc("anomaly, nT")
        .y_labels(6)
        .y_label_style(("sans-serif", 11))
        .axis_desc_style(("sans-serif", 11))
        .draw()
        .map_err(plot_error)?;
    const STEPS: usize = 64;
    let step = (high - low) / STEPS as f64;
    chart
        .draw_series((0..STEPS).map(|k| {
            let v = low + (k as f64 + 0.5) * step;
            let bottom = low + k as f64 * step;
            Rectangle::new(
                [(0.0, bottom), (1.0, bottom + step)],
                anomaly_colour(v, (low, high)).filled(),
            )
        }))
        .map_err(plot_error)?;
    Ok(())
}

/// The `rows` a map of `cells` (columns, rows) over the ranges draws: the
/// first row in each cell, so a survey of any length is a few thousand
/// points; rows outside the ranges are left out.
fn one_per_cell(
    rows: &[usize],
    (easting, northing): (&[f64], &[f64]),
    (x, y): (&std::ops::Range<f64>, &std::ops::Range<f64>),
    cells: (u32, u32),
) -> Vec<usize> {
    let cell = |value: f64, range: &std::ops::Range<f64>, count: u32| {
        let fraction = (value - range.start) / (range.end - range.start);
        (0.0..1.0)
            .contains(&fraction)
            .then_some((fraction * count as f64) as u32)
    };
    let mut taken = vec![false; cells.0 as usize * cells.1 as usize];
    rows.iter()
        .copied()
        .filter(
            |&k| match (cell(easting[k], x, cells.0), cell(northing[k], y, cells.1)) {
                (Some(column), Some(row)) => {
                    let index = row as usize * cells.0 as usize + column as usize;
                    !std::mem::replace(&mut taken[index], true)
                }
                _ => false,
            },
        )
        .collect()
}

/// Survey lines drawn as profiles at most; a flight of more draws this
/// many spread evenly over them, and says so.
const MOST_PROFILES: usize = 6;

/// Points each profile's trace keeps at most: the lowest and highest of
/// each of 150 runs, with its first, so every spike shows.
const PROFILE_POINTS: usize = 450;

/// Each survey line's profile (up to [`MOST_PROFILES`]): the channel before
/// (grey) and after (blue) compensation, each less its regional trend (a
/// straight line fitted along the line), against the time since the line began; `None` without lines. The
/// second value says how many lines the flight has.
fn line_profiles(log: &FlightLog, before: &[f64], after: &[f64]) -> Result<Option<(String, usize)>> {
    let lines = log.survey_lines();
    let time = log.time_s();
    if lines.is_empty() || before.len() != time.len() || after.len() != time.len() {
        return Ok(None);
    }
    let shown: Vec<&(f64, Vec<usize>)> = match lines.len() {
        n if n <= MOST_PROFILES => lines.iter().collect(),
        n => (0..MOST_PROFILES)
            .map(|k| &lines[k * (n - 1) / (MOST_PROFILES - 1)])
            .collect(),
    };
    const PANEL_HEIGHT: u32 = 140;
    let height = PANEL_HEIGHT * shown.len() as u32 + 24;
    let plot = svg((WIDE.0, height), |root| {
        let root = (root.titled(
            "Survey lines: before (grey) and after (blue), each less its straight-line regional trend along the line",
            ("sans-serif", 14),
        ))
        .map_err(plot_error)?;
        for (panel, (number, rows)) in root.split_evenly((shown.len(), 1)).iter().zip(&shown) {
            line_profile_panel(panel, (*number, rows), time, (before, after))?;
        }
        Ok(())
    })?;
    Ok(Some((plot, lines.len())))
}

/// One panel of [`line_profiles`]: line `number`'s samples (`rows`) before
/// and after compensation, each less its regional trend, nT, against
/// the time since the line began, s.
fn line_profile_panel(
    panel: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    (number, rows): (f64, &[usize]),
    time: &[f64],
    (before, after): (&[f64], &[f64]),
) -> Result<()> {
    let start = time[rows[0]];
    let relative = |values: &[f64]| -> Vec<(f64, f64)> {
        let trend = regional_trend(rows.iter().map(|&k| (time[k] - start, values[k])));
        decimated_to(
            rows.iter()
                .map(|&k| (time[k] - start, values[k] - trend(time[k] - start))),
            PROFILE_POINTS,
        )
    };
    let (was, now) = (relative(before), relative(after));
    let x = span(was.iter().chain(&now).map(|p| p.0));
    let y = span(was.iter().chain(&now).map(|p| p.1));
    let mut chart = ChartBuilder::on(panel)
        .margin(4)
        .x_label_area_size(34)
        .y_label_area_size(55)
        .build_cartesian_2d(x.clone(), y.clone())
        .map_err(plot_error)?;
    (chart.configure_mesh().x_label_formatter(&tick).y_label_formatter(&tick))
        .max_light_lines(0)
        .x_desc(format!("line {number}: time since its start, s"))
        .y_desc("nT")
        .y_labels(4)
        .draw()
        .map_err(plot_error)?;
    for (points, colour) in [(was, RGBColor(150, 150, 150)), (now, BLUE)] {
        chart
            .draw_series(LineSeries::new(on_canvas(points, &x, &y), colour))
            .map_err(plot_error)?;
    }
    Ok(())
}

/// The straight line fitted by least squares to a profile's finite
/// `points` (time, value): the regional gradient along the line, which
/// would otherwise span the panel and hide what compensation changed. A
/// profile of one point or none has its value (or 0) as its trend.
fn regional_trend(points: impl Iterator<Item = (f64, f64)>) -> impl Fn(f64) -> f64 {
    let points: Vec<(f64, f64)> = points.filter(|(t, v)| t.is_finite() && v.is_finite()).collect();
    let n = points.len().max(1) as f64;
    let (mean_t, mean_v) = (
        points.iter().map(|p| p.0).sum::<f64>() / n,
        points.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let spread: f64 = points.iter().map(|p| (p.0 - mean_t).powi(2)).sum();
    let slope = match spread > 0.0 {
        true => points.iter().map(|p| (p.0 - mean_t) * (p.1 - mean_v)).sum::<f64>() / spread,
        false => 0.0,
    };
    move |t| mean_v + slope * (t - mean_t)
}

/// Fourth-difference noise of each survey line, before and after.
pub fn line_noise(log: &FlightLog, before: &[f64], after: &[f64]) -> Vec<LineNoise> {
    log.survey_lines()
        .into_iter()
        .map(|(number, rows)| {
            let pick = |v: &[f64]| rows.iter().map(|&k| v[k]).collect::<Vec<f64>>();
            LineNoise {
                line: number,
                before_nt: fourth_difference_noise(&pick(before)),
                after_nt: fourth_difference_noise(&pick(after)),
            }
        })
        .collect()
}

pub(crate) fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

fn cell(cell: &Option<FomCell>, limit_per_cell: f64) -> String {
    match cell {
        Some(c) => {
            let class = if c.after_nt <= limit_per_cell { "pass" } else { "fail" };
            format!(
                "<td>{:.2}</td><td class=\"{class}\">{:.3}</td>",
                c.before_nt, c.after_nt
            )
        }
        None => "<td>–</td><td class=\"missing\">missing</td>".into(),
    }
}

fn fom_section(quality: &ChannelQuality, limit_nt: f64) -> String {
    let mut html = String::from(
        "<table class=\"fom\"><tr><th>heading</th><th>pitch before</th><th>after</th><th>roll before</th><th>after</th><th>yaw before</th><th>after</th><th>RMS after</th></tr>",
    );
    // A cell passes when it is within its twelfth of the limit.
    let per_cell = limit_nt / 12.0;
    for row in &quality.fom_table {
        let _ = write!(
            html,
            "<tr><td>{:.0}°</td>{}{}{}<td>{:.3}</td></tr>",
            row.heading_deg,
            cell(&row.pitch, per_cell),
            cell(&row.roll, per_cell),
            cell(&row.yaw, per_cell),
            row.rms_after_nt
        );
    }
    html += "</table>";
    html
}

/// The FOM line: the FOM before and after against `limit_nt`, nT, or
/// that there is none.
fn fom_line(quality: &ChannelQuality, limit_nt: f64) -> String {
    match quality.fom_after_nt {
        Some(fom) => format!(
            "<span class=\"{}\">FOM {:.2} → {fom:.2} nT</span> over {} (limit {limit_nt} nT)",
            if fom <= limit_nt { "pass" } else { "fail" },
            quality.fom_before_nt.unwrap_or(f64::NAN),
            quality.manoeuvre_count()
        ),
        None => "no labelled manoeuvres: no FOM".into(),
    }
}

/// The CSS class of a verdict's word.
fn verdict_class(verdict: crate::quality::verdict::Verdict) -> &'static str {
    match verdict {
        crate::quality::verdict::Verdict::Pass => "pass",
        crate::quality::verdict::Verdict::Check => "check",
        crate::quality::verdict::Verdict::Fail => "fail",
    }
}

/// The channel's verdict in its word, then a line per reason.
fn verdict_head(quality: &ChannelQuality) -> String {
    let mut html = format!(
        "<p class=\"verdict\"><span class=\"{}\">{}</span></p>",
        verdict_class(quality.verdict),
        quality.verdict
    );
    for reason in &quality.verdict_reasons {
        let _ = write!(html, "<p class=\"reason\">{}</p>", escape(reason));
    }
    html
}

fn verdict(quality: &ChannelQuality, limit_nt: f64) -> String {
    let mut lines = vec![fom_line(quality, limit_nt)];
    lines.push(format!(
        "IR {:.1}; band std {:.3} → {:.3} nT; 4th-difference noise {:.4} → {:.4} nT",
        quality.improvement_ratio,
        quality.band_std_before_nt,
        quality.band_std_after_nt,
        quality.noise_4th_difference_before_nt,
        quality.noise_4th_difference_after_nt
    ));
    if let Some(check) = &quality.transfer {
        let class = if check.warning.is_some() { "fail" } else { "pass" };
        lines.push(format!(
            "<span class=\"{class}\">held-out FOM {:.2} nT</span> against {:.2} nT in sample ({:.1}×; {})",
            check.held_out_fom_nt,
            check.in_sample_fom_nt,
            check.ratio,
            check.method.describe()
        ));
    }
    for transfer in &quality.box_transfer {
        lines.push(format!(
            "box transfer: fitted on {}, {} band-passed residual {:.3} nT (fitted on itself {:.3} nT)",
            transfer.fit, transfer.test, transfer.band_std_nt, transfer.own_fit_band_std_nt
        ));
    }
    lines.extend(survey_lines(quality));
    lines.iter().map(|l| format!("<p>{l}</p>")).collect()
}

/// The verdict of a channel compensated with a saved model: the model's
/// figures on its calibration flight against the FOM limit, then this
/// flight's: held out on its own manoeuvres when it names them, and its
/// noise and heading error.
fn applied_verdict(quality: &ChannelQuality, applied: &crate::pipeline::apply::AppliedModel, limit_nt: f64) -> String {
    let mut lines = Vec::new();
    let saved = applied.calibration.iter().find(|c| c.channel == quality.channel);
    let class = match saved.and_then(|c| c.fom_after_nt) {
        Some(fom) if fom <= limit_nt => "pass",
        _ => "fail",
    };
    lines.push(format!(
        "<span class=\"{class}\">On its calibration flight</span> ({}): {} (limit {limit_nt} nT)",
        escape(&applied.fitted_on.display().to_string()),
        saved.map_or("no calibration figures saved".into(), |c| c.describe())
    ));
    let how = match applied.fitted_on_this_flight {
        true => "on the windows it was fitted on",
        false => "held out on this flight's windows",
    };
    if let (Some(before), Some(after)) = (quality.fom_before_nt, quality.fom_after_nt) {
        let class = if after <= limit_nt { "pass" } else { "fail" };
        lines.push(format!(
            "<span class=\"{class}\">{how}: FOM {before:.2} → {after:.2} nT</span> over {} of 12 (limit {limit_nt} nT)",
            quality.fom_manoeuvres
        ));
    }
    if quality.improvement_ratio.is_finite() {
        lines.push(format!(
            "{how}: IR {:.1}; band std {:.3} → {:.3} nT",
            quality.improvement_ratio, quality.band_std_before_nt, quality.band_std_after_nt
        ));
    }
    lines.push(format!(
        "4th-difference noise {:.4} → {:.4} nT",
        quality.noise_4th_difference_before_nt, quality.noise_4th_difference_after_nt
    ));
    lines.extend(survey_lines(quality));
    lines.iter().map(|l| format!("<p>{l}</p>")).collect()
}

/// The survey's own figures, where the flight has them: the heading error
/// of reciprocal lines, the crossovers and the heading level.
fn survey_lines(quality: &ChannelQuality) -> Vec<String> {
    let mut lines = Vec::new();
    if let Some(error) = &quality.heading_error {
        lines.push(format!(
            "heading error {:.3} → {:.3} nT over {} matched samples of reciprocal lines",
            error.before_nt, error.after_nt, error.pairs
        ));
    }
    if let Some(figures) = &quality.crossovers {
        lines.push(crossover_line(figures));
    }
    if let Some(figures) = &quality.heading_level {
        lines.push(heading_level_line(figures));
    }
    lines
}

/// The crossover differences of a channel, in words.
fn crossover_line(figures: &crate::quality::crossovers::CrossoverFigures) -> String {
    format!(
        "crossovers {:.3} → {:.3} nT RMS over {} where survey lines cross{}",
        figures.before_nt,
        figures.after_nt,
        figures.crossovers,
        match figures.external_field_removed {
            true => " (base station's change taken out)",
            false => " (no base station: the external field's change between passes is in them)",
        }
    )
}

/// The heading level between a channel's neighbouring lines, in words.
fn heading_level_line(figures: &crate::quality::corrugation::HeadingLevelFigures) -> String {
    format!(
        "lines' heading level {:.3} → {:.3} nT (± {:.3} nT) between neighbouring lines flown in opposite directions, {} lines{}",
        figures.before_nt,
        figures.after_nt,
        figures.standard_error_nt,
        figures.lines,
        match figures.external_field_removed {
            true => " (base station's change taken out)",
            false => " (no base station: the external field's change between lines is in it)",
        }
    )
}

/// The saved model a flight was compensated with: where it comes from.
fn applied_model_section(applied: &crate::pipeline::apply::AppliedModel) -> String {
    let mut rows = vec![
        ("model file", applied.file.display().to_string()),
        ("fitted on", applied.fitted_on.display().to_string()),
        ("written by", applied.written_by.clone()),
    ];
    if let Some(flight) = &applied.flight {
        rows.push(("calibration flight", flight.describe()));
    }
    if let Some(date) = applied.date {
        rows.push(("calibration day", date.to_string()));
    }
    if let Some(age) = applied.age_days {
        rows.push(("days from calibration to this flight", age.to_string()));
    }
    if let Some(aircraft) = &applied.aircraft {
        rows.push(("aircraft", aircraft.clone()));
    }
    let mut html =
        String::from("<section id=\"model\"><h2>Saved model applied (nothing refitted)</h2><table class=\"model\">");
    for (name, value) in rows {
        let _ = write!(html, "<tr><th>{name}</th><td>{}</td></tr>", escape(&value));
    }
    html += "</table></section>";
    html
}

/// Every estimator's held-out RMS on the model's windows, best first
/// marked, so a user sees which the data favour.
fn estimator_table(model: &FittedModel) -> String {
    let Some(table) = &model.estimators else {
        return String::new();
    };
    let best = table.iter().map(|s| s.heldout_rms).fold(f64::INFINITY, f64::min);
    let mut html = String::from(
        "<table class=\"estimators\"><tr><th>estimator</th><th>setting</th><th>held-out RMS (leave one heading out), nT</th></tr>",
    );
    for scored in table {
        let setting = match scored.estimator {
            crate::numerics::estimators::Estimator::Ridge { lambda } => format!("λ {lambda:.2e}"),
            crate::numerics::estimators::Estimator::Tsvd { rank }
            | crate::numerics::estimators::Estimator::Ttls { rank } => format!("rank {rank}"),
            crate::numerics::estimators::Estimator::DampedTsvd { rank, lambda } => {
                format!("rank {rank}, λ {lambda:.2e}")
            }
            _ => String::new(),
        };
        let mark = if scored.heldout_rms == best {
            " class=\"pass\""
        } else {
            ""
        };
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td><td{mark}>{:.5}</td></tr>",
            scored.family.name(),
            escape(&setting),
            scored.heldout_rms
        );
    }
    html + "</table>"
}

/// How well the manoeuvres flown pin each coefficient, and what to fly:
/// the analysis in words, the table of terms and the candidates.
fn excitation_section(model: &FittedModel) -> String {
    let Some(analysis) = &model.excitation else {
        return String::new();
    };
    let mut html = String::from("<h3>What the calibration pins</h3>");
    for line in &analysis.summary {
        let _ = write!(html, "<p>{}</p>", escape(line));
    }
    let _ = write!(html, "<p class=\"note\">{}</p>", escape(&analysis.candidates_from));
    html += &excitation_terms(analysis);
    html += &excitation_candidates(analysis);
    html
}

/// The excitation's table of terms: each coefficient's standard error
/// against a full box, the share no manoeuvre pins, and what pins it.
fn excitation_terms(analysis: &crate::model::excitation::Excitation) -> String {
    let mut html = String::from("<table class=\"excitation\"><tr><th>term</th><th>standard error against a full box</th><th>share no manoeuvre pins</th><th>pinned by</th></tr>");
    for term in &analysis.terms {
        let by: Vec<String> = (term.pinned_by.iter().take(3))
            .map(|(label, share)| format!("{label} {:.0} %", 100.0 * share))
            .collect();
        let mark = if term.poorly_pinned { " class=\"fail\"" } else { "" };
        let _ = write!(
            html,
            "<tr><td>{}</td><td{mark}>×{:.2}</td><td>{:.0} %</td><td>{}</td></tr>",
            escape(&term.term),
            term.inflation.sqrt(),
            100.0 * term.unpinnable_fraction,
            escape(&by.join(", "))
        );
    }
    html + "</table>"
}

/// The excitation's candidates: each manoeuvre that could be added or
/// flown more strongly, and the survey uncertainty it would leave, nT.
fn excitation_candidates(analysis: &crate::model::excitation::Excitation) -> String {
    let mut html = String::from("<table class=\"advice\"><tr><th>manoeuvre</th><th>in the box</th><th>amplitude, period, length</th><th>predicted survey uncertainty, nT</th><th>change</th></tr>");
    for candidate in &analysis.additions {
        let state = match (candidate.gap, candidate.flown) {
            (true, false) => "missing".to_string(),
            (true, true) => format!("weak ({:.0} %)", 100.0 * candidate.excitation_flown),
            (false, _) => "flown".to_string(),
        };
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{state}</td><td>±{:.1}°, {:.1} s, {:.0} s</td><td>{:.4}</td><td>{:+.1} %</td></tr>",
            escape(&candidate.label()),
            candidate.amplitude_deg,
            candidate.period_s,
            candidate.duration_s,
            candidate.survey_sigma_nt,
            100.0 * candidate.change
        );
    }
    html + "</table>"
}

fn coefficient_table(model: &FittedModel) -> String {
    let scale = model.spec.terms.bt_scale_nt;
    let mut html = format!(
        "<p>A term's coefficient times the term is its interference in nT. The Tolles-Lawson terms are direction cosines u (permanent), u·B/s (induced) and u·Ḃ/s (eddy), with s = {scale} nT ([fit] bt_scale_nt) and Ḃ in nT per sample; so the permanent and induced coefficients are in nT and the eddy ones in nT·sample. ± 1σ is the fit's standard error, widened for the residual's bandwidth (√(f<sub>s</sub>/2B)).</p>\
         <table class=\"coefficients\"><tr><th>term</th><th>coefficient</th><th>unit</th><th>± 1σ</th><th>|σ/coefficient|</th></tr>"
    );
    for ((name, value), sigma) in model
        .term_names
        .iter()
        .zip(&model.coefficients)
        .zip(&model.coefficient_uncertainty)
    {
        let unit = match name.split('_').next() {
            Some("perm" | "ind") => "nT",
            Some("eddy") => "nT·sample",
            _ => "nT per unit of the term",
        };
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{value:.6e}</td><td>{unit}</td><td>{sigma:.2e}</td><td>{:.2}</td></tr>",
            escape(name),
            (sigma / value).abs()
        );
    }
    html + "</table>"
}

/// The stretches of `located` that overlap `[t0, t1]`, clipped to it.
fn overlapping(located: &[&Located], (t0, t1): (f64, f64)) -> Vec<(f64, f64)> {
    located
        .iter()
        .filter(|l| l.t_end > t0 && l.t_start < t1)
        .map(|l| (l.t_start.max(t0), l.t_end.min(t1)))
        .collect()
}

/// One manoeuvre's held-out residual before (grey) and after (red) the
/// findings, with the located stretches shaded.
fn residual_plot(trace: &ResidualTrace, marked: &[(f64, f64)]) -> Result<String> {
    svg(SMALL, |root| {
        let x = span(trace.before.iter().chain(&trace.after).map(|p| p.0));
        let y = span(trace.before.iter().chain(&trace.after).map(|p| p.1));
        let mut chart = ChartBuilder::on(root)
            .caption(&trace.label, ("sans-serif", 12))
            .margin(4)
            .x_label_area_size(30)
            .y_label_area_size(40)
            .build_cartesian_2d(x.clone(), y.clone())
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .disable_x_mesh()
            .x_labels(3)
            .y_labels(4)
            .y_desc("nT")
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(marked.iter().map(|&(a, b)| {
                let (a, b) = (near(&x, a), near(&x, b));
                Rectangle::new([(a, y.start), (b, y.end)], RGBColor(255, 200, 60).mix(0.35).filled())
            }))
            .map_err(plot_error)?;
        for (points, colour) in [(&trace.before, RGBColor(150, 150, 150)), (&trace.after, RED)] {
            // A gap in the samples breaks the line.
            let mut pieces: Vec<Vec<(f64, f64)>> = Vec::new();
            for pair in points.iter() {
                match pieces.last_mut() {
                    Some(piece) if piece.last().is_some_and(|p| pair.0 - p.0 < 1.0) => piece.push(*pair),
                    _ => pieces.push(vec![*pair]),
                }
            }
            for piece in pieces {
                chart
                    .draw_series(LineSeries::new(on_canvas(decimated(piece.into_iter()), &x, &y), colour))
                    .map_err(plot_error)?;
            }
        }
        Ok(())
    })
}

/// The diagnosis's findings as a table, or the sentence that there is
/// none.
fn findings_table(findings: &[crate::diagnose::Finding]) -> String {
    let mut html = String::new();
    if findings.is_empty() {
        html +=
            "<p>No finding: nothing in the library explains the held-out residual better than plain Tolles-Lawson.</p>";
    } else {
        html += "<table class=\"findings\"><tr><th>effect</th><th>channel</th><th>source</th><th>parameters</th><th>held-out RMS, nT</th><th>what it means</th></tr>";
        for finding in findings {
            let parameters: Vec<String> = finding
                .effect
                .parameters()
                .iter()
                .map(|(k, v)| format!("{k} = {v:.4}"))
                .collect();
            let _ = write!(
                html,
                "<tr class=\"finding\"><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.4} → {:.4}</td><td style=\"text-align:left\">{}</td></tr>",
                escape(finding.effect.name()),
                escape(&finding.channel),
                escape(finding.source.as_deref().unwrap_or("")),
                escape(&parameters.join(", ")),
                finding.heldout_rms_before_nt,
                finding.heldout_rms_after_nt,
                escape(&finding.explanation)
            );
        }
        html += "</table>";
    }
    html
}

/// The diagnosis: what was found, and per channel each manoeuvre's
/// held-out residual before and after, with the windows the findings
/// improved most and the structured stretches shaded.
pub fn diagnosis_section(diagnosis: &Diagnosis) -> Result<String> {
    let mut html = String::from("<section id=\"diagnosis\"><h2>Diagnosis: physics the model left out</h2>");
    for note in &diagnosis.notes {
        let _ = write!(html, "<p class=\"note\">{}</p>", escape(&note.to_string()));
    }
    html += &findings_table(&diagnosis.findings);
    for channel in &diagnosis.channels {
        html += &diagnosed_channel(diagnosis, channel)?;
    }
    Ok(html + "</section>")
}

/// One channel of the diagnosis section: its held-out RMS before and after,
/// the table of manoeuvres and each manoeuvre's residual plotted with the
/// stretches the findings located shaded.
fn diagnosed_channel(diagnosis: &Diagnosis, channel: &crate::diagnose::ChannelDiagnosis) -> Result<String> {
    let mut html = String::new();
    let located: Vec<&Located> = diagnosis
        .findings
        .iter()
        .filter(|f| f.channel == channel.channel)
        .flat_map(|f| &f.located)
        .chain(&channel.localisation.structured)
        .collect();
    let _ = write!(
        html,
        "<h3>{}: held-out residual per manoeuvre, plain Tolles-Lawson (grey) and with the findings (red)</h3><p>Held-out RMS {:.4} → {:.4} nT ({}); in-band sensor noise {:.4} nT. Shaded: where the findings helped most and where the residual is structured.</p>",
        escape(&channel.channel),
        channel.heldout_rms_baseline_nt,
        channel.heldout_rms_final_nt,
        escape(&channel.model.describe()),
        channel.localisation.noise_floor_nt
    );
    html += "<table class=\"diagnosis-windows\"><tr><th>manoeuvre</th><th>held-out RMS before, nT</th><th>after, nT</th></tr>";
    for window in &channel.localisation.windows {
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{:.4}</td><td>{:.4}</td></tr>",
            escape(&window.label),
            window.heldout_rms_baseline_nt,
            window.heldout_rms_final_nt
        );
    }
    html += "</table>";
    html += &residual_figures(channel, &located)?;
    Ok(html)
}

/// A diagnosed channel's grid of figures: each manoeuvre's held-out
/// residual, with the `located` stretches that overlap it shaded.
fn residual_figures(channel: &crate::diagnose::ChannelDiagnosis, located: &[&Located]) -> Result<String> {
    let mut html = String::from("<div class=\"grid\">");
    for (trace, window) in channel.localisation.traces.iter().zip(&channel.localisation.windows) {
        let marked = overlapping(located, (window.t_start, window.t_end));
        let attribute: Vec<String> = marked.iter().map(|(a, b)| format!("{a:.2}:{b:.2}")).collect();
        let _ = write!(
            html,
            "<figure class=\"diagnosis-manoeuvre\" data-label=\"{}\" data-marked=\"{}\">{}</figure>",
            escape(&trace.label),
            attribute.join(" "),
            residual_plot(trace, &marked)?
        );
    }
    html += "</div>";
    Ok(html)
}

const STYLE: &str = "body{font-family:sans-serif;margin:2em;max-width:1000px}h2{border-bottom:1px solid #ccc}\
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ddd;padding:3px 8px;text-align:right}\
.pass{color:#176b1d;font-weight:bold}.fail{color:#b00020;font-weight:bold}.check{color:#8a5a00;font-weight:bold}\
.verdict{font-size:1.3em;margin:4px 0}.reason{margin:2px 0 2px 1em}.missing{color:#888}\
.grid{display:flex;flex-wrap:wrap;gap:4px}figure{margin:0}\
.warning{background:#fff3cd;border-left:4px solid #b00020;padding:4px 8px}";

/// Stages a page with the diagnosis section alone (`magcomp diagnose`).
pub fn stage_diagnosis_report(path: &Path, flight: &Path, diagnosis: &Diagnosis) -> Result<Staged> {
    let html = format!(
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>magcomp diagnosis: {0}</title><style>{STYLE}</style></head><body><h1>Diagnosis: {0}</h1>{1}</body></html>\n",
        escape(&flight.display().to_string()),
        diagnosis_section(diagnosis)?
    );
    stage(path, |out| std::io::Write::write_all(out, html.as_bytes()))
}

/// Which diagnosed findings the fit applied and what each bought held out.
fn applied_findings_section(result: &FlightResult) -> String {
    use crate::diagnose::ApplyDiagnosis;
    let mut html = String::from("<section id=\"applied\"><h2>Model</h2>");
    let empty = result.applied_findings.is_empty();
    match (&result.model, result.diagnosis_mode) {
        (Some(_), _) if empty => {
            html += "<p>The saved model is plain Tolles-Lawson: its calibration flight applied no diagnosed finding.</p>"
        }
        (Some(_), _) => {
            html += "<p>The saved model's findings, diagnosed and applied on its calibration flight (held-out RMS there):</p>"
        }
        (None, ApplyDiagnosis::Never) => {
            html += "<p>Plain Tolles-Lawson: no diagnosis applied (<code>--plain</code> or <code>[diagnose] apply = \"never\"</code>).</p>"
        }
        (None, _) if empty => html += "<p>Plain Tolles-Lawson: no diagnosed finding changes the model.</p>",
        (None, _) => {}
    }
    if !empty {
        html += "<table><tr><th>channel</th><th>effect</th><th>source</th><th>held-out RMS before, nT</th><th>with it, nT</th></tr>";
        for applied in &result.applied_findings {
            let _ = write!(
                html,
                "<tr class=\"applied\"><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td></tr>",
                escape(&applied.channel),
                escape(applied.effect.name()),
                escape(applied.source.as_deref().unwrap_or("")),
                applied.heldout_rms_before_nt,
                applied.heldout_rms_after_nt
            );
        }
        html += "</table>";
    }
    html + "</section>"
}

/// The flight against the plan it was flown to: each channel's figures,
/// planned and flown, and the manoeuvres the flight lacks.
fn plan_section(plan: &crate::quality::against_plan::PlanComparison) -> String {
    let mut html = format!(
        "<section id=\"plan\"><h2>Against the plan</h2><p>Plan report <code>{}</code> (plan <code>{}</code>){}; a figure holds inside the range of the plan's simulated flights widened ×{}.</p>",
        escape(&plan.report.display().to_string()),
        escape(&plan.plan.display().to_string()),
        match plan.with_additions {
            true => ", with the additions it proposed, which the flight flew",
            false => "",
        },
        plan.stated_factor
    );
    if !plan.missing.is_empty() {
        let _ = write!(
            html,
            "<p class=\"warning\">Planned and not flown: {}.</p>",
            escape(&plan.missing.join(", "))
        );
    }
    if !plan.unplanned.is_empty() {
        let _ = write!(
            html,
            "<p class=\"note\">Flown and not planned: {}.</p>",
            escape(&plan.unplanned.join(", "))
        );
    }
    html += "<table><tr><th>channel</th><th>figure</th><th>planned, nT</th><th>range, nT</th><th>flown, nT</th><th>flown / planned</th><th>verdict</th></tr>";
    for channel in &plan.channels {
        html += &plan_rows(channel);
    }
    html + "</table></section>"
}

/// One channel's rows of the plan table: each figure planned, its range,
/// flown, their ratio and the verdict.
fn plan_rows(channel: &crate::quality::against_plan::ChannelAgainstPlan) -> String {
    use crate::quality::against_plan::Verdict;
    let number = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.4}"));
    let mut html = String::new();
    for figure in &channel.figures {
        let (class, verdict) = match figure.verdict {
            Verdict::AsPlanned => ("", "as planned"),
            Verdict::Worse => (" class=\"warning\"", "worse than planned"),
            Verdict::Better => (" class=\"warning\"", "better than planned"),
            Verdict::NotCompared => ("", "not compared"),
        };
        let _ = write!(
            html,
            "<tr{class}><td>{}</td><td>{}</td><td>{}</td><td>{}–{}</td><td>{}</td><td>{}</td><td>{verdict}</td></tr>",
            escape(&channel.channel),
            figure.figure,
            number(figure.planned_nt),
            number(figure.planned_low_nt),
            number(figure.planned_high_nt),
            number(figure.flown_nt),
            figure.ratio.map_or("–".to_string(), |r| format!("{r:.2}")),
        );
    }
    html
}

/// The report's page and its figures as JSON beside it (`<path>` with the
/// extension `.json`), staged for `path`.
pub struct StagedReport {
    /// The figures the page shows.
    pub figures: ReportFigures,
    /// The HTML page.
    pub page: Staged,
    /// The figures as JSON.
    pub figures_json: Staged,
}

/// The path of the report's figures JSON beside the page at `path`.
pub fn figures_path(path: &Path) -> std::path::PathBuf {
    path.with_extension("json")
}

/// Stages the report for `path` and its figures as JSON beside it
/// ([`figures_path`]).
pub fn stage_report(path: &Path, flight: &FlightRun, fom_limit_nt: f64) -> Result<StagedReport> {
    let (log, result, compensation) = (flight.log(), &flight.result, &flight.compensation);
    let mut html = report_head(result);
    html += &format!("<section id=\"timeline\">{}", attitude_timeline(log, result)?);
    if let Some(calibration_box) = box_timeline(log, result)? {
        html += &calibration_box;
    }
    html += "</section>";
    let mut figures = Vec::new();
    for ((quality, model), channel) in result.channels.iter().zip(&result.models).zip(&compensation.channels) {
        let before = log
            .channel(&model.channel)
            .map(|c| c.values.as_slice())
            .unwrap_or_default();
        let noise = line_noise(log, before, &channel.values);
        html += &channel_section(log, result, (quality, model, channel), &noise, fom_limit_nt)?;
        figures.push(channel_figures(result, (quality, model), noise, fom_limit_nt));
    }
    if let Some(diagnosis) = &result.diagnosis {
        html += &diagnosis_section(diagnosis)?;
    }
    html += "</body></html>\n";
    let page = stage(path, |out| std::io::Write::write_all(out, html.as_bytes()))?;
    let figures = ReportFigures {
        flight: result.flight.display().to_string(),
        channels: figures,
    };
    let figures_json = stage_json(&figures_path(path), "the report figures", &figures)?;
    Ok(StagedReport {
        figures,
        page,
        figures_json,
    })
}

/// One channel's figures for the report's JSON: its FOM against
/// `fom_limit_nt`, nT, its improvement ratio and each line's noise.
fn channel_figures(
    result: &FlightResult,
    (quality, model): (&ChannelQuality, &FittedModel),
    noise: Vec<LineNoise>,
    fom_limit_nt: f64,
) -> ChannelFigures {
    ChannelFigures {
        channel: model.channel.clone(),
        fom_after_nt: quality.fom_after_nt,
        fom_limit_nt,
        // A flight given a saved model passes or fails with its
        // calibration flight's FOM (or its own, held out, when it has one).
        fom_pass: (quality.fom_after_nt)
            .or_else(|| {
                let applied = result.model.as_ref()?;
                let saved = applied.calibration.iter().find(|c| c.channel == quality.channel)?;
                saved.fom_after_nt
            })
            .map(|f| f <= fom_limit_nt),
        verdict: quality.verdict,
        anomaly_gain: quality.anomaly_gain,
        improvement_ratio: quality.improvement_ratio,
        line_noise: noise,
    }
}

/// The answer first: a row per channel with its verdict, FOM, noise,
/// heading level, anomaly gain and findings, linked to its section.
fn summary_table(result: &FlightResult) -> String {
    let figure = |value: Option<f64>, decimals: usize| value.map_or("–".to_string(), |v| format!("{v:.decimals$}"));
    let mut html = String::from(
        "<section id=\"summary\"><table class=\"summary\"><tr><th class=\"text\">channel</th><th class=\"text\">verdict</th><th>FOM after, nT</th><th>survey noise after, nT</th><th>heading level before → after, nT</th><th>anomaly gain</th><th class=\"text\">findings applied</th></tr>",
    );
    for quality in &result.channels {
        let level = (quality.heading_level.as_ref())
            .map_or("–".to_string(), |f| format!("{:.2} → {:.2}", f.before_nt, f.after_nt));
        let findings: Vec<String> = (result.applied_findings.iter())
            .filter(|f| f.channel == quality.channel)
            .map(|f| f.effect.to_string())
            .collect();
        let _ = write!(
            html,
            "<tr><td class=\"text\"><a href=\"#{0}\">{0}</a></td><td class=\"text\"><span class=\"{1}\">{2}</span></td><td>{3}</td><td>{4}</td><td>{level}</td><td>{5}</td><td class=\"text\">{6}</td></tr>",
            escape(&quality.channel),
            verdict_class(quality.verdict),
            quality.verdict,
            figure(quality.fom_after_nt, 2),
            figure(quality.survey_noise_4th_difference_after_nt, 4),
            figure(quality.anomaly_gain, 3),
            escape(&findings.join(", "))
        );
    }
    html + "</table></section>"
}

/// The page's head and what it says of the whole flight: its rows, the
/// warnings, the saved model, the findings applied, the plan, the notes.
fn report_head(result: &crate::pipeline::FlightResult) -> String {
    let mut html = format!(
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>magcomp report: {0}</title><style>{STYLE}</style></head><body><h1>Compensation report: {0}</h1>",
        escape(&result.flight.display().to_string())
    );
    let _ = write!(html, "<p>{} rows.</p>", result.rows);
    html += &summary_table(result);
    for warning in &result.warnings {
        let _ = write!(
            html,
            "<p class=\"warning\">Warning: {}</p>",
            escape(&warning.to_string())
        );
    }
    if let Some(applied) = &result.model {
        html += &applied_model_section(applied);
    }
    html += &applied_findings_section(result);
    if let Some(plan) = &result.plan {
        html += &plan_section(plan);
    }
    for note in &result.notes {
        let _ = write!(html, "<p class=\"note\">{}</p>", escape(&note.to_string()));
    }
    html
}

/// The per-line noise table (nothing without lines).
fn noise_table(noise: &[LineNoise]) -> String {
    let mut html = String::new();
    if !noise.is_empty() {
        html += "<h3>Per-line noise (4th difference, nT)</h3><table class=\"noise\"><tr><th>line</th><th>before</th><th>after</th></tr>";
        for line in noise {
            let _ = write!(
                html,
                "<tr><td>{}</td><td>{:.4}</td><td>{:.4}</td></tr>",
                line.line, line.before_nt, line.after_nt
            );
        }
        html += "</table>";
    }
    html
}

/// The regularisation's reason, and for a model `fitted_here` (not
/// applied from a saved one) its PRESS and singular-value plots.
fn regularisation(model: &FittedModel, fitted_here: bool) -> Result<String> {
    let mut html = String::from("<h3>Regularisation</h3>");
    let _ = write!(html, "<p>{}</p>", escape(&model.solution.reason));
    if fitted_here {
        let _ = write!(
            html,
            "<div class=\"grid\"><figure class=\"press\">{}</figure>",
            press_plot(model)?
        );
        let _ = write!(
            html,
            "<figure class=\"singular\">{}</figure></div>",
            singular_value_plot(model)?
        );
    }
    Ok(html)
}

/// A channel's survey-line profiles before and after compensation, under
/// their heading; nothing when the flight has no lines.
fn profiles_figure(
    log: &FlightLog,
    model: &FittedModel,
    channel: &crate::compensate::CompensatedChannel,
) -> Result<String> {
    let mut html = String::new();
    let before = log
        .channel(&model.channel)
        .map(|c| c.values.as_slice())
        .unwrap_or_default();
    if let Some((profiles, lines)) = line_profiles(log, before, &channel.values)? {
        html += "<h3>Survey line profiles</h3>";
        if lines > MOST_PROFILES {
            let _ = write!(
                html,
                "<p>{MOST_PROFILES} of the flight's {lines} lines, spread over them; the per-line noise table lists every line.</p>"
            );
        }
        let _ = write!(html, "<figure class=\"profiles\">{profiles}</figure>");
    }
    Ok(html)
}

/// One channel's section: its verdict, FOM table and manoeuvres (where it
/// has windows), regularisation, coefficients, estimators, excitation,
/// survey-line map and per-line noise.
fn channel_section(
    log: &FlightLog,
    result: &crate::pipeline::FlightResult,
    (quality, model, channel): (&ChannelQuality, &FittedModel, &crate::compensate::CompensatedChannel),
    noise: &[LineNoise],
    fom_limit_nt: f64,
) -> Result<String> {
    let mut html = format!(
        "<section class=\"channel\" id=\"{0}\"><h2>{0}</h2>",
        escape(&model.channel)
    );
    html += &verdict_head(quality);
    if let Some(applied) = &result.model {
        html += &applied_verdict(quality, applied, fom_limit_nt);
    }
    if result.model.is_none() || !model.windows.is_empty() {
        if result.model.is_none() {
            html += &verdict(quality, fom_limit_nt);
        }
        html += "<h3>FOM table (band-passed peak-to-peak, nT)</h3>";
        html += &fom_section(quality, fom_limit_nt);
        html += "<h3>Manoeuvres: before (grey) and after (blue), band-passed</h3><div class=\"grid\">";
        for index in 0..model.windows.len() {
            let _ = write!(
                html,
                "<figure class=\"manoeuvre\">{}</figure>",
                manoeuvre_plot(model, index)?
            );
        }
        html += "</div>";
    }
    html += &regularisation(model, result.model.is_none())?;
    html += "<h3>Coefficients</h3>";
    html += &coefficient_table(model);
    html += &estimator_table(model);
    html += &excitation_section(model);
    if let Some(map) = line_map(log, &channel.values)? {
        let _ = write!(html, "<h3>Survey lines</h3><figure class=\"map\">{map}</figure>");
    }
    html += &profiles_figure(log, model, channel)?;
    html += &noise_table(noise);
    html += "</section>";
    Ok(html)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Draws a line chart over `x` × `y` with its axis labels, as every
    /// report plot does; fails instead of hanging.
    fn draws_within_a_second(x: std::ops::Range<f64>, y: std::ops::Range<f64>) -> bool {
        let (sender, receiver) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let drawn = svg((300, 200), |root| {
                let mut chart = ChartBuilder::on(root)
                    .x_label_area_size(20)
                    .y_label_area_size(40)
                    .build_cartesian_2d(x.clone(), y.clone())
                    .map_err(plot_error)?;
                chart
                    .configure_mesh()
                    .x_label_formatter(&tick)
                    .y_label_formatter(&tick)
                    .draw()
                    .map_err(plot_error)?;
                // A point far off the plot, as a 1e308 sample would be.
                let points = on_canvas([(x.start, y.start), (x.end, 1e308), (-1e308, y.end)], &x, &y);
                chart.draw_series(LineSeries::new(points, BLUE)).map_err(plot_error)?;
                Ok(())
            });
            let _ = sender.send(drawn.is_ok());
        });
        receiver
            .recv_timeout(std::time::Duration::from_secs(1))
            .unwrap_or(false)
    }

    #[test]
    fn the_map_is_in_metres_at_one_scale() {
        // A degree of latitude is 111.19 km on the mean Earth; a degree of
        // longitude at 60° half that.
        let (east, north) = local_metres((46.0, -75.0), (45.0, -75.0));
        assert!(east.abs() < 1e-9 && (north - 111_195.0).abs() < 1.0, "{north}");
        let (east, north) = local_metres((60.0, 11.0), (60.0, 10.0));
        assert!((east - 55_597.5).abs() < 1.0 && north.abs() < 1e-9, "{east}");
        // 1 km east and 6 km north on a 400 × 300 pixel plot: one scale,
        // both spans kept whole, centred where they were.
        let (x, y) = stretched_scale((0.0..1000.0, -3000.0..3000.0), (400, 300), 1.0);
        let scale = ((x.end - x.start) / 400.0, (y.end - y.start) / 300.0);
        assert!(
            (scale.0 - scale.1).abs() < 1e-12 && (scale.1 - 20.0).abs() < 1e-12,
            "{scale:?}"
        );
        assert!(x.start <= 0.0 && x.end >= 1000.0 && ((x.start + x.end) / 2.0 - 500.0).abs() < 1e-9);
        assert_eq!(y, -3000.0..3000.0);
    }

    #[test]
    fn a_long_narrow_block_gets_a_legible_map_and_says_it_is_stretched() {
        // 30 km east by 3.5 km north: at one scale the plot would be about
        // 90 pixels tall; it is drawn at the least height, north stretched.
        let ((width, height), stretch) = map_canvas(30_000.0, 3_500.0).unwrap();
        let plot = map_pixels((width, height)).unwrap();
        assert_eq!(width, MAP_WIDTH);
        assert!(
            (f64::from(plot.1) - f64::from(MAP_PLOT_HEIGHT.0)).abs() <= 2.0,
            "{plot:?}"
        );
        let expected = f64::from(MAP_PLOT_HEIGHT.0) / (3_500.0 / 30_000.0 * f64::from(plot.0));
        assert!(
            (stretch - expected).abs() < 0.01 && stretch > 2.0,
            "{stretch} against {expected}"
        );
        let (x, y) = stretched_scale((0.0..30_000.0, 0.0..3_500.0), plot, stretch);
        let (east_per_pixel, north_per_pixel) = (
            (x.end - x.start) / f64::from(plot.0),
            (y.end - y.start) / f64::from(plot.1),
        );
        assert!((east_per_pixel / north_per_pixel - stretch).abs() < 1e-9);
        assert!(x.start <= 0.0 && x.end >= 30_000.0 && y.start <= 0.0 && y.end >= 3_500.0);
        // A square block is drawn at one scale, as tall as it is wide up to
        // the most height.
        let (size, stretch) = map_canvas(10_000.0, 10_000.0).unwrap();
        assert_eq!((map_pixels(size).unwrap().1, stretch), (MAP_PLOT_HEIGHT.1, 1.0));
    }

    #[test]
    fn a_heading_trace_wraps_at_north_to_the_panel_edges() {
        // 350° → 10° going up through north, then back down through it.
        let points = [(0.0, 350.0), (1.0, 10.0), (2.0, 20.0), (3.0, 355.0)];
        let pieces = split_at_wraps(&points, 0.0);
        assert_eq!(pieces.len(), 3, "{pieces:?}");
        assert_eq!(pieces[0], vec![(0.0, 350.0), (0.5, 360.0)]);
        assert_eq!(pieces[1], vec![(0.5, 0.0), (1.0, 10.0), (2.0, 20.0), (2.8, 0.0)]);
        assert_eq!(pieces[2], vec![(2.8, 360.0), (3.0, 355.0)]);
        // Without a crossing, one piece as it was.
        assert_eq!(split_at_wraps(&points[1..3], 0.0), vec![points[1..3].to_vec()]);
        // On an axis from 180° (south) through north to 180°, the same
        // crossing of north is no wrap, and a crossing of south is.
        let through_north = [(0.0, 350.0), (1.0, 370.0)];
        assert_eq!(split_at_wraps(&through_north, 180.0).len(), 1);
        let through_south = [(0.0, 530.0), (1.0, 190.0)];
        let pieces = split_at_wraps(&through_south, 180.0);
        assert_eq!(pieces.len(), 2);
        assert_eq!(pieces[0].last(), Some(&(0.5, 540.0)));
        assert_eq!(pieces[1].first(), Some(&(0.5, 180.0)));
        // The axis's ends go where no line is flown: east for lines flown
        // north and south (west if east is flown), north for east-west.
        assert_eq!(heading_cut([359.0, 1.0, 0.5, 180.0].into_iter()), 90.0);
        assert_eq!(heading_cut([90.0, 270.0, 2.0].into_iter()), 180.0);
        assert_eq!(heading_cut([90.0, 270.0, 178.0].into_iter()), 0.0);
        assert_eq!(heading_cut([0.0, 180.0, 95.0].into_iter()), 270.0);
    }

    #[test]
    fn ticks_read_short_and_never_minus_zero() {
        for (value, label) in [
            (-0.0, "0"),
            (-1e-13, "0"),
            (0.30000000000000004, "0.3"),
            (-2000.0, "-2000"),
            (53156.2, "53156.2"),
            (0.0125, "0.0125"),
        ] {
            assert_eq!(tick(&value), label, "{value}");
        }
    }

    #[test]
    fn a_profile_s_regional_trend_is_its_least_squares_line() {
        // 3 nT/s along the line and a 2 nT sine about it: the trend is the
        // line, the sine is what is left.
        let points: Vec<(f64, f64)> = (0..=400)
            .map(|k| {
                let t = f64::from(k) * 0.1;
                (t, 100.0 + 3.0 * t + 2.0 * (t * std::f64::consts::PI).sin())
            })
            .collect();
        let trend = regional_trend(points.iter().copied());
        // The sine's own slope over 20 periods, −1/(π·133) nT/s, moves the
        // ends by under 0.1 nT.
        assert!((trend(0.0) - 100.0).abs() < 0.1 && (trend(40.0) - 220.0).abs() < 0.1);
        let single = regional_trend(std::iter::once((5.0, 7.0)));
        assert_eq!(single(100.0), 7.0);
    }

    #[test]
    fn an_axis_is_finite_and_drawn_whatever_the_values() {
        let normal: Vec<f64> = (0..1000).map(|k| 53_000.0 + (k as f64 * 0.1).sin()).collect();
        let cases: Vec<Vec<f64>> = vec![
            vec![-1.5e308, 1.5e308],
            [normal.clone(), vec![-1.5e308, 1.5e308]].concat(),
            vec![f64::MAX, f64::MIN, f64::NAN, f64::INFINITY],
            vec![53_000.0; 10],
            vec![4.9e-324, 0.0, -4.9e-324],
            vec![f64::NAN],
            vec![],
        ];
        for values in cases {
            let range = span(values.iter().copied());
            assert!(
                range.start.is_finite() && range.end.is_finite(),
                "{values:?}: {range:?}"
            );
            assert!(
                range.end > range.start && (range.end - range.start).is_finite(),
                "{range:?}"
            );
            assert!(
                draws_within_a_second(0.0..1.0, range.clone()),
                "{values:?}: {range:?} hangs"
            );
        }
        // Two wild samples among a thousand do not flatten the plot: the
        // axis spans the sine's ±1 nT and its 5 % pad, not ±1.5e308.
        let range = span([normal.clone(), vec![-1.5e308, 1.5e308]].concat().into_iter());
        assert!(range.start > 53_000.0 - 1.2 && range.end < 53_000.0 + 1.2, "{range:?}");
        // A real peak of a few samples three times the rest stays on the axis.
        let mut peaked = normal;
        peaked[500..504].iter_mut().for_each(|v| *v = 53_003.0);
        let range = span(peaked.into_iter());
        assert!(range.end > 53_003.0 && range.start < 52_999.0, "{range:?}");
    }

    #[test]
    fn a_long_series_is_decimated_and_keeps_its_spikes() {
        let mut series: Vec<(f64, f64)> = (0..100_000)
            .map(|k| (k as f64 * 0.1, (k as f64 * 0.01).sin()))
            .collect();
        series[54_321].1 = 40.0;
        series[7_777].1 = -30.0;
        let kept = decimated(series.iter().copied());
        assert!(kept.len() <= MOST_LINE_POINTS, "{}", kept.len());
        assert!(kept.contains(&series[54_321]) && kept.contains(&series[7_777]));
        assert!(kept.windows(2).all(|pair| pair[0].0 < pair[1].0), "kept in order");
        assert_eq!(kept[0], series[0]);
        let short: Vec<(f64, f64)> = series[..500].to_vec();
        assert_eq!(decimated(short.iter().copied()), short);
    }

    #[test]
    fn a_map_draws_one_sample_per_cell() {
        // Ten lines of 20,000 samples across a 0.1° square.
        let mut easting = Vec::new();
        let mut northing = Vec::new();
        for line in 0..10 {
            for k in 0..20_000 {
                easting.push(-75.7 + 0.1 * k as f64 / 20_000.0);
                northing.push(45.3 + 0.01 * line as f64);
            }
        }
        let rows: Vec<usize> = (0..easting.len()).collect();
        let x = span(easting.iter().copied());
        let y = span(northing.iter().copied());
        let drawn = one_per_cell(&rows, (&easting, &northing), (&x, &y), (260, 210));
        assert!(drawn.len() <= 10 * 260, "{} points", drawn.len());
        for line in 0..10 {
            let on_line = drawn.iter().filter(|&&k| k / 20_000 == line).count();
            // Each line spans the axis less its two 5 % pads: 260 / 1.1 = 236 cells.
            assert!(on_line >= 230, "line {line} keeps {on_line} points");
        }
    }
}
