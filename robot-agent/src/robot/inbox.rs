//! What the robot takes in, without ever blocking: merged hints (applied to the phase's
//! learner, or kept for the first phase as a warm start), other robots' discoveries relayed by
//! the coordinator, acknowledgements of its own, and controls from its coordinator only
//! ([`crate::gate`]) — with a restarted coordinator's re-admission ([`crate::reconnect`]).

use std::sync::atomic::Ordering;

use bus::bus_schema::Command;
use bus::{BusError, monotonic_ns};
use planner::Cell;
use report::hist::record;

use crate::discovery::AckOutcome;
use crate::error::AgentError;
use crate::experiment::Effect;
use crate::gate::Verdict;
use crate::reconnect::LinkEvent;

use super::{Phase, Robot};

impl Robot<'_> {
    /// A restarted coordinator accepted this robot: it knows none of our discoveries, so all
    /// of them go out again (it drops duplicates by seq).
    pub(super) fn on_link(&mut self, ev: LinkEvent) -> Result<(), AgentError> {
        match ev {
            LinkEvent::Rejoined => {
                self.disc.replay();
                self.c.discoveries_acked = self.disc.acked();
                self.resend_discoveries();
                Ok(())
            }
            LinkEvent::Refused(why) => Err(AgentError::Refused(BusError::Refused {
                robot_id: self.args.robot_id,
                reason: why,
            })),
        }
    }

    /// Takes in everything waiting: merged hints (applied to `phase`'s learner if there is
    /// one), relayed discoveries, acks and controls; never blocks.
    pub(super) fn poll(&mut self, mut phase: Option<&mut Phase>) -> Result<(), AgentError> {
        self.link.tick(&self.bus)?;
        let share = self.args.share.share.hints();
        // merged hints: applied in place, straight from shared memory; before the first phase,
        // and while the next one waits to be opened, they stay buffered for it (the warm start
        // from the fleet table of its goal)
        while phase.is_some()
            && !self.plan.pending()
            && let Some(sample) = self.bus.merged.receive_sample()?
        {
            let m = sample.payload();
            let now = monotonic_ns();
            if m.send_time_ns != 0 && m.send_time_ns <= now {
                record(&mut self.merged_hist, now - m.send_time_ns);
            }
            if share
                && let Some(p) = phase.as_deref_mut()
                && p.shared_model
                && m.goal_id != p.a.goal_id
            {
                // another goal's values say nothing of ours, but the moves behind them are the
                // grid's: they join this learner's model with what they reveal of the grid (the
                // cells they left and entered, free or walls, and so every move into those), so
                // it never explores a wall another robot found nor a cell another robot stood
                // on (robots with different goals on one grid); the learning loop then plans
                // with them (`Learner::settle_grid_moves`)
                let n = (m.count as usize).min(m.entries.len());
                let mut known = 0;
                for (h, &origin) in m.entries[..n].iter().zip(&m.origin_robot[..n]) {
                    if origin != self.args.robot_id {
                        known += u64::from(p.learner.add_grid_move(h.cell, usize::from(h.action)));
                    }
                }
                self.c.moves_learned_from_others += known;
                continue;
            }
            if share && let Some(p) = phase.as_deref_mut() {
                let before = self.applier.counters().entries_applied;
                self.applier
                    .apply(m, p.learner.q_mut(), p.batcher.visits(), now);
                if self.applier.counters().entries_applied != before {
                    // the planning learner's sweeps carry the new values to their predecessors
                    p.learner.table_changed();
                    if p.shared_model {
                        // and back up the moves other robots made, as their own
                        let n = (m.count as usize).min(m.entries.len());
                        for (h, &origin) in m.entries[..n].iter().zip(&m.origin_robot[..n]) {
                            if origin != self.args.robot_id {
                                p.learner.add_known_move(h.cell, usize::from(h.action));
                            }
                        }
                    }
                }
            }
        }
        // discoveries of other robots, relayed by the coordinator (lossless: always drained)
        let grid = &self.base.grid;
        while let Some(r) = self.bus.relay.receive()? {
            self.c.relays_received += 1;
            if !self.args.share.share.discoveries()
                || r.origin_robot == self.args.robot_id
                || (r.cell_x as usize) >= grid.width()
                || (r.cell_y as usize) >= grid.height()
                || !r.value.is_finite()
            {
                continue;
            }
            let cell = grid.index(Cell::new(r.cell_x, r.cell_y)) as u32;
            self.relayed
                .entry(r.goal_id)
                .or_default()
                .push((cell, r.value));
            if let Some(p) = phase.as_deref_mut()
                && p.a.goal_id == r.goal_id
                && p.learner.add_discovery(cell, r.value)
            {
                self.c.relays_applied += 1;
            }
        }
        while let Some(ack) = self.bus.ack.receive()? {
            if ack.robot_id != self.args.robot_id {
                continue;
            }
            if self.disc.on_ack(ack.up_to_seq) == AckOutcome::Rejected {
                self.c.rejected += 1; // acks something never sent
            }
            self.c.discoveries_acked = self.disc.acked();
        }
        while let Some((ctl, from)) = self.bus.recv_control_from()? {
            // a restarted coordinator's answer to our re-registration moves the gate to it
            if let Some(ev) = self.link.on_control(&ctl) {
                if ev == LinkEvent::Rejoined {
                    self.gate.accept(from);
                }
                self.on_link(ev)?;
                continue;
            }
            if self.gate.check(from) == Verdict::Drop {
                self.c.rejected += 1; // not from our coordinator: a forged or stale control
                continue;
            }
            match self.plan.on(&ctl) {
                Effect::Rejected => self.c.rejected += 1,
                // a restarted coordinator's plan for the phase we are in (or finished): that
                // phase goes on, with its discovery log and sequence numbers; a phase reported
                // already is reported again (the new coordinator never got it)
                Effect::Repeated => {
                    self.link.counters.plan_repeats += 1;
                    if let Some(p) = phase.as_deref_mut()
                        && p.reported
                        && p.a.phase == ctl.phase
                        && ctl.command == Command::AssignGoal.as_u8()
                    {
                        self.send_report(p)?;
                    }
                }
                _ => {}
            }
        }
        if self.stop.load(Ordering::Relaxed) {
            self.plan.stop();
        }
        Ok(())
    }
}
