//! What one robot reports about itself: `robot-<id>.json` ([`RobotResult`]) at the end of its
//! run, and `robot-<id>-phase-<p>.json` ([`PhaseDetail`]) after every phase of an experiment.
//!
//! The robot-agent writes these; the coordinator and the tests read them back as these types
//! (never as untyped JSON), so a field renamed here is renamed for every reader at once.

use crate::words::ShareMode;
use serde::{Deserialize, Serialize};

use crate::hist::LatencyStats;

/// How a robot's run ended, as written in its `robot-<id>.json`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EndStatus {
    /// It ran all its episodes (or every phase it was given).
    Finished,
    /// It was stopped early: by the coordinator's `Stop` or by a signal.
    Stopped,
}

impl EndStatus {
    /// `finished` or `stopped`, as in the JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            EndStatus::Finished => "finished",
            EndStatus::Stopped => "stopped",
        }
    }
}

impl std::fmt::Display for EndStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Counters of merged-hint handling at one robot.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ApplyCounters {
    /// Merged batches received.
    pub batches: u64,
    /// Batches skipped whole: another goal, or a `count` above the capacity.
    pub batches_rejected: u64,
    /// Entries looked at (valid, foreign).
    pub entries_seen: u64,
    /// Entries that changed the local Q-table.
    pub entries_applied: u64,
    /// Entries of this robot's own coming back, skipped.
    pub entries_own: u64,
    /// Entries with an out-of-range cell, action, origin robot or a non-finite value.
    pub entries_rejected: u64,
    /// Batches the robot never saw (gaps in `coordinator_seq`: overwritten, latest-wins).
    pub batches_missed: u64,
}

/// Counters of a robot's link to its coordinator (losing it, re-joining a restarted one).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkCounters {
    /// Times the coordinator was found gone.
    pub coordinator_losses: u64,
    /// Times the robot re-registered with a restarted coordinator.
    pub rejoins: u64,
    /// Milliseconds spent without a coordinator.
    pub alone_ms: u64,
    /// Discoveries made while no coordinator had accepted this robot (delivered later).
    pub discoveries_while_alone: u64,
    /// `AssignGoal`/`Start`/`Phase` controls for a phase the robot had already taken (a
    /// restarted coordinator sending its plan again): ignored, the phase goes on.
    #[serde(default)]
    pub plan_repeats: u64,
}

/// Bus traffic counters of one robot, reported in its result.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counters {
    /// States published.
    pub states_sent: u64,
    /// Hint batches published.
    pub hint_batches_sent: u64,
    /// Hint entries published.
    pub hint_entries_sent: u64,
    /// Distinct discoveries published (re-sends not counted).
    pub discoveries_sent: u64,
    /// Discoveries the coordinator acknowledged.
    pub discoveries_acked: u64,
    /// Discovery re-sends after a missing ack.
    pub discoveries_resent: u64,
    /// Discovery sends that failed (retried later).
    pub discovery_send_errors: u64,
    /// State or hint sends that failed (latest-wins: dropped).
    pub send_errors: u64,
    /// Received messages dropped as invalid (bad robot id, unknown command, an ack for a
    /// sequence number never sent).
    pub rejected: u64,
    /// Discoveries of other robots relayed by the coordinator.
    pub relays_received: u64,
    /// Of those, made pseudo targets of this robot (`--share discoveries|both`).
    pub relays_applied: u64,
    /// Merged-hint handling.
    pub merged: ApplyCounters,
    /// Fleet-table entries applied before the first episode (a restarted robot's warm start).
    pub warm_start_entries: u64,
    /// Losing and re-joining the coordinator.
    pub link: LinkCounters,
    /// Moves other robots tried on the way to other goals, and the moves they reveal (every
    /// move into a cell such a move left or entered), added to this robot's model (a shared
    /// grid: the grid's moves are shared, values only between robots of one goal).
    #[serde(default)]
    pub moves_learned_from_others: u64,
    /// Shared grid: grants dropped because another node than the coordinator this robot
    /// registered with published them (a forged or stale grant).
    #[serde(default)]
    pub grants_foreign: u64,
}

/// What a robot writes to `robot-<id>.json`: its learning metrics as in `qfleet learn --json`
/// plus its bus counters and latencies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotResult {
    /// Robot id.
    pub robot_id: u32,
    /// How the run ended.
    pub status: EndStatus,
    /// Map name.
    pub map: String,
    /// Learner kind.
    pub learner: String,
    /// Seed of this robot.
    pub seed: u64,
    /// Goal id learned (the last one, in an experiment).
    pub goal_id: u32,
    /// Start cell.
    pub start: String,
    /// Goal cell.
    pub goal: String,
    /// Episodes run.
    pub episodes: u32,
    /// BFS optimum.
    pub optimal_path_len: u32,
    /// Greedy path length at the end, after the fleet sync (null: it loops).
    pub final_path_len: Option<u32>,
    /// Greedy path length when its own episodes ended, before the fleet sync.
    pub own_final_path_len: Option<u32>,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// Most steps in one episode.
    pub max_steps: u32,
    /// First episode after which the greedy path was optimal.
    pub first_optimal_episode: Option<u32>,
    /// Steps taken in all.
    pub env_steps: u64,
    /// Episodes ending at the goal / a pseudo target / the step cap.
    pub outcomes: [u32; 3],
    /// Seconds from `Start` to the end of the last episode.
    pub learn_s: f64,
    /// Sharing mode.
    pub share: ShareMode,
    /// Traffic counters.
    pub counters: Counters,
    /// Origin of a Q update at another robot → applied here.
    pub loop_latency_ns: LatencyStats,
    /// Coordinator sent a merged batch → received here.
    pub merged_latency_ns: LatencyStats,
}

/// What a robot writes after each phase of an experiment (`robot-<id>-phase-<p>.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhaseDetail {
    /// Robot id.
    pub robot_id: u32,
    /// Phase number.
    pub phase: u32,
    /// Goal learned.
    pub goal_id: u32,
    /// Start cell.
    pub start: String,
    /// Goal cell.
    pub goal: String,
    /// Episodes run.
    pub episodes: u32,
    /// Steps taken in the phase.
    pub env_steps: u64,
    /// Mean steps per episode.
    pub avg_steps: f64,
    /// BFS optimum.
    pub optimal_path_len: u32,
    /// Greedy path at the end of the phase (null: loops).
    pub final_path_len: Option<u32>,
    /// First episode (0-based) after which the greedy path was optimal.
    pub first_optimal_episode: Option<u32>,
    /// Env steps taken until the greedy path was first optimal.
    pub steps_to_optimal: Option<u64>,
    /// Seconds from the phase's start until the greedy path was first optimal.
    pub time_to_optimal_s: Option<f64>,
    /// Monotonic time (ns) the phase started at this robot.
    pub start_ns: u64,
    /// Monotonic time (ns) of every episode's end.
    pub episode_end_ns: Vec<u64>,
    /// Cumulative env steps at every episode's end.
    pub episode_cum_steps: Vec<u64>,
    /// Discoveries published in the phase.
    pub discoveries_sent: u64,
    /// Relayed discoveries made pseudo targets in the phase.
    pub relays_applied: u64,
    /// Merged hint entries applied in the phase.
    pub hints_applied: u64,
    /// Whether the phase ran to its end (not stopped).
    pub finished: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> RobotResult {
        RobotResult {
            robot_id: 2,
            status: EndStatus::Stopped,
            map: "paper-20".into(),
            learner: "improved".into(),
            seed: 7,
            goal_id: 1,
            start: "0,0".into(),
            goal: "19,19".into(),
            episodes: 100,
            optimal_path_len: 38,
            final_path_len: None,
            own_final_path_len: Some(40),
            avg_steps: 55.5,
            max_steps: 400,
            first_optimal_episode: Some(80),
            env_steps: 5550,
            outcomes: [90, 9, 1],
            learn_s: 0.25,
            share: ShareMode::Both,
            counters: Counters {
                rejected: 3,
                ..Counters::default()
            },
            loop_latency_ns: LatencyStats::default(),
            merged_latency_ns: LatencyStats::default(),
        }
    }

    #[test]
    fn a_robot_result_reads_back_as_written_with_words_for_enums() {
        let r = sample();
        let json = serde_json::to_string(&r).unwrap();
        assert!(json.contains(r#""status":"stopped""#), "{json}");
        assert!(json.contains(r#""share":"both""#), "{json}");
        assert!(json.contains(r#""final_path_len":null"#), "{json}");
        let back: RobotResult = serde_json::from_str(&json).unwrap();
        assert_eq!(back, r);
    }

    #[test]
    fn an_unknown_status_word_is_an_error_not_a_default() {
        let json = serde_json::to_string(&sample())
            .unwrap()
            .replace(r#""stopped""#, r#""rejoined""#);
        assert!(serde_json::from_str::<RobotResult>(&json).is_err());
        assert_eq!(EndStatus::Finished.to_string(), "finished");
    }
}
