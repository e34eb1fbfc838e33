//! A campaign's flights in one process: several flights at once, and
//! within each, its channels and diagnosis candidates on the same worker
//! threads.
//!
//! [`run_flights`] starts [`FlightsAtOnce`] flight slots, one on each of
//! as many workers of a rayon pool of the run's own. Each slot takes the next flight of
//! the run's order and processes it; the flight's own parallel work
//! (channels, candidates, survey lines) goes to the same pool, where every
//! slot's work is stolen by whichever worker is free, the slots' own
//! workers among them while their flights wait on it. So a machine of N
//! cores holds N flights in memory, no more, runs N threads, and keeps its
//! cores busy while one flight reads or writes. A flight's outputs do
//! not depend on which slot or how many threads process it: each flight's
//! work is the same whatever else runs beside it.
//!
//! A flight compensated with the model another flight of the run writes
//! waits for that flight to finish; [`dependency_order`] puts such flights
//! after every other, so the flight it waits for is always already taken.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use super::{fail_campaign_flight, process_campaign_flight, CampaignFlight, Shard};
use crate::config::{FlightJob, Pipeline};
use crate::error::{Error, Result};
use crate::messages::progress::Meter;
use crate::output::sink::FlightOutputs;

/// How many flights a run holds in memory at once, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightsAtOnce {
    /// Flights processed side by side (at least 1).
    pub count: usize,
    /// Why that many, for the user.
    pub reason: String,
}

/// A flight's peak memory per byte of its input CSV (the numbers parsed
/// to `f64`, the band-passed copies, the regressors of every model and
/// diagnosis candidate, the outputs staged). `cargo bench --bench
/// campaign` measures it: simulated flights of 1 and 3 hours at 10 and
/// 20 Hz (8 to 40 MB of CSV) peak at 46 to 165 MB alone, 5.8 to 4.1 bytes
/// per byte, falling with length as a fixed part is shared out.
const PEAK_BYTES_PER_INPUT_BYTE: f64 = 6.0;

/// A process's own memory beside its flights' (code, worker stacks),
/// bytes.
const PROCESS_BYTES: f64 = 50e6;

impl FlightsAtOnce {
    /// One flight for each of `threads` worker threads, no more than the
    /// `flights` to do, and no more than `available` bytes of memory hold
    /// when each flight needs `PEAK_BYTES_PER_INPUT_BYTE` times its
    /// largest input (`largest_input` bytes). `available` is `None` where
    /// the system does not say.
    pub fn choose(threads: usize, flights: usize, largest_input: u64, available: Option<u64>) -> Self {
        let threads = threads.max(1);
        let per_flight = PEAK_BYTES_PER_INPUT_BYTE * largest_input as f64;
        let by_memory = available.map(|bytes| (((bytes as f64 - PROCESS_BYTES) / per_flight.max(1.0)) as usize).max(1));
        let count = threads.min(flights.max(1)).min(by_memory.unwrap_or(usize::MAX));
        let gigabytes = |bytes: f64| bytes / 1e9;
        let reason = match (by_memory, available) {
            (Some(cap), Some(bytes)) if cap < threads.min(flights.max(1)) => format!(
                "{count} of {threads} worker threads' worth: the largest flight needs about {:.1} GB and {:.1} GB of memory is available",
                gigabytes(per_flight),
                gigabytes(bytes as f64)
            ),
            _ if flights < threads => format!("one for each flight (there are {threads} worker threads)"),
            _ => format!("one for each of the {threads} worker threads (RAYON_NUM_THREADS sets them)"),
        };
        FlightsAtOnce { count, reason }
    }

    /// [`FlightsAtOnce::choose`] for `jobs` on this machine: the worker
    /// threads of the rayon pool, and the memory the system has available.
    pub fn for_jobs(jobs: &[&FlightJob]) -> Self {
        let largest = jobs
            .iter()
            .filter_map(|job| std::fs::metadata(&job.input).ok())
            .map(|meta| meta.len())
            .max()
            .unwrap_or(0);
        FlightsAtOnce::choose(rayon::current_num_threads(), jobs.len(), largest, available_memory())
    }
}

/// The memory the system can give without swapping (`MemAvailable` of
/// `/proc/meminfo`), bytes; `None` elsewhere.
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kilobytes: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kilobytes * 1024)
}

/// The model JSONs the flights `order` of `pipeline` write, each with the
/// flight writing it (a flight given a model writes none).
fn model_outputs<'a>(pipeline: &'a Pipeline, order: &[usize]) -> HashMap<PathBuf, &'a FlightJob> {
    order
        .iter()
        .map(|&i| &pipeline.flights[i])
        .filter_map(|job| Some((FlightOutputs::for_job(&pipeline.output_directory, job).model_json?, job)))
        .collect()
}

/// `order` with each flight compensated with the model another flight
/// of `order` writes moved after every flight that is not, the rest kept
/// in their order.
pub fn dependency_order(pipeline: &Pipeline, mut order: Vec<usize>) -> Vec<usize> {
    let outputs = model_outputs(pipeline, &order);
    let written_here = |model: &PathBuf| outputs.get(model).is_some_and(|job| job.model.is_none());
    order.sort_by_key(|&i| pipeline.flights[i].model.as_ref().is_some_and(written_here));
    order
}

/// A flight of the run, finished.
#[derive(Debug)]
pub struct FinishedFlight {
    /// Its index in the pipeline's flights.
    pub index: usize,
    /// What preparing its outputs noted (folders created).
    pub notes: Vec<crate::messages::Setup>,
    /// How it ended; an error is a status that could not be written.
    pub flight: Result<CampaignFlight>,
}

impl FinishedFlight {
    /// Whether it failed (a failed flight, or a status not written).
    pub fn failed(&self) -> bool {
        match &self.flight {
            Ok(CampaignFlight::UpToDate(_)) => false,
            Ok(CampaignFlight::Processed { result, .. }) => result.is_err(),
            Err(_) => true,
        }
    }
}

/// Where a run stands, for a progress line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Flights finished.
    pub finished: usize,
    /// Flights being processed now.
    pub running: usize,
    /// Flights in the run.
    pub total: usize,
    /// The time left at the rate of the flights processed so far (not
    /// those found current); `None` before the first.
    pub left: Option<Duration>,
}

/// What the slots share: the next flight to take, the models written and
/// failed so far, and the finished flights.
struct Board {
    next: usize,
    /// Flights finished so far.
    done: usize,
    running: usize,
    finished: Vec<Option<FinishedFlight>>,
    written: HashSet<PathBuf>,
    failed: HashSet<PathBuf>,
    /// Time spent on processed flights, and how many.
    spent: (Duration, u32),
}

impl Board {
    /// The board of a run of `total` flights, none taken.
    fn new(total: usize) -> Self {
        Board {
            next: 0,
            done: 0,
            running: 0,
            finished: (0..total).map(|_| None).collect(),
            written: HashSet::new(),
            failed: HashSet::new(),
            spent: (Duration::ZERO, 0),
        }
    }

    /// Takes the next of the `total` flights: its position, and the run's
    /// progress as it starts; `None` when every flight has been taken.
    fn take(&mut self, total: usize, slots: usize) -> Option<(usize, Progress)> {
        if self.next == total {
            return None;
        }
        self.next += 1;
        self.running += 1;
        Some((self.next - 1, self.progress(total, slots)))
    }

    fn progress(&self, total: usize, slots: usize) -> Progress {
        let finished = self.done;
        let left = match self.spent {
            (_, 0) => None,
            (time, done) => {
                let rounds = (total - finished).div_ceil(slots.max(1)) as u32;
                Some(time / done * rounds)
            }
        };
        Progress {
            finished,
            running: self.running,
            total,
            left,
        }
    }
}

/// Processes the flights `order` of `pipeline` (in [`dependency_order`]),
/// `at_once` at a time, into its output folder; calls `started` as each
/// begins (the meter it returns hears the flight's stages, and is dropped
/// as the flight ends) and `finished` as each ends (from the slot that ran
/// it), and returns every flight in `order`'s order. `prepare` makes a flight's
/// output folders and says what it made; a failure there fails the flight
/// with the same error when it writes.
pub fn run_flights(
    pipeline: &Pipeline,
    order: &[usize],
    (shard, force, at_once): (Shard, bool, usize),
    prepare: &(dyn Fn(&FlightJob, &FlightOutputs) -> Vec<crate::messages::Setup> + Sync),
    started: &(dyn Fn(&FlightJob, Progress) -> Box<dyn Meter> + Sync),
    finished: &(dyn Fn(&FinishedFlight, Progress) + Sync),
) -> Vec<FinishedFlight> {
    let folder = &pipeline.output_directory;
    let outputs = model_outputs(pipeline, order);
    // The campaign's, for a model another shard writes.
    let campaign: Vec<usize> = (0..pipeline.flights.len()).collect();
    let everywhere = model_outputs(pipeline, &campaign);
    let board = Mutex::new(Board::new(order.len()));
    let changed = Condvar::new();
    let slots = at_once.clamp(1, order.len().max(1));
    let slot = || loop {
        let Some((position, progress)) = lock(&board).take(order.len(), slots) else {
            return;
        };
        let job = &pipeline.flights[order[position]];
        let meter = started(job, progress);
        // A flight applying another's model waits for that flight, which
        // was taken before it (the order puts it first).
        let unavailable =
            (job.model.as_ref()).and_then(|model| await_model(model, (&outputs, &everywhere), (&board, &changed)));
        let began = Instant::now();
        let flight_outputs = FlightOutputs::for_job(folder, job);
        let notes = prepare(job, &flight_outputs);
        // Should the flight panic (a fault of magcomp's, not of the data),
        // a flight waiting for its model is told it failed before the
        // panic goes on, so no slot waits for ever.
        let processed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match unavailable {
            Some(error) => fail_campaign_flight(job, folder, shard, error),
            None => process_campaign_flight(job, &pipeline.settings, folder, (shard, force), meter.as_ref()),
        }));
        drop(meter);
        let flight = match processed {
            Ok(flight) => flight,
            Err(panic) => {
                if let Some(model) = flight_outputs.model_json {
                    lock(&board).failed.insert(model);
                }
                changed.notify_all();
                std::panic::resume_unwind(panic);
            }
        };
        let done = FinishedFlight {
            index: order[position],
            notes,
            flight,
        };
        {
            let mut board = lock(&board);
            board.finish(position, done, (began.elapsed(), flight_outputs.model_json));
            let progress = board.progress(order.len(), slots);
            // Under the lock: one flight's lines are printed whole.
            if let Some(done) = &board.finished[position] {
                finished(done, progress);
            }
        }
        changed.notify_all();
    };
    on_threads(slots, &slot);
    let board = board.into_inner().unwrap_or_else(|poisoned| poisoned.into_inner());
    board.finished.into_iter().flatten().collect()
}

/// Runs `slot` on `slots` worker threads of a rayon pool of the run's own
/// (as many workers as the current pool, `RAYON_NUM_THREADS`), one each,
/// until each returns; a panic on one goes on here once all have returned.
///
/// A slot is a worker, not a thread beside the pool: while its flight
/// waits on its own parallel work (channels, candidates, lines) it takes
/// part in that work and in other flights', instead of sleeping while the
/// pool's workers spin for work, and the process runs as many threads as
/// the pool has. A broadcast job runs once on each worker and cannot be
/// stolen, so no worker starts a second flight while one of its own waits:
/// flights in memory stay at most `slots`. The pool is the run's own, so
/// no other work on the caller's pool (another run among it) can be
/// stolen under a slot's flight, and its workers have the main thread's
/// stack, since each processes whole flights.
fn on_threads(slots: usize, slot: &(dyn Fn() + Sync)) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(rayon::current_num_threads())
        .stack_size(8 << 20)
        .thread_name(|k| format!("flight worker {k}"))
        .build();
    match pool {
        Ok(pool) => {
            pool.broadcast(|context| {
                if context.index() < slots {
                    slot();
                }
            });
        }
        // No threads to be had: this one processes the flights.
        Err(_) => slot(),
    }
}

/// Waits until the flight of this run that writes `model` has written it
/// or failed; why the model cannot be applied, if it cannot.
fn await_model(
    model: &Path,
    (outputs, everywhere): (&HashMap<PathBuf, &FlightJob>, &HashMap<PathBuf, &FlightJob>),
    (board, changed): (&Mutex<Board>, &Condvar),
) -> Option<Error> {
    let writer = outputs.get(model).filter(|writer| writer.model.is_none());
    if writer.is_some() {
        let mut board = lock(board);
        while !board.written.contains(model) && !board.failed.contains(model) {
            board = changed.wait(board).unwrap_or_else(|poisoned| poisoned.into_inner());
        }
    }
    model_unavailable(model, (outputs, everywhere), &lock(board).failed)
}

impl Board {
    /// Records the flight at `position` as done: its time (not counted
    /// when it was up to date), and its model as written or failed.
    fn finish(&mut self, position: usize, done: FinishedFlight, (took, model): (Duration, Option<PathBuf>)) {
        if !matches!(done.flight, Ok(CampaignFlight::UpToDate(_))) {
            self.spent = (self.spent.0 + took, self.spent.1 + 1);
        }
        if let Some(model) = model {
            if done.failed() {
                self.failed.insert(model);
            } else {
                self.written.insert(model);
            }
        }
        self.running -= 1;
        self.finished[position] = Some(done);
        self.done += 1;
    }
}

fn lock(board: &Mutex<Board>) -> std::sync::MutexGuard<'_, Board> {
    board.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Why a flight's saved `model` cannot be applied in this run: the flight
/// of the run that writes it failed (the file there, if any, is an
/// earlier run's), or no flight writes it and it is not there, or the
/// flight that would is given a model itself and writes none.
/// `everywhere` is every flight of the campaign's, for a model a flight
/// of another shard writes.
fn model_unavailable(
    model: &Path,
    (outputs, everywhere): (&HashMap<PathBuf, &FlightJob>, &HashMap<PathBuf, &FlightJob>),
    failed: &HashSet<PathBuf>,
) -> Option<Error> {
    let writer = outputs.get(model);
    let reason = match writer {
        Some(job) if job.model.is_some() => format!(
            "it is never written: {} is itself compensated with a saved model, and a flight given a model writes none; name the model of the flight that flew the calibration box",
            job.input.display()
        ),
        Some(job) if failed.contains(model) => format!(
            "the flight that writes it, {}, failed in this run, so it is not that flight's model now (a file there is an earlier run's); fix that flight and run again",
            job.input.display()
        ),
        Some(_) => return None,
        None if model.is_file() => return None,
        None => match everywhere.get(model) {
            Some(job) => format!(
                "it is not written yet: the flight that writes it, {}, is in another shard (--shard); run that shard first (or the calibration flights before the rest), then this one",
                job.input.display()
            ),
            None => "no such file, and no flight of this run writes it: give the model JSON that `magcomp compensate --model` or a run wrote for the calibration flight".into(),
        },
    };
    Some(Error::ModelUnavailable {
        model: model.to_path_buf(),
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_flight_for_each_thread_unless_memory_or_the_flights_run_short() {
        let gb = 1_000_000_000u64;
        // 16 threads, 40 flights of 100 MB, plenty of memory: 16.
        let plenty = FlightsAtOnce::choose(16, 40, 100_000_000, Some(64 * gb));
        assert_eq!(plenty.count, 16);
        assert!(plenty.reason.contains("16 worker threads"), "{}", plenty.reason);
        // Three flights on 16 threads: 3.
        assert_eq!(FlightsAtOnce::choose(16, 3, 100_000_000, Some(64 * gb)).count, 3);
        // Flights of 2 GB need about 12 GB each: 30 GB holds two.
        let short = FlightsAtOnce::choose(16, 40, 2 * gb, Some(30 * gb));
        assert_eq!(short.count, 2);
        assert!(
            short.reason.contains("12.0 GB") && short.reason.contains("30.0 GB"),
            "{}",
            short.reason
        );
        // 128 GB holds ten of them.
        assert_eq!(FlightsAtOnce::choose(16, 40, 2 * gb, Some(128 * gb)).count, 10);
        // Never none, whatever the memory; no memory figure, no cap.
        assert_eq!(FlightsAtOnce::choose(16, 40, 2 * gb, Some(0)).count, 1);
        assert_eq!(FlightsAtOnce::choose(0, 0, 0, None).count, 1);
        assert_eq!(FlightsAtOnce::choose(8, 40, 2 * gb, None).count, 8);
    }
}
