//! Shared-grid multi-agent path finding (MAPF): everything the coordinator decides when it is
//! the authority of one grid shared by a fleet. Pure: no IO, no bus, no clocks.
//!
//! - [`instance`]: a validated instance (grid, starts, goals, BFS distance tables).
//! - [`moves`]: the five moves and a robot's [`Intent`] (its moves ranked best first).
//! - [`world`]: the per-tick resolver that grants every robot one collision-free move.
//! - [`check`](mod@check): an independent checker of finished paths and their costs.
//! - [`paths`]: the mapf-visualizer path format, written and parsed.
#![deny(missing_docs)]

pub mod check;
pub mod instance;
pub mod moves;
pub mod paths;

pub use check::{Costs, Violation, check};
pub use instance::{Instance, InstanceError, MAX_AGENTS};
pub use moves::{Intent, IntentError, Move};
pub use paths::{PathsError, parse_paths, write_paths};
pub mod world;

mod pibt;
mod plan;
mod search;

pub use world::{AgentStats, Status, Tick, World, WorldConfig, WorldError};
