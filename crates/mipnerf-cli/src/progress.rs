//! Progress that works everywhere: a bar on a terminal, plain lines where standard error is not one
//! (nohup, CI, `| tee`), nothing with `--quiet`.
//!
//! Plain lines come every [`interval`] (30 s unless `MIPNERF_PROGRESS_SECONDS` says otherwise), so
//! a log shows a long run alive at least every 30 s and never floods; one more line closes each
//! task.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// Seconds between plain progress lines: `MIPNERF_PROGRESS_SECONDS` (tests and busy logs set it),
/// else 30.
#[must_use]
pub fn interval() -> Duration {
    std::env::var("MIPNERF_PROGRESS_SECONDS")
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0)
        .map_or(Duration::from_secs(30), Duration::from_secs_f64)
}

/// `1h02m03s`, `4m05s` or `6s`.
pub fn hms(d: Duration) -> String {
    let s = d.as_secs();
    match (s / 3600, s / 60 % 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, s) => format!("{h}h{m:02}m{s:02}s"),
    }
}

enum Mode {
    Hidden,
    Bar(ProgressBar),
    Lines { last: Instant, every: Duration },
}

/// One task's progress: `what` (e.g. "train"), a position out of a total, and a message.
pub struct Progress {
    what: String,
    total: u64,
    pos: u64,
    first: u64,
    start: Instant,
    message: String,
    mode: Mode,
}

impl Progress {
    /// Starts a task of `total` units at position `pos`; nothing is shown when `quiet`
    /// (`--quiet`, see `Session::progress`).
    #[must_use]
    pub fn new(quiet: bool, what: &str, pos: u64, total: u64) -> Self {
        let mode = if quiet {
            Mode::Hidden
        } else if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(total);
            bar.set_style(
                ProgressStyle::with_template("{prefix} {elapsed_precise} [{bar:30}] {pos}/{len} {msg} ETA {eta}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
            );
            bar.set_prefix(what.to_string());
            bar.set_position(pos);
            Mode::Bar(bar)
        } else {
            Mode::Lines { last: Instant::now(), every: interval() }
        };
        Self { what: what.to_string(), total, pos, first: pos, start: Instant::now(), message: String::new(), mode }
    }

    /// Prints a line above the bar (on standard error without one; nothing when quiet).
    pub fn println(&self, line: &str) {
        match &self.mode {
            Mode::Bar(b) => b.println(line),
            Mode::Lines { .. } => eprintln!("{line}"),
            Mode::Hidden => {}
        }
    }

    /// Sets the message shown after the counts (loss, PSNR, rays/s, ...).
    pub fn set_message(&mut self, message: String) {
        if let Mode::Bar(b) = &self.mode {
            b.set_message(message.clone());
        }
        self.message = message;
    }

    /// Moves to `pos`; in plain mode prints a line when the interval has passed.
    pub fn set_position(&mut self, pos: u64) {
        self.pos = pos;
        match &mut self.mode {
            Mode::Hidden => {}
            Mode::Bar(b) => b.set_position(pos),
            Mode::Lines { last, every } => {
                if last.elapsed() >= *every {
                    *last = Instant::now();
                    eprintln!("{}", self.line());
                }
            }
        }
    }

    /// Advances by one.
    pub fn inc(&mut self) {
        self.set_position(self.pos + 1);
    }

    /// The plain line: `train: 1200/2500 (48%) loss ... | elapsed 8m12s, ETA 9m01s`.
    fn line(&self) -> String {
        let elapsed = self.start.elapsed();
        let done = self.pos.saturating_sub(self.first);
        let left = self.total.saturating_sub(self.pos);
        let eta = if done == 0 {
            "?".to_string()
        } else {
            hms(Duration::from_secs_f64(elapsed.as_secs_f64() / done as f64 * left as f64))
        };
        let pct = if self.total == 0 { 100.0 } else { 100.0 * self.pos as f64 / self.total as f64 };
        let msg = if self.message.is_empty() { String::new() } else { format!(" {}", self.message) };
        format!("{}: {}/{} ({pct:.0}%){msg} | elapsed {}, ETA {eta}", self.what, self.pos, self.total, hms(elapsed))
    }

    /// Ends the task: clears the bar, or prints a last plain line.
    pub fn finish(&mut self) {
        match &self.mode {
            Mode::Hidden => {}
            Mode::Bar(b) => b.finish_and_clear(),
            Mode::Lines { .. } => eprintln!("{}", self.line()),
        }
        self.mode = Mode::Hidden;
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Mode::Bar(b) = &self.mode {
            b.finish_and_clear();
        }
    }
}
