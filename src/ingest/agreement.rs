//! Screening by the sensors' agreement: the INS attitude against each
//! fluxgate.
//!
//! The INS says how the aircraft turned; a fluxgate sees the Earth's field
//! turn the other way in its own axes. With the fluxgate's mounting $M$
//! (any orthogonal matrix: axes permuted, reversed, turned) and the
//! field's direction $u$ in north-east-down, every row should read
//!
//! $$ M\,\hat b_i \approx R_i\,u, $$
//!
//! $\hat b_i$ the fluxgate's unit reading, $R_i$ the INS rotation from
//! north-east-down to body axes. Both M and u come from the flight itself
//! (alternating orthogonal Procrustes and the mean direction, from a
//! spread of starting directions, on at most [`FIT_ROWS`] rows), so
//! neither a position, a date nor the installation is needed.
//!
//! The disagreement $d_i = M\hat b_i - R_i u$ is not zero: the aircraft's
//! own field at the fluxgate, its scale errors and any lag between the
//! two sensors leave a few degrees. The whole-sample shift between them
//! (within ±3 samples) is chosen by the fit, each row counted up to
//! [`MOST_COUNTED_DEG`] so that a glitch does not choose it; what is left
//! of the lag and the fluxgate's smoothing is taken out as multiples of
//! the INS view's first and second differences (fitted without the rows
//! far from the flight's usual disagreement, and the rows beside them).
//! All of this changes
//! smoothly with the motion. A glitch in either sensor does not: a roll
//! read 17° off on one row, a pitch read as zero for five rows, an axis
//! whose sign flips, each moves $d$ abruptly and back. Such a run starts
//! where $d$ steps by more than half the threshold and steps again
//! within [`REACH_S`]; its rows are those further than the threshold (at
//! least [`LEAST_DISAGREEMENT_DEG`], and [`NOISE_MULTIPLE`] times the
//! flight's median step) from the line between the medians of the second
//! before and the second after, every row of those seconds within it,
//! alone or summed over three rows (the lag terms spread a glitch of the
//! INS over its row and the two beside it, and the three sum to it), and
//! a row each side. Inside the screen of a single channel's rate these
//! are invisible: a 17° step at 10 Hz is within the 90°/s an attitude can
//! turn, a zero pitch within its range. A run is judged only beyond what
//! its span allows and a share of how sharply both sensors see the
//! aircraft turn there: where the turn rate steps within a sample (a roll
//! snapped in or out), the fluxgate's averaging over its interval and the
//! INS's instants part by up to about that step, and both sensors see it,
//! while a glitch is seen by one alone.
//!
//! A step that stays is not a run: a heading realigned by the INS, an
//! attitude or an axis offset that holds. Where the disagreement steps
//! and no run comes back, the channel whose jump there, taken out of its
//! readings from the step on, takes the step out is suspected; the frame,
//! the shift and the lag are fitted again without the stretch it would
//! turn (it pulls them towards it), and the step is held when, against
//! that fit, the second before and the second after each keep to their
//! line, the lines part by more than the threshold at the step, and that
//! channel's jump taken out joins them. Its rows are masked from the step
//! until the channel steps back: an opposite held step undoing three
//! quarters of it, or, where the disagreement's step back is within the
//! threshold, the channel's own opposite jump (which also closes a
//! stretch whose step out was within it). A step that never comes back
//! leaves two parts, and the agreement alone cannot say which is turned
//! (a constant offset is taken into the frame, and a heading off from
//! the start and realigned reads the same as one realigned wrongly): the
//! shorter part is masked, the frame being the longer's. Where that is
//! the wrong part, the vector's direction check against IGRF-14 says so.
//!
//! Which sensor is wrong is told by repair: the attitude angle or fluxgate
//! axis that, read on the fewest of the run's rows along its line across
//! the run (those furthest from that line first), brings the run back
//! into agreement is the one masked, on those rows. Where none alone
//! does, the run's attitude and the fluxgate's axes are all masked: the
//! sensors disagree and nothing says which to believe.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Vector3};

use crate::ingest::flight_log::{body_to_ned, AttitudeAngle, ChannelRole, FlightLog, VectorSensor};
use crate::ingest::screen::MaskReason;

/// The rows of each channel (by index) screening masks, and why.
pub type Masks = BTreeMap<usize, Vec<(usize, MaskReason)>>;

/// Smallest disagreement masked, degrees: 1° of the Earth's field is
/// 400–1,200 nT in a vector component.
pub const LEAST_DISAGREEMENT_DEG: f64 = 1.0;

/// A step of the disagreement is abrupt beyond this many times the
/// flight's median step (white noise reaches about 3 times it once in a
/// hundred thousand samples).
pub const NOISE_MULTIPLE: f64 = 8.0;

/// Rows further off than this many times the median departure from the
/// flight's usual disagreement are left out of the lag's fit.
const LAG_FIT_MULTIPLE: f64 = 5.0;

/// Largest disagreement of one row the shift's choice counts, degrees.
pub const MOST_COUNTED_DEG: f64 = 5.0;

/// Share of how sharply both sensors see the aircraft turn about a run
/// ([`Check::sharpness`]) allowed as disagreement: the lag terms take out
/// a smooth manoeuvre's, but where the turn rate steps within a sample (a
/// roll snapped in or out) the fluxgate's averaging over its interval
/// against the INS's instants leaves up to about 1.5 times the step
/// (measured on random flights at 5–50 Hz); twice is allowed.
const SHARP_SHARE: f64 = 2.0;

/// Longest run of glitches looked for, s.
pub const REACH_S: f64 = 5.0;

/// Most rows the mounting and the field's direction are fitted on.
pub const FIT_ROWS: usize = 4_000;

/// A fluxgate whose median disagreement with the INS is larger than this
/// does not follow the INS at all (another platform, another convention):
/// it is not judged against it, degrees.
const MOST_MEDIAN_DISAGREEMENT_DEG: f64 = 10.0;

/// Largest lag coefficient (per sample, per sample squared) taken out.
const MOST_LAG_SAMPLES: f64 = 2.0;

/// Most whole samples the INS is looked for behind or ahead of the
/// fluxgate.
const MOST_SHIFT_SAMPLES: isize = 3;

/// The stretch either side of a run its level is judged on, s.
const BRACKET_S: f64 = 1.0;

/// Steps across a gap longer than this are not judged, s.
const LONGEST_STEP_S: f64 = 1.0;

/// Fewest usable rows the check needs.
const FEWEST_ROWS: usize = 50;

/// The rows of each channel (by index) to mask because the INS attitude and
/// a fluxgate disagree abruptly; `masked` are the rows screening already
/// masked, which are not read.
pub fn disagreements(log: &FlightLog, masked: &Masks) -> Masks {
    let mut found = Masks::new();
    let Some(attitude) = attitude_channels(log) else {
        return found;
    };
    for sensor in log.vector_sensors() {
        // A held step leaves part of the flight turned: the frame, the
        // shift and the lag are fitted again without the stretches the
        // first look suspects, and the steps judged against that fit.
        let Some((first, suspected)) = judge(log, (attitude, &sensor), masked, &[]) else {
            continue;
        };
        let masks = match suspected.is_empty() {
            true => first,
            false => match judge(log, (attitude, &sensor), masked, &suspected) {
                Some((second, _)) => second,
                None => first,
            },
        };
        for (channel, rows) in masks {
            found.entry(channel).or_default().extend(rows);
        }
    }
    found
}

/// One fluxgate's check against the INS, fitted without the log rows
/// `left_out` (first and past-the-end): the rows of each channel to mask,
/// and the stretches (log rows) a held step seems to turn, when the check
/// can be made. Held steps are masked only when `left_out` is given: a
/// step is judged held against a fit that did not see it.
fn judge(
    log: &FlightLog,
    (attitude, sensor): ([usize; 3], &VectorSensor),
    masked: &Masks,
    left_out: &[(usize, usize)],
) -> Option<(Masks, Vec<(usize, usize)>)> {
    let shift = best_shift(log, attitude, sensor, (masked, left_out))?;
    let sensors = Sensors::new(log, attitude, sensor, (masked, shift)).without(left_out);
    let check = Check::of(&sensors)?;
    let mut found = Masks::new();
    // The runs masked: a run the check lets stand may be a held step's.
    let mut runs = Vec::new();
    for run in check.runs() {
        let culprits = check.culprits(&run);
        if !culprits.is_empty() {
            runs.push(run);
        }
        // Inside a stretch a held step turns, the disagreement is the
        // step's, and its rows are masked for it.
        let turned = |i: usize| left_out.iter().any(|&(from, to)| (from..to).contains(&check.rows[i]));
        if turned(run.first) && turned(run.last) {
            continue;
        }
        for (k, rows) in culprits {
            let rows = (rows.into_iter()).map(|i| (sensors.row_of(k, check.rows[i]), MaskReason::Disagreement));
            found.entry(sensors.channels[k]).or_default().extend(rows);
        }
    }
    let judged = !left_out.is_empty();
    let held = check.held(&runs, judged);
    if judged {
        for &(k, (from, to)) in &held {
            let values = sensors.values[k];
            let rows = (from..to).filter(|&row| values[row].is_finite());
            let rows = rows.map(|row| (row, MaskReason::HeldStep));
            found.entry(sensors.channels[k]).or_default().extend(rows);
        }
    }
    // The INS rows are read up to the shift's reach from the fluxgate's.
    let reach = MOST_SHIFT_SAMPLES as usize;
    let stretches = (held.into_iter())
        .map(|(_, (from, to))| (from.saturating_sub(reach), (to + reach).min(log.len())))
        .collect();
    Some((found, stretches))
}

/// The roll, pitch and yaw channels' indices, when all three are recorded.
fn attitude_channels(log: &FlightLog) -> Option<[usize; 3]> {
    let index = |angle: AttitudeAngle| (log.channels().iter()).position(|c| c.role == ChannelRole::Attitude(angle));
    Some([
        index(AttitudeAngle::Roll)?,
        index(AttitudeAngle::Pitch)?,
        index(AttitudeAngle::Yaw)?,
    ])
}

/// The six channels one check reads: roll, pitch, yaw, then the
/// fluxgate's x, y, z; the INS read `shift` rows later than the fluxgate.
struct Sensors<'a> {
    values: [&'a [f64]; 6],
    channels: [usize; 6],
    time_s: &'a [f64],
    shift: isize,
    usable: Vec<bool>,
    /// The usable rows the frame and the lag are fitted on.
    fitted: Vec<bool>,
    /// The median sample interval, s.
    interval_s: f64,
}

impl<'a> Sensors<'a> {
    fn new(log: &'a FlightLog, attitude: [usize; 3], sensor: &VectorSensor, (masked, shift): (&Masks, isize)) -> Self {
        let [roll, pitch, yaw] = attitude;
        let [x, y, z] = sensor.axes;
        let channels = [roll, pitch, yaw, x, y, z];
        let values = channels.map(|c| log.channels()[c].values.as_slice());
        let mut good: Vec<[bool; 6]> = (0..log.len()).map(|row| values.map(|v| v[row].is_finite())).collect();
        for (k, channel) in channels.iter().enumerate() {
            for (row, _) in masked.get(channel).into_iter().flatten() {
                good[*row][k] = false;
            }
        }
        let mut sensors = Sensors {
            values,
            channels,
            time_s: log.time_s(),
            shift,
            usable: Vec::new(),
            fitted: Vec::new(),
            interval_s: {
                let mut steps: Vec<f64> = log.time_s().windows(2).map(|w| w[1] - w[0]).collect();
                median(&mut steps)
            },
        };
        sensors.usable = (0..log.len())
            .map(|row| {
                let ins = sensors.ins_row(row).is_some_and(|r| good[r][..3].iter().all(|g| *g));
                ins && good[row][3..].iter().all(|g| *g)
            })
            .collect();
        sensors.fitted = sensors.usable.clone();
        sensors
    }

    /// The same sensors, with the log rows `left_out` (first and
    /// past-the-end) judged but not fitted on.
    fn without(mut self, left_out: &[(usize, usize)]) -> Self {
        for &(from, to) in left_out {
            self.fitted[from..to].fill(false);
        }
        self
    }

    /// The INS row read with the fluxgate's row `row`.
    fn ins_row(&self, row: usize) -> Option<usize> {
        row.checked_add_signed(self.shift).filter(|r| *r < self.time_s.len())
    }

    /// The row channel `k` (0–5) is read at with the fluxgate's row `row`.
    fn row_of(&self, k: usize, row: usize) -> usize {
        match k {
            0..=2 => self.ins_row(row).unwrap_or(row),
            _ => row,
        }
    }

    /// Row `row`'s six readings (the INS `shift` rows on).
    fn reading(&self, row: usize) -> [f64; 6] {
        std::array::from_fn(|k| self.values[k][self.row_of(k, row)])
    }

    /// The fit's (unit reading, rotation) pairs: at most [`FIT_ROWS`] of
    /// the rows fitted on, evenly spread.
    fn pairs(&self) -> Vec<(Vector3<f64>, Matrix3<f64>)> {
        let rows: Vec<usize> = (0..self.fitted.len()).filter(|&r| self.fitted[r]).collect();
        let stride = rows.len().div_ceil(FIT_ROWS).max(1);
        (rows.iter().step_by(stride))
            .filter_map(|&row| directions(self.reading(row)))
            .collect()
    }
}

/// The whole samples the INS runs behind the fluxgate (or ahead, when
/// negative), within [`MOST_SHIFT_SAMPLES`]: the shift whose frame makes
/// them agree best.
fn best_shift(
    log: &FlightLog,
    attitude: [usize; 3],
    sensor: &VectorSensor,
    (masked, left_out): (&Masks, &[(usize, usize)]),
) -> Option<isize> {
    let sensors = |shift: isize| Sensors::new(log, attitude, sensor, (masked, shift)).without(left_out);
    let start = Frame::fit(&sensors(0).pairs())?;
    (-MOST_SHIFT_SAMPLES..=MOST_SHIFT_SAMPLES)
        .filter_map(|shift| {
            let pairs = sensors(shift).pairs();
            let frame = Frame::refined(&pairs, start.field, 40)?;
            (pairs.len() >= FEWEST_ROWS).then(|| (shift, frame.cost(&pairs)))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(shift, _)| shift)
}

/// The fluxgate's unit reading and the INS rotation of one row's readings
/// (roll, pitch, yaw, x, y, z).
fn directions(reading: [f64; 6]) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let [roll, pitch, yaw, x, y, z] = reading;
    let field = Vector3::new(x, y, z);
    let norm = field.norm();
    (norm > 0.0 && norm.is_finite()).then(|| (field / norm, body_to_ned(roll, pitch, yaw).inverse().into_inner()))
}

/// The fluxgate's mounting and the field's direction that make the INS and
/// the fluxgate agree best.
#[derive(Debug, Clone, Copy)]
struct Frame {
    mounting: Matrix3<f64>,
    field: Vector3<f64>,
}

impl Frame {
    /// What one row's readings see of the field's direction in body axes.
    fn seen(&self, reading: [f64; 6]) -> Option<Seen> {
        let (b, r) = directions(reading)?;
        Some([self.mounting * b, r * self.field])
    }

    /// The frame fitted to `pairs` (unit reading, NED→body rotation), the
    /// best of starts spread over a hemisphere (−M with −u reads alike).
    fn fit(pairs: &[(Vector3<f64>, Matrix3<f64>)]) -> Option<Frame> {
        let starts = (0..16).map(|k| {
            // A Fibonacci spiral over the upper hemisphere.
            let z = 1.0 - (k as f64 + 0.5) / 16.0;
            let azimuth = k as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
            let across = (1.0 - z * z).sqrt();
            Vector3::new(across * azimuth.cos(), across * azimuth.sin(), z)
        });
        let best = (starts.filter_map(|field| Frame::refined(pairs, field, 12)))
            .min_by(|a, b| a.cost(pairs).total_cmp(&b.cost(pairs)))?;
        Frame::refined(pairs, best.field, 40)
    }

    /// The frame after `steps` alternations from the field direction
    /// `field`.
    fn refined(pairs: &[(Vector3<f64>, Matrix3<f64>)], field: Vector3<f64>, steps: usize) -> Option<Frame> {
        (0..steps).try_fold(Frame::mounted(pairs, field)?, |frame, _| {
            Frame::mounted(pairs, frame.mean_field(pairs)?)
        })
    }

    /// The orthogonal mounting that best takes the readings to the INS's
    /// view of `field` (orthogonal Procrustes).
    fn mounted(pairs: &[(Vector3<f64>, Matrix3<f64>)], field: Vector3<f64>) -> Option<Frame> {
        let h: Matrix3<f64> = (pairs.iter()).map(|(b, r)| (r * field) * b.transpose()).sum();
        let svd = h.svd(true, true);
        let mounting = svd.u? * svd.v_t?;
        Some(Frame { mounting, field })
    }

    /// The field's direction that `self.mounting` reads, on average.
    fn mean_field(&self, pairs: &[(Vector3<f64>, Matrix3<f64>)]) -> Option<Vector3<f64>> {
        let sum: Vector3<f64> = (pairs.iter()).map(|(b, r)| r.transpose() * (self.mounting * b)).sum();
        let norm = sum.norm();
        (norm > 0.0).then(|| sum / norm)
    }

    /// The mean squared disagreement over `pairs`, each row's counted up to
    /// [`MOST_COUNTED_DEG`]: a glitch of tens of degrees on a few rows does
    /// not choose the shift.
    fn cost(&self, pairs: &[(Vector3<f64>, Matrix3<f64>)]) -> f64 {
        let most = MOST_COUNTED_DEG.to_radians().powi(2);
        (pairs.iter())
            .map(|(b, r)| (self.mounting * b - r * self.field).norm_squared().min(most))
            .sum::<f64>()
            / pairs.len() as f64
    }
}

/// One run of disagreement, as indices into the check's usable rows:
/// `first..=last`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Run {
    first: usize,
    last: usize,
}

/// What one row's two sensors say of the field's direction in body axes:
/// the fluxgate's ($M\hat b_i$) and the INS's ($R_i u$).
type Seen = [Vector3<f64>; 2];

/// One fluxgate's disagreement with the INS on the usable rows.
struct Check<'a> {
    sensors: &'a Sensors<'a>,
    frame: Frame,
    /// The usable rows.
    rows: Vec<usize>,
    /// What each usable row's sensors see.
    seen: Vec<Seen>,
    /// The lag between the two sensors, as the coefficients of the INS
    /// view's first and second differences (per sample).
    lag: [f64; 2],
    /// The disagreement less the lag, degrees.
    d: Vec<Vector3<f64>>,
    /// The smallest abrupt step, degrees.
    threshold_deg: f64,
}

impl<'a> Check<'a> {
    /// The check of `sensors`, when enough rows are usable and the
    /// fluxgate follows the INS.
    fn of(sensors: &'a Sensors<'a>) -> Option<Check<'a>> {
        let rows: Vec<usize> = (0..sensors.usable.len()).filter(|&r| sensors.usable[r]).collect();
        if rows.len() < FEWEST_ROWS {
            return None;
        }
        let frame = Frame::fit(&sensors.pairs())?;
        let seen: Vec<Seen> = (rows.iter())
            .map(|&row| frame.seen(sensors.reading(row)))
            .collect::<Option<_>>()?;
        let mut check = Check {
            sensors,
            frame,
            rows,
            seen,
            lag: [0.0; 2],
            d: Vec::new(),
            threshold_deg: LEAST_DISAGREEMENT_DEG,
        };
        // A glitch disagrees by tens of degrees: the fit leaves out the rows
        // far from the flight's usual disagreement, and the rows beside
        // them (whose differences read them).
        let raw: Vec<Vector3<f64>> = check.seen.iter().map(|[fluxgate, ins]| fluxgate - ins).collect();
        let usual = Vector3::from_fn(|axis, _| median(&mut raw.iter().map(|r| r[axis]).collect::<Vec<_>>()));
        let off: Vec<f64> = raw.iter().map(|r| (r - usual).norm().to_degrees()).collect();
        let far = (LAG_FIT_MULTIPLE * median(&mut off.clone())).max(LEAST_DISAGREEMENT_DEG);
        let fitted = |i: usize| sensors.fitted[check.rows[i]];
        let near = |i: usize| fitted(i) && (i.saturating_sub(1)..=(i + 1).min(off.len() - 1)).all(|k| off[k] <= far);
        // A lag is a fraction of a sample and a smoothing over about one;
        // coefficients far beyond are not a lag but a fit pulled by
        // something else (a held step turning part of the flight), and
        // are not taken out.
        let lag = check.fitted_lag(near);
        check.lag = match lag.iter().all(|c| c.abs() <= MOST_LAG_SAMPLES) {
            true => lag,
            false => [0.0; 2],
        };
        check.d = (0..check.rows.len()).map(|i| check.lagged(&check.seen, 0, i)).collect();
        let mut sizes: Vec<f64> = check.d.iter().map(Vector3::norm).collect();
        if median(&mut sizes) > MOST_MEDIAN_DISAGREEMENT_DEG {
            return None;
        }
        let mut steps: Vec<f64> = (1..check.d.len())
            .filter_map(|k| check.step(k))
            .map(|s| s.norm())
            .collect();
        check.threshold_deg = (NOISE_MULTIPLE * median(&mut steps)).max(LEAST_DISAGREEMENT_DEG);
        Some(check)
    }

    /// The usable rows before and after `i`, each when it is near in time.
    fn neighbours(&self, i: usize) -> Option<(usize, usize)> {
        let near = |a: usize, b: usize| self.time(b) - self.time(a) <= LONGEST_STEP_S;
        (i >= 1 && i + 1 < self.rows.len() && near(i - 1, i) && near(i, i + 1)).then(|| (i - 1, i + 1))
    }

    /// The first and second differences of one sensor's view (`view`: 0
    /// the fluxgate's, 1 the INS's) about usable row `i`, per median sample
    /// interval, from `seen` (which starts at usable row `from`); zero without both neighbours. The differences follow the
    /// neighbours' times, so that a masked row beside `i` (its neighbour
    /// then two intervals away) changes neither.
    fn differences(&self, seen: &[Seen], from: usize, i: usize, view: usize) -> [Vector3<f64>; 2] {
        let Some((before, after)) = self.neighbours(i) else {
            return [Vector3::zeros(); 2];
        };
        let at = |k: usize| seen[k - from][view];
        let step = self.sensors.interval_s;
        let (h1, h2) = (
            (self.time(i) - self.time(before)) / step,
            (self.time(after) - self.time(i)) / step,
        );
        let ordered = |h: f64| h > 0.0 && h.is_finite();
        if !(ordered(h1) && ordered(h2)) {
            return [Vector3::zeros(); 2];
        }
        let (ahead, behind) = (at(after) - at(i), at(i) - at(before));
        let span = h1 + h2;
        [
            (ahead * (h1 / h2) + behind * (h2 / h1)) / span,
            (ahead / h2 - behind / h1) * (2.0 / span),
        ]
    }

    /// The lag that best explains the disagreement: least squares of the
    /// two sensors' difference on the INS view's differences, over the
    /// usable rows `kept`.
    fn fitted_lag(&self, kept: impl Fn(usize) -> bool) -> [f64; 2] {
        let (mut normal, mut right) = ([[0.0; 2]; 2], [0.0; 2]);
        for i in (0..self.rows.len()).filter(|&i| kept(i)) {
            let [rate, curve] = self.differences(&self.seen, 0, i, 1);
            let difference = self.seen[i][0] - self.seen[i][1];
            normal[0][0] += rate.dot(&rate);
            normal[0][1] += rate.dot(&curve);
            normal[1][1] += curve.dot(&curve);
            right[0] += rate.dot(&difference);
            right[1] += curve.dot(&difference);
        }
        let det = normal[0][0] * normal[1][1] - normal[0][1] * normal[0][1];
        if det.is_nan() || det <= 1e-12 * (normal[0][0] * normal[1][1]).max(f64::MIN_POSITIVE) {
            return [0.0; 2];
        }
        [
            (right[0] * normal[1][1] - right[1] * normal[0][1]) / det,
            (right[1] * normal[0][0] - right[0] * normal[0][1]) / det,
        ]
    }

    /// The disagreement of usable row `i` less the lag, degrees, from
    /// `seen` (which starts at usable row `from`).
    fn lagged(&self, seen: &[Seen], from: usize, i: usize) -> Vector3<f64> {
        let [rate, curve] = self.differences(seen, from, i, 1);
        let [fluxgate, ins] = seen[i - from];
        (fluxgate - ins - self.lag[0] * rate - self.lag[1] * curve).map(f64::to_degrees)
    }

    /// The step from usable row `k − 1` to `k`; `None` across a long gap.
    fn step(&self, k: usize) -> Option<Vector3<f64>> {
        (self.time(k) - self.time(k - 1) <= LONGEST_STEP_S).then(|| self.d[k] - self.d[k - 1])
    }

    /// What the disagreement may move beyond its smooth progression over
    /// `seconds`, degrees.
    fn allowed(&self, seconds: f64) -> f64 {
        self.threshold_deg * (1.0 + seconds)
    }

    /// The time of usable row `i`, s.
    fn time(&self, i: usize) -> f64 {
        self.sensors.time_s[self.rows[i]]
    }

    /// The runs of disagreement: where the disagreement steps by more than
    /// half the threshold, and steps again within [`REACH_S`], the rows
    /// between that lie further than the threshold from the line between
    /// the medians of the second before and the second after, those
    /// seconds themselves all within it.
    fn runs(&self) -> Vec<Run> {
        let moves: Vec<usize> = (1..self.d.len())
            .filter(|&k| self.step(k).is_some_and(|step| step.norm() > 0.5 * self.threshold_deg))
            .collect();
        let mut runs = Vec::new();
        let mut i = 0;
        while i < moves.len() {
            let start = moves[i];
            let mut j = i;
            while j + 1 < moves.len() && self.time(moves[j + 1]) - self.time(start) <= REACH_S + BRACKET_S {
                j += 1;
            }
            runs.extend(self.bracketed(start, moves[j]));
            i = j + 1;
        }
        runs
    }

    /// The run among usable rows `start..end` (from the first move to the
    /// step of the last), when the second either side agrees with its
    /// line and a row between departs from it.
    fn bracketed(&self, start: usize, end: usize) -> Option<Run> {
        let width = ((BRACKET_S / self.sensors.interval_s).round() as usize).max(5);
        let (left, right) = (start.checked_sub(width)?..start, end..end + width);
        if right.end > self.d.len() || self.time(right.end - 1) - self.time(left.start) > REACH_S + 4.0 * BRACKET_S {
            return None;
        }
        let level = |range: std::ops::Range<usize>| {
            let time = range.clone().map(|i| self.time(i)).sum::<f64>() / range.len() as f64;
            let values =
                Vector3::from_fn(|axis, _| median(&mut range.clone().map(|i| self.d[i][axis]).collect::<Vec<_>>()));
            (time, values)
        };
        let ((t0, d0), (t1, d1)) = (level(left.clone()), level(right.clone()));
        let offset = |i: usize| self.d[i] - (d0 + (self.time(i) - t0) / (t1 - t0) * (d1 - d0));
        if left.chain(right).any(|i| offset(i).norm() > self.threshold_deg) {
            return None;
        }
        let departs = |i: usize| {
            offset(i).norm() > self.threshold_deg
                || (i >= 1 && i + 1 < self.d.len())
                    && (offset(i - 1) + offset(i) + offset(i + 1)).norm() > self.threshold_deg
        };
        let first = (start..=end).find(|&i| departs(i))?;
        let last = (start..=end).rev().find(|&i| departs(i))?;
        // The lag terms spread a glitch of the INS a row each side: the
        // glitch may lie a row beyond the rows that depart.
        Some(Run {
            first: first.saturating_sub(1),
            last: (last + 1).min(end),
        })
    }

    /// How far the disagreement about `run` (one row beyond it each side,
    /// which the lag reads) lies from the line between the rows two beyond
    /// it, row by row or summed over three rows, degrees, with the run's rows marked in `repair` (a channel 0–5
    /// and one mark per row of the run) read along the line between that
    /// channel's readings either side of each stretch of marked rows
    /// (`None`: as recorded); `None` when the run is too near the
    /// record's ends.
    fn departure(&self, run: &Run, repair: Option<(usize, &[bool])>) -> Option<f64> {
        let (from, to) = (run.first.checked_sub(2)?, run.last + 2);
        if to >= self.rows.len() {
            return None;
        }
        let mut seen = self.seen[from..=to].to_vec();
        if let Some((channel, marked)) = repair {
            let mut i = run.first;
            while i <= run.last {
                if !marked[i - run.first] {
                    i += 1;
                    continue;
                }
                let end = (i..=run.last).take_while(|&j| marked[j - run.first]).count() + i;
                self.bridge(channel, (i - 1, end), (&mut seen, from))?;
                i = end;
            }
        }
        let (start, end) = (self.d[from], self.d[to]);
        let span = self.time(to) - self.time(from);
        let off: Vec<Vector3<f64>> = ((run.first - 1)..=(run.last + 1))
            .map(|i| self.lagged(&seen, from, i) - (start + (self.time(i) - self.time(from)) / span * (end - start)))
            .collect();
        // Row by row, and three rows at a time: the lag terms spread a
        // glitch of the INS over its row and the two beside it, and the
        // three sum to it.
        let rows = off.iter().map(Vector3::norm);
        let threes = off.windows(3).map(|w| (w[0] + w[1] + w[2]).norm());
        rows.chain(threes).reduce(f64::max)
    }

    /// Reads `channel` (0–5) on the usable rows strictly between `before`
    /// and `after` along the line between its readings there, into `seen`
    /// (which starts at usable row `from`).
    fn bridge(
        &self,
        channel: usize,
        (before, after): (usize, usize),
        (seen, from): (&mut [Seen], usize),
    ) -> Option<()> {
        let outside = [before, after].map(|i| self.sensors.reading(self.rows[i]));
        let (a, b) = (outside[0][channel], outside[1][channel]);
        // A heading is read across north.
        let change = match channel {
            2 => (b - a + 180.0).rem_euclid(360.0) - 180.0,
            _ => b - a,
        };
        let span = self.time(after) - self.time(before);
        for i in before + 1..after {
            let share = (self.time(i) - self.time(before)) / span;
            let mut reading = self.sensors.reading(self.rows[i]);
            reading[channel] = a + share * change;
            seen[i - from] = self.frame.seen(reading)?;
        }
        Some(())
    }

    /// What is allowed over `run`, degrees: the threshold over its span,
    /// and a share of how sharply both sensors see the aircraft turn there
    /// ([`Check::sharpness`]).
    fn allowed_over(&self, run: &Run) -> f64 {
        let (from, to) = (run.first.saturating_sub(2), (run.last + 2).min(self.rows.len() - 1));
        self.allowed(self.time(to) - self.time(from)) + SHARP_SHARE * self.sharpness(run)
    }

    /// How sharply both sensors see the aircraft turn about `run` (a row
    /// beyond it each side), degrees per median interval squared: the
    /// larger second difference of each sensor's view, the smaller of the
    /// two. A glitch is seen by one sensor only, and the other's view stays
    /// smooth; a turn whose rate steps within a sample (a roll snapped in
    /// or out) is seen by both.
    fn sharpness(&self, run: &Run) -> f64 {
        let rows = run.first.saturating_sub(1)..=(run.last + 1).min(self.rows.len() - 1);
        let sharpest = |view: usize| {
            (rows.clone())
                .map(|i| self.differences(&self.seen, 0, i, view)[1].norm())
                .fold(0.0, f64::max)
        };
        sharpest(0).min(sharpest(1)).to_degrees()
    }

    /// The channels (0–5) to mask, and their rows (indices into the usable
    /// rows): the channel whose repair restores the run's agreement over
    /// the fewest rows (then the nearest agreement); all six over the run
    /// when none does; none when the run is within what is allowed as
    /// recorded.
    fn culprits(&self, run: &Run) -> Vec<(usize, Vec<usize>)> {
        let allowed = self.allowed_over(run);
        let Some(recorded) = self.departure(run, None) else {
            return Vec::new();
        };
        if recorded <= allowed {
            return Vec::new();
        }
        let repaired = (0..6)
            .filter_map(|channel| Some((channel, self.repair(run, channel)?)))
            .min_by(|(_, a), (_, b)| a.0.len().cmp(&b.0.len()).then(a.1.total_cmp(&b.1)));
        match repaired {
            Some((channel, (rows, _))) => vec![(channel, rows)],
            None => (0..6)
                .map(|channel| (channel, (run.first..=run.last).collect()))
                .collect(),
        }
    }

    /// The held steps: a step of the disagreement by more than the
    /// threshold, outside every run, from a second that agrees with its
    /// level to a second that agrees with another, made by one channel
    /// alone (a heading realigned, an attitude or an axis offset that
    /// stays). Each is given as the channel (0–5) and the log rows it is
    /// off on: from the step to that channel's step back (an opposite
    /// held step undoing at least three quarters of it) or to the end of
    /// the record.
    fn held(&self, runs: &[Run], judged: bool) -> Vec<(usize, (usize, usize))> {
        let width = ((BRACKET_S / self.sensors.interval_s).round() as usize).max(5);
        let in_run = |k: usize| runs.iter().any(|r| r.first <= k && k <= r.last + 1);
        // The lag terms spread a step over its row and the two beside it:
        // each row whose step is over half the threshold is tried, and of
        // steps found a row or two apart, the largest jump is kept.
        let mut steps: Vec<(usize, usize, f64)> = Vec::new();
        // A first look reads the disagreement as recorded: a fit a held
        // step has pulled may take out a lag that is not there.
        let moved = |k: usize| match judged {
            true => self.step(k).map(|s| s.norm()),
            false => {
                (self.time(k) - self.time(k - 1) <= LONGEST_STEP_S).then(|| (self.raw(k) - self.raw(k - 1)).norm())
            }
        };
        let tried = (width + 2..self.d.len().saturating_sub(width + 2))
            .filter(|&k| !in_run(k) && moved(k).is_some_and(|s| s > 0.5 * self.threshold_deg));
        let at = |k: usize| match judged {
            true => self.held_at(k, width),
            false => self.suspected_at(k),
        };
        for (k, channel, jump) in tried.filter_map(|k| at(k).map(|(c, j)| (k, c, j))) {
            match steps.last_mut() {
                Some(last) if k - last.0 <= 2 && last.1 == channel => {
                    if jump.abs() > last.2.abs() {
                        *last = (k, channel, jump);
                    }
                }
                _ => steps.push((k, channel, jump)),
            }
        }
        self.stretches(&steps)
    }

    /// The log rows each held step (usable row, channel, jump) leaves its
    /// channel off, from the step to its step back.
    fn stretches(&self, steps: &[(usize, usize, f64)]) -> Vec<(usize, (usize, usize))> {
        let end = self.sensors.time_s.len();
        let mut found = Vec::new();
        let mut i = 0;
        while i < steps.len() {
            let (k, channel, jump) = steps[i];
            let back = (steps[i + 1..].iter().enumerate())
                .find(|(_, &(_, c, j))| c == channel && (jump + j).abs() <= 0.25 * jump.abs());
            let from = self.sensors.row_of(channel, self.rows[k]);
            match back {
                Some((offset, &(k2, _, _))) => {
                    found.push((channel, (from, self.sensors.row_of(channel, self.rows[k2]))));
                    i += offset + 2;
                }
                // A step that never steps back leaves the flight in two
                // parts, and the agreement alone cannot say which is
                // turned (a constant offset is taken into the frame):
                // the shorter part is masked, the frame being the rest's.
                // Where the disagreement's step back (or out) was within
                // the threshold, the channel's own opposite jump, beyond
                // its neighbours', closes the stretch.
                None => {
                    let row = |k: usize| self.sensors.row_of(channel, self.rows[k]);
                    let later = self.opposite(channel, jump, k + 1..self.rows.len().saturating_sub(1));
                    let earlier = self.opposite(channel, jump, (2..k.saturating_sub(1)).rev());
                    match (later, earlier) {
                        (Some(k2), _) => {
                            found.push((channel, (from, row(k2))));
                            while i < steps.len() && steps[i].0 <= k2 {
                                i += 1;
                            }
                        }
                        (None, Some(k0)) => {
                            found.push((channel, (row(k0), from)));
                            i += 1;
                        }
                        (None, None) => {
                            let shorter = match end - from <= from {
                                true => (from, end),
                                false => (0, from),
                            };
                            found.push((channel, shorter));
                            break;
                        }
                    }
                }
            }
        }
        // A step and its step back within the reach of a run are a
        // glitch's, judged as runs are, not a held step.
        let time_s = self.sensors.time_s;
        found.retain(|&(_, (from, to))| from == 0 || to == end || time_s[to - 1] - time_s[from] > REACH_S);
        found
    }

    /// The first usable row of `rows` where `channel` jumps back by the
    /// `jump` it made (within a quarter of it), beyond its neighbours'
    /// steps.
    fn opposite(&self, channel: usize, jump: f64, mut rows: impl Iterator<Item = usize>) -> Option<usize> {
        rows.find(|&i| {
            self.jump(channel, i)
                .is_some_and(|j| (jump + j).abs() <= 0.25 * jump.abs())
        })
    }

    /// The disagreement of usable row `i` as recorded (no lag taken out),
    /// degrees.
    fn raw(&self, i: usize) -> Vector3<f64> {
        (self.seen[i][0] - self.seen[i][1]).map(f64::to_degrees)
    }

    /// The channel (0–5) whose jump at usable row `k`, taken out of its
    /// readings from there on, takes out the disagreement's step across
    /// the rows two either side (over which the lag terms spread it), and
    /// that jump; `None` when the step is within the threshold or no one
    /// channel's jump explains it. A first look, on a fit a held step may
    /// have turned.
    fn suspected_at(&self, k: usize) -> Option<(usize, f64)> {
        let (from, to) = (k.checked_sub(3)?, k + 3);
        if to >= self.d.len() {
            return None;
        }
        let step = (self.raw(k + 2) - self.raw(k - 2)).norm();
        if step <= self.threshold_deg {
            return None;
        }
        let repaired = |channel: usize| -> Option<(f64, f64)> {
            let jump = self.jump(channel, k)?;
            let mut seen = self.seen[from..=to].to_vec();
            for i in k..=to {
                let mut reading = self.sensors.reading(self.rows[i]);
                reading[channel] -= jump;
                seen[i - from] = self.frame.seen(reading)?;
            }
            let raw = |i: usize| (seen[i - from][0] - seen[i - from][1]).map(f64::to_degrees);
            let left = (raw(k + 2) - raw(k - 2)).norm();
            // Where the fit is pulled (a shift or a lag chosen wrongly),
            // a manoeuvre leaves some of the step: a suspicion needs
            // three quarters of it taken out, the judgement (against a
            // fit that did not see it) the rest.
            (left <= 0.5 * self.threshold_deg || left <= 0.25 * step).then_some((jump, left))
        };
        (0..6)
            .filter_map(|channel| Some((channel, repaired(channel)?)))
            .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
            .map(|(channel, (jump, _))| (channel, jump))
    }

    /// The channel (0–5) that alone makes the held step at usable row `k`
    /// (brackets of `width` rows either side), and its jump there; `None`
    /// when the step is not held or no one channel makes it.
    fn held_at(&self, k: usize, width: usize) -> Option<(usize, f64)> {
        let (before, after) = (k - 1 - width..k - 1, k + 1..k + 1 + width);
        if self.time(after.end - 1) - self.time(before.start) > 4.0 * BRACKET_S {
            return None;
        }
        // Each second's line, drawn to the step: the disagreement drifts
        // smoothly as the aircraft manoeuvres, and the second is steady
        // when it keeps to its line.
        let at = (self.time(k - 1) + self.time(k)) / 2.0;
        let (left, right) = (
            self.drawn(before.clone(), &self.d[before.clone()], at)?,
            self.drawn(after.clone(), &self.d[after.clone()], at)?,
        );
        if (right - left).norm() <= self.threshold_deg {
            return None;
        }
        // Each channel read less its jump from the step on: the one that
        // brings the second after back to the second before's line.
        let from = k - 2;
        let repaired = |channel: usize| -> Option<(f64, f64)> {
            let jump = self.jump(channel, k)?;
            let mut seen = self.seen[from..after.end + 1].to_vec();
            for i in k..from + seen.len() {
                let mut reading = self.sensors.reading(self.rows[i]);
                reading[channel] -= jump;
                seen[i - from] = self.frame.seen(reading)?;
            }
            let d: Vec<Vector3<f64>> = after.clone().map(|i| self.lagged(&seen, from, i)).collect();
            let left_over = (self.drawn(after.clone(), &d, at)? - left).norm();
            (left_over <= self.threshold_deg).then_some((jump, left_over))
        };
        (0..6)
            .filter_map(|channel| Some((channel, repaired(channel)?)))
            .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
            .map(|(channel, (jump, _))| (channel, jump))
    }

    /// The least-squares line of `d` (the disagreement on usable rows
    /// `range`) at time `at`, when every row keeps within the threshold of
    /// the line.
    fn drawn(&self, range: std::ops::Range<usize>, d: &[Vector3<f64>], at: f64) -> Option<Vector3<f64>> {
        let times: Vec<f64> = range.map(|i| self.time(i) - at).collect();
        let n = times.len() as f64;
        let mean_t = times.iter().sum::<f64>() / n;
        let mean_d = d.iter().sum::<Vector3<f64>>() / n;
        let spread = times.iter().map(|t| (t - mean_t).powi(2)).sum::<f64>();
        if spread.is_nan() || spread <= 0.0 {
            return None;
        }
        let slope = (times.iter().zip(d))
            .map(|(t, v)| (t - mean_t) * (v - mean_d))
            .sum::<Vector3<f64>>()
            / spread;
        let line = |t: f64| mean_d + (t - mean_t) * slope;
        (times.iter().zip(d))
            .all(|(t, v)| (v - line(*t)).norm() <= self.threshold_deg)
            .then(|| line(0.0))
    }

    /// The jump of `channel` (0–5) from usable row `k − 1` to `k` beyond
    /// the mean of its steps either side (a heading across north).
    fn jump(&self, channel: usize, k: usize) -> Option<f64> {
        if k < 2 || k + 1 >= self.rows.len() {
            return None;
        }
        let value = |i: usize| self.sensors.reading(self.rows[i])[channel];
        let change = |a: usize, b: usize| match channel {
            2 => (value(b) - value(a) + 180.0).rem_euclid(360.0) - 180.0,
            _ => value(b) - value(a),
        };
        Some(change(k - 1, k) - 0.5 * (change(k - 2, k - 1) + change(k, k + 1)))
    }

    /// The fewest rows of `run` whose repair of `channel` restores the
    /// agreement within what is allowed, and the departure left: the rows
    /// are read along the channel's line across the run one by one, from
    /// the one that departs furthest from that line, until the run agrees.
    /// The lag spreads a glitch of the INS over the rows beside it, and
    /// two glitches a few rows apart make one run: the good rows among
    /// them are not masked. `None` when no such rows restore it.
    fn repair(&self, run: &Run, channel: usize) -> Option<(Vec<usize>, f64)> {
        let allowed = self.allowed_over(run);
        let reading = |i: usize| self.sensors.reading(self.rows[i])[channel];
        let (a, b) = (reading(run.first - 1), reading(run.last + 1));
        let across = |value: f64| match channel {
            2 => (value - a + 180.0).rem_euclid(360.0) - 180.0,
            _ => value - a,
        };
        let span = self.time(run.last + 1) - self.time(run.first - 1);
        let off_line = |i: usize| {
            let share = (self.time(i) - self.time(run.first - 1)) / span;
            (across(reading(i)) - share * across(b)).abs()
        };
        let mut order: Vec<usize> = (0..=run.last - run.first).collect();
        order.sort_by(|&j, &k| {
            off_line(run.first + k)
                .total_cmp(&off_line(run.first + j))
                .then(j.cmp(&k))
        });
        let mut marked = vec![false; order.len()];
        for k in order {
            marked[k] = true;
            let departure = self.departure(run, Some((channel, &marked)))?;
            if departure <= allowed {
                let rows = (run.first..=run.last).filter(|i| marked[i - run.first]).collect();
                return Some((rows, departure));
            }
        }
        None
    }
}

/// The median of `values` (reordered), 0 when empty.
pub(crate) fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let middle = values.len() / 2;
    *values.select_nth_unstable_by(middle, f64::total_cmp).1
}
