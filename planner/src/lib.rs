//! Grid maps and the tabular Q-learners of J. Peng's "Mobile Robot Path Planning Based on
//! Improved Q Learning Algorithm".
//!
//! A pure library: no IPC, no threads, no clocks in the learning path; the same seed gives the
//! same episode-by-episode results. The fleet crates wire it to the bus; this crate knows
//! nothing of them.

pub mod grid;
pub mod map;
pub mod path;
pub mod task;

pub use grid::{Action, Cell, Grid, GridError};
