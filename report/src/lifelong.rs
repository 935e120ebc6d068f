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
    /// What the robots learned while the fleet moved, and what it cost.
    pub learning: LifelongLearning,
}

/// Learning ahead in a lifelong run: each robot learns its next goals while it walks (each a
/// phase of its own, reported at its end), every goal cell with one fleet table that
/// warm-starts the robots sent there later.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LifelongLearning {
    /// Goals a robot may learn beyond the one it walks to (the problem's `numTasksReveal`, at
    /// least 1).
    pub ahead: u64,
    /// Goals learned (their report came in before the end).
    pub goals_learned: u64,
    /// Of them, goals whose fleet table already held values when the robot was sent.
    pub warm_started: u64,
    /// Environment steps spent learning, over all goals learned.
    pub env_steps: u64,
    /// `env_steps / goals_learned` (0 when none was).
    pub env_steps_per_goal: f64,
    /// Mean environment steps of a warm-started goal (0 when none was).
    pub env_steps_per_warm_goal: f64,
    /// Mean environment steps of a goal learned from scratch (0 when none was).
    pub env_steps_per_cold_goal: f64,
    /// Mean seconds a robot spent learning a goal.
    pub learn_s_per_goal: f64,
    /// Robot-ticks walked towards a goal whose learning had come in.
    pub ticks_goal_learned: u64,
    /// Robot-ticks walked towards a goal whose learning had not (yet) come in.
    pub ticks_goal_unlearned: u64,
}
