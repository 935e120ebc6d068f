//! Grid maps and the tabular Q-learners of J. Peng's "Mobile Robot Path Planning Based on
//! Improved Q Learning Algorithm".
//!
//! A pure library: no IPC, no threads, no clocks in the learning path; the same seed gives the
//! same episode-by-episode results. The fleet crates wire it to the bus; this crate knows
//! nothing of them.
//!
//! Steps are counted as actions taken: a move into an obstacle counts as a step (the robot
//! stays put), and path lengths are in moves, not cells.

pub mod env;
pub mod fastmath;
pub mod grid;
pub mod known;
pub mod learner;
pub mod map;
pub mod metrics;
pub mod path;
pub mod policy;
pub mod pseudo;
pub mod qtable;
pub mod rng;
pub mod suite;
pub mod task;

pub use env::{Env, Rewards, Transition};
pub use grid::{Action, Cell, Grid, GridError};
pub use learner::{ConfigError, Extras, Learner, LearnerConfig, LearnerKind, StepInfo};
pub use metrics::{EpisodeRecord, Outcome, Summary};
pub use policy::{EpsilonReading, PolicyConfig, QScale, Schedule};
pub use pseudo::PseudoConfig;
pub use qtable::QTable;
