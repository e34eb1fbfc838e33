//! # magcomp
//!
//! Post-flight compensation of aeromagnetic surveys.
//!
//! An aircraft's own magnetism (permanent, induced, eddy-current and
//! electrical fields) corrupts the total-field readings of its scalar
//! magnetometers. magcomp reads the flight log, fits the Tolles-Lawson model
//! on the calibration manoeuvres with ridge regression (λ chosen by PRESS,
//! truncated SVD as a fallback), subtracts the predicted interference from
//! every row of every scalar channel, and reports quality figures.
//!
//! The stages, each a module with a typed input and output:
//!
//! ```text
//! read_flight_log → calibration windows → model::fit → compensate → assess_quality
//! ```
//!
//! ## Layout
//!
//! The top level follows a flight through its stages.
//!
//! - [`ingest`]: the flight log and its channels ([`ingest::flight_log`]),
//!   its date and identity, the row flags, and the screen for samples no
//!   instrument can record ([`ingest::screen`]). [`formats`]: every file
//!   format, one module each that both reads and writes it (CSV, Geosoft
//!   XYZ, MCAP, HDF5), and atomic, staged writes.
//! - [`calibration`]: the box and its manoeuvres ([`calibration::detect`]),
//!   calibration windows ([`calibration::windows`]), the
//!   leave-one-heading-out rule ([`calibration::headings`]) and the
//!   fluxgate's own calibration ([`calibration::fluxgate`]).
//! - [`model`]: one model type. A [`model::ModelSpec`] (the Tolles-Lawson
//!   terms of [`model::terms`] and the physics a diagnosis adds) is fitted
//!   by [`model::fit`] into a [`model::FittedModel`] that predicts the
//!   interference and its held-out residual, and [`model::igrf`] is the
//!   Earth's main field. [`numerics`]: [`numerics::filter`] (zero-phase
//!   band-pass), [`numerics::stacked`] and [`numerics::solve`] (ridge by
//!   PRESS, truncated SVD), [`numerics::segments`], [`numerics::linalg`],
//!   [`numerics::statistics`]; it imports nothing else of magcomp.
//! - [`compensate`]: the prediction subtracted from every row, and what is
//!   made of the compensated channels: gradients between two sensors
//!   ([`compensate::gradient`]) and the DC-shifted and IGRF-reduced
//!   columns ([`compensate::reduce`]). [`vector`] compensates the fluxgate
//!   itself.
//! - [`diagnose`]: the physics the model leaves out, found, named and
//!   scored held out. [`quality`]: the figures of a compensation, the
//!   transfer check, crossovers and corrugation, and the flight against
//!   the plan it was flown to ([`quality::against_plan`]).
//! - [`pipeline`]: one flight through every stage, writing nothing
//!   ([`pipeline::run`] → [`pipeline::FlightRun`]). A flight is read and
//!   prepared once ([`pipeline::PreparedFlight`]: screened, its sensor,
//!   channels and windows chosen); each stage after it takes the
//!   [`model::Calibration`] it gives (log, sensor, channels, windows). A
//!   flight with no calibration of its own is compensated with a model
//!   saved from another ([`pipeline::apply`]). [`campaign`] runs many
//!   flights, [`config`] reads `pipeline.toml`.
//! - [`messages`]: what a run says to its user: typed warnings and notes,
//!   and, while it runs, each stage begun and each channel done, told to
//!   a [`messages::progress::Meter`].
//! - [`output`]: [`output::sink`] writes what a run produced, and
//!   [`output::report`] is the HTML page.
//! - [`plan`]: a calibration planned before the flight, and what it
//!   would achieve.
//! - [`simulate`]: flights with known truth, for tests and for users,
//!   and the sample flights ([`simulate::sample_flight`]).
//! - The command line (`src/main.rs`, the binary) is a thin layer over
//!   these: `src/cli/` holds one module per subcommand.
//!
//! No module imports another that imports it back (`tests/architecture.rs`
//! checks).
//!
//! Interface names (CSV columns, the command line, the JSON files, MCAP
//! topics) are fixed by the interface contract, `docs/CONTRACT.md`; a
//! reference "CONTRACT §n" in these docs is to its section n.
//!
//! ## Example
//!
//! Make a small sample flight, fit its tail magnetometer on the box
//! manoeuvres and compensate every row:
//!
//! ```
//! use magcomp::{compensate::{compensate, LevelConvention}, model::{fit, FitOptions, ModelSpec}};
//! use magcomp::{formats::{read_flight_log, IngestOptions}, pipeline::choose_vector_sensor};
//! use magcomp::{quality::assess_quality, simulate::sample_flight, numerics::stacked::StorePool, calibration::windows::read_detect_json};
//!
//! let folder = tempfile::tempdir()?;
//! let (csv, windows) = (folder.path().join("flight.csv"), folder.path().join("windows.json"));
//! let spec = sample_flight::SampleFlightSpec { line_count: 1, ..Default::default() };
//! sample_flight::write(&sample_flight::generate(&spec, 1), &csv, &windows)?;
//!
//! let log = read_flight_log(&csv, &IngestOptions::default())?;
//! let sensor = choose_vector_sensor(&log, Some("flux_a"))?;
//! let windows = read_detect_json(&windows, 5.0)?;
//! let (spec, options, stores) = (ModelSpec::default(), FitOptions::default(), StorePool::new());
//! let model = fit(&log, &sensor, "mag_1_uc", &windows, &spec, &options, &stores)?;
//! let models = vec![model];
//! let compensated = compensate(&log, &models, LevelConvention::Absolute)?;
//! let quality = assess_quality(&log, &models[0], &compensated.channels[0]);
//! assert_eq!(compensated.channels[0].values.len(), log.len());
//! assert!(quality.improvement_ratio > 5.0, "IR {}", quality.improvement_ratio);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![deny(missing_docs)]

pub mod calibration;
pub mod campaign;
pub mod compensate;
pub mod config;
pub mod diagnose;
pub mod error;
pub mod formats;
pub mod ingest;
pub mod messages;
pub mod model;
pub mod numerics;
pub mod output;
pub mod pipeline;
pub mod plan;
pub mod quality;
pub mod simulate;
pub mod vector;

pub use error::{Error, Result};
