//! Drift between calibrations: whether one aircraft's installation changed
//! between two calibration flights, beyond what their uncertainties
//! explain.
//!
//! Coefficients side by side mislead: a box pins some combinations of
//! them tightly and leaves others to the regulariser, so two good fits of
//! an unchanged aircraft can differ by many standard errors in a
//! coefficient that barely changes any prediction. The comparison is made
//! where it matters, in the predictions. With $\Delta$ the difference of
//! the two models' Tolles-Lawson coefficients (the terms both fitted) and
//! $M$ the mean of the two calibrations' band-passed second moments
//! ([`crate::model::excitation::Excitation::calibration_moment`]),
//!
//! $$ Q = \Delta^\top M \Delta $$
//!
//! is the mean square of the two models' predictions' difference over the
//! calibration manoeuvres, nT². Each fit's coefficients carry a blocked
//! jackknife ([`crate::numerics::solve::Solution::jackknife`]: whole
//! windows left out, so the residuals' autocorrelation is kept), whose
//! deviations $d_f$ of both fits give the covariance
//! $\Sigma = c \sum_f d_f d_f^\top$ of $\Delta$ for an unchanged aircraft,
//! with $c$ = [`BETWEEN_BOXES`]: one box's jackknife sees how its own
//! windows differ, not what differs between two boxes (the field's
//! direction, the rates, the fluxgate's own errors move the effective
//! coefficients a little), and simulated pairs of an unchanged aircraft
//! put that at about three times the variance. Then
//! $\operatorname{E}(Q) = \operatorname{tr}(M\Sigma)$, and $Q/\operatorname{E}(Q)$ is close to a
//! $\chi^2_\nu/\nu$ with $\nu = \operatorname{tr}(M\Sigma)^2 /
//! \operatorname{tr}((M\Sigma)^2)$ degrees of freedom (Satterthwaite
//! 1946); since $\Sigma$ is itself estimated from the $m = F_a + F_b - 2$
//! degrees of freedom of the two jackknives, the ratio is taken as
//! $F(\nu, m)$. The permanent field, which a box pins best and a
//! magnetised part changes first, is also tested on its own: its change
//! $\Delta_P$ (nT at the sensor) against its 3 × 3 block of $\Sigma$,
//! $T^2 = \Delta_P^\top \Sigma_P^{-1} \Delta_P$, a Hotelling $T^2$:
//! $\frac{m-2}{3m} T^2 \sim F(3, m-2)$. Either statistic above its
//! [`FALSE_ALARM`] quantile is a change the uncertainties do not explain.
//!
//! The eddy-current terms' derivatives are per sample, so their
//! coefficients scale with the sample rate; they are compared per second
//! (coefficient times the rate's reciprocal, the moment rescaled to
//! match), so flights recorded at 10 and 20 Hz compare. Models with
//! different `bt_scale_nt` are not compared.
//!
//! Only the Tolles-Lawson terms are compared: they are the airframe's.
//! A diagnosed extension (a lag, a current's coupling, the base station)
//! belongs to one flight's data, and is named when the two models differ
//! in them.

use serde_json::Value;

/// A statistic whose probability under no change is below this is
/// flagged (each of the two, so about twice this in all).
pub const FALSE_ALARM: f64 = 1e-3;

/// The jackknife covariances are multiplied by this for what differs
/// between two boxes of one aircraft and one box's windows do not see.
/// Measured on simulated pairs of an unchanged aircraft (random boxes,
/// sites, rates; `tests/drift.rs`): the permanent field's $T^2$ averaged
/// about three times its $\chi^2_3$ expectation with the bare jackknife.
pub const BETWEEN_BOXES: f64 = 3.0;

/// One channel's model from one calibration flight: what the comparison
/// needs from its model JSON.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The channel.
    pub channel: String,
    /// Term names, in the model's order.
    pub terms: Vec<String>,
    /// Coefficients, one per term.
    pub coefficients: Vec<f64>,
    /// The blocked jackknife's deviations, one row per window left out
    /// (empty without one).
    pub jackknife: Vec<Vec<f64>>,
    /// The band-passed second moment over the calibration (p × p; empty
    /// without an excitation analysis).
    pub moment: Vec<Vec<f64>>,
    /// The rate the model was fitted at, Hz.
    pub sample_rate_hz: f64,
    /// The induced and eddy terms' field scale, nT.
    pub bt_scale_nt: f64,
}

/// The family of a Tolles-Lawson term, or `None` for another column.
fn family(term: &str) -> Option<usize> {
    ["perm_", "ind_", "eddy_"].iter().position(|p| term.starts_with(p))
}

/// The families' names, in [`family`]'s order.
const FAMILIES: [&str; 3] = ["permanent", "induced", "eddy-current"];

impl Calibration {
    /// One fitted model of a model JSON's `models` list.
    pub fn from_model_json(fitted: &Value) -> Calibration {
        let numbers = |value: &Value| -> Vec<f64> {
            (value.as_array().into_iter().flatten())
                .map(|v| v.as_f64().unwrap_or(f64::NAN))
                .collect()
        };
        let matrix = |value: &Value| -> Vec<Vec<f64>> { value.as_array().into_iter().flatten().map(numbers).collect() };
        Calibration {
            channel: fitted["channel"].as_str().unwrap_or_default().to_string(),
            terms: (fitted["term_names"].as_array().into_iter().flatten())
                .map(|t| t.as_str().unwrap_or_default().to_string())
                .collect(),
            coefficients: numbers(&fitted["coefficients"]),
            jackknife: matrix(&fitted["solution"]["jackknife"]),
            moment: matrix(&fitted["excitation"]["calibration_moment"]),
            sample_rate_hz: fitted["sample_rate_hz"].as_f64().unwrap_or(f64::NAN),
            bt_scale_nt: fitted["spec"]["terms"]["bt_scale_nt"].as_f64().unwrap_or(f64::NAN),
        }
    }

    /// The factor turning term `k`'s coefficient into per-second units:
    /// the rate's reciprocal for an eddy-current term, 1 otherwise.
    fn per_second(&self, k: usize) -> f64 {
        match family(&self.terms[k]) {
            Some(2) => 1.0 / self.sample_rate_hz,
            _ => 1.0,
        }
    }

    /// The extension columns (not Tolles-Lawson terms).
    fn extensions(&self) -> Vec<&str> {
        (self.terms.iter())
            .filter(|t| family(t).is_none())
            .map(String::as_str)
            .collect()
    }

    /// Why this model cannot be compared, if it cannot.
    fn incomparable(&self) -> Option<&'static str> {
        let p = self.terms.len();
        if self.coefficients.len() != p || self.coefficients.iter().any(|c| !c.is_finite()) {
            return Some("its coefficients are missing or not finite");
        }
        if self.jackknife.is_empty() {
            return Some("its fit has no blocked jackknife (fewer than three windows, or a solver other than ridge or truncated SVD)");
        }
        if self
            .jackknife
            .iter()
            .any(|d| d.len() != p || d.iter().any(|v| !v.is_finite()))
        {
            return Some("its jackknife does not match its terms");
        }
        if self.moment.is_empty() {
            return Some("it has no excitation analysis (a window's heading unknown, or a singular design)");
        }
        if self.moment.len() != p
            || self
                .moment
                .iter()
                .any(|r| r.len() != p || r.iter().any(|v| !v.is_finite()))
        {
            return Some("its calibration moment does not match its terms");
        }
        if !(self.sample_rate_hz > 0.0 && self.sample_rate_hz.is_finite()) {
            return Some("its sample rate is missing");
        }
        None
    }
}

/// The verdict of one comparison.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// The predictions differ within what the uncertainties explain.
    Steady,
    /// They differ beyond it: the installation changed.
    Changed,
    /// No comparison could be made (see [`Drift::note`]).
    Unknown,
}

impl Verdict {
    /// `steady`, `changed` or `unknown`.
    pub fn name(self) -> &'static str {
        match self {
            Verdict::Steady => "steady",
            Verdict::Changed => "changed",
            Verdict::Unknown => "unknown",
        }
    }
}

/// One family's share of a change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FamilyChange {
    /// Its terms' part of the predictions' difference, RMS, nT.
    pub change_rms_nt: f64,
    /// What the uncertainties explain of it, RMS, nT.
    pub expected_rms_nt: f64,
}

/// How one channel's model moved between two calibrations.
#[derive(Debug, Clone, PartialEq)]
pub struct Drift {
    /// Terms compared (the Tolles-Lawson terms both fitted).
    pub compared_terms: usize,
    /// RMS of the two models' predictions' difference over the
    /// calibration manoeuvres, $\sqrt{Q}$, nT.
    pub change_rms_nt: f64,
    /// What the two fits' uncertainties explain, $\sqrt{\operatorname{E}(Q)}$, nT.
    pub expected_rms_nt: f64,
    /// $Q / \operatorname{E}(Q)$.
    pub ratio: f64,
    /// The ratio above which the change is flagged.
    pub limit: f64,
    /// The Satterthwaite degrees of freedom ν.
    pub degrees_of_freedom: f64,
    /// The degrees of freedom the covariance is estimated with, m.
    pub covariance_dof: f64,
    /// The verdict.
    pub verdict: Verdict,
    /// Each family's share (permanent, induced, eddy-current); `None` for
    /// a family not compared.
    pub families: [Option<FamilyChange>; 3],
    /// The permanent field's change at the sensor (later minus earlier),
    /// body axes, nT, with one sigma; `None` without the three terms.
    pub permanent_change_nt: Option<([f64; 3], [f64; 3])>,
    /// The permanent field's change against its jackknife covariance,
    /// $T^2 = \Delta_P^\top \Sigma_P^{-1} \Delta_P$; `NaN` without it.
    pub permanent_t2: f64,
    /// The $T^2$ above which the permanent field changed.
    pub permanent_limit: f64,
    /// What else to know: why there is no verdict, or how the models differ.
    pub note: String,
}

impl Shared {
    /// The change of the terms of family `f` and what the jackknife
    /// expects of it between two boxes, RMS, nT; `None` when no shared
    /// term is of that family.
    fn family_change(&self, f: usize) -> Option<FamilyChange> {
        let keep = |r: usize| self.terms[r].2 == f;
        if !(0..self.terms.len()).any(keep) {
            return None;
        }
        let change = self.form(&self.delta, &self.delta, &keep);
        let expected: f64 = BETWEEN_BOXES * self.deviations.iter().map(|d| self.form(d, d, &keep)).sum::<f64>();
        Some(FamilyChange {
            change_rms_nt: change.max(0.0).sqrt(),
            expected_rms_nt: expected.max(0.0).sqrt(),
        })
    }
}

/// Compares the earlier calibration `a` with the later `b` of one channel.
pub fn compare(a: &Calibration, b: &Calibration) -> Drift {
    let mut drift = Drift::unknown(String::new());
    let shared = match Shared::of(a, b) {
        Ok(shared) => shared,
        Err(why) => {
            drift.note = why;
            return drift;
        }
    };
    drift.compared_terms = shared.terms.len();
    let all = |_: usize| true;
    let q = shared.form(&shared.delta, &shared.delta, &all);
    let expected: f64 = shared.deviations.iter().map(|d| shared.form(d, d, &all)).sum();
    let mut cross = 0.0;
    for d in &shared.deviations {
        for e in &shared.deviations {
            cross += shared.form(d, e, &all).powi(2);
        }
    }
    if !(expected > 0.0 && cross > 0.0 && q.is_finite()) {
        drift.note = "not compared: the jackknife gives no spread over the calibration (every window alike)".into();
        return drift;
    }
    // ν is unchanged by the covariance's factor; \operatorname{E}(Q) scales with it.
    let nu = expected * expected / cross;
    let expected = BETWEEN_BOXES * expected;
    drift.change_rms_nt = q.max(0.0).sqrt();
    drift.expected_rms_nt = expected.sqrt();
    drift.ratio = q / expected;
    let m = shared.deviations.len() as f64 - 2.0;
    drift.degrees_of_freedom = nu;
    drift.covariance_dof = m;
    drift.limit = f_quantile(nu, m, 1.0 - FALSE_ALARM);
    for (f, slot) in drift.families.iter_mut().enumerate() {
        *slot = shared.family_change(f);
    }
    test_permanent(a, &shared, m, &mut drift);
    drift.verdict = match drift.ratio > drift.limit || drift.permanent_t2 > drift.permanent_limit {
        true => Verdict::Changed,
        false => Verdict::Steady,
    };
    let (own_a, own_b) = (a.extensions(), b.extensions());
    if own_a != own_b {
        let list = |e: &[&str]| match e.is_empty() {
            true => "none".to_string(),
            false => e.join(", "),
        };
        if !drift.note.is_empty() {
            drift.note += "; ";
        }
        drift.note += &format!(
            "the models differ beyond Tolles-Lawson (earlier: {}; later: {}); a term one model adds can move the shared coefficients a little",
            list(&own_a),
            list(&own_b)
        );
    }
    drift
}

/// The Tolles-Lawson terms two calibrations share, in per-second units:
/// the change of their coefficients, the mean of their moment matrices
/// (in the reciprocal units, so each quadratic form is unchanged) and
/// every jackknife deviation of either.
struct Shared {
    /// (index in a, index in b, family) of each shared term.
    terms: Vec<(usize, usize, usize)>,
    /// Later less earlier coefficient of each shared term.
    delta: Vec<f64>,
    /// The mean moment matrix over the shared terms.
    moment: Vec<Vec<f64>>,
    /// The jackknife deviations of both calibrations over the shared terms.
    deviations: Vec<Vec<f64>>,
}

impl Shared {
    /// The shared terms of `a` and `b`, or why they cannot be compared.
    fn of(a: &Calibration, b: &Calibration) -> std::result::Result<Shared, String> {
        for (which, calibration) in [("earlier", a), ("later", b)] {
            if let Some(why) = calibration.incomparable() {
                return Err(format!("not compared: the {which} model cannot be: {why}"));
            }
        }
        if a.bt_scale_nt != b.bt_scale_nt {
            return Err(format!(
                "not compared: the models scale the induced and eddy terms differently (bt_scale_nt {} and {}); fit both with the same [fit] bt_scale_nt",
                a.bt_scale_nt, b.bt_scale_nt
            ));
        }
        let terms: Vec<(usize, usize, usize)> = (a.terms.iter().enumerate())
            .filter_map(|(i, term)| {
                let f = family(term)?;
                let j = b.terms.iter().position(|t| t == term)?;
                Some((i, j, f))
            })
            .collect();
        if terms.is_empty() {
            return Err("not compared: the two models share no Tolles-Lawson term".into());
        }
        let delta = (terms.iter())
            .map(|&(i, j, _)| b.coefficients[j] * b.per_second(j) - a.coefficients[i] * a.per_second(i))
            .collect();
        let moment = (terms.iter())
            .map(|&(i, j, _)| {
                (terms.iter())
                    .map(|&(k, l, _)| {
                        let from_a = a.moment[i][k] / (a.per_second(i) * a.per_second(k));
                        let from_b = b.moment[j][l] / (b.per_second(j) * b.per_second(l));
                        0.5 * (from_a + from_b)
                    })
                    .collect()
            })
            .collect();
        let deviations = (a.jackknife.iter())
            .map(|d| terms.iter().map(|&(i, _, _)| d[i] * a.per_second(i)).collect())
            .chain((b.jackknife.iter()).map(|d| terms.iter().map(|&(_, j, _)| d[j] * b.per_second(j)).collect()))
            .collect();
        Ok(Shared {
            terms,
            delta,
            moment,
            deviations,
        })
    }

    /// $x^T M y$ over the shared terms `keep` holds.
    fn form(&self, x: &[f64], y: &[f64], keep: &dyn Fn(usize) -> bool) -> f64 {
        let n = self.terms.len();
        let mut total = 0.0;
        for r in (0..n).filter(|&r| keep(r)) {
            for c in (0..n).filter(|&c| keep(c)) {
                total += x[r] * self.moment[r][c] * y[c];
            }
        }
        total
    }
}

/// The permanent field's change on its own: Hotelling's $T^2$ of its
/// three coefficients against their jackknife covariance (`m` its degrees
/// of freedom), set on `drift`.
fn test_permanent(a: &Calibration, shared: &Shared, m: f64, drift: &mut Drift) {
    let n = shared.terms.len();
    let (delta, deviations) = (&shared.delta, &shared.deviations);
    let permanent: Vec<usize> = ["perm_x", "perm_y", "perm_z"]
        .iter()
        .filter_map(|name| (0..n).find(|&r| a.terms[shared.terms[r].0] == *name))
        .collect();
    let [x, y, z] = permanent[..] else {
        return;
    };
    let sigma = |r: usize| (BETWEEN_BOXES * deviations.iter().map(|d| d[r] * d[r]).sum::<f64>()).sqrt();
    drift.permanent_change_nt = Some(([delta[x], delta[y], delta[z]], [sigma(x), sigma(y), sigma(z)]));
    let index = [x, y, z];
    let covariance = nalgebra::Matrix3::from_fn(|r, c| {
        BETWEEN_BOXES * deviations.iter().map(|d| d[index[r]] * d[index[c]]).sum::<f64>()
    });
    let change = nalgebra::Vector3::new(delta[x], delta[y], delta[z]);
    match covariance.try_inverse() {
        Some(inverse) => {
            drift.permanent_t2 = change.dot(&(inverse * change));
            drift.permanent_limit = 3.0 * m / (m - 2.0) * f_quantile(3.0, m - 2.0, 1.0 - FALSE_ALARM);
        }
        None => {
            drift.note = "the permanent field is not tested on its own: its jackknife covariance is singular".into()
        }
    }
}

impl Drift {
    /// No comparison, for the reason `note`.
    pub fn unknown(note: String) -> Drift {
        Drift {
            compared_terms: 0,
            change_rms_nt: f64::NAN,
            expected_rms_nt: f64::NAN,
            ratio: f64::NAN,
            limit: f64::NAN,
            degrees_of_freedom: f64::NAN,
            covariance_dof: f64::NAN,
            verdict: Verdict::Unknown,
            families: [None; 3],
            permanent_change_nt: None,
            permanent_t2: f64::NAN,
            permanent_limit: f64::NAN,
            note,
        }
    }

    /// The family whose change the uncertainties explain least, if the
    /// model changed.
    pub fn mostly_in(&self) -> Option<&'static str> {
        if self.verdict != Verdict::Changed {
            return None;
        }
        (0..3)
            .filter_map(|f| {
                let share = self.families[f]?;
                Some((
                    f,
                    share.change_rms_nt * share.change_rms_nt / share.expected_rms_nt.powi(2).max(f64::MIN_POSITIVE),
                ))
            })
            .max_by(|x, y| x.1.total_cmp(&y.1))
            .map(|(f, _)| FAMILIES[f])
    }

    /// The sentence of a changed installation: the tests it failed, the
    /// `permanent` field's move and the models' `predictions`, and where
    /// the change mostly lies.
    fn describe_change(&self, permanent: &Option<String>, predictions: &str) -> String {
        let mut reasons = Vec::new();
        if self.permanent_t2 > self.permanent_limit {
            reasons.extend(permanent.clone());
        }
        if self.ratio > self.limit {
            reasons.push(predictions.to_string());
            if let Some(family) = self.mostly_in() {
                reasons.push(format!("the change is mostly in the {family} terms"));
            }
        }
        format!(
            "changed: {}: the installation changed between the flights (a part moved, added or magnetised, or the sensor moved); recalibrate before using the earlier model",
            reasons.join("; ")
        )
    }

    /// The comparison in one sentence.
    pub fn describe(&self) -> String {
        if self.verdict == Verdict::Unknown {
            return self.note.clone();
        }
        let predictions = format!(
            "the two models' predictions over the calibration manoeuvres differ by {:.3} nT RMS against {:.3} nT the uncertainties explain (ratio {:.2}, limit {:.2})",
            self.change_rms_nt, self.expected_rms_nt, self.ratio, self.limit
        );
        let permanent = self.permanent_change_nt.map(|(change, sigma)| {
            format!(
                "the permanent field at the sensor moved by ({:+.2} ± {:.2}, {:+.2} ± {:.2}, {:+.2} ± {:.2}) nT (x, y, z; T² {:.1}, limit {:.1})",
                change[0], sigma[0], change[1], sigma[1], change[2], sigma[2], self.permanent_t2, self.permanent_limit
            )
        });
        let mut text = match self.verdict {
            Verdict::Changed => self.describe_change(&permanent, &predictions),
            _ => {
                let mut text = format!("steady: {predictions}");
                if let Some(permanent) = permanent {
                    text += &format!("; {permanent}");
                }
                text
            }
        };
        if !self.note.is_empty() {
            text += &format!(" ({})", self.note);
        }
        text
    }
}

/// The `probability` quantile of Fisher's F distribution with `d1` and
/// `d2` degrees of freedom (not necessarily whole); `NaN` for a
/// non-positive one.
pub fn f_quantile(d1: f64, d2: f64, probability: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, FisherSnedecor};
    match FisherSnedecor::new(d1, d2) {
        Ok(f) => f.inverse_cdf(probability),
        Err(_) => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// F quantiles against tabulated values (Abramowitz & Stegun table
    /// 26.9 and the 0.999 points of standard tables) to 0.5 %.
    #[test]
    fn f_quantiles_match_the_tables() {
        for (d1, d2, p, table) in [
            (3.0, 20.0, 0.999, 8.098),
            (3.0, 10.0, 0.999, 12.553),
            (5.0, 20.0, 0.95, 2.711),
            (1.0, 30.0, 0.99, 7.562),
        ] {
            let got = f_quantile(d1, d2, p);
            assert!(
                (got / table - 1.0).abs() < 0.005,
                "F({d1}, {d2}) at {p}: {got} against {table}"
            );
        }
        assert!(f_quantile(0.0, 3.0, 0.9).is_nan());
    }

    fn calibration(coefficients: Vec<f64>, jackknife: Vec<Vec<f64>>) -> Calibration {
        let terms = ["perm_x", "perm_y", "perm_z", "ind_xx"].map(String::from).to_vec();
        let moment = (0..4)
            .map(|i| (0..4).map(|j| if i == j { 0.3 } else { 0.05 }).collect())
            .collect();
        Calibration {
            channel: "mag_1_uc".into(),
            terms,
            coefficients,
            jackknife,
            moment,
            sample_rate_hz: 10.0,
            bt_scale_nt: 50_000.0,
        }
    }

    /// The statistic by hand on a small case: Q, \operatorname{E}(Q) and ν from their
    /// definitions, and the verdict either side of the limit.
    #[test]
    fn the_statistic_matches_its_definition() {
        let deviations = |scale: f64| -> Vec<Vec<f64>> {
            (0..6)
                .map(|f| {
                    (0..4)
                        .map(|j| scale * ((f * 7 + j * 3) % 5) as f64 - scale * 2.0)
                        .collect()
                })
                .collect()
        };
        let a = calibration(vec![1.0, 2.0, 3.0, 0.1], deviations(0.1));
        let b = calibration(vec![1.1, 1.9, 3.0, 0.1], deviations(0.2));
        let drift = compare(&a, &b);
        let m = |i: usize, j: usize| if i == j { 0.3 } else { 0.05 };
        let quad = |x: &[f64], y: &[f64]| -> f64 {
            (0..4)
                .flat_map(|i| (0..4).map(move |j| (i, j)))
                .map(|(i, j)| x[i] * m(i, j) * y[j])
                .sum()
        };
        let delta = [0.1, -0.1, 0.0, 0.0];
        let all: Vec<Vec<f64>> = deviations(0.1).into_iter().chain(deviations(0.2)).collect();
        let expected: f64 = all.iter().map(|d| quad(d, d)).sum();
        let cross: f64 = all
            .iter()
            .flat_map(|d| all.iter().map(move |e| quad(d, e).powi(2)))
            .sum();
        assert!((drift.change_rms_nt - quad(&delta, &delta).sqrt()).abs() < 1e-12);
        assert!((drift.expected_rms_nt - (BETWEEN_BOXES * expected).sqrt()).abs() < 1e-12);
        assert!((drift.degrees_of_freedom - expected * expected / cross).abs() < 1e-9);
        assert_eq!(drift.compared_terms, 4);
        let (change, sigma) = drift.permanent_change_nt.unwrap();
        assert!((change[0] - 0.1).abs() < 1e-12 && (change[1] + 0.1).abs() < 1e-12);
        let by_hand = (BETWEEN_BOXES * all.iter().map(|d| d[2] * d[2]).sum::<f64>()).sqrt();
        assert!((sigma[2] - by_hand).abs() < 1e-12);
        // Hotelling's T² of the permanent terms, and the limits, by hand.
        let covariance =
            nalgebra::Matrix3::from_fn(|r, c| BETWEEN_BOXES * all.iter().map(|d| d[r] * d[c]).sum::<f64>());
        let change = nalgebra::Vector3::new(0.1, -0.1, 0.0);
        let t2 = change.dot(&(covariance.try_inverse().unwrap() * change));
        assert!(
            (drift.permanent_t2 / t2 - 1.0).abs() < 1e-9,
            "{} against {t2}",
            drift.permanent_t2
        );
        let m = 12.0 - 2.0;
        assert_eq!(drift.covariance_dof, m);
        assert!((drift.permanent_limit - 3.0 * m / (m - 2.0) * f_quantile(3.0, m - 2.0, 0.999)).abs() < 1e-9);
        assert!((drift.limit - f_quantile(drift.degrees_of_freedom, m, 0.999)).abs() < 1e-9);
        let verdict = match drift.ratio > drift.limit || drift.permanent_t2 > drift.permanent_limit {
            true => Verdict::Changed,
            false => Verdict::Steady,
        };
        assert_eq!(drift.verdict, verdict);
        // Ten times the change is flagged; none is not.
        let far = calibration(vec![11.0, -8.0, 3.0, 0.1], deviations(0.2));
        assert_eq!(
            compare(&a, &far).verdict,
            Verdict::Changed,
            "{}",
            compare(&a, &far).describe()
        );
        assert_eq!(compare(&a, &a).verdict, Verdict::Steady);
        assert!(compare(&a, &far).describe().contains("permanent"));
    }

    /// A model without a jackknife is not compared, and says why.
    #[test]
    fn a_model_without_a_jackknife_is_not_compared() {
        let a = calibration(vec![1.0, 2.0, 3.0, 0.1], Vec::new());
        let b = calibration(vec![1.0, 2.0, 3.0, 0.1], vec![vec![0.1; 4]; 3]);
        let drift = compare(&a, &b);
        assert_eq!(drift.verdict, Verdict::Unknown);
        assert!(
            drift.note.contains("earlier") && drift.note.contains("jackknife"),
            "{}",
            drift.note
        );
    }
}
