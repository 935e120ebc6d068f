//! The control protocol between the coordinator and a robot — the one protocol of plain runs
//! and experiments — and [`Plan`], the robot's reading of it, without IO.
//!
//! # Protocol
//! 1. The robot registers (`Register` on `robot/register`); the coordinator answers `Ack` or
//!    `Refuse` on `coord/control` (see the `bus` crate's start handshake).
//! 2. Before each phase `p` the coordinator sends `AssignGoal` to this robot (`goal_id`, goal
//!    cell, `phase = p`, `episodes`, 0 = the robot's `--episodes`), then `Start` (phase 0) or
//!    `Phase` (later phases) to all, with `phase = p` too.
//! 3. The robot learns `episodes` episodes towards its goal, sharing by `--share` (Q hints and
//!    discoveries tagged with the goal id), and stops the phase early after the episode whose
//!    greedy path is optimal when `--stop-at-optimum` is given.
//! 4. It flushes its hints, waits until its discoveries are acknowledged, writes
//!    `robot-<id>-phase-<p>.json` and sends one `FinalReport` for the phase (`status` Finished,
//!    or Failed if stopped), then publishes its state `Finished`.
//! 5. Until the next `AssignGoal` + `Phase`, or `Stop`, it keeps applying merged hints of its
//!    goal (the fleet sync: every robot ends with what the whole fleet learned).
//! 6. In a shared grid, `Execute` (after every robot finished learning) makes it move from its
//!    start to its goal among the others as the coordinator grants, tick by tick
//!    ([`crate::execute`]); then it waits for `Stop` again.
//! 7. At `Stop` it writes `robot-<id>.json` and exits.
//!
//! A plain run is a plan with one goal and one phase: `AssignGoal` with `episodes = 0` (the
//! robot's own `--episodes`), `Start`, and `Stop` once every robot is `Finished`. A `Start`
//! without any `AssignGoal` before it means the same with the command line's goal as goal 0.
//! **When the report goes:** a phase whose assignment names its episodes (`episodes > 0`, what
//! experiments send) is reported at its end (step 4), because the coordinator waits for the
//! reports before the next phase; a single-phase plan (`episodes = 0`, or no assignment) is
//! reported after `Stop`, so that its report carries the greedy path after the fleet sync.
//! `Stop` may come at any time: the robot ends the phase it is in, reports it, and exits.
//!
//! **A repeated plan is not a new phase.** A coordinator restarted mid-run (`qfleet run
//! --restart on-failure`) admits the re-joining robots and sends its plan again: `AssignGoal`
//! and `Start` for the phase the robots are already in, or have finished. The robot ignores an
//! `AssignGoal`, `Start` or `Phase` whose phase is not after the last phase it took
//! ([`Effect::Repeated`]): it goes on with that phase and keeps its discovery log and its
//! sequence numbers, instead of learning the phase again from scratch. A phase of an experiment
//! it already reported is reported again on the repeated `AssignGoal` (an experiment's
//! coordinator restarted by `qfleet experiment --restart on-failure` waits for that report).
//!
//! # Q-tables per goal
//! The robot keeps one Q-table per goal. A phase starts a fresh learner (its schedule and
//! pseudo-target removal run over the phase's episodes) whose table is the robot's table for that
//! goal so far: coming back to a goal resumes what was learned. Relayed discoveries are kept per
//! goal and become pseudo targets of every later learner on that goal (`--share
//! discoveries|both`).

use bus::bus_schema::{Command, Control, HORIZON_RADIUS_CAP};
use planner::Cell;

/// One phase the coordinator asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Assignment {
    /// Goal id (the fleet table and the hints of this goal).
    pub goal_id: u32,
    /// Goal cell; `None`: the goal of the robot's command line.
    pub goal: Option<Cell>,
    /// Phase number.
    pub phase: u32,
    /// Episodes; `None`: the robot's `--episodes`.
    pub episodes: Option<u32>,
    /// Whether the phase is reported at its end (its assignment named its episodes: a phase
    /// of an experiment) or after `Stop` (a single-phase plan; see the protocol).
    pub report_at_end: bool,
}

impl Assignment {
    /// The implicit plan of a plain run: the command line's goal as goal 0, phase 0.
    pub const IMPLICIT: Assignment = Assignment {
        goal_id: 0,
        goal: None,
        phase: 0,
        episodes: None,
        report_at_end: false,
    };
}

/// What one control message did to the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Effect {
    /// `Stop`: end the phase, report, exit.
    Stop,
    /// `AssignGoal`: the next phase is known.
    Assigned,
    /// `Start` / `Phase`: go on to the assigned phase.
    Go,
    /// `AssignGoal`, `Start` or `Phase` for a phase the robot already took (it is in it, or
    /// finished it): a restarted coordinator sending its plan again. Ignored, not rejected.
    Repeated,
    /// Handshake traffic (`Ack`, `Refuse`): the link's business, nothing for the plan.
    Handshake,
    /// `Execute`: move on the shared grid now (see [`crate::execute`]).
    Execute,
    /// An unknown command byte: dropped, count it as rejected.
    Rejected,
}

/// The robot's reading of the coordinator's controls (see the protocol above).
#[derive(Debug, Default, Clone)]
pub struct Plan {
    assigned: Option<Assignment>,
    go: bool,
    stopped: bool,
    started: bool,
    /// `Execute` came and was not taken yet: the horizon it asks for.
    execute: Option<u8>,
    /// The phase of the last assignment taken: the phase the robot is in, or has finished.
    current: Option<u32>,
}

impl Plan {
    /// Takes one control addressed to this robot (or to all).
    pub fn on(&mut self, ctl: &Control) -> Effect {
        match Command::try_from(ctl.command) {
            Ok(Command::Stop) => {
                self.stopped = true;
                Effect::Stop
            }
            Ok(Command::AssignGoal) if self.taken(ctl.phase) => Effect::Repeated,
            Ok(Command::Start | Command::Phase) if self.taken(ctl.phase) => Effect::Repeated,
            Ok(Command::AssignGoal) => {
                self.assigned = Some(Assignment {
                    goal_id: ctl.goal_id,
                    goal: Some(Cell::new(ctl.goal_x, ctl.goal_y)),
                    phase: ctl.phase,
                    episodes: (ctl.episodes > 0).then_some(ctl.episodes),
                    report_at_end: ctl.episodes > 0,
                });
                Effect::Assigned
            }
            Ok(Command::Start | Command::Phase) => {
                if !self.started && self.assigned.is_none() {
                    self.assigned = Some(Assignment::IMPLICIT);
                }
                self.started = true;
                self.go = true;
                Effect::Go
            }
            Ok(Command::Ack | Command::Refuse) => Effect::Handshake,
            Ok(Command::Execute) => {
                // `episodes` carries the horizon (0: one intent per tick), at most the wire's
                let h = ctl.episodes.min(u32::from(HORIZON_RADIUS_CAP));
                self.execute = Some(h as u8);
                Effect::Execute
            }
            Err(_) => Effect::Rejected,
        }
    }

    /// Whether `phase` is one the robot already took (in it, or finished with it).
    fn taken(&self, phase: u32) -> bool {
        self.current.is_some_and(|c| phase <= c)
    }

    /// The phase of the last assignment taken ([`take_next`](Self::take_next)), if any.
    pub fn current_phase(&self) -> Option<u32> {
        self.current
    }

    /// Whether `Stop` came (or the caller stopped the robot).
    pub fn stopped(&self) -> bool {
        self.stopped
    }

    /// Stops the plan from outside (a signal).
    pub fn stop(&mut self) {
        self.stopped = true;
    }

    /// The phase to learn now, if one is assigned and its `Start`/`Phase` came (and no `Stop`).
    pub fn take_next(&mut self) -> Option<Assignment> {
        if self.stopped || !self.go {
            return None;
        }
        let a = self.assigned.take()?;
        self.go = false;
        self.current = Some(a.phase);
        Some(a)
    }

    /// Whether a phase is assigned and started but not taken yet: what arrives for its goal
    /// now (its fleet table, a warm start) waits for it.
    pub fn pending(&self) -> bool {
        self.go && self.assigned.is_some() && !self.stopped
    }

    /// The horizon of the `Execute` that came since the last call (and no `Stop`); clears it.
    pub fn take_execute(&mut self) -> Option<u8> {
        self.execute.take().filter(|_| !self.stopped)
    }

    /// Drops an assignment that turned out unusable (a goal outside the map or on a wall).
    pub fn drop_assignment(&mut self) {
        self.assigned = None;
        self.go = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctl(command: Command) -> Control {
        Control {
            command: command.as_u8(),
            ..Control::ZEROED
        }
    }

    fn assign(goal_id: u32, x: u16, phase: u32, episodes: u32) -> Control {
        Control {
            goal_id,
            goal_x: x,
            goal_y: 1,
            phase,
            episodes,
            ..ctl(Command::AssignGoal)
        }
    }

    #[test]
    fn a_start_without_an_assignment_is_the_command_lines_goal_as_goal_0_phase_0() {
        let mut p = Plan::default();
        assert_eq!(p.take_next(), None);
        assert_eq!(p.on(&ctl(Command::Start)), Effect::Go);
        assert_eq!(p.take_next(), Some(Assignment::IMPLICIT));
        assert_eq!(p.take_next(), None, "one phase per Start");
    }

    #[test]
    fn an_assignment_waits_for_its_start_and_carries_goal_phase_and_episodes() {
        let mut p = Plan::default();
        assert_eq!(p.on(&assign(2, 5, 0, 0)), Effect::Assigned);
        assert_eq!(p.take_next(), None, "no Start yet");
        p.on(&ctl(Command::Start));
        let a = p.take_next().unwrap();
        assert_eq!(
            a,
            Assignment {
                goal_id: 2,
                goal: Some(Cell::new(5, 1)),
                phase: 0,
                episodes: None,
                report_at_end: false,
            }
        );
        // the next phase: a new assignment, then Phase (carrying the phase number)
        p.on(&assign(1, 3, 1, 40));
        assert_eq!(p.take_next(), None);
        p.on(&go(Command::Phase, 1));
        let b = p.take_next().unwrap();
        assert_eq!((b.goal_id, b.phase, b.episodes), (1, 1, Some(40)));
        assert!(
            b.report_at_end,
            "a phase of an experiment reports at its end"
        );
    }

    #[test]
    fn a_phase_is_pending_from_its_start_until_it_is_taken() {
        let mut p = Plan::default();
        p.on(&assign(3, 1, 0, 9));
        assert!(!p.pending(), "assigned, not started");
        p.on(&ctl(Command::Start));
        assert!(p.pending());
        p.take_next().unwrap();
        assert!(!p.pending());
        p.on(&assign(4, 2, 1, 9));
        p.on(&go(Command::Phase, 1));
        assert!(p.pending());
        p.on(&ctl(Command::Stop));
        assert!(!p.pending(), "Stop wins");
    }

    #[test]
    fn a_later_phase_without_a_new_assignment_is_not_a_phase() {
        let mut p = Plan::default();
        p.on(&ctl(Command::Start));
        p.take_next().unwrap();
        p.on(&ctl(Command::Phase));
        assert_eq!(
            p.take_next(),
            None,
            "the implicit plan is only the first phase"
        );
    }

    #[test]
    fn stop_wins_over_everything_pending() {
        let mut p = Plan::default();
        p.on(&assign(0, 1, 0, 0));
        p.on(&ctl(Command::Start));
        assert_eq!(p.on(&ctl(Command::Stop)), Effect::Stop);
        assert!(p.stopped());
        assert_eq!(p.take_next(), None);
    }

    #[test]
    fn unknown_commands_are_rejected_and_handshake_traffic_is_not_the_plans() {
        let mut p = Plan::default();
        let bad = Control {
            command: 250,
            ..Control::ZEROED
        };
        assert_eq!(p.on(&bad), Effect::Rejected);
        assert_eq!(p.on(&ctl(Command::Ack)), Effect::Handshake);
        assert_eq!(p.take_next(), None);
        assert!(!p.stopped());
    }

    fn go(command: Command, phase: u32) -> Control {
        Control {
            phase,
            ..ctl(command)
        }
    }

    #[test]
    fn a_restarted_coordinators_plan_for_the_phase_being_learned_is_ignored() {
        let mut p = Plan::default();
        p.on(&assign(0, 5, 0, 0));
        p.on(&go(Command::Start, 0));
        assert_eq!(p.take_next().map(|a| a.phase), Some(0));
        // mid-phase, a restarted coordinator admits the robot again and resends its plan
        assert_eq!(p.on(&assign(0, 5, 0, 0)), Effect::Repeated);
        assert_eq!(p.on(&go(Command::Start, 0)), Effect::Repeated);
        assert_eq!(p.take_next(), None, "phase 0 is not learned again");
        assert_eq!(p.current_phase(), Some(0));
        assert!(!p.stopped());
        // its Stop is obeyed as usual
        assert_eq!(p.on(&ctl(Command::Stop)), Effect::Stop);
    }

    #[test]
    fn a_finished_earlier_phase_is_not_taken_again_but_the_next_one_is() {
        let mut p = Plan::default();
        p.on(&assign(0, 5, 0, 40));
        p.on(&go(Command::Start, 0));
        p.take_next().unwrap();
        p.on(&assign(1, 3, 1, 40));
        p.on(&go(Command::Phase, 1));
        assert_eq!(p.take_next().map(|a| (a.goal_id, a.phase)), Some((1, 1)));
        // a resent plan of phase 0 or 1 (finished, or being learned) changes nothing
        for phase in [0, 1] {
            assert_eq!(p.on(&assign(0, 5, phase, 40)), Effect::Repeated);
            assert_eq!(p.on(&go(Command::Phase, phase)), Effect::Repeated);
            assert_eq!(p.take_next(), None);
        }
        // phase 2 is new
        assert_eq!(p.on(&assign(0, 5, 2, 40)), Effect::Assigned);
        assert_eq!(p.take_next(), None, "waits for its Phase");
        assert_eq!(p.on(&go(Command::Phase, 2)), Effect::Go);
        assert_eq!(p.take_next().map(|a| a.phase), Some(2));
    }

    #[test]
    fn a_fresh_robot_takes_any_phase_it_is_given() {
        // a restarted robot process joins mid-experiment: its first assignment may be phase 3
        let mut p = Plan::default();
        assert_eq!(p.on(&assign(1, 3, 3, 40)), Effect::Assigned);
        assert_eq!(p.on(&go(Command::Phase, 3)), Effect::Go);
        assert_eq!(p.take_next().map(|a| a.phase), Some(3));
    }

    #[test]
    fn an_unusable_assignment_is_dropped_with_its_start() {
        let mut p = Plan::default();
        p.on(&assign(0, 999, 0, 0));
        p.on(&ctl(Command::Start));
        p.drop_assignment();
        assert_eq!(p.take_next(), None);
        p.on(&assign(0, 2, 0, 0));
        p.on(&ctl(Command::Phase));
        assert_eq!(p.take_next().map(|a| a.goal), Some(Some(Cell::new(2, 1))));
    }
}
