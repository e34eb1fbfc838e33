//! Progress on a terminal: a line per flight in progress, with a bar for
//! each long stage (the channels diagnosed, fitted, assessed), and for
//! `run` a bar of the flights done with the time left. indicatif draws
//! nothing when stderr is not a terminal (piped or redirected).

use std::path::Path;
use std::time::Duration;

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use magcomp::campaign::Progress;
use magcomp::messages::progress::{Meter, Stage};

use super::duration_words;

/// One flight's line: its name, the stage and, for a stage of several
/// steps, a bar and how much of it is done.
pub struct FlightBar {
    bar: ProgressBar,
}

impl FlightBar {
    /// A line for `flight` on its own (`compensate`), first saying `first`.
    pub fn alone(flight: &Path, first: &str) -> Self {
        Self::on(ProgressBar::new(0), flight, first)
    }

    /// A line for `flight` under the campaign's bar.
    pub fn in_campaign(campaign: &CampaignBar, flight: &Path, first: &str) -> Self {
        Self::on(campaign.lines.add(ProgressBar::new(0)), flight, first)
    }

    fn on(bar: ProgressBar, flight: &Path, first: &str) -> Self {
        bar.set_style(stage_style(0));
        bar.set_prefix(flight.display().to_string());
        bar.set_message(first.to_string());
        bar.enable_steady_tick(Duration::from_millis(120));
        FlightBar { bar }
    }
}

impl Meter for FlightBar {
    fn begin(&self, stage: Stage, steps: u64) {
        self.bar.set_style(stage_style(steps));
        self.bar.set_length(steps);
        self.bar.set_position(0);
        self.bar.set_message(stage.words());
    }

    fn step(&self) {
        self.bar.inc(1);
    }
}

impl Drop for FlightBar {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

/// A stage's line: a bar and the share done when it has steps to count,
/// a spinner otherwise; both with the time the flight has taken.
fn stage_style(steps: u64) -> ProgressStyle {
    let template = match steps {
        0 => "{spinner} {prefix}: {msg} [{elapsed}]",
        _ => "{spinner} {prefix}: {msg} [{bar:20}] {percent:>3} % [{elapsed}]",
    };
    ProgressStyle::with_template(template)
        .unwrap_or_else(|_| ProgressStyle::default_spinner())
        .progress_chars("=> ")
}

/// `run`'s display: the flights done out of the run's, with the time left,
/// above a line per flight in progress.
pub struct CampaignBar {
    lines: MultiProgress,
    flights: ProgressBar,
}

impl CampaignBar {
    /// The display of a run of `total` flights, on stderr.
    pub fn new(total: usize) -> Self {
        Self::drawn_to(total, ProgressDrawTarget::stderr())
    }

    fn drawn_to(total: usize, target: ProgressDrawTarget) -> Self {
        let lines = MultiProgress::with_draw_target(target);
        let flights = lines.add(ProgressBar::new(total as u64));
        flights.set_style(
            ProgressStyle::with_template("[{bar:30}] {pos}/{len} flights done{msg} [{elapsed}]")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        flights.enable_steady_tick(Duration::from_millis(250));
        CampaignBar { lines, flights }
    }

    /// Shows `progress`: the flights done, how many run now, the time left.
    /// A view older than the one shown (taken by a slot before another
    /// finished its flight) is not shown.
    pub fn show(&self, progress: Progress) {
        if (progress.finished as u64) < self.flights.position() {
            return;
        }
        self.flights.set_position(progress.finished as u64);
        self.flights.set_message(progress_words(progress));
    }

    /// Runs `print` with the display taken off the terminal, so what it
    /// prints is not drawn over.
    pub fn suspend<R>(&self, print: impl FnOnce() -> R) -> R {
        self.lines.suspend(print)
    }

    /// Takes the display off the terminal for good.
    pub fn clear(&self) {
        self.flights.finish_and_clear();
        // Nothing to do when the terminal is gone.
        let _ = self.lines.clear();
    }
}

/// ", 2 in progress, about 3 min left".
fn progress_words(progress: Progress) -> String {
    let running = match progress.running {
        0 => String::new(),
        n => format!(", {n} in progress"),
    };
    let left = match progress.left {
        Some(left) if progress.finished < progress.total => format!(", about {} left", duration_words(left)),
        _ => String::new(),
    };
    format!("{running}{left}")
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use indicatif::TermLike;

    use super::*;

    /// A terminal that keeps what is written to it.
    #[derive(Debug, Clone, Default)]
    struct Screen(Arc<Mutex<String>>);

    impl Screen {
        fn text(&self) -> String {
            self.0.lock().unwrap().clone()
        }
    }

    impl TermLike for Screen {
        fn width(&self) -> u16 {
            120
        }
        fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn write_line(&self, s: &str) -> std::io::Result<()> {
            self.0.lock().unwrap().push_str(&format!("{s}\n"));
            Ok(())
        }
        fn write_str(&self, s: &str) -> std::io::Result<()> {
            self.0.lock().unwrap().push_str(s);
            Ok(())
        }
        fn clear_line(&self) -> std::io::Result<()> {
            Ok(())
        }
        fn flush(&self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_flight_shows_its_stage_and_the_share_of_its_channels_done() {
        let screen = Screen::default();
        let campaign = CampaignBar::drawn_to(4, ProgressDrawTarget::term_like(Box::new(screen.clone())));
        campaign.show(Progress {
            finished: 1,
            running: 2,
            total: 4,
            left: Some(Duration::from_secs(150)),
        });
        let flight = FlightBar::in_campaign(&campaign, Path::new("flight_2.csv"), "starting");
        flight.begin(Stage::Diagnosing, 10);
        for _ in 0..4 {
            flight.step();
        }
        // A bar left standing is drawn one last time, as it is now.
        flight.bar.abandon();
        campaign.flights.abandon();
        let text = screen.text();
        assert!(text.contains("flight_2.csv: diagnosing [========>"), "{text}");
        assert!(text.contains(" 40 %"), "{text}");
        assert!(
            text.contains("1/4 flights done, 2 in progress, about 3 min left"),
            "{text}"
        );
    }

    #[test]
    fn a_stage_without_steps_has_no_bar() {
        let screen = Screen::default();
        let flight = FlightBar::alone(Path::new("survey.csv"), "starting");
        flight
            .bar
            .set_draw_target(ProgressDrawTarget::term_like(Box::new(screen.clone())));
        flight.begin(Stage::Writing, 0);
        flight.bar.abandon();
        let text = screen.text();
        assert!(text.contains("survey.csv: writing ["), "{text}");
        assert!(!text.contains('%'), "{text}");
    }
}
