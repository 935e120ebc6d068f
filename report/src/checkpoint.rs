//! The coordinator's checkpoint (`coordinator-checkpoint.json`): what a coordinator restarted
//! in the middle of a run (`qfleet run --restart on-failure`) takes over from the one that died.
//!
//! The coordinator writes it about once a second while the run is served and once more at the
//! end (marked [`complete`](CoordinatorCheckpoint::complete)), through the atomic writer
//! without `fsync` ([`Durability::Process`](crate::Durability::Process)): a reader never sees
//! half of one, and the serving loop never waits for a busy disk. It is small on purpose: counters, the liveness record and
//! the fleet's robot states, not the fleet tables (a restarted coordinator's tables fill again
//! from the robots' hints) nor the latency histograms (they restart empty).
//!
//! A new coordinator resumes from a checkpoint only when [`CoordinatorCheckpoint::resumable`]
//! says so: same run id, same fleet size, started by the same launcher process (its parent),
//! and the run not complete. Anything else is another run's file and is not used.

use serde::{Deserialize, Serialize};

use crate::run::LivenessEvent;

/// What the coordinator knew of one robot id when it wrote the checkpoint.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RobotCheckpoint {
    /// Robot id.
    pub robot_id: u32,
    /// Its process died without a final report (no restart took its place yet).
    pub lost: bool,
    /// Restarts of the robot so far.
    pub restarts: u32,
    /// Whether its latest process was warm-started from the fleet table.
    pub warm_started: bool,
    /// Distinct discoveries received from its processes that were lost without a report.
    pub discoveries_from_lost: u64,
}

/// The coordinator's checkpoint (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CoordinatorCheckpoint {
    /// Run id.
    pub run_id: String,
    /// Fleet size.
    pub robots: u32,
    /// Process id of the process that started the coordinator (the launcher).
    pub launcher_pid: u32,
    /// Written at the end of the run: there is nothing to resume.
    pub complete: bool,
    /// Coordinator restarts before the process that wrote this one took over.
    pub coordinator_restarts: u32,
    /// CLOCK_MONOTONIC ns when the run's first coordinator started.
    pub began_ns: u64,
    /// CLOCK_MONOTONIC ns when the run's `Start` went out (the throughput's time base).
    pub started_ns: u64,
    /// CLOCK_MONOTONIC ns when this checkpoint was written.
    pub written_ns: u64,
    /// Messages received.
    pub messages: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Fleet-table entries changed by merging.
    pub fleet_changes: u64,
    /// Merged batches published.
    pub merged_batches_sent: u64,
    /// The next merged batch's `coordinator_seq` (robots count gaps in it).
    pub merged_seq: u64,
    /// Discovery relays sent.
    pub relays_sent: u64,
    /// Messages dropped as invalid.
    pub rejected: u64,
    /// Liveness checks made.
    pub checks: u64,
    /// Discovery resends dropped as duplicates.
    pub discovery_duplicates: u64,
    /// Discoveries received from robot processes that died and were restarted.
    pub discoveries_from_dead: u64,
    /// Distinct (goal id, cell index) pairs relayed to the fleet.
    pub relayed: Vec<(u32, u32)>,
    /// One entry per robot id.
    pub fleet: Vec<RobotCheckpoint>,
    /// Every liveness event so far.
    pub events: Vec<LivenessEvent>,
}

/// Why a checkpoint found in the out directory is not resumed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NotResumed {
    /// Another run's checkpoint.
    #[error("it is run {0}'s")]
    OtherRun(String),
    /// Same run id, another fleet size.
    #[error("it is for {0} robots")]
    OtherFleet(u32),
    /// Written under another launcher process (an earlier launch with the same id).
    #[error("another launcher (pid {0}) wrote it")]
    OtherLauncher(u32),
    /// The run it describes ended.
    #[error("its run ended")]
    Complete,
}

impl CoordinatorCheckpoint {
    /// Whether the coordinator of run `run_id` with `robots` robots, started by the process
    /// `launcher_pid`, takes over from this checkpoint (`Ok`), or why not.
    pub fn resumable(
        &self,
        run_id: &str,
        robots: u32,
        launcher_pid: u32,
    ) -> Result<(), NotResumed> {
        if self.run_id != run_id {
            return Err(NotResumed::OtherRun(self.run_id.clone()));
        }
        if self.robots != robots {
            return Err(NotResumed::OtherFleet(self.robots));
        }
        if self.launcher_pid != launcher_pid {
            return Err(NotResumed::OtherLauncher(self.launcher_pid));
        }
        if self.complete {
            return Err(NotResumed::Complete);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::LivenessKind;

    fn cp() -> CoordinatorCheckpoint {
        CoordinatorCheckpoint {
            run_id: "r1".into(),
            robots: 3,
            launcher_pid: 42,
            complete: false,
            coordinator_restarts: 0,
            began_ns: 1,
            started_ns: 2,
            written_ns: 3,
            messages: 10,
            q_updates_merged: 20,
            fleet_changes: 5,
            merged_batches_sent: 4,
            merged_seq: 4,
            relays_sent: 1,
            rejected: 0,
            checks: 7,
            discovery_duplicates: 0,
            discoveries_from_dead: 0,
            relayed: vec![(0, 17)],
            fleet: vec![RobotCheckpoint::default(); 3],
            events: vec![LivenessEvent {
                robot_id: 1,
                kind: LivenessKind::Lost,
                at_ns: 9,
                silent_ms: 0,
            }],
        }
    }

    #[test]
    fn the_same_runs_coordinator_under_the_same_launcher_resumes() {
        assert_eq!(cp().resumable("r1", 3, 42), Ok(()));
    }

    #[test]
    fn another_run_fleet_launcher_or_an_ended_run_is_not_resumed() {
        assert_eq!(
            cp().resumable("r2", 3, 42),
            Err(NotResumed::OtherRun("r1".into()))
        );
        assert_eq!(cp().resumable("r1", 4, 42), Err(NotResumed::OtherFleet(3)));
        // `--force` onto the out directory of an earlier launch of the same id
        assert_eq!(
            cp().resumable("r1", 3, 43),
            Err(NotResumed::OtherLauncher(42))
        );
        let done = CoordinatorCheckpoint {
            complete: true,
            ..cp()
        };
        assert_eq!(done.resumable("r1", 3, 42), Err(NotResumed::Complete));
    }

    #[test]
    fn a_checkpoint_reads_back_as_written() {
        let c = cp();
        let json = serde_json::to_string(&c).unwrap();
        assert_eq!(
            serde_json::from_str::<CoordinatorCheckpoint>(&json).unwrap(),
            c
        );
    }
}
