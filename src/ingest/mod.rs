//! Reading a flight: what every later stage starts from.
//!
//! - [`flight_log`]: the flight log, its channels and their roles, and the
//!   vector magnetometers found by their columns.
//! - [`flight_date`]: the flight's date, from the file or the user.
//! - [`flight_identity`]: the flight's identity (the hash of its input),
//!   which the model and the campaign's status name.
//! - [`flags`]: the row flags every output carries.
//! - [`screen`]: the samples no instrument can record, flagged before any
//!   fit.
//! - [`agreement`]: the samples the INS and a fluxgate, read together,
//!   show to be glitches, for [`screen`].
//! - [`text_file`]: a settings or results file read whole, refused when it
//!   is a named pipe or a device.
//!
//! The file formats themselves are [`crate::formats`], which both reads
//! and writes.

pub mod agreement;
pub mod flags;
pub mod flight_date;
pub mod flight_identity;
pub mod flight_log;
pub mod magnitude;
pub mod screen;
pub mod text_file;

pub use text_file::read_text;
