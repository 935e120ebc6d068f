//! Moving on a shared grid as the coordinator grants, tick by tick: each grant is answered
//! with this robot's moves ranked by its learned values ([`crate::execute`] for the protocol
//! and the ranking).

use std::time::{Duration, Instant};

use bus::bus_schema::{EARLY_HORIZON_RADIUS, GRANT_CAP, GridState, HORIZON_CELLS, RobotStatus};
use bus::iceoryx2::prelude::PayloadHeader;
use bus::{BusError, monotonic_ns};
use planner::Cell;

use crate::error::AgentError;
use crate::execute::{Answering, Prepared, early_answer_due};

use super::{Phase, Robot};

impl Robot<'_> {
    /// Settles the values merged hints changed and, on a shared grid (`--shared-grid`), makes
    /// what `Execute` will rank with ([`Prepared`]) and sends the answer to the execution's
    /// first tick: the horizon of radius [`EARLY_HORIZON_RADIUS`] at its start (it answers tick
    /// 0 on any fleet horizon, see `mapf::Coverage::answers`). Again only when the values
    /// changed since. The coordinator takes it if it is this phase's and centered where the
    /// robot starts; the robot still answers the first grant it reads, so one the coordinator
    /// did not take costs only the wakeup it saved. Never after the phase's execution began
    /// ([`early_answer_due`]): a horizon for a tick already past is stale.
    pub(super) fn prepare_execution(&mut self, p: &mut Phase) {
        let changed = p.learner.settle();
        let applied = self.applier.counters().entries_applied;
        let sent_with = p.prepared.as_ref().map(|r| r.1);
        if !self.args.shared_grid || !early_answer_due(p.executed, changed, sent_with, applied) {
            return;
        }
        let ready = p.prepare();
        let (start, ranks) = (p.task.start, ready.first);
        p.prepared = Some((ready, applied));
        let robot_id = self.args.robot_id;
        let sent = self.bus.horizon.send_with(|m| {
            m.robot_id = robot_id;
            m.tick = 0;
            m.cell_x = start.x;
            m.cell_y = start.y;
            m.radius = EARLY_HORIZON_RADIUS;
            m.ranked = ranks;
            m.send_time_ns = monotonic_ns();
        });
        if sent.is_err() {
            self.c.send_errors += 1;
        }
    }

    /// Moves on the shared grid as the coordinator grants, tick by tick, until the execution
    /// ends (a grant that is not `Moving`, this robot no longer on the grid, `Stop`, a signal);
    /// see [`crate::execute`] for the protocol and the ranking.
    pub(super) fn execute(&mut self, p: &mut Phase, horizon: u8) -> Result<(), AgentError> {
        // from now on tick 0 is granted or past: no more early answers this phase
        p.executed = true;
        // the values it ranks by, consistent with every merged hint applied so far, and what
        // it ranks with: made while it waited unless the values changed since
        let changed = p.learner.settle();
        let applied = self.applier.counters().entries_applied;
        let mut answering = Answering::new(horizon);
        let Prepared {
            ranker, mut cache, ..
        } = match p.prepared.take() {
            Some((ready, at)) if !changed && at == applied => {
                // what it sent early still holds: the coordinator asks no more of it (one
                // intent per tick, horizon 0, takes no early answer)
                if horizon > 0 {
                    answering.answered_early(p.task.start);
                }
                ready
            }
            _ => p.prepare(),
        };
        let me = self.args.robot_id as usize;
        let mut ranks = [0u16; HORIZON_CELLS];
        let mut answered: Option<u32> = None;
        // whose grants those ticks were: a coordinator that took over counts ticks afresh
        let mut granter = self.gate.coordinator().map(|o| o.node);
        let mut heard = Instant::now();
        let mut polled = Instant::now();
        let mut intents = 0u64;
        loop {
            // the newest grant of this robot's coordinator: only its tick, state and this
            // robot's entry matter
            let coordinator = self.gate.coordinator().map(|o| o.node);
            if coordinator != granter {
                // a restarted coordinator executes the phase again from tick 0: answer it
                // from there, not only past the last tick the old one granted
                granter = coordinator;
                answered = None;
                answering = Answering::new(horizon);
            }
            let mut newest: Option<(u32, u8, Cell, bool)> = None;
            while let Some(g) = self.bus.grant.receive_sample()? {
                if coordinator != Some(g.header().node_id().value()) {
                    self.c.grants_foreign += 1;
                    continue;
                }
                let g = g.payload();
                if me < GRANT_CAP && newest.is_none_or(|n| g.tick >= n.0) {
                    let cell = Cell::new(g.cell_x[me], g.cell_y[me]);
                    newest = Some((g.tick, g.state, cell, g.present[me] != 0));
                }
            }
            if let Some((tick, state, cell, present)) = newest
                && answered.is_none_or(|t| tick > t)
            {
                heard = Instant::now();
                answered = Some(tick);
                if !p.task.grid.contains(cell.x.into(), cell.y.into()) {
                    // no grant of this run's coordinator puts a robot off the map
                    self.c.rejected += 1;
                    continue;
                }
                let at = p.task.grid.index(cell) as u32;
                if state != GridState::Moving.as_u8() || !present {
                    p.episode_step = tick;
                    self.send_state(p, RobotStatus::Finished, at);
                    let _ = self.bus.state.notify();
                    break;
                }
                let robot_id = self.args.robot_id;
                let sent = match answering.due(tick, cell) {
                    // the last horizon still answers this tick here: nothing to send
                    None => None,
                    Some(_) if answering.horizon() == 0 => {
                        let (ranked, count) = ranker.rank(&p.task, p.learner.q(), cell);
                        Some(self.bus.intent.send_with(|m| {
                            m.robot_id = robot_id;
                            m.tick = tick;
                            m.cell_x = cell.x;
                            m.cell_y = cell.y;
                            m.count = count;
                            m.ranked = ranked;
                            m.send_time_ns = monotonic_ns();
                        }))
                    }
                    Some(radius) => {
                        let q = p.learner.q();
                        ranker.rank_horizon(&p.task, q, &mut cache, cell, radius, &mut ranks);
                        answering.answered(tick, cell, radius);
                        Some(self.bus.horizon.send_with(|m| {
                            m.robot_id = robot_id;
                            m.tick = tick;
                            m.cell_x = cell.x;
                            m.cell_y = cell.y;
                            m.radius = radius;
                            m.ranked = ranks;
                            m.send_time_ns = monotonic_ns();
                        }))
                    }
                };
                match sent {
                    // no wakeup: the coordinator polls while it collects a tick (a notification
                    // per robot per tick cost each robot a syscall and the coordinator one
                    // wakeup per robot)
                    Some(Ok(_)) => intents += 1,
                    Some(Err(_)) => self.c.send_errors += 1,
                    None => {}
                }
                // observers see the ticks on robot/state (no wakeup: nobody waits for it)
                p.episode_step = tick;
                self.send_state(p, RobotStatus::Running, at);
            }
            if polled.elapsed() >= Duration::from_millis(20) {
                polled = Instant::now();
                let applied = self.applier.counters().entries_applied;
                self.poll(Some(p))?;
                if self.applier.counters().entries_applied != applied {
                    // merged hints changed the values: rank anew
                    cache.clear();
                }
                if self.plan.stopped() {
                    break;
                }
            }
            if heard.elapsed() >= self.timeout {
                return Err(BusError::Timeout {
                    what: "the coordinator's next grant on the shared grid".into(),
                    timeout: self.timeout,
                }
                .into());
            }
            self.bus.grant.wait(Duration::from_millis(10))?;
        }
        report::log_line!(
            "robot-agent {}: shared grid: {intents} intents sent, last tick {}",
            self.args.robot_id,
            answered.unwrap_or(0)
        );
        Ok(())
    }
}
