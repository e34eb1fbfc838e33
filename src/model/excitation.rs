//! What the calibration cannot tell: how well the manoeuvres flown pin
//! each coefficient, and which manoeuvre would pin them better.
//!
//! The band-passed design $A$ of a fit (its terms and extension columns,
//! each column scaled to unit norm over the windows) splits by window into
//! information matrices $G_w = A_w^\top A_w$, with $G = \sum_w G_w$. A
//! coefficient's variance is $\sigma^2 (G^{-1})_{jj}$, and its information
//! splits among the windows: with $v_j = G^{-1} e_j$,
//!
//! $$ \sum_w \frac{v_j^\top G_w v_j}{v_j^\top G v_j} = 1, $$
//!
//! each term the window's share of what pins coefficient j.
//!
//! What "poorly" means needs a yardstick: the same candidate manoeuvres
//! a pilot would fly (pitch, roll and yaw on every heading of the box, at
//! the amplitudes and periods flown, through the Earth's field the flight
//! records), simulated and band-passed as the fit's windows are. Their sum
//! $G_{\text{box}}$, scaled to the same total excitation (trace) as $G$,
//! is a full box of the same strength. Directions $G_{\text{box}}$ does not
//! see (the sums of the diagonal induced and eddy terms, which no rotation
//! changes, and any below [`UNPINNABLE_FRACTION`] of its spectrum) no
//! manoeuvre pins: the regulariser sets them and they are set aside. In
//! the rest, a coefficient whose variance exceeds the full box's fourfold
//! (twice the standard error) is poorly pinned.
//!
//! Advice scores each candidate by the predicted uncertainty of the
//! compensated survey: with $S$ the second moment of the survey rows'
//! design about its calibration mean (the compensated value is relative
//! to its level over the calibration, as the sigma column is),
//! $\sigma_{\text{survey}}^2 = \sigma^2 \operatorname{tr}(S G^{-1})$ on the
//! pinnable directions. Adding a candidate adds its $G_c$; dropping a
//! flown window subtracts its $G_w$ (an I-optimal design criterion; Atkinson,
//! Donev & Tobias 2007, ch. 10). The least-squares covariance is used, not
//! ridge's: ridge's variance shrinks in exactly the directions the data
//! leave open, where its error is bias, so it would score new information
//! there as a loss.

use std::ops::Range;

use faer::Mat;
use serde::Serialize;

use crate::calibration::headings::{angle_apart, distinct_headings, same_heading};
use crate::calibration::windows::{CalibrationWindow, ManoeuvreKind};
use crate::error::Result;
use crate::ingest::flight_log::{body_to_ned, Channel, ChannelRole, FlightLog, VectorSensor};
use crate::numerics::linalg::gram;
use crate::numerics::stacked::StorePool;

use super::band::{band_data, BandData, FitOptions};
use super::extensions::SourceTerm;
use super::{FittedModel, Prepared, SharedDesign, WindowFit};

/// A coefficient whose variance exceeds a full box's of the same length
/// by this factor (its standard error twice as large) is poorly pinned.
pub const POOR_INFLATION: f64 = 4.0;

/// Directions of the scaled information whose eigenvalue is below this
/// fraction of the largest, even with a full box added, no manoeuvre
/// pins.
pub const UNPINNABLE_FRACTION: f64 = 1e-7;

/// A manoeuvre whose windows on a heading give less than this fraction of
/// the excitation of the same manoeuvre at the kind's typical amplitude
/// (a quarter: half the amplitude) is a gap in the box.
pub const WEAK_EXCITATION: f64 = 0.25;

/// Added to the diagonal of the scaled information (times its mean
/// diagonal) before it is inverted: a direction the windows flown leave
/// wholly open (a kind of manoeuvre never flown) gets a large, finite
/// variance.
const FLOOR: f64 = 1e-9;

/// A window (or manoeuvre) whose share of a coefficient's information is
/// at least this pins it "mostly".
const MOSTLY: f64 = 0.5;

/// Amplitudes (degrees) assumed for candidate manoeuvres when the flight
/// records no INS attitude: pitch, roll, yaw (the simulator's defaults).
const NOMINAL_AMPLITUDE_DEG: [f64; 3] = [5.0, 10.0, 5.0];

/// Period (s) assumed for candidate manoeuvres when the flight records no
/// attitude.
const NOMINAL_PERIOD_S: f64 = 6.0;

/// Level flight before and after a candidate manoeuvre, s: what the
/// detection's window margins give a flown one.
const CANDIDATE_MARGIN_S: f64 = 3.0;

/// How well one fit's manoeuvres pin its coefficients, and what to fly.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Excitation {
    /// One entry per coefficient, in the model's order.
    pub terms: Vec<TermPinning>,
    /// Combinations of coefficients no manoeuvre pins (the regulariser
    /// sets them), strongest terms first.
    pub unpinnable: Vec<Vec<(String, f64)>>,
    /// Each flown window's share of the information, and what dropping it
    /// would cost.
    pub windows: Vec<WindowShare>,
    /// Candidate manoeuvres, the most useful addition first.
    pub additions: Vec<Candidate>,
    /// The compensated survey's uncertainty from the information flown
    /// (the pinnable part, least squares), one sigma, nT.
    pub survey_sigma_nt: f64,
    /// Rows the survey figure is taken over: survey lines, or the rows
    /// outside the calibration windows; 0 when there are none and the
    /// calibration rows stand in.
    pub survey_rows: usize,
    /// How the candidate manoeuvres were made.
    pub candidates_from: String,
    /// The analysis in plain words.
    pub summary: Vec<String>,
    /// The band-passed design's second moment over the calibration
    /// windows, $M = A^\top A / n$ (p × p, the coefficients' own units, the
    /// model's term order). For two models' coefficient difference
    /// $\Delta$, $\Delta^\top M \Delta$ is the mean square of their
    /// predictions' difference over this calibration's manoeuvres, nT²:
    /// what compares two calibrations of one aircraft
    /// ([`crate::campaign::drift`]).
    pub calibration_moment: Vec<Vec<f64>>,
}

/// How well one coefficient is pinned.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TermPinning {
    /// Term name.
    pub term: String,
    /// Variance against a full box of the same length (pinnable part): 1
    /// is as well pinned, 4 twice the standard error.
    pub inflation: f64,
    /// Fraction of the term (its unit vector's squared length) in
    /// directions no manoeuvre pins.
    pub unpinnable_fraction: f64,
    /// Inflation above [`POOR_INFLATION`].
    pub poorly_pinned: bool,
    /// The windows that pin it, largest share first (shares of at least
    /// 5 %).
    pub pinned_by: Vec<(String, f64)>,
}

/// One flown window's part in the fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WindowShare {
    /// Window label.
    pub label: String,
    /// Its share of the trace of the scaled information.
    pub information_share: f64,
    /// The survey uncertainty without it, nT (infinite when the rest
    /// cannot pin what it pins).
    pub survey_sigma_without_nt: f64,
    /// Relative change of the survey uncertainty without it.
    pub change: f64,
}

/// A manoeuvre that could be flown.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate {
    /// Manoeuvre.
    pub kind: ManoeuvreKind,
    /// Heading, degrees clockwise from north.
    pub heading_deg: f64,
    /// Amplitude, degrees.
    pub amplitude_deg: f64,
    /// Period, s.
    pub period_s: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Whether the flight already has this manoeuvre on this heading.
    pub flown: bool,
    /// The excitation its windows on this heading gave (the trace of their
    /// scaled information) over what this candidate gives: 0 when not
    /// flown, about 1 when flown as the candidate is.
    pub excitation_flown: f64,
    /// The samples its windows on this heading kept and had, when gaps in
    /// the recording cut them ([`super::CUT_BY_GAPS`]): the excitation
    /// flown counts only what was kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub samples_kept: Option<[usize; 2]>,
    /// A gap in the box: not flown, or flown with under
    /// [`WEAK_EXCITATION`] of the candidate's excitation (never when the
    /// windows carry no manoeuvre kind).
    pub gap: bool,
    /// The survey uncertainty with it added, nT.
    pub survey_sigma_nt: f64,
    /// Relative change of the survey uncertainty (negative: better).
    pub change: f64,
    /// D-optimal gain: half the log of the determinant's growth on the
    /// pinnable directions, nats (how much the joint confidence region of
    /// the coefficients shrinks).
    pub information_gain: f64,
    /// A-optimal: the sum of the scaled coefficients' variances with it
    /// added, relative to without.
    pub variance_ratio: f64,
}

impl Candidate {
    /// "roll, heading 110".
    pub fn label(&self) -> String {
        format!("{}, heading {}", self.kind.name(), self.heading_deg.round())
    }

    /// "±10.0°, 6.0 s period, 30 s".
    pub fn shape_words(&self) -> String {
        format!(
            "±{:.1}°, {:.1} s period, {:.0} s",
            self.amplitude_deg, self.period_s, self.duration_s
        )
    }
}

impl Excitation {
    /// One sentence per gap in the box (the first four): what is missing
    /// or weak, how to fly it and what it would do to the survey.
    pub fn gaps(&self) -> Vec<String> {
        (self.additions.iter().filter(|c| c.gap).take(4))
            .map(|gap| self.gap_words(gap))
            .collect()
    }

    /// The sentence of one gap: what is missing or weak, how to fly it
    /// and what it would do to the survey.
    pub fn gap_words(&self, gap: &Candidate) -> String {
        let state = match (gap.flown, gap.samples_kept) {
            (false, _) => "is not among the windows".to_string(),
            (true, Some([kept, had])) => format!(
                "was flown, but gaps in the recording left {kept} of its {had} samples: {:.0} % of the excitation of a typical {} reached the fit",
                100.0 * gap.excitation_flown,
                gap.kind.name()
            ),
            (true, None) => format!(
                "was flown with {:.0} % of the excitation of a typical {}",
                100.0 * gap.excitation_flown,
                gap.kind.name()
            ),
        };
        format!(
            "The box's {} {state}: fly it ({}); {}.",
            gap.label(),
            gap.shape_words(),
            self.change_words(gap)
        )
    }

    /// "the predicted survey uncertainty goes from … to … (…)".
    fn change_words(&self, candidate: &Candidate) -> String {
        format!(
            "the predicted survey uncertainty goes from {:.3} nT to {:.3} nT ({:+.0} %)",
            self.survey_sigma_nt,
            candidate.survey_sigma_nt,
            100.0 * candidate.change
        )
    }
}

/// The excitation analysis of `model` (fitted on `windows` of `log`, its
/// terms built from `sensor`). `None` when the candidates cannot be
/// placed (windows without a heading on a flight without attitude) or the
/// flown information is singular even on the pinnable directions. The
/// whole flight's terms come from `shared` when it holds them.
pub fn analyse(
    log: &FlightLog,
    sensor: &VectorSensor,
    model: &FittedModel,
    windows: &[CalibrationWindow],
    options: &FitOptions,
    (stores, shared): (&StorePool, &[SharedDesign]),
) -> Result<Option<Excitation>> {
    Ok(analyse_design(log, sensor, model, windows, options, (stores, shared))?.map(|(excitation, _)| excitation))
}

/// The information behind an analysis, for scoring sets of additions
/// (planning): the flown information and every candidate's, scaled
/// alike, and what turns information into the survey's uncertainty.
#[derive(Debug, Clone)]
pub struct Design {
    /// The pinnable directions of the scaled coefficients (p × r).
    basis: Mat<f64>,
    /// The survey's second moment on them (r × r).
    survey: Mat<f64>,
    /// σ² per unit information.
    noise_variance: f64,
    /// Added to the reduced information's diagonal.
    floor: f64,
    /// The flown windows' scaled information (p × p).
    flown: Mat<f64>,
    /// Each candidate and its scaled information, in the order of
    /// [`Excitation::additions`] before sorting: heading by heading,
    /// pitch, roll, yaw.
    candidates: Vec<(Candidate, Mat<f64>)>,
}

impl Design {
    /// The candidates, unscored.
    pub fn candidates(&self) -> impl Iterator<Item = &Candidate> {
        self.candidates.iter().map(|c| &c.0)
    }

    /// The survey uncertainty (the coefficients' part, least squares,
    /// one sigma, nT) with the candidates at `chosen` (indices into
    /// [`Self::candidates`], repeats allowed) flown as well.
    pub fn survey_sigma_with(&self, chosen: &[usize]) -> f64 {
        let mut information = self.flown.clone();
        for &k in chosen {
            if let Some((_, g)) = self.candidates.get(k) {
                information += g;
            }
        }
        self.survey_sigma(&information)
    }

    /// The inverses of the reduced, floored informations `g`; `None` when
    /// one is not positive definite.
    fn reduced_inverses<const N: usize>(&self, g: [&Mat<f64>; N]) -> Option<[Mat<f64>; N]> {
        let inverses: Vec<Mat<f64>> = g.iter().map(|g| inverse_spd(&self.reduced(g))).collect::<Option<_>>()?;
        inverses.try_into().ok()
    }

    /// The reduced, floored information.
    fn reduced(&self, g: &Mat<f64>) -> Mat<f64> {
        let mut reduced = self.basis.transpose() * g * &self.basis;
        for k in 0..reduced.nrows() {
            reduced[(k, k)] += self.floor;
        }
        reduced
    }

    /// Each flown window's share of the information, and the survey
    /// uncertainty without it.
    fn window_shares(&self, labels: &[String], flown: &[Mat<f64>], survey_sigma_nt: f64) -> Vec<WindowShare> {
        let information = &self.flown;
        let p = information.nrows();
        let trace: f64 = (0..p).map(|i| information[(i, i)]).sum();
        (labels.iter().zip(flown))
            .map(|(label, g)| {
                let sigma = self.survey_sigma(&(information - g));
                WindowShare {
                    label: label.clone(),
                    information_share: (0..p).map(|i| g[(i, i)]).sum::<f64>() / trace,
                    survey_sigma_without_nt: sigma,
                    change: sigma / survey_sigma_nt - 1.0,
                }
            })
            .collect()
    }

    /// Each candidate added to the flown windows: the survey uncertainty,
    /// information gain and variance it leaves; the box's gaps first (the
    /// FOM and the usual acceptance need the whole box), then the rest,
    /// each by the survey uncertainty it leaves.
    fn additions(
        &self,
        candidates: &[(Candidate, Mat<f64>)],
        (survey_sigma_nt, flown_log_det, flown_variance): (f64, f64, f64),
    ) -> Vec<Candidate> {
        let (information, r) = (&self.flown, self.basis.ncols());
        let mut additions: Vec<Candidate> = candidates
            .iter()
            .map(|(candidate, g)| {
                let mut candidate = candidate.clone();
                let with = information + g;
                candidate.survey_sigma_nt = self.survey_sigma(&with);
                candidate.change = candidate.survey_sigma_nt / survey_sigma_nt - 1.0;
                candidate.information_gain = 0.5 * (log_det(&self.reduced(&with)) - flown_log_det);
                candidate.variance_ratio = inverse_spd(&self.reduced(&with)).map_or(f64::NAN, |inverse| {
                    (0..r).map(|k| inverse[(k, k)]).sum::<f64>() / flown_variance
                });
                candidate
            })
            .collect();
        additions.sort_by(|a, b| (b.gap.cmp(&a.gap)).then(a.survey_sigma_nt.total_cmp(&b.survey_sigma_nt)));
        additions
    }

    /// The survey uncertainty of scaled information `g`, nT.
    fn survey_sigma(&self, g: &Mat<f64>) -> f64 {
        match inverse_spd(&self.reduced(g)) {
            Some(inverse) => (self.noise_variance * trace_product(&self.survey, &inverse))
                .max(0.0)
                .sqrt(),
            None => f64::INFINITY,
        }
    }
}

/// The flown windows' information in the design's columns.
struct Flown {
    /// Each window's, scaled by `scale`.
    per_window: Vec<Mat<f64>>,
    /// Their sum.
    information: Mat<f64>,
    /// Each column's norm over the windows (1 for an empty column).
    scale: Vec<f64>,
    /// The calibration's moment matrix, unscaled, per row.
    calibration_moment: Vec<Vec<f64>>,
}

impl Flown {
    /// The information of each window of `fits` in the band-passed design
    /// `stacked`.
    fn of(stacked: &crate::numerics::stacked::Stacked, fits: &[WindowFit]) -> Self {
        let p = stacked.columns();
        let rows: usize = fits.iter().map(|f| f.stacked_rows.len()).sum();
        let per_window: Vec<Mat<f64>> = fits
            .iter()
            .map(|f| rows_gram(|j| stacked.column_range(j, f.stacked_rows.clone()), p))
            .collect();
        let total = sum(per_window.iter(), p);
        let calibration_moment = (0..p)
            .map(|i| (0..p).map(|j| total[(i, j)] / rows.max(1) as f64).collect())
            .collect();
        let scale: Vec<f64> = (0..p)
            .map(|j| total[(j, j)].sqrt())
            .map(|d| if d > 0.0 && d.is_finite() { d } else { 1.0 })
            .collect();
        let per_window: Vec<Mat<f64>> = per_window.iter().map(|g| scaled_by(g, &scale)).collect();
        Flown {
            information: sum(per_window.iter(), p),
            per_window,
            scale,
            calibration_moment,
        }
    }
}

/// The pinnable directions: those a full box (`reference`, scaled
/// information) sees, less the sums no rotation can change (see
/// [`structural_null`]). Their basis, every eigenvector, and the indices
/// of those left unpinnable; `None` when the eigendecomposition fails.
fn pinnable_basis(
    term_names: &[String],
    scale: &[f64],
    reference: &Mat<f64>,
) -> Option<(Mat<f64>, Mat<f64>, Vec<usize>)> {
    let p = scale.len();
    let null = structural_null(term_names, scale);
    let project = Mat::from_fn(p, p, |i, j| {
        f64::from(i == j) - null.iter().map(|n| n[i] * n[j]).sum::<f64>()
    });
    let eigen = (&project * reference * &project)
        .self_adjoint_eigen(faer::Side::Lower)
        .ok()?;
    let (vectors, values) = (eigen.U(), eigen.S());
    let largest = (0..p).map(|k| values[k]).fold(0.0, f64::max);
    let (pinnable, unpinnable): (Vec<usize>, Vec<usize>) =
        (0..p).partition(|&k| values[k] > UNPINNABLE_FRACTION * largest);
    let basis = Mat::from_fn(p, pinnable.len(), |i, k| vectors[(i, pinnable[k])]);
    Some((basis, vectors.to_owned(), unpinnable))
}

/// The calibration `windows`' fits in the band-passed design of `model`
/// (on `prepared`, its flight with its extension columns), the sample
/// rate, and the information each window holds.
fn flown_windows(
    prepared: &Prepared,
    (sensor, model, windows): (&VectorSensor, &FittedModel, &[CalibrationWindow]),
    options: &FitOptions,
    stores: &StorePool,
) -> Result<(Vec<WindowFit>, f64, Flown)> {
    let BandData {
        stacked,
        windows: fits,
        sample_rate_hz,
    } = band_data(
        &prepared.log,
        sensor,
        (&model.channel, &prepared.scalar),
        windows,
        (model.spec.fitted_terms(), &options.filter),
        &prepared.extra_columns(),
        stores,
    )?;
    let flown = Flown::of(&stacked, &fits);
    stores.recycle(stacked);
    Ok((fits, sample_rate_hz, flown))
}

/// [`analyse`], and the information it rests on.
pub fn analyse_design(
    log: &FlightLog,
    sensor: &VectorSensor,
    model: &FittedModel,
    windows: &[CalibrationWindow],
    options: &FitOptions,
    (stores, shared): (&StorePool, &[SharedDesign]),
) -> Result<Option<(Excitation, Design)>> {
    let prepared = Prepared::new(log, sensor, &model.channel, &model.spec)?;
    let Some(plan) = CandidatePlan::of_flight(&prepared.log, sensor, windows) else {
        return Ok(None);
    };
    let (fits, sample_rate_hz, flown) = flown_windows(&prepared, (sensor, model, windows), options, stores)?;
    let p = flown.scale.len();
    let Flown {
        per_window: flown,
        information,
        scale,
        calibration_moment,
    } = flown;

    // One of each kind on each heading: the candidates, and together a
    // full box.
    let candidates = box_candidates((&prepared, model, options), &plan, (&fits, &flown, windows), &scale)?;
    let (reference, flown_trace) = reference_box(&candidates, &information);

    let Some((basis, vectors, unpinnable)) = pinnable_basis(&model.term_names, &scale, &reference) else {
        return Ok(None);
    };

    let (survey_moment, survey_rows) = survey_moment(log, model, (&fits, shared), &scale)?;
    // σ² per unit information: the band-passed residual's variance times
    // f_s / 2B for its autocorrelation, as the coefficient uncertainty.
    let correlation = (sample_rate_hz / (2.0 * options.filter.band.bandwidth_hz(sample_rate_hz))).max(1.0);
    let mut design = Design {
        survey: basis.transpose() * &survey_moment * &basis,
        basis,
        noise_variance: model.solution.residual_rms.powi(2) * correlation,
        // A floor for directions the flown windows leave wholly open.
        floor: FLOOR * flown_trace / p as f64,
        flown: information,
        candidates: Vec::new(),
    };
    let (basis, information) = (&design.basis, &design.flown);
    let Some([flown_inverse, reference_inverse]) = design.reduced_inverses([information, &reference]) else {
        return Ok(None);
    };
    let survey_sigma_nt = design.survey_sigma(information);
    let flown_log_det = log_det(&design.reduced(information));
    let flown_variance: f64 = (0..flown_inverse.nrows()).map(|k| flown_inverse[(k, k)]).sum();
    let flown_covariance = basis * &flown_inverse * basis.transpose();
    let reference_covariance = basis * &reference_inverse * basis.transpose();

    let labels: Vec<String> = fits.iter().map(|f| f.window.display_label()).collect();
    let terms = term_pinning(
        model,
        (&labels, &flown, information),
        basis,
        (&flown_covariance, &reference_covariance),
    );
    let window_shares = design.window_shares(&labels, &flown, survey_sigma_nt);
    let additions = design.additions(&candidates, (survey_sigma_nt, flown_log_det, flown_variance));
    let unpinnable = unpinnable_loadings(&terms, &unpinnable, |i, k| vectors[(i, k)]);
    let mut excitation = Excitation {
        terms,
        unpinnable,
        windows: window_shares,
        additions,
        survey_sigma_nt,
        survey_rows,
        candidates_from: plan.described,
        summary: Vec::new(),
        calibration_moment,
    };
    excitation.summary = summarise(&excitation);
    design.candidates = candidates;
    Ok(Some((excitation, design)))
}

/// The terms each unpinnable direction `k` loads (|loading| ≥ 0.2, from
/// `loading(term, k)`), largest first.
fn unpinnable_loadings(
    terms: &[TermPinning],
    unpinnable: &[usize],
    loading: impl Fn(usize, usize) -> f64,
) -> Vec<Vec<(String, f64)>> {
    unpinnable
        .iter()
        .map(|&k| {
            let mut loadings: Vec<(String, f64)> = (terms.iter().enumerate())
                .map(|(i, t)| (t.term.clone(), loading(i, k)))
                .filter(|(_, v)| v.abs() >= 0.2)
                .collect();
            loadings.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            loadings
        })
        .collect()
}

/// The full box the `candidates` make together, scaled to the same total
/// information (trace) as the flown windows' `information`; and that
/// trace.
fn reference_box(candidates: &[(Candidate, Mat<f64>)], information: &Mat<f64>) -> (Mat<f64>, f64) {
    let p = information.nrows();
    let box_information = sum(candidates.iter().map(|c| &c.1), p);
    let box_trace: f64 = (0..p).map(|i| box_information[(i, i)]).sum();
    let flown_trace: f64 = (0..p).map(|i| information[(i, i)]).sum();
    let reference = Mat::from_fn(p, p, |i, j| box_information[(i, j)] * flown_trace / box_trace);
    (reference, flown_trace)
}

/// One candidate of each kind on each of the box's headings, with its
/// scaled information and how much of it the flown windows already gave.
fn box_candidates(
    (prepared, model, options): (&Prepared, &FittedModel, &FitOptions),
    plan: &CandidatePlan,
    (fits, flown, windows): (&[WindowFit], &[Mat<f64>], &[CalibrationWindow]),
    scale: &[f64],
) -> Result<Vec<(Candidate, Mat<f64>)>> {
    let p = scale.len();
    let kinds_known = windows.iter().any(|w| w.kind.is_some());
    let mut candidates: Vec<(Candidate, Mat<f64>)> = Vec::new();
    for &heading_deg in &plan.headings {
        for kind in [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw] {
            let shape = plan.shapes[kind_index(kind)];
            let gram = candidate_gram(prepared, model, options, plan.field_ned, (kind, heading_deg, shape))?;
            let own: Vec<usize> = (0..fits.len())
                .filter(|&k| {
                    let w = &fits[k].window;
                    w.kind == Some(kind) && w.heading_deg.is_some_and(|h| same_heading(h, heading_deg))
                })
                .collect();
            let scaled_gram = scaled_by(&gram, scale);
            let candidate_trace: f64 = (0..p).map(|i| scaled_gram[(i, i)]).sum();
            let flown_trace: f64 = own.iter().map(|&k| (0..p).map(|i| flown[k][(i, i)]).sum::<f64>()).sum();
            let excitation_flown = match candidate_trace > 0.0 {
                true => flown_trace / candidate_trace,
                false => 0.0,
            };
            let candidate = Candidate {
                kind,
                heading_deg,
                amplitude_deg: shape.amplitude_deg,
                period_s: shape.period_s,
                duration_s: shape.duration_s,
                flown: !own.is_empty(),
                excitation_flown,
                samples_kept: samples_kept(own.iter().map(|&k| &fits[k])),
                gap: kinds_known && excitation_flown < WEAK_EXCITATION,
                survey_sigma_nt: f64::NAN,
                change: f64::NAN,
                information_gain: f64::NAN,
                variance_ratio: f64::NAN,
            };
            candidates.push((candidate, scaled_gram));
        }
    }
    Ok(candidates)
}

/// The samples `windows` kept and had, when gaps cut any of them.
fn samples_kept<'a>(windows: impl Iterator<Item = &'a WindowFit>) -> Option<[usize; 2]> {
    let (mut kept, mut had, mut cut) = (0, 0, false);
    for window in windows {
        kept += window.samples_in_window - window.samples_lost_to_gaps;
        had += window.samples_in_window;
        cut |= window.cut_by_gaps();
    }
    cut.then_some([kept, had])
}

/// `g` with each row and column divided by its column's scale.
fn scaled_by(g: &Mat<f64>, scale: &[f64]) -> Mat<f64> {
    let p = scale.len();
    Mat::from_fn(p, p, |i, j| g[(i, j)] / (scale[i] * scale[j]))
}

/// How well the flown windows pin each term: its variance against a full
/// box's, the part of it no box pins, and the windows that pin it.
fn term_pinning(
    model: &FittedModel,
    (labels, flown, information): (&[String], &[Mat<f64>], &Mat<f64>),
    basis: &Mat<f64>,
    (flown_covariance, reference_covariance): (&Mat<f64>, &Mat<f64>),
) -> Vec<TermPinning> {
    let (p, r) = (basis.nrows(), basis.ncols());
    (0..p)
        .map(|j| {
            let inflation = flown_covariance[(j, j)] / reference_covariance[(j, j)];
            let v: Vec<f64> = (0..p).map(|i| flown_covariance[(i, j)]).collect();
            let whole = quadratic(information, &v);
            let mut pinned_by: Vec<(String, f64)> = (labels.iter().zip(flown))
                .map(|(label, g)| (label.clone(), quadratic(g, &v) / whole))
                .filter(|(_, share)| *share >= 0.05)
                .collect();
            pinned_by.sort_by(|a, b| b.1.total_cmp(&a.1));
            let in_pinnable: f64 = (0..r).map(|k| basis[(j, k)].powi(2)).sum();
            TermPinning {
                term: model
                    .term_names
                    .get(j)
                    .cloned()
                    .unwrap_or_else(|| format!("column {j}")),
                inflation,
                unpinnable_fraction: (1.0 - in_pinnable).clamp(0.0, 1.0),
                poorly_pinned: inflation > POOR_INFLATION,
                pinned_by,
            }
        })
        .collect()
}

/// The directions of the scaled coefficients that no rotation of the
/// aircraft excites, unit vectors: with all three diagonal induced terms,
/// their sum, $B_t \sum_i u_i^2 / s = B_t / s$, constant in the band; with
/// all three diagonal eddy terms, theirs, $B_t \sum_i u_i \dot u_i / s =
/// B_t \tfrac{d}{dt}|u|^2 / 2s = 0$ (a finite difference leaves a trace of
/// order $(\omega\,\Delta t)^2$). Only changes of the field's size, which a
/// box's manoeuvres do not make, show them.
fn structural_null(names: &[String], scale: &[f64]) -> Vec<Vec<f64>> {
    [["ind_xx", "ind_yy", "ind_zz"], ["eddy_xx", "eddy_yy", "eddy_zz"]]
        .iter()
        .filter_map(|triple| {
            let at: Vec<usize> = triple
                .iter()
                .map(|name| names.iter().position(|n| n == name))
                .collect::<Option<_>>()?;
            // Unscaled (1, 1, 1) is scaled D·(1, 1, 1).
            let mut v = vec![0.0; scale.len()];
            for &k in &at {
                v[k] = scale[k];
            }
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            (norm > 0.0).then(|| v.into_iter().map(|x| x / norm).collect())
        })
        .collect()
}

/// `Σ g`.
fn sum<'a>(parts: impl Iterator<Item = &'a Mat<f64>>, p: usize) -> Mat<f64> {
    let mut total = Mat::zeros(p, p);
    for g in parts {
        total += g;
    }
    total
}

/// `vᵀ g v`.
fn quadratic(g: &Mat<f64>, v: &[f64]) -> f64 {
    let p = v.len();
    (0..p)
        .map(|i| v[i] * (0..p).map(|j| g[(i, j)] * v[j]).sum::<f64>())
        .sum()
}

/// `tr(a b)` of two symmetric matrices.
fn trace_product(a: &Mat<f64>, b: &Mat<f64>) -> f64 {
    let n = a.nrows();
    (0..n).map(|i| (0..n).map(|j| a[(i, j)] * b[(j, i)]).sum::<f64>()).sum()
}

/// The log-determinant of a small symmetric positive definite matrix
/// (by its Cholesky factor); −∞ when it is not positive definite.
fn log_det(a: &Mat<f64>) -> f64 {
    match crate::numerics::linalg::cholesky_lower(a.as_ref()) {
        Some(lower) => 2.0 * (0..a.nrows()).map(|i| lower[(i, i)].ln()).sum::<f64>(),
        None => f64::NEG_INFINITY,
    }
}

/// The inverse of a small symmetric positive definite matrix; `None` when
/// it is numerically singular.
fn inverse_spd(a: &Mat<f64>) -> Option<Mat<f64>> {
    let n = a.nrows();
    let llt = a.llt(faer::Side::Lower).ok()?;
    let inverse = faer::linalg::solvers::Solve::solve(&llt, Mat::<f64>::identity(n, n).as_ref());
    (0..n)
        .all(|i| inverse[(i, i)].is_finite() && inverse[(i, i)] > 0.0)
        .then_some(inverse)
}

/// The Gram matrix of the columns `column(0..p)` (all of one length).
fn rows_gram(column: impl Fn(usize) -> Vec<f64>, p: usize) -> Mat<f64> {
    let columns: Vec<Vec<f64>> = (0..p).map(column).collect();
    let rows = columns.first().map_or(0, Vec::len);
    gram(Mat::from_fn(rows, p, |i, j| columns[j][i]).as_ref())
}

/// Rows of the centred design summed into the survey moment at a time.
const MOMENT_BLOCK_ROWS: usize = 4096;

/// The second moment, about its mean over the calibration rows, of the
/// scaled design over the survey: the survey lines' rows, or without lines
/// the rows outside every window (the calibration rows when there are
/// none); with the survey rows it is over (0 for the calibration's).
fn survey_moment(
    log: &FlightLog,
    model: &FittedModel,
    (fits, shared): (&[WindowFit], &[SharedDesign]),
    scale: &[f64],
) -> Result<(Mat<f64>, usize)> {
    let owned = model.flight_columns(log, shared)?;
    let p = scale.len();
    let columns: Vec<Option<&[f64]>> = (0..p).map(|j| owned.get(j).map(|c| c.as_ref())).collect();
    let value = |row: usize, j: usize| -> f64 { columns[j].map_or(0.0, |c| c[row]) };
    let finite = |row: usize| columns.iter().all(|c| c.is_none_or(|c| c[row].is_finite()));
    let calibration: Vec<usize> = (fits.iter())
        .flat_map(|f| f.flight_rows.iter().cloned().flatten())
        .filter(|&r| finite(r))
        .collect();
    let mean: Vec<f64> = (0..p)
        .map(|j| calibration.iter().map(|&r| value(r, j)).sum::<f64>() / calibration.len().max(1) as f64)
        .collect();
    let lines = log.survey_lines();
    let survey: Vec<usize> = match lines.is_empty() {
        false => lines.into_iter().flat_map(|(_, rows)| rows).collect(),
        true => {
            let mut inside = vec![false; log.len()];
            for fit in fits {
                inside[fit.window.rows(log.time_s())].fill(true);
            }
            (0..log.len()).filter(|&r| !inside[r]).collect()
        }
    };
    let survey: Vec<usize> = survey.into_iter().filter(|&r| finite(r)).collect();
    // A flight that is all calibration: its figures are over the
    // calibration rows (`survey_rows` 0, and the summary says so).
    let (survey, count) = match survey.is_empty() {
        true => (calibration, 0),
        false => {
            let count = survey.len();
            (survey, count)
        }
    };
    // Summed a block of rows at a time (a whole flight's centred design
    // would be as large as the design itself), unscaled, then scaled.
    let mut moment = Mat::<f64>::zeros(p, p);
    for block in survey.chunks(MOMENT_BLOCK_ROWS) {
        let centred = Mat::from_fn(block.len(), p, |i, j| value(block[i], j) - mean[j]);
        moment += gram(centred.as_ref());
    }
    let rows = survey.len().max(1) as f64;
    Ok((
        Mat::from_fn(p, p, |i, j| moment[(i, j)] / (rows * scale[i] * scale[j])),
        count,
    ))
}

/// The sine a candidate manoeuvre swings through.
#[derive(Debug, Clone, Copy)]
struct Shape {
    amplitude_deg: f64,
    period_s: f64,
    duration_s: f64,
}

/// Where and how the candidate manoeuvres are flown.
struct CandidatePlan {
    /// The box's headings: the flown ones, completed to four 90° apart.
    headings: Vec<f64>,
    /// Pitch, roll and yaw.
    shapes: [Shape; 3],
    /// The Earth's field in north-east-down, nT.
    field_ned: [f64; 3],
    /// In words.
    described: String,
}

impl CandidatePlan {
    /// The candidates of a flight: the headings of its windows (from the
    /// INS yaw for windows without one), each kind's median amplitude,
    /// period and length over its windows (from the INS attitude; the
    /// simulator's defaults without it), and the Earth's field as the
    /// vector magnetometer reads it. `None` when a window's heading is
    /// unknown.
    fn of_flight(log: &FlightLog, sensor: &VectorSensor, windows: &[CalibrationWindow]) -> Option<Self> {
        let attitude = log.attitude();
        let time = log.time_s();
        let headed: Vec<CalibrationWindow> = windows
            .iter()
            .map(|w| {
                let mut w = w.clone();
                if w.heading_deg.is_none() {
                    w.heading_deg = attitude.and_then(|[_, _, yaw]| circular_mean(&yaw[w.rows(time)]));
                }
                w
            })
            .collect();
        if headed.iter().any(|w| w.heading_deg.is_none()) {
            return None;
        }
        let mut headings = distinct_headings(&headed);
        let first = *headings.first()?;
        for k in 1..4 {
            let heading = (first + 90.0 * k as f64).rem_euclid(360.0);
            if !headings.iter().any(|h| angle_apart(*h, heading) < 45.0) {
                headings.push(heading);
            }
        }
        let field_ned = earth_field_ned(log, sensor, &headed)?;
        let (shapes, measured) = manoeuvre_shapes(attitude, (&headed, windows), time);
        let shape_words = [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw]
            .map(|kind| {
                let s = shapes[kind_index(kind)];
                format!(
                    "{} ±{:.1}° every {:.1} s for {:.0} s",
                    kind.name(),
                    s.amplitude_deg,
                    s.period_s,
                    s.duration_s
                )
            })
            .join(", ");
        let source = match (attitude.is_some(), measured) {
            (true, true) => "amplitudes and periods are the medians the INS recorded over the windows of each kind (the simulator's defaults for a kind not flown)",
            (true, false) => "the windows carry no manoeuvre kind, so amplitudes and periods are the simulator's defaults",
            (false, _) => "the flight records no INS attitude, so amplitudes and periods are the simulator's defaults",
        };
        let described = format!(
            "Candidates: pitch, roll and yaw on headings {} through the Earth's field the vector magnetometer reads ({:.0} nT north, {:.0} east, {:.0} down); {shape_words}; {source}.",
            headings.iter().map(|h| format!("{h:.0}")).collect::<Vec<_>>().join(", "),
            field_ned[0],
            field_ned[1],
            field_ned[2],
        );
        Some(CandidatePlan {
            headings,
            shapes,
            field_ned,
            described,
        })
    }
}

/// Each kind's shape (pitch, roll, yaw): the median amplitude, period and
/// length the INS `attitude` recorded over the `headed` windows of that
/// kind; else the simulator's amplitude and period, with the median length
/// of that kind's `headed` windows (of all `windows` where none is of that
/// kind, 30 s without any); and whether any kind was measured.
fn manoeuvre_shapes(
    attitude: Option<[&[f64]; 3]>,
    (headed, windows): (&[CalibrationWindow], &[CalibrationWindow]),
    time: &[f64],
) -> ([Shape; 3], bool) {
    let all_durations: Vec<f64> = windows.iter().map(|w| w.t_end - w.t_start).collect();
    let typical_duration = median(all_durations).unwrap_or(30.0);
    let mut measured = false;
    let shapes = [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw].map(|kind| {
        let own: Vec<&CalibrationWindow> = headed.iter().filter(|w| w.kind == Some(kind)).collect();
        let window_duration = median(own.iter().map(|w| w.t_end - w.t_start).collect()).unwrap_or(typical_duration);
        let swings: Vec<(f64, f64, f64)> = match attitude {
            Some(angles) => own
                .iter()
                .filter_map(|w| swing(angles[kind_index_in_attitude(kind)], w.rows(time), time, kind))
                .collect(),
            None => Vec::new(),
        };
        let typical = |k: usize| median(swings.iter().map(|s| [s.0, s.1, s.2][k]).collect());
        match (typical(0), typical(1), typical(2)) {
            (Some(amplitude_deg), Some(period_s), Some(duration_s)) => {
                measured = true;
                Shape {
                    amplitude_deg,
                    period_s,
                    duration_s,
                }
            }
            _ => Shape {
                amplitude_deg: NOMINAL_AMPLITUDE_DEG[kind_index(kind)],
                period_s: NOMINAL_PERIOD_S,
                duration_s: window_duration,
            },
        }
    });
    (shapes, measured)
}

fn kind_index(kind: ManoeuvreKind) -> usize {
    match kind {
        ManoeuvreKind::Pitch => 0,
        ManoeuvreKind::Roll => 1,
        ManoeuvreKind::Yaw => 2,
    }
}

/// The attitude column (roll, pitch, yaw order) a manoeuvre swings.
fn kind_index_in_attitude(kind: ManoeuvreKind) -> usize {
    match kind {
        ManoeuvreKind::Roll => 0,
        ManoeuvreKind::Pitch => 1,
        ManoeuvreKind::Yaw => 2,
    }
}

/// The median of `values` (NaNs left out); `None` when there is none.
fn median(mut values: Vec<f64>) -> Option<f64> {
    values.retain(|v| v.is_finite());
    values.sort_by(f64::total_cmp);
    let n = values.len();
    (n > 0).then(|| match n % 2 {
        1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    })
}

/// The circular mean of angles in degrees (0 to 360); `None` without a
/// finite one.
fn circular_mean(angles: &[f64]) -> Option<f64> {
    let (s, c, n) = angles
        .iter()
        .filter(|a| a.is_finite())
        .fold((0.0, 0.0, 0usize), |(s, c, n), a| {
            (s + a.to_radians().sin(), c + a.to_radians().cos(), n + 1)
        });
    (n > 0 && (s != 0.0 || c != 0.0)).then(|| s.atan2(c).to_degrees().rem_euclid(360.0))
}

/// Amplitude (degrees), period and duration (s) of the swing of `angle`
/// over `rows`. The swing is taken between the first and the last
/// crossing of the mean (yaw's circular mean), counted with a hysteresis
/// of half the RMS so turbulence does not add crossings: the period is
/// twice the time between crossings, the amplitude √2 times the RMS there
/// (a sine's). `None` with fewer than three crossings.
fn swing(angle: &[f64], rows: Range<usize>, time: &[f64], kind: ManoeuvreKind) -> Option<(f64, f64, f64)> {
    let values: Vec<(f64, f64)> = rows
        .filter(|&r| angle[r].is_finite())
        .map(|r| (time[r], angle[r]))
        .collect();
    let centre = match kind {
        ManoeuvreKind::Yaw => circular_mean(&values.iter().map(|v| v.1).collect::<Vec<_>>())?,
        _ => values.iter().map(|v| v.1).sum::<f64>() / values.len().max(1) as f64,
    };
    let deviation: Vec<f64> = values
        .iter()
        .map(|v| match kind {
            ManoeuvreKind::Yaw => (v.1 - centre + 540.0).rem_euclid(360.0) - 180.0,
            _ => v.1 - centre,
        })
        .collect();
    let rms = (deviation.iter().map(|d| d * d).sum::<f64>() / deviation.len().max(1) as f64).sqrt();
    // Crossings of the mean, with a hysteresis of half the window's RMS.
    let mut side = 0.0;
    let mut crossings: Vec<usize> = Vec::new();
    for (k, d) in deviation.iter().enumerate() {
        if d.abs() < 0.5 * rms {
            continue;
        }
        let now = d.signum();
        if side != 0.0 && now != side {
            crossings.push(k);
        }
        side = now;
    }
    let (first, last) = (*crossings.first()?, *crossings.last()?);
    if crossings.len() < 3 || rms <= 0.0 {
        return None;
    }
    let period = 2.0 * (values[last].0 - values[first].0) / (crossings.len() - 1) as f64;
    // The swing's amplitude from its RMS between the first and the last
    // crossing (level flight either side left out).
    let swinging = &deviation[first..=last];
    let amplitude =
        std::f64::consts::SQRT_2 * (swinging.iter().map(|d| d * d).sum::<f64>() / swinging.len() as f64).sqrt();
    let duration = values[last].0 - values[first].0 + period / 2.0;
    Some((amplitude, period, duration))
}

/// The Earth's field in north-east-down, nT, as the vector magnetometer
/// reads it over the windows: each row rotated by the INS attitude when
/// the flight records it, otherwise each window's mean rotated by its
/// heading (level flight, the manoeuvres swinging about it). `None`
/// without a finite reading.
fn earth_field_ned(log: &FlightLog, sensor: &VectorSensor, windows: &[CalibrationWindow]) -> Option<[f64; 3]> {
    let field = log.vector_components(sensor);
    let body = |row: usize| nalgebra::Vector3::new(field[0][row], field[1][row], field[2][row]);
    let mut total = nalgebra::Vector3::zeros();
    let mut count = 0usize;
    for window in windows {
        let rows = window.rows(log.time_s());
        let readings: Vec<nalgebra::Vector3<f64>> = match (log.attitude(), window.heading_deg) {
            (Some([roll, pitch, yaw]), _) => rows.map(|r| body_to_ned(roll[r], pitch[r], yaw[r]) * body(r)).collect(),
            (None, Some(heading)) => rows.map(|r| body_to_ned(0.0, 0.0, heading) * body(r)).collect(),
            (None, None) => Vec::new(),
        };
        for reading in readings.into_iter().filter(|v| v.iter().all(|x| x.is_finite())) {
            total += reading;
            count += 1;
        }
    }
    (count > 0).then(|| [total[0], total[1], total[2]].map(|t| t / count as f64))
}

/// The Earth's field `field_ned` in body axes, per axis, through one
/// manoeuvre of `kind` on `heading_deg` with `shape`: `margin` rows of
/// level flight, `swinging` rows of its sine swing, `margin` more, `dt`
/// apart.
fn swung_field(
    field_ned: [f64; 3],
    (kind, heading_deg, shape): (ManoeuvreKind, f64, Shape),
    (margin, swinging, dt): (usize, usize, f64),
) -> [Vec<f64>; 3] {
    let b = nalgebra::Vector3::from(field_ned);
    let readings: Vec<nalgebra::Vector3<f64>> = (0..swinging + 2 * margin)
        .map(|k| {
            let angle = match k.checked_sub(margin).filter(|&m| m < swinging) {
                Some(m) => shape.amplitude_deg * (2.0 * std::f64::consts::PI * m as f64 * dt / shape.period_s).sin(),
                None => 0.0,
            };
            let [roll, pitch, yaw] = kind.attitude_offset(angle);
            body_to_ned(roll, pitch, heading_deg + yaw).inverse() * b
        })
        .collect();
    [0, 1, 2].map(|axis| readings.iter().map(|r| r[axis]).collect::<Vec<f64>>())
}

/// The unscaled information of one candidate manoeuvre, band-passed and
/// trimmed as a flown window is: the manoeuvre
/// flown through `field_ned` with level flight either side, the vector
/// magnetometer reading the field in body axes, the model's extension
/// columns built from it (a source column held at its level, so it adds
/// nothing: no manoeuvre moves a current).
fn candidate_gram(
    prepared: &Prepared,
    model: &FittedModel,
    options: &FitOptions,
    field_ned: [f64; 3],
    (kind, heading_deg, shape): (ManoeuvreKind, f64, Shape),
) -> Result<Mat<f64>> {
    let log = &prepared.log;
    let dt = log.median_interval_s();
    let margin = (CANDIDATE_MARGIN_S / dt).ceil() as usize + options.filter.trim_samples;
    let swinging = (shape.duration_s / dt).round().max(1.0) as usize;
    let rows = swinging + 2 * margin;
    let axes = swung_field(field_ned, (kind, heading_deg, shape), (margin, swinging, dt));
    let sensor = prepared.sensor;
    let mut channels: Vec<Channel> = (sensor.axes.iter().zip(axes))
        .map(|(&index, values)| Channel {
            name: log.channels()[index].name.clone(),
            role: log.channels()[index].role.clone(),
            values,
        })
        .collect();
    channels.push(Channel {
        name: model.channel.clone(),
        role: ChannelRole::ScalarMagnetometer,
        values: vec![0.0; rows],
    });
    for source in &model.spec.extensions.sources {
        if channels.iter().any(|c| c.name == source.column()) {
            continue;
        }
        let level = match source {
            SourceTerm::AuxCoupling { level, .. } | SourceTerm::ExternalField { level, .. } => *level,
            SourceTerm::AuxCouplingRate { .. } | SourceTerm::CrossSensor { .. } => 0.0,
        };
        channels.push(Channel {
            name: source.column().to_string(),
            role: ChannelRole::Auxiliary,
            values: vec![level; rows],
        });
    }
    let time: Vec<f64> = (0..rows).map(|k| k as f64 * dt).collect();
    let flight = FlightLog::new(log.source(), log.time_column(), time, channels)?;
    let Some(candidate_sensor) = flight.vector_sensor(&sensor.prefix) else {
        return Ok(Mat::zeros(model.coefficients.len(), model.coefficients.len()));
    };
    // The field is already what the model reads: no fluxgate calibration again.
    let mut spec = model.spec.clone();
    spec.extensions.vector_calibration = None;
    // A cross-sensor signal is made from sensors the candidate manoeuvre
    // does not fly: it sits at its level, zero, as a coupled column does.
    // A survey-fitted one adds no regressor.
    spec.extensions.sources.retain(|s| s.survey_gain().is_none());
    for source in &mut spec.extensions.sources {
        if let SourceTerm::CrossSensor { name, .. } = source {
            let column = std::mem::take(name);
            *source = SourceTerm::AuxCoupling { column, level: 0.0 };
        }
    }
    let candidate = Prepared::new(&flight, &candidate_sensor, &model.channel, &spec)?;
    let window = CalibrationWindow::new(0.0, (rows - 1) as f64 * dt);
    let data = band_data(
        &candidate.log,
        &candidate_sensor,
        (&model.channel, &candidate.scalar),
        &[window],
        (spec.fitted_terms(), &options.filter),
        &candidate.extra_columns(),
        &StorePool::new(),
    )?;
    let p = data.stacked.columns();
    Ok(rows_gram(|j| data.stacked.column(j), p))
}

/// The summary's words on how well the `terms` are pinned: every one, or
/// the first six poorly pinned with what pins them, and how many more.
fn pinning_lines(terms: &[TermPinning]) -> Vec<String> {
    let mut lines = Vec::new();
    let poor: Vec<&TermPinning> = terms.iter().filter(|t| t.poorly_pinned).collect();
    match poor.is_empty() {
        true => lines.push(format!(
            "Every coefficient is pinned within {:.0}× the standard error a full box of the same length would give.",
            POOR_INFLATION.sqrt()
        )),
        false => {
            for term in poor.iter().take(6) {
                let by = match term.pinned_by.first() {
                    Some((label, share)) if *share >= MOSTLY => {
                        format!("{:.0} % of what pins it comes from {label}", 100.0 * share)
                    }
                    _ => "no single window pins most of it".to_string(),
                };
                lines.push(format!(
                    "{} is poorly pinned: its standard error is {:.1}× a full box's; {by}.",
                    term.term,
                    term.inflation.sqrt()
                ));
            }
            if poor.len() > 6 {
                lines.push(format!(
                    "{} more coefficients are poorly pinned (see the table).",
                    poor.len() - 6
                ));
            }
        }
    }
    lines
}

/// The analysis in a few sentences for people.
fn summarise(excitation: &Excitation) -> Vec<String> {
    let mut lines = Vec::new();
    if excitation.survey_rows == 0 {
        lines.push("The flight has no survey rows (every row lies in a calibration window): the survey uncertainties below are taken over the calibration rows.".to_string());
    }
    lines.extend(pinning_lines(&excitation.terms));
    for combination in &excitation.unpinnable {
        let named: Vec<String> = combination
            .iter()
            .take(4)
            .map(|(name, weight)| format!("{weight:+.2} {name}"))
            .collect();
        if !named.is_empty() {
            lines.push(format!(
                "No manoeuvre pins the combination {}: the band sees it as (nearly) constant, so the regulariser sets it.",
                named.join(" ")
            ));
        }
    }
    lines.extend(excitation.gaps());
    if let Some(best) = excitation.additions.iter().find(|c| !c.gap) {
        match best.change <= -0.05 {
            true => lines.push(format!(
                "Most useful repeat: {} again ({}): {}.",
                best.label(),
                best.shape_words(),
                excitation.change_words(best)
            )),
            false => lines.push(format!(
                "No repeat of a flown manoeuvre lowers the predicted survey uncertainty ({:.3} nT) by 5 % or more; the best, {}, by {:.0} %.",
                excitation.survey_sigma_nt,
                best.label(),
                -100.0 * best.change
            )),
        }
    }
    if let Some(least) = excitation.windows.iter().min_by(|a, b| a.change.total_cmp(&b.change)) {
        lines.push(format!(
            "Least missed if dropped: {} (survey uncertainty {:+.0} %).",
            least.label,
            100.0 * least.change
        ));
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sine of known amplitude and period between level flight, with a
    /// little turbulence: the swing's amplitude within 3 % and its period
    /// within 2 %, yaw about a heading across north included.
    #[test]
    fn a_swing_is_measured_from_the_attitude() {
        for (kind, centre) in [(ManoeuvreKind::Roll, 0.0), (ManoeuvreKind::Yaw, 358.0)] {
            let dt = 0.1;
            let time: Vec<f64> = (0..400).map(|k| k as f64 * dt).collect();
            let angle: Vec<f64> = time
                .iter()
                .map(|&t| {
                    let swing = match (5.0..35.0).contains(&t) {
                        true => 12.0 * (2.0 * std::f64::consts::PI * (t - 5.0) / 6.0).sin(),
                        false => 0.0,
                    };
                    let value = centre + swing + 0.1 * (t * 7.3).sin();
                    match kind {
                        // Yaw is a heading, 0 to 360; roll is signed.
                        ManoeuvreKind::Yaw => value.rem_euclid(360.0),
                        _ => value,
                    }
                })
                .collect();
            let (amplitude, period, duration) = swing(&angle, 0..400, &time, kind).unwrap();
            assert!((amplitude - 12.0).abs() < 0.36, "{kind:?} amplitude {amplitude}");
            assert!((period - 6.0).abs() < 0.12, "{kind:?} period {period}");
            assert!((duration - 30.0).abs() < 3.0, "{kind:?} duration {duration}");
        }
    }

    /// The sums no rotation changes are unit vectors along the scaled
    /// (1, 1, 1) of the diagonal terms, and absent when a term is.
    #[test]
    fn the_structural_sums_follow_the_scaled_diagonal_terms() {
        let names: Vec<String> = ["perm_x", "ind_xx", "ind_yy", "ind_zz", "eddy_xx", "eddy_yy"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let scale = [1.0, 1.0, 2.0, 2.0, 1.0, 1.0];
        let null = structural_null(&names, &scale);
        assert_eq!(null.len(), 1, "no eddy_zz: no eddy sum");
        let expected = [0.0, 1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0, 0.0, 0.0];
        for (got, want) in null[0].iter().zip(expected) {
            assert!((got - want).abs() < 1e-15, "{got} against {want}");
        }
    }

    /// `tr(S G⁻¹)` by the inverse equals the sum of `S`'s quadratic forms
    /// in the columns of `G⁻¹` on a small case worked by hand.
    #[test]
    fn the_survey_criterion_is_the_trace_of_s_against_the_inverse() {
        let g = Mat::from_fn(2, 2, |i, j| [[4.0, 1.0], [1.0, 3.0]][i][j]);
        let s = Mat::from_fn(2, 2, |i, j| [[2.0, 0.5], [0.5, 1.0]][i][j]);
        let inverse = inverse_spd(&g).unwrap();
        // G⁻¹ = [[3, −1], [−1, 4]] / 11; tr(S G⁻¹) = (6 − 0.5 − 0.5 + 4) / 11.
        assert!((trace_product(&s, &inverse) - 9.0 / 11.0).abs() < 1e-14);
        assert!((log_det(&g) - 11f64.ln()).abs() < 1e-14);
    }
}
