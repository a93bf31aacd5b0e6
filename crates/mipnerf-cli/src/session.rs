//! What every command shares from the global flags (`--quiet`, `--allow-unverified`) and the lines
//! it says only once, passed down from `main` rather than kept in process globals.

use std::sync::Mutex;

use crate::progress::Progress;

/// The global flags of one invocation, and the lines already said.
#[derive(Debug, Default)]
pub struct Session {
    /// `--quiet`: no progress bars or lines.
    pub quiet: bool,
    /// `--allow-unverified`: read checkpoints without a checksum instead of refusing them.
    pub allow_unverified: bool,
    said: Mutex<Vec<String>>,
}

impl Clone for Session {
    fn clone(&self) -> Self {
        Self { quiet: self.quiet, allow_unverified: self.allow_unverified, said: Mutex::new(self.said_lines()) }
    }
}

impl Session {
    /// The session of these flags.
    #[must_use]
    pub fn new(quiet: bool, allow_unverified: bool) -> Self {
        Self { quiet, allow_unverified, said: Mutex::new(Vec::new()) }
    }

    fn said_lines(&self) -> Vec<String> {
        self.said.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone()
    }

    /// Prints `line` to standard error unless this session has printed it already (the demo
    /// opens a backend for each of its phases; the choice is said once).
    pub fn say_once(&self, line: String) {
        let mut said = self.said.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if !said.contains(&line) {
            eprintln!("{line}");
            said.push(line);
        }
    }

    /// A task's progress (`what`, from `pos` of `total`), silent with `--quiet`.
    #[must_use]
    pub fn progress(&self, what: &str, pos: u64, total: u64) -> Progress {
        Progress::new(self.quiet, what, pos, total)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_is_said_once_per_session_and_a_clone_remembers_it() {
        let s = Session::new(true, false);
        s.say_once("backend: cpu".into());
        s.say_once("backend: cpu".into());
        s.say_once("backend: gpu".into());
        assert_eq!(s.said_lines(), ["backend: cpu", "backend: gpu"]);
        assert_eq!(s.clone().said_lines(), s.said_lines());
        assert!(Session::new(false, false).said_lines().is_empty(), "sessions share nothing");
    }
}
