//! Sharing Q-values in a fleet, the code both processes run, without IO: the robot's hint
//! batcher and merged-hint applier ([`apply`]) and the coordinator's fleet table with its merge
//! rules ([`merge`]). The benchmarks (`fleetbench`) run the same code on their lightweight
//! robots, so a transport comparison measures the transport, not another copy of the logic.

pub mod apply;
pub mod merge;

pub use apply::{ApplyCtx, HintBatcher, MergedApplier};
pub use merge::FleetTable;
