//! Ctrl-C (SIGINT), SIGTERM (kill, systemd, Docker, Slurm, CI) and SIGHUP (a closed terminal),
//! alike, in every command: the process exits with code 130.
//!
//! - During training ([`Cooperation`] held) the first signal lets the step finish and the
//!   checkpoint be written; the loop sees [`stop_requested`].
//! - A phase that checks between its items (`render`, between images) also holds a
//!   [`Cooperation`] and ends with [`Interrupted`].
//! - Anywhere else the process exits at once. Every output a command leaves is either whole or
//!   absent: files are written to a temporary name and renamed, `eval` fills `eval.partial/` and
//!   renames it, and `convert` writes `metadata.json` last.
//! - A second signal always exits at once.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The exit code of an interrupted command (128 + SIGINT, the shell's convention), whatever the
/// signal.
pub const EXIT_INTERRUPTED: i32 = 130;

static STOP: AtomicBool = AtomicBool::new(false);
static ACTED_ON: AtomicBool = AtomicBool::new(false);
static COOPERATING: AtomicUsize = AtomicUsize::new(0);

/// Installs the handler (once, at the start of `main`).
pub fn install() {
    let _ = ctrlc::set_handler(|| {
        if STOP.swap(true, Ordering::SeqCst) {
            eprintln!("\ninterrupted again: stopping now");
            std::process::exit(EXIT_INTERRUPTED);
        }
        if COOPERATING.load(Ordering::SeqCst) == 0 {
            eprintln!("\ninterrupted (Ctrl-C, SIGTERM or SIGHUP): stopping");
            std::process::exit(EXIT_INTERRUPTED);
        }
        eprintln!(
            "\ninterrupted (Ctrl-C, SIGTERM or SIGHUP): finishing this step and saving what it has (again to stop at once)..."
        );
    });
}

/// Whether a signal asked the process to stop.
#[must_use]
pub fn stop_requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

/// Says that the running phase has acted on the stop (saved what it had, and will exit with
/// [`EXIT_INTERRUPTED`] after saying so).
pub fn acted_on() {
    ACTED_ON.store(true, Ordering::SeqCst);
}

/// While alive, a signal asks the running phase to stop (it checks [`stop_requested`]) instead of
/// exiting at once.
#[must_use = "the phase cooperates only while this is alive"]
pub struct Cooperation(());

impl Cooperation {
    /// Starts cooperating.
    pub fn start() -> Self {
        COOPERATING.fetch_add(1, Ordering::SeqCst);
        Self(())
    }
}

impl Drop for Cooperation {
    fn drop(&mut self) {
        COOPERATING.fetch_sub(1, Ordering::SeqCst);
        // A signal that came during the phase and was not acted on (it ended first) stops the
        // process now, before any later phase starts.
        if stop_requested() && !ACTED_ON.load(Ordering::SeqCst) && COOPERATING.load(Ordering::SeqCst) == 0 {
            eprintln!("stopped: interrupted");
            std::process::exit(EXIT_INTERRUPTED);
        }
    }
}

/// The error of a phase that stopped on a signal, saying what it left; `main` exits with
/// [`EXIT_INTERRUPTED`].
#[derive(Debug)]
pub struct Interrupted(pub String);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted: {}", self.0)
    }
}

impl std::error::Error for Interrupted {}
