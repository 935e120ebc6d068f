//! An experiment's progress, kept in `experiment-checkpoint.json` in its out directory so that a
//! coordinator process started again after a crash resumes it: the phases done are not run
//! again, the phase under way keeps its start time, the counts of earlier coordinator processes
//! are carried over.
//!
//! The driver writes the checkpoint (atomically, through `report`'s writer) when a coordinator
//! starts (counting the start), when a phase starts, and after each phase with its result.
//! This type only decides; it does no IO.
//!
//! On a shared grid the checkpoint also keeps where the last phase done left the robots
//! ([`Checkpoint::at`]), so that the next phase's execution starts there after a restart too,
//! and each phase done keeps its grid result. A phase whose execution was under way when the
//! coordinator died is run again from its start: its learning is reported again by the robots,
//! and its execution restarts cleanly from where the phase before left the robots.
//!
//! What a killed coordinator counted after the last checkpoint (merged Q updates, relays,
//! rejected messages, liveness events of the interrupted phase) is lost with it; discoveries
//! are not, because every robot replays its discoveries to a new coordinator.

use planner::Cell;
use serde::{Deserialize, Serialize};

use report::run::PhaseResult;

/// Counts that add up over the coordinator processes of one experiment.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Totals {
    /// Distinct discoveries received up to the end of the last phase done (from every robot
    /// process, the replaced ones too).
    pub discoveries: u64,
    /// Of those, the ones from robot processes that were replaced (a new coordinator never
    /// hears them again).
    pub from_dead: u64,
    /// Relays sent.
    pub relays_sent: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Messages rejected.
    pub rejected: u64,
}

/// The phase under way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Current {
    /// Phase number.
    pub phase: usize,
    /// When it started (monotonic ns, the clock every process of the machine shares).
    pub started_ns: u64,
}

/// What one coordinator process of this experiment counted so far (its engine's figures).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LifeCounts {
    /// Distinct discoveries from the robots' current processes.
    pub received: u64,
    /// Distinct discoveries from robot processes replaced during this life.
    pub from_dead: u64,
    /// Relays sent.
    pub relays_sent: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Messages rejected.
    pub rejected: u64,
}

/// The progress of one experiment (one seed).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The run id it belongs to (a checkpoint of another run is never resumed).
    pub run_id: String,
    /// The seed it belongs to.
    pub seed: u64,
    /// Coordinator processes started for this experiment, this one included.
    pub coordinator_starts: u32,
    /// When the first coordinator started (monotonic ns).
    pub began_ns: u64,
    /// Results of the phases done, in order.
    pub phases: Vec<PhaseResult>,
    /// The phase under way, if any.
    pub current: Option<Current>,
    /// Counts up to the end of the last phase done.
    pub totals: Totals,
    /// On a shared grid: where the last phase done left the robots (its execution's end, by
    /// robot id); `None` before any phase was executed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at: Option<Vec<Cell>>,
    /// Counts of the coordinator processes before this one, up to the last checkpoint
    /// (the base this process adds its own to; not written).
    #[serde(skip)]
    base: Totals,
}

impl Checkpoint {
    /// The checkpoint a coordinator starting at `now_ns` works with: `prev` continued if it
    /// belongs to this run id and seed and fits a plan of `phases` phases (a restart), else a
    /// fresh one (the first start).
    pub fn resume(
        prev: Option<Checkpoint>,
        run_id: &str,
        seed: u64,
        phases: usize,
        now_ns: u64,
    ) -> Checkpoint {
        match prev {
            Some(mut c)
                if c.run_id == run_id
                    && c.seed == seed
                    && c.phases.len() <= phases
                    && c.phases.iter().enumerate().all(|(i, p)| p.phase == i) =>
            {
                c.coordinator_starts = c.coordinator_starts.saturating_add(1);
                c.base = c.totals;
                c
            }
            _ => Checkpoint {
                run_id: run_id.to_string(),
                seed,
                coordinator_starts: 1,
                began_ns: now_ns,
                phases: Vec::new(),
                current: None,
                totals: Totals::default(),
                at: None,
                base: Totals::default(),
            },
        }
    }

    /// Coordinator restarts so far.
    pub fn restarts(&self) -> u32 {
        self.coordinator_starts.saturating_sub(1)
    }

    /// The first phase not done yet (the number of phases when all are done).
    pub fn next_phase(&self) -> usize {
        self.phases.len()
    }

    /// Phase `p` starts (or resumes) at `now_ns`; returns its start time, the earlier one if
    /// it was under way when the last coordinator died.
    pub fn start_phase(&mut self, p: usize, now_ns: u64) -> u64 {
        match self.current {
            Some(c) if c.phase == p => c.started_ns,
            _ => {
                self.current = Some(Current {
                    phase: p,
                    started_ns: now_ns,
                });
                now_ns
            }
        }
    }

    /// The totals now: the earlier processes' plus this one's `life` figures.
    pub fn totals_with(&self, life: LifeCounts) -> Totals {
        let b = self.base;
        let from_dead = b.from_dead + life.from_dead;
        Totals {
            discoveries: life.received + from_dead,
            from_dead,
            relays_sent: b.relays_sent + life.relays_sent,
            q_updates_merged: b.q_updates_merged + life.q_updates_merged,
            rejected: b.rejected + life.rejected,
        }
    }

    /// Phase `result` is done with the counts `life` of this process: its
    /// `discoveries_received` is filled in (those received since the last phase ended) and it
    /// is kept.
    pub fn phase_done(&mut self, mut result: PhaseResult, life: LifeCounts) {
        let now = self.totals_with(life);
        result.discoveries_received = now.discoveries.saturating_sub(self.totals.discoveries);
        self.totals = now;
        self.current = None;
        self.phases.push(result);
    }

    /// The last phase done left the robots at `at` on the shared grid.
    pub fn left_at(&mut self, at: Vec<Cell>) {
        self.at = Some(at);
    }

    /// Where the next phase's execution starts on the shared grid: where the last phase done
    /// left the robots, or `planned` (phase 0, or a checkpoint without positions for this
    /// fleet).
    pub fn grid_starts(&self, planned: Vec<Cell>) -> Vec<Cell> {
        match &self.at {
            Some(at) if !self.phases.is_empty() && at.len() == planned.len() => at.clone(),
            _ => planned,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use report::run::{RobotOutcome, RobotPhase};

    fn phase(p: usize, sent: &[u64]) -> PhaseResult {
        PhaseResult {
            phase: p,
            name: format!("phase-{p}"),
            episodes: 10,
            goals: Vec::new(),
            robots: sent
                .iter()
                .enumerate()
                .map(|(r, &s)| RobotPhase {
                    robot_id: r as u32,
                    goal: 0,
                    status: RobotOutcome::Finished,
                    episodes: 10,
                    env_steps: 100,
                    avg_steps: 10.0,
                    optimal_path_len: 5,
                    final_path_len: Some(5),
                    steps_to_optimal: None,
                    time_to_optimal_s: None,
                    steps_at_merged_optimal: None,
                    discoveries_sent: s,
                    relays_applied: 0,
                    hints_applied: 0,
                })
                .collect(),
            discoveries_sent: sent.iter().sum(),
            discoveries_received: 0,
            wall_s: 1.0,
            grid: None,
        }
    }

    fn life(received: u64, q: u64) -> LifeCounts {
        LifeCounts {
            received,
            q_updates_merged: q,
            ..LifeCounts::default()
        }
    }

    /// Through JSON, as a restarted process reads it.
    fn reread(c: &Checkpoint) -> Option<Checkpoint> {
        Some(serde_json::from_str(&serde_json::to_string(c).unwrap()).unwrap())
    }

    #[test]
    fn a_first_start_begins_at_phase_0_and_counts_one_start() {
        let c = Checkpoint::resume(None, "r", 1, 2, 100);
        assert_eq!((c.next_phase(), c.restarts(), c.began_ns), (0, 0, 100));
    }

    #[test]
    fn a_restart_resumes_after_the_phases_done_with_their_counts() {
        let mut c = Checkpoint::resume(None, "r", 1, 3, 100);
        assert_eq!(c.start_phase(0, 200), 200);
        c.phase_done(phase(0, &[3, 4]), life(7, 50));
        assert_eq!(c.phases[0].discoveries_received, 7);
        assert_eq!(c.phases[0].discoveries_sent, 7);
        assert_eq!(c.start_phase(1, 300), 300);
        // killed during phase 1: the next process resumes phase 1 with its start time
        let mut d = Checkpoint::resume(reread(&c), "r", 1, 3, 400);
        assert_eq!((d.next_phase(), d.restarts(), d.began_ns), (1, 1, 100));
        assert_eq!(
            d.start_phase(1, 500),
            300,
            "a resumed phase keeps its clock"
        );
        // the robots replayed all 7 earlier discoveries and made 5 new ones
        d.phase_done(phase(1, &[2, 3]), life(12, 20));
        assert_eq!(d.phases[1].discoveries_received, 5);
        assert_eq!(d.phases[1].discoveries_sent, 5);
        assert_eq!(
            d.totals.q_updates_merged, 70,
            "earlier processes' counts carried"
        );
        assert_eq!(d.start_phase(2, 600), 600);
    }

    #[test]
    fn discoveries_of_replaced_robot_processes_are_carried_over_restarts() {
        let mut c = Checkpoint::resume(None, "r", 1, 2, 0);
        c.start_phase(0, 0);
        // robot 1 was replaced in phase 0: 2 of its discoveries only the dead process had
        c.phase_done(
            phase(0, &[3, 1]),
            LifeCounts {
                received: 4,
                from_dead: 2,
                ..LifeCounts::default()
            },
        );
        assert_eq!(c.phases[0].discoveries_received, 6);
        let mut d = Checkpoint::resume(reread(&c), "r", 1, 2, 0);
        d.start_phase(1, 0);
        d.phase_done(phase(1, &[1, 0]), life(5, 0));
        assert_eq!(d.phases[1].discoveries_received, 1);
    }

    #[test]
    fn the_next_execution_starts_where_the_last_phase_done_left_the_robots_across_a_restart() {
        let planned = vec![Cell::new(1, 1), Cell::new(2, 2)];
        let mut c = Checkpoint::resume(None, "r", 1, 3, 0);
        assert_eq!(
            c.grid_starts(planned.clone()),
            planned,
            "phase 0: as planned"
        );
        c.start_phase(0, 0);
        c.phase_done(phase(0, &[]), LifeCounts::default());
        // robot 1 did not reach its goal: the next phase starts where it stood
        let left = vec![Cell::new(5, 5), Cell::new(2, 3)];
        c.left_at(left.clone());
        c.start_phase(1, 0);
        // killed during phase 1's execution: the restarted coordinator starts it again there
        let d = Checkpoint::resume(reread(&c), "r", 1, 3, 9);
        assert_eq!(d.next_phase(), 1);
        assert_eq!(d.grid_starts(planned.clone()), left);
        // positions for another fleet size are not used
        assert_eq!(d.grid_starts(vec![Cell::new(0, 0)]), vec![Cell::new(0, 0)]);
    }

    #[test]
    fn a_checkpoint_of_another_run_or_seed_is_not_resumed() {
        let mut c = Checkpoint::resume(None, "r", 1, 2, 0);
        c.start_phase(0, 0);
        c.phase_done(phase(0, &[]), LifeCounts::default());
        for (id, seed, phases) in [("other", 1, 2), ("r", 2, 2), ("r", 1, 0)] {
            let d = Checkpoint::resume(reread(&c), id, seed, phases, 9);
            assert_eq!((d.next_phase(), d.restarts(), d.began_ns), (0, 0, 9));
        }
    }
}
