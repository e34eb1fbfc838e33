//! Headings and the held-out splits built on them, shared by the transfer
//! check ([`crate::quality::transfer`]), the diagnosis ([`crate::diagnose`]) and the
//! FOM table ([`crate::quality`]).
//!
//! Two headings are the same leg when they are closer than
//! [`SAME_HEADING_DEG`] around the circle. Leaving one heading out fits on
//! the other headings and measures the left-out one: the interference of
//! a heading the fit never saw must be predicted from the others, which is
//! what the survey lines ask of a calibration.

use crate::calibration::windows::CalibrationWindow;

/// Headings closer than this are one heading (one leg of a box, one row of
/// the FOM table), degrees.
pub const SAME_HEADING_DEG: f64 = 15.0;

/// `a − b` around the circle, in (−180°, 180°].
pub fn heading_difference(a: f64, b: f64) -> f64 {
    (a - b + 540.0).rem_euclid(360.0) - 180.0
}

/// How far apart two headings are around the circle, 0–180°.
pub fn angle_apart(a: f64, b: f64) -> f64 {
    heading_difference(a, b).abs()
}

/// Whether two headings are one ([`SAME_HEADING_DEG`]).
pub fn same_heading(a: f64, b: f64) -> bool {
    angle_apart(a, b) < SAME_HEADING_DEG
}

/// The headings of `windows`, one per group of the same heading, in order
/// of first appearance; windows without a heading are skipped.
pub fn distinct_headings(windows: &[CalibrationWindow]) -> Vec<f64> {
    let mut headings: Vec<f64> = Vec::new();
    for heading in windows.iter().filter_map(|w| w.heading_deg) {
        if !headings.iter().any(|h| same_heading(*h, heading)) {
            headings.push(heading);
        }
    }
    headings
}

/// Leave one heading out: for each heading (in order of first appearance)
/// its windows, held out, and the others, to fit on. `None` unless every
/// window has a heading and there are at least three headings (with two,
/// a fit on one heading cannot separate the terms).
pub fn heading_splits(windows: &[CalibrationWindow]) -> Option<Vec<(Vec<CalibrationWindow>, Vec<CalibrationWindow>)>> {
    let headings = distinct_headings(windows);
    if headings.len() < 3 || windows.iter().any(|w| w.heading_deg.is_none()) {
        return None;
    }
    Some(
        headings
            .iter()
            .map(|&heading| {
                windows
                    .iter()
                    .cloned()
                    .partition(|w| w.heading_deg.is_some_and(|h| same_heading(h, heading)))
            })
            .collect(),
    )
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 10 s window from `t` on `heading` (for the unit tests here and
    /// in the modules that hold out by heading).
    pub(crate) fn window(t: f64, heading: f64) -> CalibrationWindow {
        CalibrationWindow {
            heading_deg: Some(heading),
            ..CalibrationWindow::new(t, t + 10.0)
        }
    }

    #[test]
    fn differences_wrap_through_north() {
        assert_eq!(heading_difference(350.0, 10.0), -20.0);
        assert_eq!(heading_difference(10.0, 350.0), 20.0);
        assert_eq!(angle_apart(359.0, 1.0), 2.0);
        assert!(same_heading(355.0, 8.0) && !same_heading(355.0, 11.0));
    }

    #[test]
    fn each_heading_is_held_out_once_with_its_repeats() {
        let windows: Vec<CalibrationWindow> = [(0.0, 358.0), (20.0, 91.0), (40.0, 181.0), (60.0, 3.0), (80.0, 268.0)]
            .iter()
            .map(|&(t, h)| window(t, h))
            .collect();
        assert_eq!(distinct_headings(&windows), [358.0, 91.0, 181.0, 268.0]);
        let splits = heading_splits(&windows).unwrap();
        assert_eq!(splits.len(), 4);
        let starts = |ws: &[CalibrationWindow]| ws.iter().map(|w| w.t_start).collect::<Vec<_>>();
        assert_eq!(starts(&splits[0].0), [0.0, 60.0]);
        assert_eq!(starts(&splits[0].1), [20.0, 40.0, 80.0]);
        assert_eq!(starts(&splits[3].0), [80.0]);
    }

    #[test]
    fn two_headings_or_an_unlabelled_window_give_no_splits() {
        let two: Vec<CalibrationWindow> = [(0.0, 0.0), (20.0, 90.0), (40.0, 5.0)]
            .iter()
            .map(|&(t, h)| window(t, h))
            .collect();
        assert!(heading_splits(&two).is_none());
        let mut three: Vec<CalibrationWindow> = [(0.0, 0.0), (20.0, 90.0), (40.0, 180.0)]
            .iter()
            .map(|&(t, h)| window(t, h))
            .collect();
        assert!(heading_splits(&three).is_some());
        three.push(CalibrationWindow::new(60.0, 70.0));
        assert!(heading_splits(&three).is_none());
    }
}
