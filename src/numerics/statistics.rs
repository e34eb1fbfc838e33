//! Plain statistics of a slice of values: its spread, its root mean
//! square and its peak-to-peak range; white noise from a fourth
//! difference.

/// The standard deviation of white noise over the RMS of its fourth
/// difference with the Seequent QCNOISE normalisation: the difference
/// $(x_{-2} - 4x_{-1} + 6x_0 - 4x_{+1} + x_{+2})/16$ of white noise of
/// standard deviation σ has standard deviation $\sqrt{70}\,σ/16 ≈ 0.52σ$.
pub const WHITE_NOISE_PER_FOURTH_DIFFERENCE: f64 = 1.912_365_774_935_03;

/// Population standard deviation (0 for an empty slice).
pub fn standard_deviation(values: &[f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
}

/// Root mean square (0 for an empty slice).
pub fn root_mean_square(values: &[f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
}

/// Largest minus smallest value (0 for an empty slice).
pub fn peak_to_peak(values: &[f64]) -> f64 {
    let (low, high) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    if values.is_empty() {
        0.0
    } else {
        high - low
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peak_to_peak_and_spread() {
        assert_eq!(peak_to_peak(&[1.0, -2.5, 3.0]), 5.5);
        assert_eq!(standard_deviation(&[1.0, 3.0]), 1.0);
        assert_eq!(root_mean_square(&[3.0, 4.0]), (12.5f64).sqrt());
    }
}
