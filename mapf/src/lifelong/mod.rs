//! Lifelong multi-agent path finding: a robot gets its next goal the tick it reaches one, and the
//! figure of merit is throughput, goals reached per tick (the League of Robot Runners' problems).
//!
//! - [`problem`]: a League of Robot Runners 2023 problem (map, starts, tasks dealt round robin),
//!   validated before anything runs.
//! - [`fleet`]: the resolver and goal stream: one collision-free move per robot per tick, goals
//!   dealt as they are reached, never stopping.
//! - [`output`]: the competition's output JSON, as its visualiser PlanViz loads it.

pub mod fleet;
pub mod output;
pub mod problem;

pub use fleet::{LifeTick, Lifelong, LifelongConfig};
pub use output::competition_output;
pub use problem::{Part, Problem, ProblemError, STRATEGIES, Spec, parse_cells};
