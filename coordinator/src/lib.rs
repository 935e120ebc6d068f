//! The qfleet coordinator: receives every robot's traffic, merges Q hints into a fleet table,
//! sends merged hints back, measures the update loop, and writes the run's result.
//!
//! A thin process over the `bus` crate; the merge rules live in [`merge`], the run and the wait
//! strategies in [`run`](mod@run).

pub mod experiment;
pub mod merge;
pub mod run;

pub use merge::{FleetTable, MergeRule};
pub use run::{CoordArgs, CoordError, RobotEntry, RunResult, Throughput, WaitStrategy, run};
