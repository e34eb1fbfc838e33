//! Contiguous runs of valid samples.
//!
//! Filters and derivatives must never run across a gap: a stretch of missing
//! samples, or a jump in time longer than the normal sample interval.

use std::ops::Range;

/// A time step longer than this many median intervals is a gap. Clock jitter
/// of a few percent stays well below it; one dropped sample (2 intervals)
/// already counts as a gap.
pub const GAP_FACTOR: f64 = 1.5;

/// Splits `range` into maximal runs where `valid[i]` holds and no time step
/// exceeds `GAP_FACTOR × median_interval_s`.
pub fn valid_runs(time_s: &[f64], valid: &[bool], range: Range<usize>, median_interval_s: f64) -> Vec<Range<usize>> {
    let max_step = GAP_FACTOR * median_interval_s;
    let mut runs = Vec::new();
    let mut start: Option<usize> = None;
    let mut i = range.start;
    while i < range.end {
        // Inside a run, a stretch of valid samples with short steps only
        // continues it: checked a chunk at a time.
        if start.is_some() {
            let end = (i + CHUNK).min(range.end);
            if end - i == CHUNK && continues_through(&time_s[i - 1..end], &valid[i..end], max_step) {
                i = end;
                continue;
            }
        }
        let continues = start.is_some() && time_s[i] - time_s[i - 1] <= max_step;
        match (valid[i], start) {
            (true, Some(_)) if continues => {}
            (true, _) => {
                if let Some(s) = start {
                    runs.push(s..i);
                }
                start = Some(i);
            }
            (false, Some(s)) => {
                runs.push(s..i);
                start = None;
            }
            (false, None) => {}
        }
        i += 1;
    }
    if let Some(s) = start {
        runs.push(s..range.end);
    }
    runs
}

/// Samples checked together by [`valid_runs`].
const CHUNK: usize = 64;

/// True when every sample of `valid` holds and every step of `time_s` (one
/// time longer, starting a sample earlier) is at most `max_step`.
fn continues_through(time_s: &[f64], valid: &[bool], max_step: f64) -> bool {
    let all_valid = valid.iter().fold(true, |all, &v| all & v);
    let long_steps = time_s
        .windows(2)
        .fold(0usize, |n, w| n + usize::from(w[1] - w[0] > max_step));
    all_valid && long_steps == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_at_missing_samples_and_time_jumps() {
        let time: Vec<f64> = vec![0.0, 0.1, 0.2, 0.3, 0.4, 1.4, 1.5, 1.6];
        let valid = vec![true, true, false, true, true, true, true, true];
        assert_eq!(valid_runs(&time, &valid, 0..8, 0.1), vec![0..2, 3..5, 5..8]);
        assert_eq!(valid_runs(&time, &valid, 4..7, 0.1), vec![4..5, 5..7]);
    }

    /// The chunked scan finds the runs a sample-by-sample scan finds, with
    /// gaps and missing samples at and around chunk edges.
    #[test]
    fn chunked_scan_equals_the_sample_scan() {
        let n = 1000;
        let mut time = Vec::with_capacity(n);
        let mut t = 0.0;
        for i in 0..n {
            t += if [63, 64, 128, 300, 301, 777].contains(&i) {
                0.5
            } else {
                0.1
            };
            time.push(t);
        }
        let valid: Vec<bool> = (0..n)
            .map(|i| ![0, 190, 191, 255, 256, 640, 999].contains(&i))
            .collect();
        // The definition: a run breaks at a missing sample or a long step.
        let mut expected: Vec<Range<usize>> = Vec::new();
        for i in 0..n {
            if !valid[i] {
                continue;
            }
            match expected.last_mut() {
                Some(run) if run.end == i && time[i] - time[i - 1] <= 0.15 => run.end = i + 1,
                _ => expected.push(i..i + 1),
            }
        }
        assert_eq!(valid_runs(&time, &valid, 0..n, 0.1), expected);
        assert_eq!(expected.len(), 10);
    }
}
