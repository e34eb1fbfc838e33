//! What a run leaves behind: its files and its report.
//!
//! - [`sink`]: writes what a run produced (the compensated flight, the
//!   model, the quality and diagnosis JSON), each file staged and renamed
//!   into place.
//! - [`report`]: the HTML report.
//!
//! The file formats themselves are [`crate::formats`].

pub mod report;
pub mod sink;
