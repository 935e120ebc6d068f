//! What a long study tells its caller while it runs: how many runs it will make, each run done,
//! and notes for the person watching (a map skipped, where the maps came from). The caller
//! decides how to show them (the CLI: a progress bar and `qfleet: …` lines on stderr).

/// Receives a study's progress; every method defaults to doing nothing.
pub trait Progress {
    /// The study is about to make `total` runs.
    fn start(&mut self, _total: u64) {}
    /// One more run finished.
    fn advance(&mut self) {}
    /// Every run finished (the study goes on to write its files).
    fn finish(&mut self) {}
    /// A line for the person watching, e.g. `eval: skipped …`.
    fn note(&mut self, _line: &str) {}
}

/// No progress shown (tests, callers that only want the result).
impl Progress for () {}
