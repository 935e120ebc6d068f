//! What a shared-grid run reports ([`GridResult`]): the MAPF figures a user of such tools reads
//! (all arrived, sum of costs, makespan, the lower bound and their ratio), what the
//! coordinator's resolution cost (waits, denied moves), the independent check's conflict count
//! (always 0 unless something is broken) and the tick loop's speed and latency.

use serde::{Deserialize, Serialize};

use crate::hist::LatencyStats;

/// Why a shared-grid execution ended (as written in JSON: kebab case).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GridEnd {
    /// Every robot on the grid stood on its goal.
    Arrived,
    /// The tick limit (`--max-ticks`) passed first.
    TickLimit,
    /// The coordinator's complete search proved that no plan brings every robot home from
    /// where they stood.
    Unsolvable,
    /// A stop request (signal, `q` in the live view, `--time-limit`).
    Stopped,
}

/// One robot's part of a shared-grid execution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridRobot {
    /// Robot id (its line in the scenario).
    pub robot_id: u32,
    /// Start cell `x,y`.
    pub start: String,
    /// Goal cell `x,y`.
    pub goal: String,
    /// Shortest path length alone on the map (BFS, moves).
    pub shortest: u32,
    /// The tick from which it stood on its goal for good; `None`: it never settled there.
    pub arrived_at: Option<u32>,
    /// Ticks it stood still before it settled on its goal (or to the end, if it never did).
    pub waits: u64,
    /// Ticks its first-ranked move was not granted.
    pub denied: u64,
    /// It left the grid (declared lost) before the end.
    pub left: bool,
}

/// The shared grid of a run: the figures MAPF tools report, plus the tick loop's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridResult {
    /// Number of robots (agents) on the grid at the start.
    pub agents: u32,
    /// The scenario file the starts and goals came from, if any.
    pub scen: Option<String>,
    /// Why the execution ended.
    pub ended: GridEnd,
    /// Every robot stands on its goal at the end.
    pub all_arrived: bool,
    /// Robots that settled on their goal.
    pub arrived: u32,
    /// Sum over robots of the tick from which each stood on its goal for good (a robot that
    /// never settled counts the last tick).
    pub sum_of_costs: u64,
    /// The largest of those ticks.
    pub makespan: u32,
    /// Sum of the robots' shortest paths alone on the map (BFS): no plan costs less.
    pub lower_bound: u64,
    /// `sum_of_costs / lower_bound` (1.0: nobody waited or detoured).
    pub soc_ratio: f64,
    /// Ticks executed.
    pub ticks: u32,
    /// Ticks robots stood still before settling on their goals, summed.
    pub waits: u64,
    /// Ticks a robot's first-ranked move was not granted, summed.
    pub denied_moves: u64,
    /// Vertex and swap conflicts the coordinator's independent check found in the executed
    /// paths: 0 unless something is broken.
    pub conflicts: u64,
    /// Intents dropped as invalid (a wrong tick or cell, a bad move code, a foreign sender).
    pub intents_rejected: u64,
    /// Seconds from the first grant to the last.
    pub exec_s: f64,
    /// Ticks per second over `exec_s`.
    pub ticks_per_s: f64,
    /// One tick at the coordinator: grant published (and the robots woken) → every robot's
    /// intent in → resolved.
    pub tick_latency_ns: LatencyStats,
    /// Per robot and tick: grant published → that robot's intent received (the robot woke,
    /// moved to its granted cell, ranked its moves and answered).
    pub intent_latency_ns: LatencyStats,
    /// Per tick: the resolver's part of it (`mapf::World::step`: PIBT on the intents, the
    /// look-ahead plan, a complete search when it stalls).
    #[serde(default)]
    pub resolve_latency_ns: LatencyStats,
    /// The paths file in the out directory (mapf-visualizer format), if written.
    pub paths_file: Option<String>,
    /// Per robot.
    pub robots: Vec<GridRobot>,
}

impl GridEnd {
    /// How the execution ended, in words.
    pub fn words(self) -> &'static str {
        match self {
            GridEnd::Arrived => "every robot arrived",
            GridEnd::TickLimit => "the tick limit passed",
            GridEnd::Unsolvable => "no plan brings every robot home (proved by search)",
            GridEnd::Stopped => "stopped",
        }
    }
}

impl GridResult {
    /// One line of a human summary: how it ended, the costs against the lower bound, the
    /// independent check's conflicts and the paths file (an experiment prints one per phase).
    pub fn line(&self) -> String {
        format!(
            "{} ({} of {} arrived) after {} ticks; sum of costs {} (lower bound {}, ratio {:.3}), \
             makespan {}, conflicts {}{}",
            self.ended.words(),
            self.arrived,
            self.agents,
            self.ticks,
            self.sum_of_costs,
            self.lower_bound,
            self.soc_ratio,
            self.makespan,
            self.conflicts,
            self.paths_file
                .as_deref()
                .map_or(String::new(), |f| format!(", {f}"))
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result() -> GridResult {
        GridResult {
            agents: 2,
            scen: None,
            ended: GridEnd::Arrived,
            all_arrived: true,
            arrived: 2,
            sum_of_costs: 11,
            makespan: 6,
            lower_bound: 10,
            soc_ratio: 1.1,
            ticks: 6,
            waits: 1,
            denied_moves: 1,
            conflicts: 0,
            intents_rejected: 0,
            exec_s: 0.5,
            ticks_per_s: 12.0,
            tick_latency_ns: LatencyStats::default(),
            intent_latency_ns: LatencyStats::default(),
            resolve_latency_ns: LatencyStats::default(),
            paths_file: Some("paths-phase-1.txt".into()),
            robots: vec![GridRobot {
                robot_id: 0,
                start: "0,0".into(),
                goal: "3,3".into(),
                shortest: 6,
                arrived_at: Some(6),
                waits: 0,
                denied: 0,
                left: false,
            }],
        }
    }

    #[test]
    fn the_summary_line_says_how_it_ended_what_it_cost_and_where_the_paths_are() {
        assert_eq!(
            result().line(),
            "every robot arrived (2 of 2 arrived) after 6 ticks; sum of costs 11 (lower bound \
             10, ratio 1.100), makespan 6, conflicts 0, paths-phase-1.txt"
        );
    }

    #[test]
    fn a_grid_result_round_trips_through_json() {
        let r = result();
        let back: GridResult = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back, r);
    }
}
