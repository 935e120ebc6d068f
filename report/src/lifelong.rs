//! The result of a lifelong shared grid (`qfleet run --world shared --lorr PROBLEM.json`): goals
//! reached and throughput (goals per tick, the League of Robot Runners' figure), per robot, and
//! what the tick loop cost.

use serde::{Deserialize, Serialize};

use crate::LatencyStats;

/// A lifelong run's figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LifelongResult {
    /// The problem file.
    pub problem: String,
    /// Robots on the grid at the start (the problem's team).
    pub agents: u32,
    /// Ticks run (the run lasts exactly `--ticks` unless stopped).
    pub ticks: u32,
    /// Why the run ended: `ticks` (the planned end) or `stopped`.
    pub ended: String,
    /// Goals reached by the whole fleet (the competition's `numTaskFinished`).
    pub goals_reached: u64,
    /// `goals_reached / ticks`.
    pub throughput: f64,
    /// Goals reached per tick over the second half of the run (a fleet that deadlocks for good
    /// shows it here first).
    pub throughput_2nd_half: f64,
    /// Per robot: goals reached, by robot id.
    pub robot_goals: Vec<u64>,
    /// Robots that left the grid (their process died), by robot id.
    pub robots_lost: Vec<u32>,
    /// Vertex and swap conflicts `mapf::check`'s independent checker finds in the executed paths:
    /// 0 unless something is broken.
    pub conflicts: u64,
    /// Robot-ticks whose move was ranked by a robot's learned values for its goal (0 today).
    pub ticks_by_values: u64,
    /// Robot-ticks ranked by map distance to the robot's goal (today every robot-tick: the
    /// lifelong resolver does not read learned values yet; a tick never waits for a robot).
    pub ticks_by_distance: u64,
    /// Seconds from the first tick to the last.
    pub exec_s: f64,
    /// Ticks per second over `exec_s`.
    pub ticks_per_s: f64,
    /// One tick at the coordinator (rankings read, resolved, goals dealt, published).
    pub tick_latency_ns: LatencyStats,
    /// The paths file (mapf-visualizer format, ticks 0 to `ticks`), if written.
    pub paths_file: Option<String>,
    /// The competition's output file (for its visualiser, PlanViz), if written.
    pub lorr_file: Option<String>,
}
