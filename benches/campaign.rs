//! Campaign throughput: `cargo bench --bench campaign [-- flights=100]`.
//!
//! Simulates a campaign of one-hour flights (10 Hz, one calibration box
//! and ten 18 km survey lines each, two scalar sensors and a fluxgate) and
//! runs `magcomp run` over it with default settings, once with one worker
//! thread and once with two (`RAYON_NUM_THREADS`), each into its own output
//! folder. Reports flights per minute, the peak resident set of the run,
//! the campaign machinery's own cost (a second run that finds every flight
//! current does only that: hash the input and settings, read the status),
//! and the wall time 10 000 such flights would take on N nodes like this
//! one, from the measured rates.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use magcomp::simulate::scenario::{RawScenario, Scenario};
use rayon::prelude::*;

/// Writes the one-hour flight of `seed` to `path`.
fn one_hour_flight(path: &Path, seed: u64) {
    let mut raw = RawScenario {
        seed,
        ..RawScenario::default()
    };
    raw.survey.line_count = 10;
    raw.survey.line_length_m = 18_000.0;
    let flight = magcomp::simulate::simulate(&Scenario::try_from(raw).expect("a valid scenario")).expect("simulated");
    magcomp::formats::write_flight_log(&flight.log, path).expect("written");
}

/// Largest resident set of any child waited for so far, MB.
fn children_peak_rss_mb() -> f64 {
    // SAFETY: getrusage fills the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let answer = unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) };
    match answer {
        0 => usage.ru_maxrss as f64 / 1024.0,
        _ => f64::NAN,
    }
}

/// Runs `magcomp run config` as `shards` processes side by side (`--shard
/// K/shards`), each with `threads` workers; wall time, s.
fn run(config: &Path, shards: usize, threads: usize) -> f64 {
    let started = Instant::now();
    let children: Vec<std::process::Child> = (0..shards)
        .map(|k| {
            Command::new(env!("CARGO_BIN_EXE_magcomp"))
                .args(["run", config.to_str().expect("UTF-8 path")])
                .args(["--shard", &format!("{k}/{shards}")])
                .env("RAYON_NUM_THREADS", threads.to_string())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .expect("magcomp runs")
        })
        .collect();
    for child in children {
        let output = child.wait_with_output().expect("magcomp ends");
        assert!(
            output.status.success(),
            "magcomp run failed: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    started.elapsed().as_secs_f64()
}

fn main() {
    let flights: usize = std::env::args()
        .find_map(|a| a.strip_prefix("flights=").and_then(|n| n.parse().ok()))
        .unwrap_or(100);
    let folder = tempfile::tempdir().expect("a temporary folder");
    let started = Instant::now();
    std::fs::create_dir_all(folder.path().join("flights")).expect("folder");
    (0..flights).into_par_iter().for_each(|index| {
        one_hour_flight(
            &folder.path().join(format!("flights/flight_{index:05}.csv")),
            1000 + index as u64,
        );
    });
    let bytes: u64 = std::fs::read_dir(folder.path().join("flights"))
        .expect("listed")
        .map(|e| e.expect("entry").metadata().expect("metadata").len())
        .sum();
    println!(
        "campaign: {flights} one-hour flights, {:.0} MB of CSV, simulated in {:.0} s",
        bytes as f64 / 1e6,
        started.elapsed().as_secs_f64()
    );
    let mut rates = Vec::new();
    for (shards, threads) in [(1, 1), (1, 2), (2, 1)] {
        let name = format!("{shards}x{threads}");
        let config = folder.path().join(format!("{name}.toml"));
        std::fs::write(
            &config,
            format!("[output]\ndirectory = \"out_{name}\"\n\n[campaign]\ninputs = [\"flights/*.csv\"]\n"),
        )
        .expect("config written");
        let wall = run(&config, shards, threads);
        let peak = children_peak_rss_mb();
        let skipped = run(&config, shards, threads);
        let rate = flights as f64 / (wall / 60.0);
        println!(
            "  {shards} process(es) of {threads} thread(s): {wall:.1} s, {:.2} s a flight, {rate:.1} flights/min; largest peak RSS so far {peak:.0} MB",
            wall / flights as f64,
        );
        println!(
            "    campaign machinery alone (every flight current: hash input and settings, read the status): {skipped:.2} s, {:.2} % of the processing",
            100.0 * skipped / wall
        );
        rates.push(rate);
    }
    let node_rate = rates.iter().copied().fold(0.0, f64::max);
    println!("projected wall time of 10 000 such flights at {node_rate:.1} flights/min a node (the best above):");
    for nodes in [1, 10, 100, 1000] {
        let minutes = 10_000.0 / (node_rate * nodes as f64);
        println!("  {nodes:>5} nodes: {minutes:.1} min ({:.2} h)", minutes / 60.0);
    }
}
