//! Attitude-independent scalar calibration of a vector magnetometer.
//!
//! A fluxgate reads $m = K\,b + o$: the field $b$ distorted by its scale
//! factors and non-orthogonality (K) and shifted by its offsets (o); the
//! aircraft's own field at the fluxgate (hard and soft iron) has the same
//! form. The scalar magnetometers read $|b|$ without either error, so over
//! a flight that turns through many attitudes the nine numbers of
//!
//! $$\hat b = C\,(m - o), \qquad C = K^{-1} \text{ lower-triangular},$$
//!
//! follow from $|C(m_i - o)| = F_i$ alone, with no knowledge of the
//! attitude (Gebre-Egziabher et al. 2006; Foster & Elkaim 2008; Crassidis
//! et al. 2005). A rotation of the sensor is not observable this way;
//! taking C lower-triangular fixes it (the x axis keeps its direction, y
//! stays in the x-y plane).
//!
//! Steps:
//! 1. **Ellipsoid fit.** $(m-o)^\top A (m-o) = F^2$ with $A = C^\top C$ is
//!    a quadric in m, linear in its ten coefficients; the quadric closest
//!    to the readings comes from the SVD of the R factor of the ten
//!    monomial columns (never their normal equations), on readings scaled
//!    to about one. One step of Levenberg-Marquardt is taken from it (when
//!    $A$ comes out positive definite) and one from the identity (a
//!    factory-calibrated fluxgate is close to it); the rest go on from the
//!    one that went further down. A calibration of nearly the same rows
//!    (a heading's windows held out of the whole flight's) starts from
//!    the whole flight's instead.
//! 2. **Levenberg-Marquardt** on the residuals $|C(m_i - o)| - F_i$ for the
//!    nine parameters, with the analytic Jacobian: Marquardt's diagonal
//!    scaling on the 9×9 normal equations, accumulated in one streaming
//!    pass over the rows (no n×9 Jacobian is stored), stopping when the
//!    cost falls by less than 1e-14 of itself.
//!
//! Why not the `levenberg-marquardt` crate (MINPACK's `lmder`, Moré 1978):
//! it was tried and measured. On clean synthetic readings the two agree to
//! 1e-10 in the parameters at the same speed. On a flight whose fluxgate
//! also sees the aircraft's own field, the problem has a shallow valley.
//! There the crate's trust region needs hundreds of evaluations to meet
//! its step tolerance, and each evaluation stores and factors an n×9
//! Jacobian where this solver streams one 9×9 sum. The diagnosis was 15
//! times slower with the crate's own stopping rule, and a fifth slower
//! with the same budget of 100 (figures: docs/measurements.md, section
//! calibration::fluxgate: the Levenberg-Marquardt solver).
//!
//! The scalar reference carries its own aircraft interference (a few nT on
//! a tail stinger), which sets the floor of the residual; the quietest
//! scalar channel is the default reference.

use std::ops::Range;

use faer::Mat;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibration::windows::Calibration;
use crate::calibration::windows::CalibrationWindow;
use crate::error::{Error, Result};
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::numerics::linalg::{solve_spd, tall_skinny_r};

/// `[vector_calibration]` settings: a pipeline stage that calibrates the
/// fluxgate against a scalar channel before the Tolles-Lawson fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VectorCalibrationOptions {
    /// Calibrate the fluxgate before fitting.
    pub enabled: bool,
    /// Scalar channel whose total field is the reference; the quietest
    /// scalar channel on the calibration windows when absent.
    pub reference: Option<String>,
    /// Calibrate on every valid row of the flight (`true`) or only on the
    /// calibration windows (`false`).
    pub whole_flight: bool,
    /// Most Levenberg-Marquardt iterations.
    pub max_iterations: usize,
}

impl Default for VectorCalibrationOptions {
    fn default() -> Self {
        VectorCalibrationOptions {
            enabled: false,
            reference: None,
            whole_flight: true,
            max_iterations: 100,
        }
    }
}

/// A fitted calibration: $\hat b = C(m - o)$, and the error model
/// $m = K b + o$ it implies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VectorCalibration {
    /// Vector magnetometer prefix.
    pub sensor: String,
    /// Scalar channel used as the reference total field.
    pub reference: String,
    /// C, lower-triangular, row by row.
    pub correction: [[f64; 3]; 3],
    /// o, nT.
    pub offset_nt: [f64; 3],
    /// Scale factor of each axis (row norms of K = C⁻¹; 1 is perfect).
    pub scale: [f64; 3],
    /// Non-orthogonality (xy, xz, yz): how far the y axis leans towards x,
    /// and the z axis towards x and towards y, degrees.
    pub non_orthogonality_deg: [f64; 3],
    /// Rows used.
    pub samples: usize,
    /// Levenberg-Marquardt iterations taken.
    pub iterations: usize,
    /// RMS of $|m| - F$ about its mean before calibration, nT.
    pub mismatch_rms_before_nt: f64,
    /// RMS of $|C(m - o)| - F$ after, nT.
    pub mismatch_rms_after_nt: f64,
    /// Condition number of the final Jacobian (columns scaled to unit
    /// norm): how well the flight's attitudes pin the nine parameters.
    pub condition_number: f64,
    /// One-sigma uncertainty of the nine parameters: C's six entries
    /// (row by row, lower triangle) and the three offsets (nT), from the
    /// Jacobian and the residual, whose samples are counted as
    /// independent only as far as its lag-one autocorrelation allows.
    #[serde(default)]
    pub uncertainty: [f64; 9],
}

/// Fewest rows a calibration needs.
const MIN_SAMPLES: usize = 100;

/// Above this Jacobian condition number the attitudes flown do not pin
/// the nine parameters.
const CONDITION_LIMIT: f64 = 1e8;

/// Largest one-sigma uncertainty of an entry of C for a usable calibration
/// (1 % of scale, about 0.6° of angle). A calibration box, which turns the
/// sensor through many attitudes, pins them an order of magnitude or more
/// below it; a short stretch of straight survey flight leaves them far
/// above it (measured figures: docs/measurements.md, section
/// calibration::fluxgate).
const MAX_MATRIX_UNCERTAINTY: f64 = 0.01;

/// Largest one-sigma uncertainty of an offset for a usable calibration, nT
/// (1 % of the Earth's field; measured figures: docs/measurements.md,
/// section calibration::fluxgate).
const MAX_OFFSET_UNCERTAINTY_NT: f64 = 500.0;

/// Fits the calibration of `sensor` against scalar channel `reference` on
/// `rows` of the flight (every row when empty).
pub fn calibrate(
    log: &FlightLog,
    sensor: &VectorSensor,
    reference: &str,
    rows: &[Range<usize>],
    max_iterations: usize,
) -> Result<VectorCalibration> {
    calibrate_from(log, sensor, (reference, rows), max_iterations, None)
}

/// [`calibrate`], starting from `near`: a calibration of the same sensor
/// on much the same rows (the whole flight's, for a calibration with one
/// heading's windows held out), whose optimum lies a few steps away.
pub fn calibrate_near(
    log: &FlightLog,
    sensor: &VectorSensor,
    (reference, rows): (&str, &[Range<usize>]),
    max_iterations: usize,
    near: &VectorCalibration,
) -> Result<VectorCalibration> {
    calibrate_from(log, sensor, (reference, rows), max_iterations, Some(near))
}

/// The fit's one-sigma parameter uncertainty (offsets in nT), or an error
/// in words when it is too large to use (the flight's attitudes do not pin
/// the parameters); `unit` is the field's unit the samples `m` and `f`
/// were scaled by.
fn pinned_uncertainty(
    m: &[[f64; 3]],
    f: &[f64],
    fitted: &Parameters,
    unit: f64,
) -> std::result::Result<[f64; 9], String> {
    let uncertainty = parameter_uncertainty(m, f, fitted).map(|u| {
        let mut u = u;
        for o in &mut u[6..] {
            *o *= unit;
        }
        u
    });
    let uncertainty = uncertainty.unwrap_or([f64::INFINITY; 9]);
    let worst_matrix = uncertainty[..6].iter().fold(0.0f64, |a, &b| a.max(b));
    let worst_offset = uncertainty[6..].iter().fold(0.0f64, |a, &b| a.max(b));
    if !(worst_matrix <= MAX_MATRIX_UNCERTAINTY && worst_offset <= MAX_OFFSET_UNCERTAINTY_NT) {
        return Err(format!(
            "the flight's attitudes do not pin the fluxgate calibration: its correction is uncertain by up to ±{worst_matrix:.3} and its offsets by up to ±{worst_offset:.0} nT (one sigma; at most ±{MAX_MATRIX_UNCERTAINTY} and ±{MAX_OFFSET_UNCERTAINTY_NT} nT are usable); calibrate on a flight with turns through all headings and pitch and roll manoeuvres"
        ));
    }
    Ok(uncertainty)
}

/// The rows of `rows` (every row when empty) where the scalar reads a
/// positive field and the fluxgate reads all three axes.
fn usable_rows(scalar: &[f64], field: [&[f64]; 3], rows: &[Range<usize>]) -> Vec<usize> {
    let every = 0..scalar.len();
    let ranges = if rows.is_empty() {
        std::slice::from_ref(&every)
    } else {
        rows
    };
    ranges
        .iter()
        .flat_map(Clone::clone)
        .filter(|&i| scalar[i].is_finite() && field.iter().all(|c| c[i].is_finite()) && scalar[i] > 0.0)
        .collect()
}

impl VectorCalibration {
    /// This calibration as the fit's parameters, offsets in `unit`s of the
    /// field: the start of a refit near it.
    fn start(&self, unit: f64) -> Parameters {
        let c = self.correction;
        let o = self.offset_nt.map(|o| o / unit);
        Parameters([c[0][0], c[1][0], c[1][1], c[2][0], c[2][1], c[2][2], o[0], o[1], o[2]])
    }
}

fn calibrate_from(
    log: &FlightLog,
    sensor: &VectorSensor,
    (reference, rows): (&str, &[Range<usize>]),
    max_iterations: usize,
    near: Option<&VectorCalibration>,
) -> Result<VectorCalibration> {
    let fail = |message: String| Error::Fit {
        path: log.source().to_path_buf(),
        channel: sensor.prefix.clone(),
        source: crate::error::FitFailure::Other(message),
    };
    let scalar = &log
        .channel(reference)
        .ok_or_else(|| {
            fail(format!(
                "the reference scalar channel '{reference}' is not in the flight"
            ))
        })?
        .values;
    let field = log.vector_components(sensor);
    let used = usable_rows(scalar, field, rows);
    if used.len() < MIN_SAMPLES {
        return Err(fail(format!(
            "calibrating against '{reference}' needs at least {MIN_SAMPLES} rows where both are valid, found {}",
            used.len()
        )));
    }
    // Work in units of the median total field so every parameter is near 0 or 1.
    let mut totals: Vec<f64> = used.iter().map(|&i| scalar[i]).collect();
    totals.sort_by(f64::total_cmp);
    let unit = totals[totals.len() / 2];
    let m: Vec<[f64; 3]> = used.iter().map(|&i| [0, 1, 2].map(|a| field[a][i] / unit)).collect();
    let f: Vec<f64> = used.iter().map(|&i| scalar[i] / unit).collect();

    let (fitted, iterations) = match near {
        Some(near) => levenberg_marquardt(&m, &f, (near.start(unit), NEAR_DAMPING), max_iterations),
        None => fit_from_best_start(&m, &f, max_iterations),
    };
    let condition_number = jacobian_condition(&m, &fitted);
    if condition_number.is_nan() || condition_number >= CONDITION_LIMIT {
        return Err(fail(format!(
            "the flight's attitudes do not determine the fluxgate calibration (condition number {condition_number:.1e}); calibrate on a flight with turns through all headings and pitch and roll manoeuvres"
        )));
    }
    let uncertainty = pinned_uncertainty(&m, &f, &fitted, unit).map_err(fail)?;
    let before: Vec<f64> = m.iter().zip(&f).map(|(v, f)| (norm(*v) - f) * unit).collect();
    let mean = before.iter().sum::<f64>() / before.len() as f64;
    let mismatch_rms_before_nt = rms(before.iter().map(|v| v - mean));
    let mismatch_rms_after_nt = rms(m.iter().zip(&f).map(|(v, f)| fitted.residual(v, *f) * unit));
    let correction = fitted.matrix();
    let (scale, non_orthogonality_deg) = error_model(&correction);
    Ok(VectorCalibration {
        sensor: sensor.prefix.clone(),
        reference: reference.to_string(),
        correction,
        offset_nt: fitted.offset().map(|o| o * unit),
        scale,
        non_orthogonality_deg,
        samples: used.len(),
        iterations,
        mismatch_rms_before_nt,
        mismatch_rms_after_nt,
        condition_number,
        uncertainty,
    })
}

impl VectorCalibration {
    /// The calibrated reading $C(m - o)$ of one sample.
    pub fn correct(&self, reading: [f64; 3]) -> [f64; 3] {
        let v = [0, 1, 2].map(|a| reading[a] - self.offset_nt[a]);
        [0, 1, 2].map(|r| (0..3).map(|c| self.correction[r][c] * v[c]).sum())
    }

    /// The flight with the fluxgate's three columns calibrated (same names;
    /// missing samples stay missing).
    pub fn apply(&self, log: &FlightLog, sensor: &VectorSensor) -> Result<FlightLog> {
        let field = log.vector_components(sensor);
        let corrected: Vec<[f64; 3]> = (0..log.len())
            .map(|i| self.correct([field[0][i], field[1][i], field[2][i]]))
            .collect();
        let mut calibrated = log.clone();
        for (axis, &index) in sensor.axes.iter().enumerate() {
            let name = &log.channels()[index].name;
            calibrated = calibrated.with_values(name, corrected.iter().map(|b| b[axis]).collect())?;
        }
        Ok(calibrated)
    }

    /// The calibration as a note: what it was calibrated against, its
    /// scale, non-orthogonality and offset, and the mismatch it removed.
    pub fn summary(&self) -> crate::messages::Note {
        crate::messages::Note::FluxgateCalibrated {
            sensor: self.sensor.clone(),
            reference: self.reference.clone(),
            scale: self.scale,
            non_orthogonality_deg: self.non_orthogonality_deg,
            offset_nt: self.offset_nt,
            mismatch_rms_nt: [self.mismatch_rms_before_nt, self.mismatch_rms_after_nt],
            rows: self.samples,
        }
    }
}

/// Calibrates against each of `references` and keeps the one that leaves
/// the smallest residual: the scalar with the least aircraft interference
/// of its own. Candidates that cannot be calibrated against are skipped;
/// the error of the first is returned when none can.
pub fn calibrate_best(
    log: &FlightLog,
    sensor: &VectorSensor,
    references: &[String],
    rows: &[Range<usize>],
    max_iterations: usize,
) -> Result<VectorCalibration> {
    use rayon::prelude::*;
    let results: Vec<Result<VectorCalibration>> = references
        .par_iter()
        .map(|r| calibrate(log, sensor, r, rows, max_iterations))
        .collect();
    let best = results
        .iter()
        .filter_map(|r| r.as_ref().ok())
        .min_by(|a, b| a.mismatch_rms_after_nt.total_cmp(&b.mismatch_rms_after_nt))
        .cloned();
    match best {
        Some(best) => Ok(best),
        None => match results.into_iter().next() {
            Some(Err(error)) => Err(error),
            _ => Err(Error::Fit {
                path: log.source().to_path_buf(),
                channel: sensor.prefix.clone(),
                source: crate::error::FitFailure::Other("no scalar channel to calibrate the fluxgate against".into()),
            }),
        },
    }
}

/// The `[vector_calibration]` stage: `None` when it is off.
pub fn calibrate_stage(
    calibration: &Calibration,
    options: &VectorCalibrationOptions,
) -> Result<Option<VectorCalibration>> {
    if !options.enabled {
        return Ok(None);
    }
    let rows = match options.whole_flight {
        true => Vec::new(),
        false => window_rows(calibration.log, calibration.windows),
    };
    let references = match &options.reference {
        Some(reference) => vec![reference.clone()],
        None => calibration.channels.to_vec(),
    };
    let (log, sensor) = (calibration.log, calibration.sensor);
    calibrate_best(log, sensor, &references, &rows, options.max_iterations).map(Some)
}

/// The rows of the calibration windows, for [`calibrate`].
pub fn window_rows(log: &FlightLog, windows: &[CalibrationWindow]) -> Vec<Range<usize>> {
    windows.iter().map(|w| w.rows(log.time_s())).collect()
}

/// Scale factors and non-orthogonality angles of $K = C^{-1}$ (see
/// `simulate::physics::FluxgateErrors`: row i of K is the direction of
/// axis i times its scale).
fn error_model(c: &[[f64; 3]; 3]) -> ([f64; 3], [f64; 3]) {
    // Inverse of a lower-triangular matrix.
    let k00 = 1.0 / c[0][0];
    let k11 = 1.0 / c[1][1];
    let k22 = 1.0 / c[2][2];
    let k10 = -c[1][0] * k00 * k11;
    let k21 = -c[2][1] * k11 * k22;
    let k20 = -(c[2][0] * k00 + c[2][1] * k10) * k22;
    let k = [[k00, 0.0, 0.0], [k10, k11, 0.0], [k20, k21, k22]];
    let scale = k.map(norm);
    let angle = |v: f64| v.clamp(-1.0, 1.0).asin().to_degrees();
    (
        scale,
        [angle(k10 / scale[1]), angle(k20 / scale[2]), angle(k21 / scale[2])],
    )
}

/// The nine parameters: C's lower triangle (c00, c10, c11, c20, c21, c22)
/// and the offset, in units of the median total field.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Parameters([f64; 9]);

impl Parameters {
    const IDENTITY: Parameters = Parameters([1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);

    fn matrix(&self) -> [[f64; 3]; 3] {
        let p = &self.0;
        [[p[0], 0.0, 0.0], [p[1], p[2], 0.0], [p[3], p[4], p[5]]]
    }

    fn offset(&self) -> [f64; 3] {
        [self.0[6], self.0[7], self.0[8]]
    }

    /// $C(m - o)$ and $m - o$.
    fn apply(&self, m: &[f64; 3]) -> ([f64; 3], [f64; 3]) {
        let p = &self.0;
        let v = [m[0] - p[6], m[1] - p[7], m[2] - p[8]];
        let w = [
            p[0] * v[0],
            p[1] * v[0] + p[2] * v[1],
            p[3] * v[0] + p[4] * v[1] + p[5] * v[2],
        ];
        (w, v)
    }

    fn residual(&self, m: &[f64; 3], f: f64) -> f64 {
        norm(self.apply(m).0) - f
    }

    /// Residual and its gradient with respect to the nine parameters.
    fn residual_gradient(&self, m: &[f64; 3], f: f64) -> (f64, [f64; 9]) {
        let (w, v) = self.apply(m);
        let n = norm(w);
        let g = [w[0] / n, w[1] / n, w[2] / n];
        let p = &self.0;
        // d|w|/do = −Cᵀ g.
        let offset = [
            -(p[0] * g[0] + p[1] * g[1] + p[3] * g[2]),
            -(p[2] * g[1] + p[4] * g[2]),
            -(p[5] * g[2]),
        ];
        (
            n - f,
            [
                g[0] * v[0],
                g[1] * v[0],
                g[1] * v[1],
                g[2] * v[0],
                g[2] * v[1],
                g[2] * v[2],
                offset[0],
                offset[1],
                offset[2],
            ],
        )
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, count) = values.fold((0.0, 0usize), |(s, c), v| (s + v * v, c + 1));
    (sum / count.max(1) as f64).sqrt()
}

/// Sum of squared residuals (blocks of [`BLOCK_ROWS`] in parallel, added
/// in order).
fn cost(m: &[[f64; 3]], f: &[f64], p: &Parameters) -> f64 {
    let blocks: Vec<f64> = (m.par_chunks(BLOCK_ROWS).zip(f.par_chunks(BLOCK_ROWS)))
        .map(|(m, f)| m.iter().zip(f).map(|(v, f)| p.residual(v, *f).powi(2)).sum())
        .collect();
    blocks.into_iter().sum()
}

/// The linear ellipsoid fit: the quadric $m^\top A m + b^\top m + c = 0$
/// closest to every reading (the smallest right singular vector of the
/// ten monomial columns, from their R factor), then $o = -A^{-1} b / 2$,
/// A scaled so that $(m-o)^\top A (m-o)$ averages $F^2$, and C the
/// lower-triangular factor with $C^\top C = A$. `None` when A is not
/// positive definite (too little attitude change to shape the ellipsoid).
fn ellipsoid_start(m: &[[f64; 3]], f: &[f64]) -> Option<Parameters> {
    let terms: [fn(&[f64; 3]) -> f64; 10] = [
        |v| v[0] * v[0],
        |v| 2.0 * v[0] * v[1],
        |v| 2.0 * v[0] * v[2],
        |v| v[1] * v[1],
        |v| 2.0 * v[1] * v[2],
        |v| v[2] * v[2],
        |v| v[0],
        |v| v[1],
        |v| v[2],
        |_| 1.0,
    ];
    let columns: Vec<Vec<f64>> = terms.iter().map(|t| m.iter().map(t).collect()).collect();
    let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
    let r = tall_skinny_r(&views);
    let (_, _, v) = crate::numerics::linalg::small_svd(r.as_ref())?;
    let theta: Vec<f64> = (0..10).map(|i| v[(i, 9)]).collect();
    let a = Mat::from_fn(3, 3, |i, j| theta[[[0, 1, 2], [1, 3, 4], [2, 4, 5]][i][j]]);
    // A may come out negative definite: the quadric's sign is arbitrary.
    let sign = if a[(0, 0)] + a[(1, 1)] + a[(2, 2)] < 0.0 {
        -1.0
    } else {
        1.0
    };
    let a = Mat::from_fn(3, 3, |i, j| sign * a[(i, j)]);
    let b = [6, 7, 8].map(|k| -0.5 * sign * theta[k]);
    let offset = solve_spd(a.as_ref(), &b)?;
    let quadratic = |x: &[f64; 3]| {
        let d = [x[0] - offset[0], x[1] - offset[1], x[2] - offset[2]];
        (0..3)
            .map(|i| (0..3).map(|j| a[(i, j)] * d[i] * d[j]).sum::<f64>())
            .sum::<f64>()
    };
    let ratio = m.iter().zip(f).map(|(x, f)| quadratic(x) / (f * f)).sum::<f64>() / m.len() as f64;
    if ratio.is_nan() || ratio <= 0.0 {
        return None;
    }
    // Lower-triangular C with CᵀC = A/ratio: reverse the axes, take the
    // Cholesky factor L, reverse back: A = P L Lᵀ P, so C = P Lᵀ P.
    let reversed = Mat::from_fn(3, 3, |i, j| a[(2 - i, 2 - j)] / ratio);
    let lower = crate::numerics::linalg::cholesky_lower(reversed.as_ref())?;
    let c = |i: usize, j: usize| lower[(2 - j, 2 - i)];
    Some(Parameters([
        c(0, 0),
        c(1, 0),
        c(1, 1),
        c(2, 0),
        c(2, 1),
        c(2, 2),
        offset[0],
        offset[1],
        offset[2],
    ]))
}

/// Rows are summed in blocks of this many, the blocks side by side and
/// their sums added in block order: the same sums whatever the number of
/// threads.
const BLOCK_ROWS: usize = 4096;

/// $J^\top J$ and $J^\top r$ over every row, and the sum of squared
/// residuals (blocks of [`BLOCK_ROWS`] in parallel, added in order).
fn normal_equations(m: &[[f64; 3]], f: &[f64], p: &Parameters) -> ([[f64; 9]; 9], [f64; 9], f64) {
    let blocks: Vec<([[f64; 9]; 9], [f64; 9], f64)> = (m.par_chunks(BLOCK_ROWS).zip(f.par_chunks(BLOCK_ROWS)))
        .map(|(m, f)| block_normal_equations(m, f, p))
        .collect();
    let mut sum = ([[0.0; 9]; 9], [0.0; 9], 0.0);
    for (jtj, jtr, cost) in blocks {
        for ((total_row, row), (total, value)) in sum.0.iter_mut().zip(&jtj).zip(sum.1.iter_mut().zip(&jtr)) {
            *total += value;
            for (t, v) in total_row.iter_mut().zip(row) {
                *t += v;
            }
        }
        sum.2 += cost;
    }
    sum
}

/// [`normal_equations`] of one block, summed in row order.
fn block_normal_equations(m: &[[f64; 3]], f: &[f64], p: &Parameters) -> ([[f64; 9]; 9], [f64; 9], f64) {
    let mut jtj = [[0.0; 9]; 9];
    let mut jtr = [0.0; 9];
    let mut cost = 0.0;
    for (v, f) in m.iter().zip(f) {
        let (r, g) = p.residual_gradient(v, *f);
        cost += r * r;
        for i in 0..9 {
            jtr[i] += g[i] * r;
            for j in 0..=i {
                jtj[i][j] += g[i] * g[j];
            }
        }
    }
    let full = std::array::from_fn(|i| std::array::from_fn(|j| if j <= i { jtj[i][j] } else { jtj[j][i] }));
    (full, jtr, cost)
}

/// Levenberg-Marquardt's first damping from a start of unknown distance
/// (a fraction of each parameter's curvature): cautious steps, the damping
/// shrinking threefold with each success.
const COLD_DAMPING: f64 = 1e-3;

/// The first damping from a start a few steps from the optimum (the
/// whole flight's calibration, for one with a heading's windows held
/// out): Gauss-Newton at once, as near the optimum it converges fastest.
/// On a 2.2-hour survey flight the four held-out calibrations took 5 or 6
/// iterations from it against 13 to 16 from [`COLD_DAMPING`] (whose
/// steps barely move a flight's weakly pinned directions until it has
/// shrunk), to the same optimum.
const NEAR_DAMPING: f64 = 1e-9;

/// Levenberg-Marquardt from the better of two starts: the identity (a
/// fluxgate is built and calibrated near it) and the linear ellipsoid fit
/// (closer where the sensor's errors are large). Where the flight's
/// attitudes shape the ellipsoid poorly, its fit can start thousands of
/// nT from the identity's optimum, and the iterations walk the long
/// valley back: 44 of them against 14 from the identity, to the same
/// minimum, on a 2.2-hour survey flight with its box. One step from each,
/// and the rest from the one that went further down; returns the
/// parameters and the iterations taken (the first step counted once).
fn fit_from_best_start(m: &[[f64; 3]], f: &[f64], max_iterations: usize) -> (Parameters, usize) {
    let first_steps = max_iterations.min(1);
    let first = [Some(Parameters::IDENTITY), ellipsoid_start(m, f)]
        .into_iter()
        .flatten()
        .map(|start| levenberg_marquardt(m, f, (start, COLD_DAMPING), first_steps).0)
        .map(|p| (cost(m, f, &p), p))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map_or(Parameters::IDENTITY, |(_, p)| p);
    if max_iterations <= 1 {
        return (first, max_iterations);
    }
    let (fitted, iterations) = levenberg_marquardt(m, f, (first, COLD_DAMPING), max_iterations - 1);
    (fitted, iterations + 1)
}

/// Levenberg-Marquardt with Marquardt's diagonal scaling from a start and
/// its first damping; returns the
/// parameters and the iterations taken.
fn levenberg_marquardt(
    m: &[[f64; 3]],
    f: &[f64],
    (start, damping): (Parameters, f64),
    max_iterations: usize,
) -> (Parameters, usize) {
    let (mut p, mut damping) = (start, damping);
    let (mut jtj, mut jtr, mut current) = normal_equations(m, f, &p);
    for iteration in 1..=max_iterations {
        let mut improved = false;
        while damping < 1e12 {
            let k = Mat::from_fn(9, 9, |i, j| match i == j {
                true => jtj[i][i] * (1.0 + damping) + 1e-300,
                false => jtj[i][j],
            });
            let Some(step) = solve_spd(k.as_ref(), &jtr.map(|v| -v)) else {
                damping *= 10.0;
                continue;
            };
            let mut next = p;
            for (value, s) in next.0.iter_mut().zip(&step) {
                *value += s;
            }
            let trial = cost(m, f, &next);
            if trial < current {
                let gain = (current - trial) / current.max(f64::MIN_POSITIVE);
                p = next;
                (jtj, jtr, current) = normal_equations(m, f, &p);
                damping = (damping / 3.0).max(1e-12);
                improved = true;
                if gain < 1e-14 {
                    return (p, iteration);
                }
                break;
            }
            damping *= 4.0;
        }
        if !improved {
            return (p, iteration);
        }
    }
    (p, max_iterations)
}

/// One-sigma uncertainty of the parameters at `p`: the diagonal of
/// $\sigma^2 (J^\top J)^{-1}$, σ² the residual variance, inflated by
/// $n / n_{eff}$ with $n_{eff} = n (1 - \rho)/(1 + \rho)$ for the
/// residual's lag-one autocorrelation ρ (the aircraft's own field and the
/// crust leave slowly varying, not white, residuals). `None` when
/// $J^\top J$ is singular.
fn parameter_uncertainty(m: &[[f64; 3]], f: &[f64], p: &Parameters) -> Option<[f64; 9]> {
    let (jtj, _, cost) = normal_equations(m, f, p);
    let residuals: Vec<f64> = m.iter().zip(f).map(|(v, f)| p.residual(v, *f)).collect();
    let n = residuals.len() as f64;
    let mean = residuals.iter().sum::<f64>() / n;
    let variance = residuals.iter().map(|r| (r - mean).powi(2)).sum::<f64>();
    let lagged: f64 = residuals.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum();
    let rho = (lagged / variance.max(f64::MIN_POSITIVE)).clamp(0.0, 0.999);
    let effective = (n * (1.0 - rho) / (1.0 + rho)).max(10.0);
    let sigma2 = cost / (n - 9.0).max(1.0) * n / effective;
    let k = Mat::from_fn(9, 9, |i, j| jtj[i][j]);
    let mut out = [0.0; 9];
    for (i, value) in out.iter_mut().enumerate() {
        let unit: Vec<f64> = (0..9).map(|j| if i == j { 1.0 } else { 0.0 }).collect();
        let column = solve_spd(k.as_ref(), &unit)?;
        *value = (sigma2 * column[i]).max(0.0).sqrt();
    }
    Some(out)
}

/// Condition number of the Jacobian at `p`, its columns scaled to unit
/// norm: the ratio of the extreme singular values of their R factor.
fn jacobian_condition(m: &[[f64; 3]], p: &Parameters) -> f64 {
    // The R factor of the Jacobian's columns, each scaled to unit norm,
    // not JᵀJ: squaring would floor the ratio at √(1/ε) ≈ 1e8, the limit
    // itself.
    let mut columns: Vec<Vec<f64>> = (0..9).map(|_| Vec::with_capacity(m.len())).collect();
    for v in m {
        let (_, gradient) = p.residual_gradient(v, 0.0);
        for (column, g) in columns.iter_mut().zip(gradient) {
            column.push(g);
        }
    }
    for column in &mut columns {
        let length = column.iter().map(|g| g * g).sum::<f64>().sqrt().max(f64::MIN_POSITIVE);
        column.iter_mut().for_each(|g| *g /= length);
    }
    if columns.iter().flatten().any(|g| !g.is_finite()) {
        return f64::NAN;
    }
    let views: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
    let r = tall_skinny_r(&views);
    match crate::numerics::linalg::small_svd(r.as_ref()) {
        Some((_, sigma, _)) => sigma[0] / sigma[8].max(f64::MIN_POSITIVE),
        None => f64::INFINITY,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::physics::FluxgateErrors;

    /// Readings of a fluxgate with known errors over a sweep of attitudes.
    fn readings(errors: &FluxgateErrors, count: usize) -> (Vec<[f64; 3]>, Vec<f64>) {
        let earth = [19_000.0, -1_500.0, 47_000.0];
        let (mut m, mut f) = (Vec::new(), Vec::new());
        for k in 0..count {
            let t = k as f64;
            let (roll, pitch, yaw) = (0.3 * (t * 0.37).sin(), 0.2 * (t * 0.23).cos(), t * 0.011);
            let b = crate::simulate::physics::to_body(earth, roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees());
            let r = errors.read(b);
            m.push([r[0] / 50_000.0, r[1] / 50_000.0, r[2] / 50_000.0]);
            f.push(norm(b) / 50_000.0);
        }
        (m, f)
    }

    #[test]
    fn levenberg_marquardt_recovers_known_errors() {
        let errors = FluxgateErrors::new([1.015, 0.985, 1.01], [0.6, -0.4, 0.8], [120.0, -80.0, 45.0]);
        let (m, f) = readings(&errors, 3000);
        let start = ellipsoid_start(&m, &f).expect("a positive-definite ellipsoid");
        let (p, _) = levenberg_marquardt(&m, &f, (start, COLD_DAMPING), 100);
        let (scale, angles) = error_model(&p.matrix());
        for axis in 0..3 {
            assert!(
                (scale[axis] - [1.015, 0.985, 1.01][axis]).abs() < 1e-9,
                "scale {scale:?}"
            );
            assert!(
                (angles[axis] - [0.6, -0.4, 0.8][axis]).abs() < 1e-7,
                "angles {angles:?}"
            );
            assert!((p.offset()[axis] * 50_000.0 - [120.0, -80.0, 45.0][axis]).abs() < 1e-5);
        }
    }

    #[test]
    fn analytic_gradient_matches_differences() {
        let p = Parameters([1.01, 0.02, 0.99, -0.01, 0.03, 1.02, 0.002, -0.001, 0.003]);
        let m = [0.38, -0.05, 0.93];
        let (_, g) = p.residual_gradient(&m, 1.0);
        for (i, analytic) in g.iter().enumerate() {
            let mut q = p;
            q.0[i] += 1e-7;
            let mut r = p;
            r.0[i] -= 1e-7;
            let numeric = (q.residual(&m, 1.0) - r.residual(&m, 1.0)) / 2e-7;
            assert!(
                (numeric - analytic).abs() < 1e-8,
                "parameter {i}: {numeric} against {analytic}"
            );
        }
    }

    /// A flight log of a fluxgate and a scalar over the given body-frame fields.
    fn log_of(fields: &[[f64; 3]]) -> (FlightLog, VectorSensor) {
        use crate::ingest::flight_log::{Channel, ChannelRole, VectorAxis};
        let mut channels = vec![Channel {
            name: "mag_1_uc".into(),
            role: ChannelRole::ScalarMagnetometer,
            values: fields.iter().map(|b| norm(*b)).collect(),
        }];
        for (axis, kind) in [VectorAxis::X, VectorAxis::Y, VectorAxis::Z].into_iter().enumerate() {
            channels.push(Channel {
                name: format!("flux_a_{}", ["x", "y", "z"][axis]),
                role: ChannelRole::VectorMagnetometer {
                    sensor: "flux_a".into(),
                    axis: kind,
                },
                values: fields.iter().map(|b| b[axis] * 1.01 + 30.0).collect(),
            });
        }
        let time = (0..fields.len()).map(|k| k as f64 * 0.1).collect();
        let log = FlightLog::new("test", "tt", time, channels).unwrap();
        let sensor = log.vector_sensors().remove(0);
        (log, sensor)
    }

    #[test]
    fn straight_and_level_flight_cannot_calibrate() {
        // One attitude throughout: the nine parameters are not determined.
        let fields = vec![[19_000.0, -1_500.0, 47_000.0]; 500];
        let (log, sensor) = log_of(&fields);
        let error = calibrate(&log, &sensor, "mag_1_uc", &[], 100).unwrap_err().to_string();
        assert!(error.contains("do not determine the fluxgate calibration"), "{error}");
    }

    #[test]
    fn a_short_straight_segment_does_not_pin_the_calibration() {
        // 100 s of survey flight: a few degrees of roll, pitch and heading,
        // and a scalar with 0.3 nT of irregular disturbance (crust, aircraft).
        let earth = [19_000.0, -1_500.0, 47_000.0];
        let fields: Vec<[f64; 3]> = (0..1000)
            .map(|k| {
                let t = k as f64 * 0.1;
                crate::simulate::physics::to_body(
                    earth,
                    3.0 * (t * 0.4).sin(),
                    1.5 * (t * 0.25).cos(),
                    2.0 * (t * 0.05).sin(),
                )
            })
            .collect();
        let (mut log, sensor) = log_of(&fields);
        let disturbed: Vec<f64> = fields
            .iter()
            .enumerate()
            .map(|(k, b)| norm(*b) + 0.3 * ((k as f64 * 0.7).sin() + (k as f64 * 1.9).cos()))
            .collect();
        log = log.with_values("mag_1_uc", disturbed).unwrap();
        let error = calibrate(&log, &sensor, "mag_1_uc", &[], 100).unwrap_err().to_string();
        assert!(error.contains("do not pin the fluxgate calibration"), "{error}");
    }

    /// The body-axis field of 200 s of turning through every heading
    /// with pitch and roll swinging, at 10 Hz.
    fn turning_fields() -> Vec<[f64; 3]> {
        let earth = [19_000.0, -1_500.0, 47_000.0];
        (0..2000)
            .map(|k| {
                let t = k as f64 * 0.1;
                crate::simulate::physics::to_body(earth, 15.0 * (t * 0.3).sin(), 8.0 * (t * 0.2).cos(), t * 1.7)
            })
            .collect()
    }

    #[test]
    fn calibrated_flight_reads_the_scalar_total_field() {
        let fields = turning_fields();
        let (log, sensor) = log_of(&fields);
        let calibration = calibrate(&log, &sensor, "mag_1_uc", &[], 100).unwrap();
        // Readings 1.01 b + 30 nT: scale 1.01 and offset 30 nT on each axis.
        for axis in 0..3 {
            assert!((calibration.scale[axis] - 1.01).abs() < 1e-9, "{calibration:?}");
            assert!((calibration.offset_nt[axis] - 30.0).abs() < 1e-5, "{calibration:?}");
            assert!(calibration.non_orthogonality_deg[axis].abs() < 1e-7, "{calibration:?}");
        }
        // Exact readings over every heading: the parameters are pinned.
        assert!(
            calibration.uncertainty[..6].iter().all(|u| *u < 1e-6),
            "{calibration:?}"
        );
        assert!(
            calibration.uncertainty[6..].iter().all(|u| *u < 1e-2),
            "{calibration:?}"
        );
        let calibrated = calibration.apply(&log, &sensor).unwrap();
        let field = calibrated.vector_components(&sensor);
        for (k, b) in fields.iter().enumerate() {
            for axis in 0..3 {
                assert!((field[axis][k] - b[axis]).abs() < 1e-5);
            }
        }
    }

    /// Held out a stretch, the calibration started from the whole
    /// flight's lands where a cold start does, in fewer iterations.
    #[test]
    fn a_calibration_started_near_lands_where_a_cold_one_does() {
        let fields = turning_fields();
        let (log, sensor) = log_of(&fields);
        let whole = calibrate(&log, &sensor, "mag_1_uc", &[], 100).unwrap();
        let rest = [0..600, 900..2000];
        let cold = calibrate(&log, &sensor, "mag_1_uc", &rest, 100).unwrap();
        let near = calibrate_near(&log, &sensor, ("mag_1_uc", &rest), 100, &whole).unwrap();
        for axis in 0..3 {
            assert!((near.scale[axis] - cold.scale[axis]).abs() < 1e-9, "{near:?} {cold:?}");
            assert!(
                (near.offset_nt[axis] - cold.offset_nt[axis]).abs() < 1e-5,
                "{near:?} {cold:?}"
            );
        }
        assert_eq!(near.samples, 1700);
        assert!(
            near.iterations < cold.iterations,
            "{} against {}",
            near.iterations,
            cold.iterations
        );
    }
}
