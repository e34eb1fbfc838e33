//! Held-out residuals: each heading's windows predicted by a fit on the
//! others (see [`folds`]), the figure every candidate is scored by.

use super::*;

/// Held-out residuals of a model: per window, predicted by a fit without
/// that window's heading.
#[derive(Clone)]
pub(super) struct HeldOut {
    pub(super) rms_nt: f64,
    pub(super) windows: Vec<WindowFit>,
    /// Samples the RMS is measured on.
    pub(super) samples: usize,
    /// The most coefficients of any of its fits.
    pub(super) terms: usize,
    /// The fewest samples any of its fits was made on.
    pub(super) fewest_training_samples: usize,
    /// Each split's fit as a ridge λ on the unscaled design, in split
    /// order: its own λ, or for a truncated SVD of rank r the product of
    /// the singular values either side of the cut (0 at full rank). The
    /// screen ([`super::screen`]) fits candidates with it.
    pub(super) ridge: Vec<f64>,
}

impl HeldOut {
    /// Why this held-out figure cannot serve as a baseline, if it cannot:
    /// zero or non-finite, measured on fewer samples than the model has
    /// terms, or from a fit on fewer samples than terms.
    pub(super) fn unusable(&self) -> Option<String> {
        if !self.rms_nt.is_finite() || self.rms_nt <= 0.0 {
            return Some(format!("the held-out RMS is {} nT", self.rms_nt));
        }
        if self.samples < self.terms {
            return Some(format!(
                "the held-out residual has {} samples, fewer than the model's {} terms",
                self.samples, self.terms
            ));
        }
        if self.fewest_training_samples <= self.terms {
            return Some(format!(
                "a fold was fitted on {} samples, no more than the model's {} terms",
                self.fewest_training_samples, self.terms
            ));
        }
        None
    }
}

impl Problem<'_> {
    /// The full model of `extensions` on the problem's terms.
    pub(super) fn spec(&self, extensions: &Model) -> ModelSpec {
        ModelSpec::new(self.terms, extensions.clone())
    }
}

/// The flight and extension columns `spec` fits on: the problem's flight
/// is already calibrated as the model wants it. Every score fits and
/// predicts on the problem's windows, so the columns are built on their
/// rows alone.
pub(super) fn prepare<'a>(problem: &Problem<'a>, spec: &'a ModelSpec) -> Result<Prepared<'a>> {
    Prepared::on_rows(
        Cow::Borrowed(problem.log),
        (problem.sensor, problem.channel),
        spec,
        problem.direction,
        crate::calibration::windows::merged_rows(problem.windows, problem.log.time_s()),
    )
}

/// The fit options of a score: it keeps the coefficients and the λ that
/// chose them, nothing the fit would report beside them.
pub(super) fn score_options(problem: &Problem) -> FitOptions {
    FitOptions {
        solve: SolveOptions {
            figures: Figures::Choice,
            ..problem.options.solve.clone()
        },
        ..problem.options.clone()
    }
}

/// Held-out residuals of `model` (see [`folds`]).
pub(super) fn held_out(problem: &Problem, model: &Model) -> Result<HeldOut> {
    residuals(problem, model, folds(problem.windows))
}

/// In-sample residuals of `model`: fitted on every window, and each
/// window's residual from that fit.
pub(super) fn in_sample(problem: &Problem, model: &Model) -> Result<HeldOut> {
    residuals(
        problem,
        model,
        vec![(problem.windows.to_vec(), problem.windows.to_vec())],
    )
}

/// The residuals of `model` on each split's first windows, fitted on its
/// second.
pub(super) fn residuals(
    problem: &Problem,
    model: &Model,
    splits: Vec<(Vec<CalibrationWindow>, Vec<CalibrationWindow>)>,
) -> Result<HeldOut> {
    let spec = problem.spec(model);
    let prepared = prepare(problem, &spec)?;
    let options = score_options(problem);
    let mut windows = Vec::new();
    let (mut terms, mut fewest_training_samples) = (0, usize::MAX);
    let mut ridge = Vec::new();
    // Every window of the splits band-passed once, each split's fit and
    // residual taken from it (the second-order passes band-pass only the
    // scalar again).
    let (every, places) = every_window(&splits);
    let band = prepared.band(&every, &options, problem.stores)?;
    for place in &places {
        let fitted = prepared.fit_within(&band, &place[1], &options, problem.stores)?;
        ridge.push(ridge_of(&fitted.solution));
        terms = terms.max(fitted.coefficients.len());
        fewest_training_samples = fewest_training_samples.min(fitted.solution.samples);
        windows.extend(prepared.held_out_within(&band, &fitted, (&place[0], &options), problem.stores)?);
    }
    problem.stores.recycle(band.stacked);
    let all: Vec<f64> = windows.iter().flat_map(|w| w.band_after_nt.iter().copied()).collect();
    Ok(HeldOut {
        rms_nt: root_mean_square(&all),
        windows,
        samples: all.len(),
        terms,
        fewest_training_samples,
        ridge,
    })
}

/// The ridge a fit used: its λ, or for a truncated SVD the product of the
/// singular values either side of the cut (0 with none cut).
fn ridge_of(solution: &crate::numerics::solve::Solution) -> f64 {
    solution.lambda.unwrap_or_else(|| {
        let sigma = &solution.singular_values;
        match solution.rank {
            Some(r) if r > 0 && r < sigma.len() => sigma[r - 1] * sigma[r],
            _ => 0.0,
        }
    })
}

/// The windows of `splits`, each once in the order first met, and where
/// each split's windows (held out, trained on) are among them.
fn every_window(
    splits: &[(Vec<CalibrationWindow>, Vec<CalibrationWindow>)],
) -> (Vec<CalibrationWindow>, Vec<[Vec<usize>; 2]>) {
    let mut every: Vec<CalibrationWindow> = Vec::new();
    let mut place = |window: &CalibrationWindow| match every.iter().position(|w| w == window) {
        Some(index) => index,
        None => {
            every.push(window.clone());
            every.len() - 1
        }
    };
    let places = (splits.iter())
        .map(|(out, rest)| {
            [
                out.iter().map(&mut place).collect(),
                rest.iter().map(&mut place).collect(),
            ]
        })
        .collect();
    (every, places)
}

/// How the calibration windows are held out.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum HoldOut {
    /// No window at all.
    Nothing,
    /// Windows of a box (each with its heading) on fewer than three headings.
    TooFewHeadings(Vec<f64>),
    /// Leave one heading out, over these headings.
    ByHeading(Vec<f64>),
    /// Leave one window out (windows without headings, three or more).
    ByWindow(usize),
    /// Leave one quarter of a window out (one or two windows without headings).
    ByQuarter(usize),
}

impl HoldOut {
    /// How `windows` can be held out. Windows that all carry a heading come
    /// from a box (detected, or a DETECT.json): they are held out by
    /// heading or not at all. Windows given by time alone are held out as
    /// well as their number allows.
    pub(super) fn of(windows: &[CalibrationWindow]) -> Self {
        let headings = distinct_headings(windows);
        let boxed = windows.iter().all(|w| w.heading_deg.is_some());
        match windows.len() {
            0 => HoldOut::Nothing,
            _ if boxed && headings.len() >= 3 => HoldOut::ByHeading(headings),
            _ if boxed => HoldOut::TooFewHeadings(headings),
            n if n >= 3 => HoldOut::ByWindow(n),
            n => HoldOut::ByQuarter(n),
        }
    }

    /// What makes the windows unfit for a diagnosis, in words.
    pub(super) fn insufficient(&self) -> Option<String> {
        match self {
            HoldOut::Nothing => Some("it has no calibration windows: no manoeuvres were detected and none were given".into()),
            HoldOut::TooFewHeadings(headings) => Some(format!(
                "its calibration manoeuvres are on {} heading{} ({}), too few to hold one out (leave-one-heading-out needs three)",
                headings.len(),
                if headings.len() == 1 { "" } else { "s" },
                headings.iter().map(|h| format!("{h:.0}°")).collect::<Vec<_>>().join(", ")
            )),
            _ => None,
        }
    }

    /// What a diagnosis held out this way cannot test, in words.
    pub(super) fn caveat(&self) -> Option<Note> {
        match *self {
            HoldOut::ByWindow(windows) => Some(Diagnosing::HeldOutByWindow { windows }.into()),
            HoldOut::ByQuarter(windows) => Some(Diagnosing::HeldOutByQuarter { windows }.into()),
            _ => None,
        }
    }
}

/// The flight's error for a diagnosis its calibration cannot support.
pub(super) fn not_enough_calibration(log: &FlightLog, problem: String) -> crate::Error {
    crate::Error::NotEnoughCalibration {
        path: log.source().to_path_buf(),
        task: "the diagnosis",
        problem,
        hint: "Nothing was diagnosed. Fly (or give) a calibration box with manoeuvres on at least three headings (`magcomp detect FLIGHT --out DETECT.json` shows what detection found and what is missing), or name the windows to test with --window T0:T1; the diagnosis then reports what those windows can test.".into(),
    }
}

/// The held-out splits (held out, trained on): each heading with three
/// headings or more (leave one heading out); otherwise each window with
/// three windows or more; otherwise each quarter of every window.
pub(super) fn folds(windows: &[CalibrationWindow]) -> Vec<(Vec<CalibrationWindow>, Vec<CalibrationWindow>)> {
    if let Some(splits) = heading_splits(windows) {
        return splits;
    }
    let split = |pieces: &[CalibrationWindow], is_out: &dyn Fn(usize, &CalibrationWindow) -> bool| {
        let (out, rest): (Vec<_>, Vec<_>) = pieces.iter().enumerate().partition(|(k, w)| is_out(*k, w));
        (
            out.into_iter().map(|(_, w)| w.clone()).collect(),
            rest.into_iter().map(|(_, w)| w.clone()).collect(),
        )
    };
    let pieces: Vec<CalibrationWindow> = if windows.len() >= 3 {
        windows.to_vec()
    } else {
        windows
            .iter()
            .flat_map(|w| {
                let quarter = (w.t_end - w.t_start) / 4.0;
                (0..4).map(move |q| CalibrationWindow {
                    label: format!("{} (quarter {})", w.display_label(), q + 1),
                    ..CalibrationWindow::new(w.t_start + q as f64 * quarter, w.t_start + (q + 1) as f64 * quarter)
                })
            })
            .collect()
    };
    (0..pieces.len()).map(|k| split(&pieces, &|j, _| j == k)).collect()
}
