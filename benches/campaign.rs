//! Campaign throughput: `cargo bench --bench campaign [-- flights=N]`.
//!
//! Simulates a campaign of one-hour flights (10 Hz, one calibration box
//! and ten 18 km survey lines each, two scalar sensors and a fluxgate; by
//! default four for each core) and runs `magcomp run` over it with default
//! settings: one process with one worker thread, with two, and with one for
//! each core (`RAYON_NUM_THREADS`), and one one-thread shard for each core
//! side by side, each into its own output folder. Reports flights per
//! minute, the peak resident set of each run, the ratio of one process's
//! wall time to the shards', the campaign machinery's own cost (a second
//! run that finds every flight current does only that: hash the input and
//! settings, read the status), and the wall time 10 000 such flights would
//! take on N nodes like this one.
//!
//! Then the peak memory of one flight by its length and rate: `magcomp
//! compensate` of a flight of 1 and 3 hours at 10 and 20 Hz, alone.
//!
//! `MAGCOMP_BIN` names the magcomp binary to run (another machine's copy);
//! by default the one cargo built beside this bench.

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

/// The magcomp binary: `MAGCOMP_BIN`, or the one cargo built.
fn magcomp_binary() -> String {
    std::env::var("MAGCOMP_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_magcomp").to_string())
}

/// A process's peak resident set so far (`VmHWM` of its status), MB;
/// `None` once it has ended.
fn peak_so_far_mb(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kilobytes: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kilobytes / 1024.0)
}

/// Waits for `children` and returns the largest peak resident set of one
/// of them, MB; panics with the error output of one that failed.
///
/// The peak is read from `/proc` every few milliseconds while each runs,
/// not from `wait4`: on Linux a child's `ru_maxrss` counts the memory of
/// this process when it was forked, and the flights simulated here would
/// be counted as the child's.
fn wait_peak_rss_mb(mut children: Vec<std::process::Child>) -> f64 {
    let mut peak: f64 = 0.0;
    while !children.is_empty() {
        let mut running = Vec::with_capacity(children.len());
        for mut child in children {
            if let Some(mb) = peak_so_far_mb(child.id()) {
                peak = peak.max(mb);
            }
            match child.try_wait().expect("magcomp waited for") {
                None => running.push(child),
                Some(status) if status.success() => {}
                Some(_) => {
                    let mut text = String::new();
                    if let Some(stderr) = child.stderr.as_mut() {
                        let _ = std::io::Read::read_to_string(stderr, &mut text);
                    }
                    panic!("magcomp failed: {text}");
                }
            }
        }
        children = running;
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    peak
}

/// Runs `magcomp run config` as `shards` processes side by side (`--shard
/// K/shards`), each with `threads` workers; wall time, s, and the largest
/// peak resident set of one process, MB.
fn run(config: &Path, shards: usize, threads: usize) -> (f64, f64) {
    let started = Instant::now();
    let children: Vec<std::process::Child> = (0..shards)
        .map(|k| {
            Command::new(magcomp_binary())
                .args(["run", config.to_str().expect("UTF-8 path")])
                .args(["--shard", &format!("{k}/{shards}")])
                .env("RAYON_NUM_THREADS", threads.to_string())
                .stdout(std::process::Stdio::null())
                // Errors are few lines; a pipe never fills.
                .stderr(std::process::Stdio::piped())
                .spawn()
                .expect("magcomp runs")
        })
        .collect();
    let peak = wait_peak_rss_mb(children);
    (started.elapsed().as_secs_f64(), peak)
}

/// Writes a flight of `hours` at `rate_hz` into `folder`; its path and
/// CSV size, MB.
fn long_flight(folder: &Path, hours: f64, rate_hz: f64) -> (std::path::PathBuf, f64) {
    let mut raw = RawScenario {
        seed: 7,
        sample_rate_hz: rate_hz,
        ..RawScenario::default()
    };
    raw.survey.line_count = (10.0 * hours).round() as usize;
    raw.survey.line_length_m = 18_000.0;
    let flight = magcomp::simulate::simulate(&Scenario::try_from(raw).expect("a valid scenario")).expect("simulated");
    let path = folder.join(format!("long_{hours}h_{rate_hz}hz.csv"));
    magcomp::formats::write_flight_log(&flight.log, &path).expect("written");
    let size = std::fs::metadata(&path).expect("written").len() as f64 / 1e6;
    (path, size)
}

/// `magcomp compensate flight` alone with `threads` workers: wall time,
/// s, and peak resident set, MB.
fn compensate(flight: &Path, threads: usize) -> (f64, f64) {
    let started = Instant::now();
    let child = Command::new(magcomp_binary())
        .args(["compensate", flight.to_str().expect("UTF-8 path"), "--out"])
        .arg(flight.with_extension("out.csv"))
        .env("RAYON_NUM_THREADS", threads.to_string())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("magcomp runs");
    let peak = wait_peak_rss_mb(vec![child]);
    (started.elapsed().as_secs_f64(), peak)
}

/// `name=a,b` arguments of the bench.
fn argument(name: &str) -> Option<String> {
    std::env::args().find_map(|a| a.strip_prefix(&format!("{name}=")).map(str::to_string))
}

fn main() {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let flights: usize = argument("flights").and_then(|n| n.parse().ok()).unwrap_or(4 * cores);
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
    println!("machine: {cores} cores");
    // `setups=1x16,16x1`: processes × threads to measure.
    let mut setups: Vec<(usize, usize)> = match argument("setups") {
        Some(list) => list
            .split(',')
            .filter_map(|s| s.split_once('x'))
            .filter_map(|(p, t)| Some((p.parse().ok()?, t.parse().ok()?)))
            .collect(),
        None => vec![(1, 1), (1, 2), (1, cores), (cores, 1)],
    };
    setups.sort();
    setups.dedup();
    let mut rates = Vec::new();
    let mut walls = std::collections::BTreeMap::new();
    for (shards, threads) in setups {
        let name = format!("{shards}x{threads}");
        let config = folder.path().join(format!("{name}.toml"));
        std::fs::write(
            &config,
            format!("[output]\ndirectory = \"out_{name}\"\n\n[campaign]\ninputs = [\"flights/*.csv\"]\n"),
        )
        .expect("config written");
        let (wall, peak) = run(&config, shards, threads);
        let (skipped, _) = run(&config, shards, threads);
        let rate = flights as f64 / (wall / 60.0);
        println!(
            "  {shards} process(es) of {threads} thread(s): {wall:.1} s, {:.2} s a flight, {rate:.1} flights/min; peak RSS {peak:.0} MB a process",
            wall / flights as f64,
        );
        println!(
            "    campaign machinery alone (every flight current: hash input and settings, read the status): {skipped:.2} s, {:.2} % of the processing",
            100.0 * skipped / wall
        );
        rates.push(rate);
        walls.insert((shards, threads), wall);
    }
    if let (Some(one), Some(shards)) = (walls.get(&(1, cores)), walls.get(&(cores, 1))) {
        println!(
            "one process of {cores} threads against {cores} one-thread shards: {:.2}× their wall time (goal: at most 1.25×)",
            one / shards
        );
    }
    if let (Some(one), Some(two)) = (walls.get(&(1, 1)), walls.get(&(1, 2))) {
        println!("one process, 1 → 2 threads: {:.2}× faster", one / two);
    }
    let node_rate = rates.iter().copied().fold(0.0, f64::max);
    println!("projected wall time of 10 000 such flights at {node_rate:.1} flights/min a node (the best above):");
    for nodes in [1, 10, 100, 1000] {
        let minutes = 10_000.0 / (node_rate * nodes as f64);
        println!("  {nodes:>5} nodes: {minutes:.1} min ({:.2} h)", minutes / 60.0);
    }
    if argument("memory").as_deref() == Some("no") {
        return;
    }
    let (hour, size) = long_flight(folder.path(), 1.0, 10.0);
    println!("one flight alone (magcomp compensate, 1 h at 10 Hz, {size:.0} MB of CSV):");
    let mut threads = vec![1, 2, cores];
    threads.dedup();
    // A first run, not counted, brings the file and the binary into the
    // page cache as the campaign's own reads did.
    compensate(&hour, 1);
    let mut one_thread = f64::NAN;
    for n in threads {
        let (wall, peak) = compensate(&hour, n);
        if n == 1 {
            one_thread = wall;
        }
        println!(
            "  {n} thread(s): {wall:.2} s, {:.2}× one thread, peak RSS {peak:.0} MB",
            one_thread / wall
        );
    }
    println!("peak memory of one flight, compensated alone with every core:");
    for (hours, rate_hz) in [(1.0, 10.0), (1.0, 20.0), (3.0, 10.0), (3.0, 20.0)] {
        let (path, size) = long_flight(folder.path(), hours, rate_hz);
        let (wall, peak) = compensate(&path, cores);
        println!(
            "  {hours} h at {rate_hz} Hz ({size:.0} MB of CSV): {wall:.1} s, peak RSS {peak:.0} MB, {:.1} bytes per byte of input",
            peak / size
        );
    }
}
