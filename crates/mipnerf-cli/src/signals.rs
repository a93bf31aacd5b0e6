//! Ctrl-C (SIGINT), SIGTERM (kill, systemd, Docker, Slurm, CI) and SIGHUP (a closed terminal),
//! alike, in every command: the process exits with code 130.
//!
//! - During training ([`Cooperation`] held) the first signal lets the step finish and the
//!   checkpoint be written; the loop sees [`stop_requested`].
//! - A phase that checks between its items (`render`, between images) also holds a
//!   [`Cooperation`] and ends with [`Interrupted`]. Inside an item that may take long (an image:
//!   minutes at the paper preset on a CPU, hours at 16384 px) it [`suspend`](Cooperation::suspend)s
//!   cooperating, so that a signal there stops the process at once, saying what the phase left.
//! - Anywhere else the process exits at once. Every output a command leaves is either whole or
//!   absent: files are written to a temporary name and renamed, `eval` fills `eval.partial/` and
//!   renames it, and `convert` writes `metadata.json` last.
//! - A second signal always exits at once.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The exit code of an interrupted command (128 + SIGINT, the shell's convention), whatever the
/// signal.
pub const EXIT_INTERRUPTED: i32 = 130;

static STOP: AtomicBool = AtomicBool::new(false);
static ACTED_ON: AtomicBool = AtomicBool::new(false);
static COOPERATING: AtomicUsize = AtomicUsize::new(0);
/// What a suspended phase has left, said when a signal stops it ([`Cooperation::suspend`]).
static LEFT: Mutex<Option<String>> = Mutex::new(None);

/// Temporary files filled over a long time (a video, frame by frame, under its temporary name):
/// a signal that exits at once removes them, as their owners would on the way out.
static PARTIAL_FILES: Mutex<Vec<std::path::PathBuf>> = Mutex::new(Vec::new());

/// Registers `path`, a temporary file that is filled over a long time, to be removed if a signal
/// exits the process at once; [`keep_on_exit`] takes it back (it was renamed into place, or
/// removed).
pub fn remove_on_exit(path: &std::path::Path) {
    if let Ok(mut files) = PARTIAL_FILES.lock() {
        files.push(path.to_path_buf());
    }
}

/// Takes back a [`remove_on_exit`].
pub fn keep_on_exit(path: &std::path::Path) {
    if let Ok(mut files) = PARTIAL_FILES.lock() {
        files.retain(|f| f != path);
    }
}

/// Exits at once, with [`EXIT_INTERRUPTED`], removing the [`remove_on_exit`] files first.
fn exit_now() -> ! {
    if let Ok(files) = PARTIAL_FILES.lock() {
        for f in files.iter() {
            let _ = std::fs::remove_file(f);
        }
    }
    std::process::exit(EXIT_INTERRUPTED);
}

/// Installs the handler (once, at the start of `main`).
pub fn install() {
    let _ = ctrlc::set_handler(|| {
        if STOP.swap(true, Ordering::SeqCst) {
            eprintln!("\ninterrupted again: stopping now");
            exit_now();
        }
        if COOPERATING.load(Ordering::SeqCst) == 0 {
            // The handler runs on its own thread (the `ctrlc` crate's), so it may lock.
            match LEFT.lock().ok().and_then(|left| left.clone()) {
                Some(left) => eprintln!("\ninterrupted (Ctrl-C, SIGTERM or SIGHUP): stopping; {left}"),
                None => eprintln!("\ninterrupted (Ctrl-C, SIGTERM or SIGHUP): stopping"),
            }
            exit_now();
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

    /// Stops cooperating while the returned guard lives, for one item of the phase that may take
    /// long: a signal then exits at once, saying `left` (what the phase has left; the item in
    /// progress is lost, and every file is whole). `None` when a signal came before: the phase
    /// acts on it as between items.
    #[must_use = "cooperation is suspended only while the guard lives"]
    pub fn suspend(&self, left: String) -> Option<Suspension<'_>> {
        if let Ok(mut slot) = LEFT.lock() {
            *slot = Some(left);
        }
        COOPERATING.fetch_sub(1, Ordering::SeqCst);
        let suspension = Suspension(std::marker::PhantomData);
        // A signal before the line above was left for the phase; one after it exits at once.
        (!stop_requested()).then_some(suspension)
    }
}

/// A [`Cooperation`] suspended ([`Cooperation::suspend`]); cooperation resumes when dropped.
#[must_use = "cooperation is suspended only while this is alive"]
pub struct Suspension<'a>(std::marker::PhantomData<&'a Cooperation>);

impl Drop for Suspension<'_> {
    fn drop(&mut self) {
        COOPERATING.fetch_add(1, Ordering::SeqCst);
        if let Ok(mut slot) = LEFT.lock() {
            *slot = None;
        }
    }
}

impl Drop for Cooperation {
    fn drop(&mut self) {
        COOPERATING.fetch_sub(1, Ordering::SeqCst);
        // A signal that came during the phase and was not acted on (it ended first) stops the
        // process now, before any later phase starts.
        if stop_requested() && !ACTED_ON.load(Ordering::SeqCst) && COOPERATING.load(Ordering::SeqCst) == 0 {
            eprintln!("stopped: interrupted");
            exit_now();
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
