//! Any bytes given as a .csv flight go through every stage (reading,
//! screening, detection, the fit, compensation and the report) to a result
//! or an error, never a panic or an abort.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "harness.rs"]
mod harness;

fuzz_target!(|data: &[u8]| {
    harness::exercise(data, "csv");
});
