//! A cheap first look at every candidate, so that only the promising few
//! are scored in full.
//!
//! The full score of a candidate ([`held_out`]) builds and band-passes its
//! whole design on every split, then picks λ by PRESS on each: a hundred
//! candidates of thirty auxiliary columns cost a hundred times the fit.
//! But most candidates add a few columns to the current model (a source's
//! coupling) or change only its target (a lag, a base station's variation
//! subtracted), and the held-out residual
//! of a linear fit is a function of moment matrices: with the current
//! model's band-passed design X and target y on each held-out piece (a
//! heading's windows, a window, a quarter), and a candidate's new columns
//! C and target y′,
//!
//! $$ G = \begin{pmatrix} X^\top X & X^\top C \\ C^\top X & C^\top C
//! \end{pmatrix}, \qquad b = \begin{pmatrix} X^\top y' \\ C^\top y'
//! \end{pmatrix}, $$
//!
//! summed over a split's training pieces, give its coefficients $β = (G +
//! Λ)^{-1} b$, and over its held-out pieces its residual sum of squares
//! $y'^\top y' - 2β^\top b + β^\top G β$. X's moments are gathered once per
//! step of the search; a candidate costs the band-pass of its own columns
//! and their products with X: a few per cent of its full score.
//!
//! Λ holds the current model's own ridge λ of that split on X's columns
//! (its regularisation, which the full score would mostly choose again)
//! and none on a source's columns, so the screen asks what they add to the
//! model as it stands; an eddy time constant's lagged terms, which replace
//! X's nine eddy columns, take the model's λ as those did. A model with
//! the second-order term fits the scalar less the term of its own fit:
//! the screen takes that target once, from the model fitted on every
//! piece ([`Screen::new`]). It ranks; it decides nothing: the best
//! [`SCREENED_KEEP`] by the screen, and every candidate it cannot judge
//! (the second-order term added or removed; a lag or a base station on a
//! model with the second-order term, whose corrected target the screen
//! does not refit; a source with gaps on the windows, which changes the
//! rows), go on to the full score and to every test after it.

use faer::linalg::solvers::Solve;
use faer::Mat;

use super::*;
use crate::model::band::band_data;
use crate::model::terms::{EddyTerms, InducedTerms};
use crate::model::ExtraColumn;

/// Candidates the screen passes on to the full score, besides those it
/// cannot judge. The search checks the best few of the full scores against
/// the control ([`CONTROL_CHECKS`]) and the other λ criterion: the screen
/// keeps twice as many.
pub(super) const SCREENED_KEEP: usize = 8;

/// The current model's band-passed design on every held-out piece, and
/// each piece's moments.
pub(super) struct Screen {
    /// The held-out pieces, split by split.
    pieces: Vec<CalibrationWindow>,
    /// The split holding out each piece.
    split_of: Vec<usize>,
    /// Each split's ridge λ on the current design.
    ridge: Vec<f64>,
    /// The model screened against.
    model: Model,
    /// Names of its design columns (terms, then extension columns).
    names: Vec<String>,
    /// Its design columns over the stacked rows of every piece.
    columns: Vec<Vec<f64>>,
    /// Its band-passed target over the same rows.
    target: Vec<f64>,
    /// Each piece's stacked rows and flight rows.
    rows: Vec<std::ops::Range<usize>>,
    flight_rows: Vec<Vec<std::ops::Range<usize>>>,
    /// Each piece's $X^\top X$ (row-major) and $X^\top y$, $y^\top y$.
    gram: Vec<Vec<f64>>,
    cross: Vec<Vec<f64>>,
    squares: Vec<f64>,
}

/// $a^\top b$, in eight running sums the compiler can keep in one vector
/// register (the order of the additions is fixed: the same bits on any
/// machine and thread count).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut sums = [0.0; 8];
    let (a_chunks, b_chunks) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = (a_chunks.remainder().iter())
        .zip(b_chunks.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a_chunks.zip(b_chunks) {
        for lane in 0..8 {
            sums[lane] += x[lane] * y[lane];
        }
    }
    sums.iter().sum::<f64>() + tail
}

impl Screen {
    /// The screen of `model`, fitted on each split with ridge λ `ridge`
    /// ([`HeldOut::ridge`]); `None` where it cannot be built (a split
    /// count that does not match, a design that does not fill the
    /// pieces).
    ///
    /// A model with the second-order term fits the scalar less the term of
    /// its own fit, which differs a little from split to split and moves
    /// with any column added. The screen takes one target for every
    /// piece: the scalar less the term of the model fitted on all of
    /// them. What it ranks is what a candidate's columns add to that
    /// corrected residual; the full score of those it keeps makes the
    /// passes of each split.
    pub(super) fn new(problem: &Problem, model: &Model, ridge: &[f64]) -> Option<Screen> {
        let splits = folds(problem.windows);
        if ridge.len() != splits.len() {
            return None;
        }
        let (mut pieces, mut split_of) = (Vec::new(), Vec::new());
        for (split, (out, _)) in splits.iter().enumerate() {
            pieces.extend(out.iter().cloned());
            split_of.extend(std::iter::repeat_n(split, out.len()));
        }
        let spec = problem.spec(model);
        let prepared = prepare(problem, &spec).ok()?;
        if !prepared.covers(&pieces) {
            return None;
        }
        let scalar = (prepared.fitted_target(&pieces, &score_options(problem), problem.stores)).ok()?;
        let data = band_data(
            &prepared.log,
            problem.sensor,
            (problem.channel, &scalar),
            &pieces,
            (spec.fitted_terms(), &problem.options.filter),
            &prepared.extra_columns(),
            problem.stores,
        )
        .ok()?;
        let p = data.stacked.columns();
        let columns: Vec<Vec<f64>> = (0..p).map(|j| data.stacked.column(j)).collect();
        let target = data.stacked.target();
        problem.stores.recycle(data.stacked);
        let rows: Vec<_> = data.windows.iter().map(|w| w.stacked_rows.clone()).collect();
        let (gram, cross, squares) = piece_moments(&columns, &target, &rows);
        Some(Screen {
            pieces,
            split_of,
            ridge: ridge.to_vec(),
            model: model.clone(),
            names: (spec.fitted_terms().names().into_iter())
                .chain(prepared.extra.iter().map(|c| c.name.clone()))
                .collect(),
            columns,
            target,
            flight_rows: data.windows.iter().map(|w| w.flight_rows.clone()).collect(),
            rows,
            gram,
            cross,
            squares,
        })
    }

    /// The screened held-out RMS of `candidate`, nT; `None` where the
    /// screen cannot judge it.
    fn score(&self, problem: &Problem, candidate: &Model) -> Option<f64> {
        let model = &self.model;
        if candidate.second_order != model.second_order || candidate.vector_calibration != model.vector_calibration {
            return None;
        }
        let spec = problem.spec(candidate);
        let prepared = prepare(problem, &spec).ok()?;
        if !prepared.covers(&self.pieces) {
            return None;
        }
        // The candidate's design: the model's columns it keeps (an eddy
        // time constant drops the nine instantaneous eddy terms), then its
        // new ones.
        let names: Vec<String> = (spec.fitted_terms().names().into_iter())
            .chain(prepared.extra.iter().map(|c| c.name.clone()))
            .collect();
        let kept: Vec<usize> = (0..self.names.len())
            .filter(|&i| names.contains(&self.names[i]))
            .collect();
        let new: Vec<&ExtraColumn> = (prepared.extra.iter())
            .filter(|c| !self.names.contains(&c.name))
            .collect();
        if kept.len() + new.len() != names.len() {
            return None;
        }
        // A lag reads the scalar at other times; a base station is
        // subtracted from it: either changes the target. With the
        // second-order term that target is corrected by a fit the screen
        // does not make for each candidate: such a candidate goes on to
        // the full score.
        let retargeted = candidate.lag_s != model.lag_s || station_columns(candidate) != station_columns(model);
        if retargeted && model.second_order {
            return None;
        }
        let (added, target) = self.band_passed(problem, &prepared, &new, retargeted)?;
        let p = kept.len();
        // The model's regularisation on its own columns and on columns
        // that stand in for its terms (the lagged eddy terms); none on a
        // source's.
        let penalised: Vec<bool> = (0..p)
            .map(|_| true)
            .chain(new.iter().map(|c| c.name.starts_with("eddy_lagged")))
            .collect();
        let y = target.as_deref().unwrap_or(&self.target);
        // Each piece's moments of [X C] and y′.
        let moments = self.piece_moments(&kept, &added, y, retargeted);
        self.held_out_rms(&moments, &penalised)
    }

    /// The candidate's `new` columns band-passed on the screen's pieces,
    /// and its own target where it is `retargeted`; `None` where they do
    /// not fill the same rows as the model's.
    #[allow(clippy::type_complexity)]
    fn band_passed(
        &self,
        problem: &Problem,
        prepared: &Prepared,
        new: &[&ExtraColumn],
        retargeted: bool,
    ) -> Option<(Vec<Vec<f64>>, Option<Vec<f64>>)> {
        let none = TermSet {
            permanent: false,
            induced: InducedTerms::None,
            eddy: EddyTerms::None,
            field_derivative: false,
            bias: false,
            ..problem.terms
        };
        let new_values: Vec<&[f64]> = new.iter().map(|c| c.values.as_slice()).collect();
        let data = band_data(
            &prepared.log,
            problem.sensor,
            (problem.channel, &prepared.scalar),
            &self.pieces,
            (none, &problem.options.filter),
            &new_values,
            problem.stores,
        )
        .ok()?;
        // The candidate's columns must fill the same rows as the model's.
        let aligned = data.windows.len() == self.rows.len()
            && (data.windows.iter())
                .zip(&self.flight_rows)
                .all(|(w, rows)| w.flight_rows == *rows);
        let added: Vec<Vec<f64>> = (0..new.len()).map(|j| data.stacked.column(j)).collect();
        let target = retargeted.then(|| data.stacked.target());
        problem.stores.recycle(data.stacked);
        aligned.then_some((added, target))
    }

    /// Each piece's moments of the candidate's design [X C] (the model's
    /// `kept` columns, then the `added` ones) and of its target `y`: the
    /// Gram matrix (row-major), X′y and y′y. The model's own moments are
    /// reused where the target is the model's.
    fn piece_moments(
        &self,
        kept: &[usize],
        added: &[Vec<f64>],
        y: &[f64],
        retargeted: bool,
    ) -> Vec<(Vec<f64>, Vec<f64>, f64)> {
        let (p, k, all) = (kept.len(), added.len(), self.columns.len());
        let q = p + k;
        (self.rows.iter().enumerate())
            .map(|(piece, range)| {
                let x: Vec<&[f64]> = kept.iter().map(|&i| &self.columns[i][range.clone()]).collect();
                let c: Vec<&[f64]> = added.iter().map(|c| &c[range.clone()]).collect();
                let y = &y[range.clone()];
                let mut g = vec![0.0; q * q];
                for (a, &i) in kept.iter().enumerate() {
                    for (b, &j) in kept.iter().enumerate() {
                        g[a * q + b] = self.gram[piece][i * all + j];
                    }
                }
                for a in 0..k {
                    for (i, column) in x.iter().enumerate() {
                        let value = dot(c[a], column);
                        g[(p + a) * q + i] = value;
                        g[i * q + p + a] = value;
                    }
                    for b in a..k {
                        let value = dot(c[a], c[b]);
                        g[(p + a) * q + p + b] = value;
                        g[(p + b) * q + p + a] = value;
                    }
                }
                let mut b: Vec<f64> = match retargeted {
                    true => x.iter().map(|column| dot(column, y)).collect(),
                    false => kept.iter().map(|&i| self.cross[piece][i]).collect(),
                };
                b.extend(c.iter().map(|column| dot(column, y)));
                let squares = match retargeted {
                    true => dot(y, y),
                    false => self.squares[piece],
                };
                (g, b, squares)
            })
            .collect()
    }

    /// The held-out RMS of the ridge fit of each split's complement,
    /// predicted on the split, from the pieces' `moments`: `penalised`
    /// says which columns λ regularises.
    fn held_out_rms(&self, moments: &[(Vec<f64>, Vec<f64>, f64)], penalised: &[bool]) -> Option<f64> {
        let q = penalised.len();
        let (mut residual, mut samples) = (0.0, 0usize);
        for (split, &lambda) in self.ridge.iter().enumerate() {
            let (mut g, mut b) = (vec![0.0; q * q], vec![0.0; q]);
            for (piece, (gp, bp, _)) in moments.iter().enumerate() {
                if self.split_of[piece] != split {
                    g.iter_mut().zip(gp).for_each(|(s, v)| *s += v);
                    b.iter_mut().zip(bp).for_each(|(s, v)| *s += v);
                }
            }
            let system = Mat::from_fn(q, q, |i, j| {
                g[i * q + j] + if i == j && penalised[i] { lambda } else { 0.0 }
            });
            let factor = system.llt(faer::Side::Lower).ok()?;
            let beta = factor.solve(Mat::from_fn(q, 1, |i, _| b[i]));
            let beta: Vec<f64> = (0..q).map(|i| beta[(i, 0)]).collect();
            for (piece, (gp, bp, yy)) in moments.iter().enumerate() {
                if self.split_of[piece] != split {
                    continue;
                }
                let g_beta: Vec<f64> = gp.chunks_exact(q).map(|row| dot(row, &beta)).collect();
                residual += yy - 2.0 * dot(&beta, bp) + dot(&beta, &g_beta);
                samples += self.rows[piece].len();
            }
        }
        (samples > 0 && residual.is_finite()).then(|| (residual.max(0.0) / samples as f64).sqrt())
    }

    /// The candidates worth the full score: the best [`SCREENED_KEEP`] by
    /// the screen, every one it cannot judge, and the column alone of a
    /// column kept with its rate (the rate must earn its place against it,
    /// [`drop_unearned_rates`]). The screen's best first, in its order,
    /// then the rest in `candidates`' order.
    pub(super) fn select(&self, problem: &Problem, candidates: Vec<(Model, Extension)>) -> Vec<(Model, Extension)> {
        let scores: Vec<Option<f64>> = candidates.par_iter().map(|(m, _)| self.score(problem, m)).collect();
        let mut ranked: Vec<usize> = (0..candidates.len()).filter(|&i| scores[i].is_some()).collect();
        ranked.sort_by(|&a, &b| {
            scores[a]
                .unwrap_or(f64::INFINITY)
                .total_cmp(&scores[b].unwrap_or(f64::INFINITY))
        });
        let mut keep: Vec<bool> = scores.iter().map(Option::is_none).collect();
        for &i in ranked.iter().take(SCREENED_KEEP) {
            keep[i] = true;
        }
        let partners: Vec<String> = (0..candidates.len())
            .filter(|&i| keep[i])
            .filter_map(|i| match &candidates[i].1 {
                Extension::CouplingWithRate { source } => Some(source.clone()),
                _ => None,
            })
            .collect();
        for (i, (_, extension)) in candidates.iter().enumerate() {
            if let Extension::Coupling { source } = extension {
                keep[i] |= partners.contains(source);
            }
        }
        let mut place = vec![usize::MAX; candidates.len()];
        for (rank, &i) in ranked.iter().take(SCREENED_KEEP).enumerate() {
            place[i] = rank;
        }
        let mut kept: Vec<(usize, (Model, Extension))> =
            (candidates.into_iter().enumerate()).filter(|(i, _)| keep[*i]).collect();
        kept.sort_by_key(|(i, _)| (place[*i], *i));
        kept.into_iter().map(|(_, candidate)| candidate).collect()
    }
}

/// The base-station columns `model` subtracts from the scalar.
fn station_columns(model: &Model) -> Vec<String> {
    (model.sources.iter())
        .filter(|s| s.is_external_field())
        .map(|s| s.column().to_string())
        .collect()
}

/// Per row range: the columns' Gram matrix (row-major), their products
/// with the target, and the target's sum of squares.
type PieceMoments = (Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<f64>);

/// The [`PieceMoments`] of `columns` and `target` over each range of
/// `rows`.
fn piece_moments(columns: &[Vec<f64>], target: &[f64], rows: &[std::ops::Range<usize>]) -> PieceMoments {
    let p = columns.len();
    let (mut gram, mut cross, mut squares) = (Vec::new(), Vec::new(), Vec::new());
    for range in rows {
        let piece: Vec<&[f64]> = columns.iter().map(|c| &c[range.clone()]).collect();
        let y = &target[range.clone()];
        let mut g = vec![0.0; p * p];
        for i in 0..p {
            for j in i..p {
                let value = dot(piece[i], piece[j]);
                g[i * p + j] = value;
                g[j * p + i] = value;
            }
        }
        gram.push(g);
        cross.push(piece.iter().map(|c| dot(c, y)).collect());
        squares.push(dot(y, y));
    }
    (gram, cross, squares)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::tests::TestFlight;

    /// With no new column and the same target, the screen's figure is the
    /// model's own held-out RMS: the moments give what the rows give, so
    /// the screen and the full score measure the same thing. A lag (a new
    /// target) screens within 20 % of its full score (which picks its own
    /// λ).
    #[test]
    fn the_screen_of_the_model_itself_is_its_held_out_rms() {
        let flight = TestFlight::new(&[]);
        let problem = flight.problem();
        let model = Model::default();
        let full = held_out(&problem, &model).unwrap();
        let screen = Screen::new(&problem, &model, &full.ridge).unwrap();
        let screened = screen.score(&problem, &model).unwrap();
        assert!(
            (screened - full.rms_nt).abs() < 1e-6 * full.rms_nt,
            "{screened} against {}",
            full.rms_nt
        );
        let lagged = Model {
            lag_s: 0.1,
            ..Model::default()
        };
        let lag = screen.score(&problem, &lagged).unwrap();
        let lag_full = held_out(&problem, &lagged).unwrap().rms_nt;
        assert!(
            lag.is_finite() && lag > 0.0 && (lag / lag_full - 1.0).abs() < 0.2,
            "{lag} against {lag_full}"
        );
    }

    /// A model with the second-order term is screened on the scalar less
    /// the term of its fit on every piece (not the scalar as recorded):
    /// its own screened figure lies near its held-out RMS (each split's
    /// passes correct the target a little differently); a lag on it
    /// changes a target the screen does not refit, so it goes on to the
    /// full score.
    #[test]
    fn a_model_with_the_second_order_term_is_screened_on_its_corrected_target() {
        let flight = TestFlight::new(&[]);
        let problem = flight.problem();
        let model = with_second_order(&Model::default());
        let full = held_out(&problem, &model).unwrap();
        let screen = Screen::new(&problem, &model, &full.ridge).unwrap();
        let screened = screen.score(&problem, &model).unwrap();
        assert!(
            (screened / full.rms_nt - 1.0).abs() < 0.1,
            "{screened} against {}",
            full.rms_nt
        );
        let plain = held_out(&problem, &Model::default()).unwrap();
        let plain_screen = Screen::new(&problem, &Model::default(), &plain.ridge).unwrap();
        let moved = (screen.target.iter().zip(&plain_screen.target))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(moved > 1e-6, "the target corrected by at most {moved} nT");
        let lagged = Model { lag_s: 0.1, ..model };
        assert_eq!(screen.score(&problem, &lagged), None);
    }
}
