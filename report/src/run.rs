//! The coordinator's side of the results contract: what `result.json` of a run
//! ([`RunResult`]) and of an experiment ([`ExperimentResult`]) hold, robot outcomes and
//! liveness events as enums, and the two coordinator settings a result names ([`WaitStrategy`],
//! [`MergeRule`]). Everything is `Serialize + Deserialize`, so the launcher and the tests read
//! results back into these types instead of indexing untyped JSON.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::hist::LatencyStats;
use crate::hosts::HostEntry;

/// How the coordinator waits for messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WaitStrategy {
    /// Busy-poll all inboxes.
    Spin,
    /// Block on a WaitSet of the inboxes' wake listeners.
    Event,
    /// Spin `--spin-us` after each message, then block.
    Hybrid,
}

impl crate::Word for WaitStrategy {
    const ALL: &'static [Self] = &[
        WaitStrategy::Spin,
        WaitStrategy::Event,
        WaitStrategy::Hybrid,
    ];

    fn word(self) -> &'static str {
        match self {
            WaitStrategy::Spin => "spin",
            WaitStrategy::Event => "event",
            WaitStrategy::Hybrid => "hybrid",
        }
    }

    fn help(self) -> &'static str {
        match self {
            WaitStrategy::Spin => "Busy-poll all inboxes",
            WaitStrategy::Event => "Block on a WaitSet of the inboxes' wake listeners",
            WaitStrategy::Hybrid => "Spin `--spin-us` after each message, then block",
        }
    }
}

crate::display_word!(WaitStrategy);

/// How the coordinator merges robots' Q-values into the fleet table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MergeRule {
    /// Largest last-reported value (the owner may lower its own).
    Max,
    /// Visit-weighted mean.
    Mean,
    /// Newest value wins.
    Latest,
    /// Smallest value ever reported (for learners whose values are upper bounds of Q*).
    Min,
}

impl crate::Word for MergeRule {
    const ALL: &'static [Self] = &[
        MergeRule::Max,
        MergeRule::Mean,
        MergeRule::Latest,
        MergeRule::Min,
    ];

    fn word(self) -> &'static str {
        match self {
            MergeRule::Max => "max",
            MergeRule::Mean => "mean",
            MergeRule::Latest => "latest",
            MergeRule::Min => "min",
        }
    }

    fn help(self) -> &'static str {
        match self {
            MergeRule::Max => "Largest last-reported value (the owner may lower its own)",
            MergeRule::Mean => "Visit-weighted mean",
            MergeRule::Latest => "Newest value wins",
            MergeRule::Min => {
                "Smallest value ever reported (for learners whose values are upper bounds of Q*)"
            }
        }
    }
}

crate::display_word!(MergeRule);

/// How a robot ended a run or a phase (as written in JSON: lower case).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RobotOutcome {
    /// It ran all its episodes and reported.
    Finished,
    /// It reported, but was stopped early (a signal, a stop request) or gave up.
    Stopped,
    /// Its process died before it reported (and no restart took its place in time).
    Lost,
    /// Silent past the heartbeat deadline at the end, its process still there.
    Hung,
    /// No report, though its process was not seen to die (e.g. the report timed out).
    Missing,
}

impl RobotOutcome {
    /// The word written in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            RobotOutcome::Finished => "finished",
            RobotOutcome::Stopped => "stopped",
            RobotOutcome::Lost => "lost",
            RobotOutcome::Hung => "hung",
            RobotOutcome::Missing => "missing",
        }
    }
}

impl std::fmt::Display for RobotOutcome {
    /// The JSON word (width and alignment flags are honoured).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.as_str())
    }
}

/// What happened to a robot (or the coordinator) during a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LivenessKind {
    /// Its process died (its node is gone or dead).
    Lost,
    /// Silent past the heartbeat deadline, process still there.
    Hung,
    /// A hung robot spoke again.
    Resumed,
    /// A new process took the place of a dead one.
    Restarted,
    /// A process this coordinator had not admitted registered during the run: a robot
    /// re-joining a restarted coordinator, or a late one.
    Joined,
    /// The robot died before it ever registered (seen by the launcher or by its node).
    NeverRegistered,
    /// A new coordinator process took over the run from its checkpoint (the event's robot id
    /// is `ROBOT_ID_ALL`, 4294967295; `silent_ms` is the time since the dead coordinator's
    /// last checkpoint).
    CoordinatorRestarted,
}

impl LivenessKind {
    /// The word printed in `event <kind> …` lines and written in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            LivenessKind::Lost => "lost",
            LivenessKind::Hung => "hung",
            LivenessKind::Resumed => "resumed",
            LivenessKind::Restarted => "restarted",
            LivenessKind::Joined => "joined",
            LivenessKind::NeverRegistered => "neverregistered",
            LivenessKind::CoordinatorRestarted => "coordinatorrestarted",
        }
    }
}

impl std::fmt::Display for LivenessKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One liveness event of the run (also printed as an `event …` line on stdout).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LivenessEvent {
    /// The robot (`ROBOT_ID_ALL` for an event of the coordinator).
    pub robot_id: u32,
    /// What happened.
    pub kind: LivenessKind,
    /// CLOCK_MONOTONIC time of the event, ns (comparable with other processes' clocks).
    pub at_ns: u64,
    /// How long the robot had been silent when the event was raised, ms.
    pub silent_ms: u64,
}

/// One robot in the run result.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobotEntry {
    /// Robot id.
    pub robot_id: u32,
    /// How it ended.
    pub status: RobotOutcome,
    /// Greedy path length at the end (null: loops / unknown).
    pub final_path_len: Option<u32>,
    /// Greedy path length from the robot's own learning, before the final fleet sync.
    pub own_final_path_len: Option<u32>,
    /// BFS optimum.
    pub optimal_path_len: Option<u32>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Episodes run.
    pub episodes: u32,
    /// First episode with an optimal greedy path.
    pub first_optimal_episode: Option<u32>,
    /// Steps taken.
    pub env_steps: u64,
    /// Seed of the robot.
    pub seed: u64,
    /// Discoveries the robot published.
    pub discoveries_sent: u64,
    /// Of those, acknowledged by the coordinator.
    pub discoveries_acked: u64,
    /// Hint batches published.
    pub hints_sent: u64,
    /// Merged batches received.
    pub hints_received: u64,
    /// Merged entries that changed its Q-table.
    pub hints_applied: u64,
    /// End-to-end loop latency of the hints it applied.
    pub loop_latency_ns: LatencyStats,
    /// Times a new process took this robot's place (`qfleet run --restart on-failure`).
    #[serde(default)]
    pub restarts: u32,
    /// Whether its latest process was warm-started from the coordinator's fleet table.
    #[serde(default)]
    pub warm_started: bool,
    /// Fleet-table entries its latest process applied before its first episode.
    #[serde(default)]
    pub warm_start_entries: Option<u64>,
}

/// Throughput of the run, over the active time (Start → every robot finished).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Throughput {
    /// Messages received per second (all robot→coordinator topics).
    pub messages_per_s: f64,
    /// Q-hint entries merged per second.
    pub q_updates_merged_per_s: f64,
    /// Messages received.
    pub messages: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Fleet-table entries changed by merging.
    pub fleet_changes: u64,
    /// Merged batches published.
    pub merged_batches_sent: u64,
    /// Seconds from Start until every robot finished.
    pub active_s: f64,
}

/// Node liveness as the coordinator saw it.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct LivenessReport {
    /// Liveness checks made.
    pub checks: u64,
    /// Robots whose process died before reporting.
    pub lost: Vec<u32>,
    /// Robot nodes alive at the last check.
    pub alive_at_end: Vec<u32>,
    /// Robots hung at the end (silent past the heartbeat deadline, process still there).
    #[serde(default)]
    pub hung: Vec<u32>,
    /// Restarts over the fleet.
    #[serde(default)]
    pub restarts: u32,
    /// Times a new coordinator process took over the run from its checkpoint.
    #[serde(default)]
    pub coordinator_restarts: u32,
    /// Discoveries received from robot processes that died and were restarted (their
    /// successors start numbering again and report only their own).
    #[serde(default)]
    pub discoveries_from_dead: u64,
    /// Every liveness event, in order.
    #[serde(default)]
    pub events: Vec<LivenessEvent>,
}

/// The result of a run (`result.json`, and what `qfleet run --json` prints).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunResult {
    /// Run id.
    pub run_id: String,
    /// Map name.
    pub map: String,
    /// Start cell.
    pub start: String,
    /// Goal cell.
    pub goal: String,
    /// Wait strategy.
    pub wait: WaitStrategy,
    /// Merge rule.
    pub merge: MergeRule,
    /// The robots' apply rule (`--apply`), filled in by `qfleet run` (the coordinator does not
    /// know it); with `merge`, the resolved sharing rules of the run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub apply: Option<String>,
    /// One entry per robot id.
    pub robots: Vec<RobotEntry>,
    /// Whether every robot ended on a shortest path.
    pub all_optimal: bool,
    /// Robots whose final report was accepted with no greedy path to the goal (`final_path_len`
    /// null: they stopped before they found one, an honest "no path yet"), so a reader tells
    /// them from robots that were lost or whose report was rejected (issue 36).
    #[serde(default)]
    pub without_path: Vec<u32>,
    /// Discoveries the robots report as published.
    pub discoveries_sent: u64,
    /// Distinct discoveries the coordinator received.
    pub discoveries_received: u64,
    /// Of `discoveries_received`, those from robots lost without a final report (their
    /// processes cannot report what they sent): `discoveries_sent + discoveries_from_lost`
    /// accounts for what was received.
    #[serde(default)]
    pub discoveries_from_lost: u64,
    /// Discovery duplicates (re-sends) received and dropped.
    pub discovery_duplicates: u64,
    /// Distinct pseudo-target cells the fleet found.
    pub pseudo_targets: usize,
    /// Latency percentiles per measured path, ns.
    pub latency_ns: BTreeMap<String, LatencyStats>,
    /// Throughput.
    pub throughput: Throughput,
    /// Liveness.
    pub liveness: LivenessReport,
    /// Messages dropped as invalid: a field out of range (robot id, goal id, cell, count,
    /// status, schema version, a non-finite value), or a message naming a robot id from a node
    /// that did not register it.
    pub rejected: u64,
    /// Whether the run was stopped early by a signal.
    pub interrupted: bool,
    /// Wall time of the whole coordinator run, s.
    pub elapsed_s: f64,
    /// Where the robots ran, with the coordinator's host first, for a run with robots on other
    /// hosts (filled in by `qfleet run`; empty, and not written, on one host).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub hosts: Vec<HostEntry>,
    /// The shared grid, in a run with `--world shared` (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<crate::grid::GridResult>,
    /// A lifelong shared grid (`--lorr`): goals reached and throughput (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lifelong: Option<crate::lifelong::LifelongResult>,
}

impl RunResult {
    /// The result of a run whose out directory is `out`: its `result.json`, else the JSON the
    /// coordinator `sent` on its stdout because it could not write the file (a full disk); with
    /// whether it came from `sent`. None when neither reads as a result.
    pub fn recover(out: &std::path::Path, sent: Option<&str>) -> Option<(RunResult, bool)> {
        let written = std::fs::read_to_string(out.join(crate::OutFile::Result.name()));
        if let Some(r) = written.ok().and_then(|t| serde_json::from_str(&t).ok()) {
            return Some((r, false));
        }
        serde_json::from_str(sent?).ok().map(|r| (r, true))
    }
}

/// One robot's result in one phase.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobotPhase {
    /// Robot id.
    pub robot_id: u32,
    /// Goal index.
    pub goal: usize,
    /// How it ended the phase.
    pub status: RobotOutcome,
    /// Episodes run.
    pub episodes: u32,
    /// Env steps in the phase.
    pub env_steps: u64,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// BFS optimum from its start.
    pub optimal_path_len: u32,
    /// Its greedy path at the end (null: loops).
    pub final_path_len: Option<u32>,
    /// Env steps until its own greedy path was first optimal.
    pub steps_to_optimal: Option<u64>,
    /// Seconds until its own greedy path was first optimal.
    pub time_to_optimal_s: Option<f64>,
    /// Its env steps when the merged table of its goal first gave optimal paths.
    pub steps_at_merged_optimal: Option<u64>,
    /// Discoveries it published.
    pub discoveries_sent: u64,
    /// Relayed discoveries it used as pseudo targets.
    pub relays_applied: u64,
    /// Merged hint entries it applied.
    pub hints_applied: u64,
}

/// One goal in one phase.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GoalPhase {
    /// Goal index.
    pub goal: usize,
    /// Goal name.
    pub name: String,
    /// Goal cell.
    pub cell: String,
    /// Robots assigned.
    pub robots: Vec<u32>,
    /// Merged-table greedy path length from each assigned robot's start at the end (null: loops).
    pub merged_path_len: Vec<Option<u32>>,
    /// BFS optimum from each assigned robot's start.
    pub optimal_path_len: Vec<u32>,
    /// Whether the merged table gave optimal paths from every start at some point.
    pub merged_optimal: bool,
    /// Seconds from the phase start until it first did.
    pub merged_time_to_optimal_s: Option<f64>,
    /// Mean env steps per robot when it first did.
    pub merged_steps_per_robot: Option<f64>,
    /// Mean env steps until their own greedy path was optimal, over the robots that got there.
    pub robot_steps_to_optimal: Option<f64>,
    /// Robots whose own greedy path became optimal in the phase.
    pub robots_reached_optimal: usize,
    /// Mean seconds until their own greedy path was optimal, over the robots that got there.
    pub robot_time_to_optimal_s: Option<f64>,
    /// Mean steps per episode over the robots.
    pub avg_steps: f64,
    /// Whether every assigned robot ended on an optimal path.
    pub all_robots_optimal: bool,
    /// Distinct pseudo-target cells relayed for this goal (over the run so far).
    pub relayed: usize,
}

/// One phase.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PhaseResult {
    /// Phase number.
    pub phase: usize,
    /// Phase name.
    pub name: String,
    /// Episodes per robot (upper bound with `stop_at_optimum`).
    pub episodes: u32,
    /// Per goal.
    pub goals: Vec<GoalPhase>,
    /// Per robot.
    pub robots: Vec<RobotPhase>,
    /// Discoveries the robots made in this phase (the sum of `robots[].discoveries_sent`).
    #[serde(default)]
    pub discoveries_sent: u64,
    /// Distinct discoveries of this phase the coordinator received (a restarted coordinator
    /// gets the robots' replays, so it counts them too).
    #[serde(default)]
    pub discoveries_received: u64,
    /// Wall time of the phase, s (from its start, also across a coordinator restart).
    pub wall_s: f64,
    /// The phase's execution on the shared grid (`world = "shared"`; absent otherwise, and
    /// when the phase was cut short before it): from where the last phase left the robots to
    /// this phase's goals. Its paths are in `paths-phase-<p>.txt`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<crate::grid::GridResult>,
}

/// The result of one experiment run (one seed).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExperimentResult {
    /// Experiment name.
    pub name: String,
    /// Run id.
    pub run_id: String,
    /// Seed.
    pub seed: u64,
    /// Map name.
    pub map: String,
    /// Robots.
    pub robots: u32,
    /// Sharing mode.
    pub sharing: String,
    /// Resolved sharing rules `APPLY/MERGE` (e.g. `min/min`), filled in by `qfleet
    /// experiment` (the coordinator knows only the merge rule).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rules: Option<String>,
    /// Phases.
    pub phases: Vec<PhaseResult>,
    /// Discoveries received (distinct).
    pub discoveries_received: u64,
    /// Relays sent.
    pub relays_sent: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Messages dropped as invalid (bad fields, or from a node that did not register the
    /// robot id they name).
    pub rejected: u64,
    /// Liveness as the last coordinator process saw it (a restarted coordinator starts a new
    /// record).
    #[serde(default)]
    pub liveness: LivenessReport,
    /// Times the coordinator process was started again after it died (the experiment resumed
    /// from its checkpoint each time).
    #[serde(default)]
    pub coordinator_restarts: u32,
    /// Stopped by a signal before the last phase ended (the phases done are in `phases`).
    #[serde(default)]
    pub interrupted: bool,
    /// Wall time, s.
    pub wall_s: f64,
    /// Where the robots ran, with the coordinator's host first, for an experiment with robots
    /// on other hosts (filled in by `qfleet experiment`; empty, and not written, on one host).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub hosts: Vec<HostEntry>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_json(run_id: &str) -> String {
        serde_json::json!({
            "run_id": run_id, "map": "paper-10", "start": "(0,0)", "goal": "(9,9)",
            "wait": "hybrid", "merge": "max", "robots": [], "all_optimal": true,
            "discoveries_sent": 0, "discoveries_received": 0, "discovery_duplicates": 0,
            "pseudo_targets": 0, "latency_ns": {},
            "throughput": {"messages_per_s": 0.0, "q_updates_merged_per_s": 0.0, "messages": 0,
                "q_updates_merged": 0, "fleet_changes": 0, "merged_batches_sent": 0,
                "active_s": 0.0},
            "liveness": {"checks": 0, "lost": [], "alive_at_end": []},
            "rejected": 0, "interrupted": false, "elapsed_s": 1.0
        })
        .to_string()
    }

    #[test]
    fn a_result_is_recovered_from_its_file_or_else_from_what_was_sent() {
        let dir = std::env::temp_dir().join(format!("report-recover-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let _ = std::fs::remove_file(dir.join("result.json"));
        assert!(RunResult::recover(&dir, None).is_none());
        assert!(RunResult::recover(&dir, Some("not json")).is_none());
        let (r, sent) = RunResult::recover(&dir, Some(&run_json("sent"))).unwrap();
        assert_eq!((r.run_id.as_str(), sent), ("sent", true));
        std::fs::write(dir.join("result.json"), run_json("file")).unwrap();
        let (r, sent) = RunResult::recover(&dir, Some(&run_json("sent"))).unwrap();
        assert_eq!((r.run_id.as_str(), sent), ("file", false));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn outcomes_and_event_kinds_are_written_as_their_words() {
        for o in [
            RobotOutcome::Finished,
            RobotOutcome::Stopped,
            RobotOutcome::Lost,
            RobotOutcome::Hung,
            RobotOutcome::Missing,
        ] {
            let json = serde_json::to_string(&o).unwrap();
            assert_eq!(json, format!("\"{o}\""));
            assert_eq!(serde_json::from_str::<RobotOutcome>(&json).unwrap(), o);
        }
        for k in [
            LivenessKind::Lost,
            LivenessKind::Hung,
            LivenessKind::Resumed,
            LivenessKind::Restarted,
            LivenessKind::Joined,
            LivenessKind::NeverRegistered,
            LivenessKind::CoordinatorRestarted,
        ] {
            let json = serde_json::to_string(&k).unwrap();
            assert_eq!(
                json,
                format!("\"{k}\""),
                "the event line and the JSON agree"
            );
        }
        assert_eq!(format!("{:8}|", RobotOutcome::Lost), "lost    |");
    }

    /// A result as written before `without_path` existed (issue 36): the smallest one a run
    /// could write.
    const OLD_RESULT: &str = r#"{"run_id": "r", "map": "m", "start": "(0, 0)", "goal": "(1, 1)",
        "wait": "hybrid", "merge": "max", "robots": [], "all_optimal": false,
        "discoveries_sent": 0, "discoveries_received": 0, "discovery_duplicates": 0,
        "pseudo_targets": 0, "latency_ns": {}, "throughput": {"messages_per_s": 0.0,
        "q_updates_merged_per_s": 0.0, "messages": 0, "q_updates_merged": 0,
        "fleet_changes": 0, "merged_batches_sent": 0, "active_s": 0.0},
        "liveness": {"checks": 0, "lost": [], "alive_at_end": []}, "rejected": 0,
        "interrupted": false, "elapsed_s": 0.0}"#;

    #[test]
    fn robots_without_a_path_survive_a_round_trip_and_old_results_still_parse() {
        let mut r: RunResult = serde_json::from_str(OLD_RESULT).unwrap();
        assert!(r.without_path.is_empty());
        r.without_path = vec![3, 250];
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(json["without_path"], serde_json::json!([3, 250]));
        let back: RunResult = serde_json::from_value(json).unwrap();
        assert_eq!(back.without_path, vec![3, 250]);
    }
}
