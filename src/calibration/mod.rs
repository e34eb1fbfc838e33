//! The calibration a flight carries: the box, its manoeuvres and windows,
//! and the fluxgate's own calibration.
//!
//! - [`detect`]: the calibration box and its manoeuvres, found in the
//!   attitude and heading.
//! - [`windows`]: calibration windows, detected or given, as every fit
//!   takes them.
//! - [`headings`]: the headings of a box, and the leave-one-heading-out
//!   rule the diagnosis and the quality checks share.
//! - [`fluxgate`]: a three-axis fluxgate's scale factors,
//!   non-orthogonality and offsets, calibrated against the scalar
//!   magnetometers without the attitude.

pub mod detect;
pub mod fluxgate;
pub mod headings;
pub mod windows;
