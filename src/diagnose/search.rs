//! The greedy search: from plain Tolles-Lawson (λ by the better criterion),
//! every candidate extension is scored held out, the best accepted while it
//! lowers the held-out RMS by `min_improvement` and beats the second-order
//! control and shifted copies of its source; then the next.

use super::*;

/// Plain Tolles-Lawson held out with λ picked by the criterion the
/// pipeline does not use; `None` when λ is fixed.
///
/// Blocked PRESS (the default) guards against the autocorrelation of
/// band-passed noise, which makes leave-one-sample-out PRESS pick too
/// little regularisation. Where the noise is small against the
/// interference the guard costs more than it saves: the larger λ it picks
/// leaves a bias well above the noise in the held-out fit, which a slow
/// attitude-following column (the trim tab) can then "explain". Which one
/// predicts the held-out headings better is measured, not assumed, and the
/// search starts from it (measured figures: docs/measurements.md, section
/// diagnose::search).
pub(super) fn criterion_trial(problem: &Problem) -> Result<Option<(Model, HeldOut)>> {
    if problem.options.solve.lambda != LambdaChoice::Select {
        return Ok(None);
    }
    let model = Model {
        lambda_criterion: Some(problem.options.solve.criterion.other()),
        ..Model::default()
    };
    let result = held_out(problem, &model)?;
    Ok(Some((model, result)))
}

/// `model` with λ picked by the other criterion, held out; `None` when λ
/// is fixed or the fit fails.
pub(super) fn flip_criterion(problem: &Problem, model: &Model) -> Option<(Model, HeldOut)> {
    if problem.options.solve.lambda != LambdaChoice::Select {
        return None;
    }
    let flipped = Model {
        lambda_criterion: match model.lambda_criterion {
            Some(_) => None,
            None => Some(problem.options.solve.criterion.other()),
        },
        ..model.clone()
    };
    let result = held_out(problem, &flipped).ok()?;
    Some((flipped, result))
}

/// Where the residual left after the search stands out (its
/// localisation), adding an `unexplained` finding to `findings` where it
/// is structured, or far above the noise on a box held out by heading.
/// `current` is the final model's held-out RMS; `control` its fit with
/// the second-order term.
fn residual_findings(
    problem: &Problem,
    model: &Model,
    (baseline_windows, current_windows): (&[WindowFit], &[WindowFit]),
    (current, control): (f64, &HeldOut),
    findings: &mut Vec<Finding>,
) -> Result<localise::Localisation> {
    let localisation = localise::localise(
        problem.log,
        problem.channel,
        (baseline_windows, current_windows),
        problem.direction,
        problem.options,
    );
    // What the total field's second-order term explains is physics the
    // library knows, not `unexplained`: judge what is left after it where
    // it lowers the held-out RMS (on a cabin sensor it can be most of the
    // structured residual; figures: docs/measurements.md, section
    // diagnose::search).
    let localise_windows = |windows: &[WindowFit]| {
        localise::localise(
            problem.log,
            problem.channel,
            (baseline_windows, windows),
            problem.direction,
            problem.options,
        )
    };
    let with_control = control.rms_nt < current;
    let explained = with_control.then(|| (control.rms_nt, localise_windows(&control.windows)));
    let (left_rms, left) = explained
        .as_ref()
        .map_or((current, &localisation), |(rms, l)| (*rms, l));
    // Missing physics leaves its structure whether or not a heading is
    // held out; what a fit on every heading removes was the held-out
    // fit's extrapolation to the heading it never saw.
    let in_sample_fit = || {
        let model = match with_control {
            true => with_second_order(model),
            false => model.clone(),
        };
        in_sample(problem, &model)
    };
    let structured = unexplained(problem.channel, left_rms, left);
    if let Some(found) = structured {
        let fitted = in_sample_fit()?;
        if is_structured(fitted.rms_nt, &localise_windows(&fitted.windows)) {
            findings.push(found);
        }
    }
    // Far above the noise, a residual is unexplained whether or not it
    // stands out in stretches: "nothing to report" would be a claim.
    // Only on a box held out by heading: a window of straight flight
    // (held out by quarters) holds the survey's geology in the band,
    // which is the Earth's field and no residual of the aircraft's.
    let boxed = matches!(HoldOut::of(problem.windows), HoldOut::ByHeading(_));
    if boxed
        && !findings.iter().any(|f| f.effect.kind() == EffectKind::Unexplained)
        && left_rms > FAR_ABOVE_NOISE * left.noise_floor_nt
    {
        let fitted = in_sample_fit()?;
        findings.extend(far_above_noise(problem.channel, left_rms, fitted.rms_nt, left));
    }
    Ok(localisation)
}

/// Every candidate extension of `model` the screen keeps, scored held out
/// (the second-order one is the `control`, already scored), best first; a
/// leading lag or eddy τ takes the other λ criterion where it predicts it
/// better and still pays against the current model under it.
fn score_candidates(
    problem: &Problem,
    (model, current_ridge): (&Model, &[f64]),
    control: &HeldOut,
    settings: &DiagnoseOptions,
) -> Vec<(Model, Extension, HeldOut)> {
    let keep = 1.0 - settings.min_improvement;
    let candidates = candidates(problem, model, settings);
    let candidates = match super::screen::Screen::new(problem, model, current_ridge) {
        Some(screen) => screen.select(problem, candidates),
        None => candidates,
    };
    // The second-order candidate is the control, already scored.
    let mut scored: Vec<(Model, Extension, HeldOut)> = candidates
        .into_par_iter()
        .filter_map(|(next, extension)| {
            let result = match extension {
                Extension::SecondOrder if next == with_second_order(model) => Ok(control.clone()),
                _ => held_out(problem, &next),
            };
            result.ok().map(|h| (next, extension, h))
        })
        // A candidate with more terms than its folds have samples
        // measures nothing.
        .filter(|(_, _, h)| h.unusable().is_none())
        .collect();
    drop_unearned_rates(&mut scored, keep);
    scored.sort_by(|a, b| a.2.rms_nt.total_cmp(&b.2.rms_nt));
    // A lag or an eddy τ changes the model's own regressors (the
    // scalar shifted, the eddy terms lagged), so the λ criterion that
    // suited the current model need not suit it: blocked PRESS can
    // shrink the lagged eddy terms too hard, enough for a wing eddy τ to
    // lose to a lag (figures: docs/measurements.md, section
    // diagnose::search). Such leading candidates take the other
    // criterion when it predicts them better and the effect pays by
    // the threshold against the current model under that criterion
    // too: a change of criterion alone is no finding. A source adds
    // terms to an unchanged model and keeps its criterion (letting the
    // 30 sources of the two-hour benchmark flight choose too named a
    // slow one on a quiet sensor).
    let current_other = flip_criterion(problem, model).map_or(f64::INFINITY, |(_, h)| h.rms_nt);
    let flips: Vec<Option<(Model, HeldOut)>> = scored
        .par_iter()
        .take(CRITERION_CHECKS)
        .map(|(next, extension, plain)| match extension {
            Extension::Lag { .. } | Extension::Eddy { .. } => flip_criterion(problem, next)
                .filter(|(_, h)| h.rms_nt < plain.rms_nt && h.rms_nt <= current_other * keep),
            Extension::Coupling { .. }
            | Extension::CouplingRate { .. }
            | Extension::CouplingWithRate { .. }
            | Extension::External { .. }
            | Extension::SecondOrder => None,
        })
        .collect();
    for (entry, flip) in scored.iter_mut().zip(flips) {
        if let Some((flipped, result)) = flip {
            (entry.0, entry.2) = (flipped, result);
        }
    }
    scored.sort_by(|a, b| a.2.rms_nt.total_cmp(&b.2.rms_nt));
    scored
}

pub(super) fn diagnose_channel(
    problem: &Problem,
    start: Model,
    baseline: HeldOut,
    settings: &DiagnoseOptions,
) -> Result<(ChannelDiagnosis, Vec<Finding>)> {
    let search_criterion = start.lambda_criterion.unwrap_or(problem.options.solve.criterion);
    let mut model = start;
    let mut control = held_out(problem, &with_second_order(&model))?;
    let second_order = control.rms_nt;
    let mut current = baseline.rms_nt;
    let mut current_ridge = baseline.ridge.clone();
    let baseline_windows = baseline.windows.clone();
    let mut current_windows = baseline.windows;
    let mut findings = Vec::new();
    let mut strongest_rejected = None;
    let keep = 1.0 - settings.min_improvement;
    while findings.len() < settings.max_findings {
        let mut scored = score_candidates(problem, (&model, &current_ridge), &control, settings);
        prefer_recorded(&mut scored, current * keep);
        let state = SearchState {
            model: &model,
            ridge: &current_ridge,
            rms_nt: current,
            windows: &current_windows,
            control: &control,
        };
        let (found, next, result) = match next_finding(problem, (&state, scored), settings)? {
            Ok(accepted) => accepted,
            Err(rejected) => {
                strongest_rejected = rejected;
                break;
            }
        };
        findings.push(found);
        control = held_out(problem, &with_second_order(&next))?;
        current_ridge = result.ridge.clone();
        (model, current, current_windows) = (next, result.rms_nt, result.windows);
    }
    let localisation = residual_findings(
        problem,
        &model,
        (&baseline_windows, &current_windows),
        (current, &control),
        &mut findings,
    )?;
    let summary = ChannelDiagnosis {
        channel: problem.channel.to_string(),
        heldout_rms_baseline_nt: baseline.rms_nt,
        heldout_rms_second_order_nt: second_order,
        heldout_rms_final_nt: current,
        strongest_rejected,
        heldout_rms_calibrated_fluxgate_nt: None,
        heldout_rms_other_criterion_nt: None,
        search_criterion,
        fluxgate: FluxgateReading::Raw,
        model,
        localisation,
    };
    Ok((summary, findings))
}

/// The finding the search takes next from the `scored` candidates, with
/// the model it makes and its held-out figures: the step's
/// ([`step`]), else, unless `[diagnose] cross_sensor = "report"`, a
/// cross-sensor signal the survey bears out
/// ([`super::survey::survey_step`]); or the strongest candidate rejected
/// and why.
fn next_finding(
    problem: &Problem,
    (state, mut scored): (&SearchState, Vec<(Model, Extension, HeldOut)>),
    settings: &DiagnoseOptions,
) -> Result<std::result::Result<(Finding, Model, HeldOut), Option<String>>> {
    let current = (state.rms_nt, state.windows);
    // Only where a finding the survey bears out may be applied.
    let surveying = matches!(settings.cross_sensor, CrossSensorUse::Survey | CrossSensorUse::Apply);
    let (index, surveyed) = match step(problem, state, &scored, 1.0 - settings.min_improvement) {
        Step::Accept(index) => (index, false),
        Step::Stop(rejected) if !surveying => return Ok(Err(rejected)),
        Step::Stop(rejected) => match super::survey::survey_step(problem, (state.model, state.rms_nt), &scored)? {
            Some((index, _)) => (index, true),
            None => return Ok(Err(rejected)),
        },
    };
    let (next, extension, result) = scored.swap_remove(index);
    let (mut found, next, result) = match surveyed {
        // Borne out on the survey as fitted: no other λ criterion.
        true => finding(problem, next, &extension, current, result)?,
        false => accept(problem, (next, &extension, result), current)?,
    };
    surveyed_cross_sensor(problem, (state.model, &next), &extension, &mut found)?;
    Ok(Ok((found, next, result)))
}

/// A cross-sensor finding with what the survey says of it
/// ([`super::survey::survey_evidence`]): its effect becomes
/// [`Effect::CrossSensor`] with the evidence. Other findings are left as
/// they are.
fn surveyed_cross_sensor(
    problem: &Problem,
    (before, after): (&Model, &Model),
    extension: &Extension,
    found: &mut Finding,
) -> Result<()> {
    let Extension::Coupling { source } = extension else {
        return Ok(());
    };
    let Effect::AuxCoupling(coupling) = &found.effect else {
        return Ok(());
    };
    if !super::cross::is_cross_column(source) {
        return Ok(());
    }
    let survey = super::survey::survey_evidence(problem, (before, after), source)?;
    found.effect = Effect::CrossSensor(CrossSensor {
        k: coupling.k_nt_per_unit.unwrap_or_default(),
        survey,
        survey_gain: None,
    });
    Ok(())
}

/// Puts the recorded candidates that pass the threshold (`passing_nt`)
/// before every cross-sensor signal: a recorded column that pays holds
/// the cause itself, where another sensor's signal holds that sensor's
/// share of it and its noise. The order within each part is kept.
fn prefer_recorded(scored: &mut [(Model, Extension, HeldOut)], passing_nt: f64) {
    let cross = |extension: &Extension| match extension {
        Extension::Coupling { source } => super::cross::is_cross_column(source),
        _ => false,
    };
    if scored.iter().any(|(_, e, h)| !cross(e) && h.rms_nt <= passing_nt) {
        scored.sort_by_key(|(_, e, _)| cross(e));
    }
}

/// Where the search stands before a step: the model, each split's ridge
/// λ, its held-out RMS and windows, and its second-order control.
struct SearchState<'a> {
    model: &'a Model,
    ridge: &'a [f64],
    rms_nt: f64,
    windows: &'a [WindowFit],
    control: &'a HeldOut,
}

/// What a step of the search does: accept the scored candidate at this
/// index, or stop, with the strongest candidate rejected and why.
enum Step {
    Accept(usize),
    Stop(Option<String>),
}

/// The step the `scored` candidates (best first) allow: the first of the
/// best few that lowers the held-out RMS by the threshold, pays against
/// the second-order control, holds across headings and beats its shifted
/// sources.
fn step(problem: &Problem, state: &SearchState, scored: &[(Model, Extension, HeldOut)], keep: f64) -> Step {
    let Some(best) = scored.first() else {
        return Step::Stop(None);
    };
    let current = state.rms_nt;
    // The best few that pass, each checked against the control: with
    // the second-order term in both, does the effect still pay?
    let passing = scored
        .iter()
        .take(CONTROL_CHECKS)
        .take_while(|(_, _, h)| h.rms_nt <= current * keep)
        .count();
    // Each side takes the second-order term only where it helps on
    // held-out data (it is only as good as the fitted aircraft field).
    let reference = current.min(state.control.rms_nt);
    let controlled: Vec<f64> = scored[..passing]
        .par_iter()
        .map(|(next, _, plain)| {
            let with = held_out(problem, &with_second_order(next)).map_or(f64::INFINITY, |h| h.rms_nt);
            plain.rms_nt.min(with)
        })
        .collect();
    // The second-order term is the control itself: it pays against
    // the model before it, like any effect without a control.
    let bar = |extension: &Extension| match extension {
        Extension::SecondOrder => current * keep,
        _ => reference * keep,
    };
    let paying: Vec<usize> = (0..passing).filter(|&i| controlled[i] <= bar(&scored[i].1)).collect();
    let accepted = paying.iter().copied().find(|&i| {
        consistent_across_headings(state.windows, &scored[i].2.windows)
            && beats_shifted_sources(problem, (state.model, state.ridge), &scored[i].1, scored[i].2.rms_nt)
    });
    if let Some(index) = accepted {
        return Step::Accept(index);
    }
    let (_, extension, result) = best;
    let why = match (paying.is_empty(), passing > 0) {
        (false, _) => "; with every source column shifted in time, one explains as much, so the recorded timing does not single it out".into(),
        (true, true) => {
            format!("; explained as well by the total field's second-order term (held-out {reference:.4} nT)")
        }
        (true, false) => String::new(),
    };
    Step::Stop(Some(format!(
        "{}: held-out RMS {:.4} nT ({:+.1} % against {current:.4} nT, the model before it){why}",
        describe(extension),
        result.rms_nt,
        100.0 * (result.rms_nt / current - 1.0)
    )))
}

/// The finding of an accepted candidate, and the model it makes with its
/// held-out figures: under the other λ criterion where that predicts it
/// better. `current` is the model before it, held out.
fn accept(
    problem: &Problem,
    (next, extension, result): (Model, &Extension, HeldOut),
    current: (f64, &[WindowFit]),
) -> Result<(Finding, Model, HeldOut)> {
    let (mut found, next, result) = finding(problem, next, extension, current, result)?;
    // The λ criterion that predicted plain Tolles-Lawson better need
    // not predict the extended model better: try the other again. The
    // second-order term adds no coefficient (it is computed from the
    // fitted ones), so the criterion that suited the model suits it
    // still; letting it flip to the less regularised one opened the
    // next step to a servo current standing in for residual on a
    // clean cabin sensor (seed 509: −38 % held out with the flip,
    // −19 % without).
    let flipped = match extension {
        Extension::SecondOrder => None,
        _ => flip_criterion(problem, &next),
    };
    Ok(match flipped {
        Some((flipped, h)) if h.rms_nt < result.rms_nt => {
            found.heldout_rms_after_nt = h.rms_nt;
            (found, flipped, h)
        }
        _ => (found, next, result),
    })
}

/// Whether an extension's held-out gain holds across the calibration and
/// not on one part of it: grouped by heading (by window where the windows
/// carry none), the held-out RMS must fall on every group but one. A real
/// effect acts on every heading, since each manoeuvre drives it; a column
/// that stands in for residual it did not cause (a servo current that
/// follows one heading's rolls) buys most of its pooled gain on one or two
/// headings, which a pooled RMS does not see. Block-wise, the test is
/// immune to the residual's autocorrelation within a manoeuvre.
pub(super) fn consistent_across_headings(before: &[WindowFit], after: &[WindowFit]) -> bool {
    let key = |w: &WindowFit, index: usize| match w.window.heading_deg {
        Some(heading) => format!("heading {:.0}", heading.rem_euclid(360.0)),
        None => format!("window {index}"),
    };
    let mut groups: BTreeMap<String, (f64, f64, usize)> = BTreeMap::new();
    for (index, (b, a)) in before.iter().zip(after).enumerate() {
        let entry = groups.entry(key(b, index)).or_insert((0.0, 0.0, 0));
        entry.0 += b.band_after_nt.iter().map(|v| v * v).sum::<f64>();
        entry.1 += a.band_after_nt.iter().map(|v| v * v).sum::<f64>();
        entry.2 += 1;
    }
    let improved = groups.values().filter(|(b, a, _)| a < b).count();
    improved + 1 >= groups.len()
}

/// Drops every candidate of a column with its rate whose rate does not
/// earn its place: it must lower the held-out RMS of the column alone by
/// the same threshold as any other effect, so that a coupling is not
/// described with a rate it does not need.
pub(super) fn drop_unearned_rates(scored: &mut Vec<(Model, Extension, HeldOut)>, keep: f64) {
    let alone: BTreeMap<String, f64> = scored
        .iter()
        .filter_map(|(_, extension, h)| match extension {
            Extension::Coupling { source } => Some((source.clone(), h.rms_nt)),
            _ => None,
        })
        .collect();
    scored.retain(|(_, extension, h)| match extension {
        Extension::CouplingWithRate { source } => alone.get(source).is_none_or(|rms| h.rms_nt <= keep * rms),
        _ => true,
    });
}

/// The candidates that change the model's timing: a sensor lag on the
/// 0.05 s grid up to `[diagnose] max_lag_s` either way, and an eddy time
/// constant from 0.1 to 1.5 s (where the diagnosis's term set has eddy
/// terms), each where the model has none yet.
fn timing_candidates(problem: &Problem, model: &Model, settings: &DiagnoseOptions) -> Vec<(Model, Extension)> {
    let mut list = Vec::new();
    if model.lag_s == 0.0 {
        let steps = (settings.max_lag_s / 0.05).round() as i64;
        for step in (-steps..=steps).filter(|s| *s != 0) {
            let lag_s = step as f64 * 0.05;
            list.push((Model { lag_s, ..model.clone() }, Extension::Lag { lag_s }));
        }
    }
    if model.eddy_tau_s == 0.0 && problem.terms.eddy != crate::model::terms::EddyTerms::None {
        for tau_s in [0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.1, 1.5] {
            list.push((
                Model {
                    eddy_tau_s: tau_s,
                    ..model.clone()
                },
                Extension::Eddy { tau_s },
            ));
        }
    }
    list
}

/// Every extension of `model` worth scoring.
pub(super) fn candidates(problem: &Problem, model: &Model, settings: &DiagnoseOptions) -> Vec<(Model, Extension)> {
    let mut list = timing_candidates(problem, model, settings);
    for channel in problem.log.channels() {
        let Some(&level) = problem.levels.get(&channel.name) else {
            continue;
        };
        let column = channel.name.clone();
        let (extension, term) = match &channel.role {
            ChannelRole::BaseStation => (
                Extension::External { source: column.clone() },
                SourceTerm::ExternalField { column, level },
            ),
            _ => (
                Extension::Coupling { source: column.clone() },
                SourceTerm::AuxCoupling { column, level },
            ),
        };
        if !model.sources.iter().any(|s| s.column() == channel.name) {
            let mut next = model.clone();
            next.sources.push(term);
            // A cross-sensor signal's rate is another sensor's noise
            // differentiated: only the signal itself is a candidate.
            let rated = !super::cross::is_cross_column(&channel.name);
            if let (Extension::Coupling { source }, true) = (&extension, rated) {
                let mut with_rate = next.clone();
                with_rate
                    .sources
                    .push(SourceTerm::AuxCouplingRate { column: source.clone() });
                list.push((with_rate, Extension::CouplingWithRate { source: source.clone() }));
            }
            list.push((next, extension));
        }
    }
    // The total field's second-order term: physics the first-order model
    // leaves out where the aircraft's field is large (a cabin sensor).
    if !model.second_order {
        list.push((with_second_order(model), Extension::SecondOrder));
    }
    // A coupled column's rate of change: the eddy currents a changing
    // current induces near the sensor.
    for source in &model.sources {
        let SourceTerm::AuxCoupling { column, .. } = source else {
            continue;
        };
        if super::cross::is_cross_column(column) {
            continue;
        }
        let refined = SourceTerm::AuxCouplingRate { column: column.clone() };
        if !model.sources.contains(&refined) {
            let mut next = model.clone();
            next.sources.push(refined);
            list.push((next, Extension::CouplingRate { source: column.clone() }));
        }
    }
    list
}

/// Every column that may drive a source term, with its median: auxiliary
/// columns that are not magnetometer products and base-station columns,
/// recorded on more than half the rows.
pub(super) fn source_levels(log: &FlightLog) -> BTreeMap<String, f64> {
    log.channels()
        .iter()
        .filter(|c| match c.role {
            ChannelRole::Auxiliary => !is_magnetic_product(&c.name),
            ChannelRole::BaseStation => true,
            _ => false,
        })
        .filter(|c| c.values.iter().filter(|v| v.is_finite()).count() * 2 > c.values.len())
        .map(|c| (c.name.clone(), column_level(&c.values)))
        .collect()
}

/// Columns that are themselves magnetometer products (SGL's compensated
/// `mag_1_c`, `mag_1_c_d`, IGRF and diurnal corrections, fluxgate totals):
/// they carry the Earth's field the scalar records, so as "sources" they
/// would explain the target with itself.
pub(super) fn is_magnetic_product(name: &str) -> bool {
    let name = name.to_ascii_lowercase();
    name.starts_with("mag_")
        || name.starts_with("flux_")
        || name.starts_with("ogs_mag")
        || name.contains("igrf")
        || name.contains("diurnal")
}

/// Refines a parameter found on a coarse grid: `steps` either side of
/// `coarse` spaced `step` apart, then a parabola through the best three.
/// `with` sets the parameter on the model.
pub(super) fn refine(
    problem: &Problem,
    (coarse, step, steps): (f64, f64, i32),
    with: impl Fn(f64) -> Model + Sync,
) -> Result<(f64, HeldOut)> {
    let score = |value: f64| held_out(problem, &with(value)).map(|h| (value, h));
    let fine: Vec<(f64, HeldOut)> = (-steps..=steps)
        .into_par_iter()
        .map(|k| score(coarse + k as f64 * step))
        .collect::<Result<_>>()?;
    let best = (0..fine.len())
        .min_by(|&a, &b| fine[a].1.rms_nt.total_cmp(&fine[b].1.rms_nt))
        .unwrap_or(steps as usize);
    let value = if best > 0 && best + 1 < fine.len() {
        let (a, b, c) = (fine[best - 1].1.rms_nt, fine[best].1.rms_nt, fine[best + 1].1.rms_nt);
        let curvature = a - 2.0 * b + c;
        let shift = if curvature > 0.0 {
            0.5 * (a - c) / curvature
        } else {
            0.0
        };
        fine[best].0 + shift.clamp(-0.5, 0.5) * step
    } else {
        fine[best].0
    };
    score(value)
}
