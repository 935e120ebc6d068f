//! qfleet's learning studies, run in-process: one learner on one task ([`learn`]), the paper's
//! Table 1 regenerated ([`replicate`]), learner configurations on the map suite ([`eval`]), the
//! measured value of sharing over fleets of robots ([`sweep`]), and their figures ([`plots`],
//! [`runplots`]).
//!
//! Each study takes a typed options struct and returns a typed result (serde both ways) and
//! its own error enum, whose `is_bad_input` tells a caller the input was refused (the CLI's
//! exit code 2) from a study that failed while it ran (exit code 1). Nothing here parses a
//! command line or writes to the terminal: progress and notes go through [`Progress`], and
//! the fleet runs of a sweep through [`sweep::Fleet`], both implemented by the caller.

pub mod eval;
pub mod files;
pub mod learn;
pub mod plots;
pub mod progress;
pub mod replicate;
pub mod runplots;
pub mod sweep;

pub use progress::Progress;
