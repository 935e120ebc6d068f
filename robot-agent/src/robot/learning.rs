//! Learning one phase: the episode loop, with hints batched and sent as values change (and
//! after the planning learner's sweeps), states every `--state-every` steps, the inbox read
//! every `--poll-every` steps, `--pace` pauses, and the discoveries each episode found.

use bus::bus_schema::RobotStatus;
use bus::monotonic_ns;

use crate::error::AgentError;

use super::{Phase, Robot};

impl Robot<'_> {
    /// Learns one phase's episodes (or until `Stop`, or the optimum with `--stop-at-optimum`).
    pub(super) fn learn(&mut self, p: &mut Phase, first: bool) -> Result<(), AgentError> {
        let share = self.args.share.share.hints();
        let state_every = u64::from(self.args.share.state_every);
        let poll_every = u64::from(self.args.share.poll_every);
        let flush_steps = u64::from(self.args.share.hint_flush_steps);
        // warm start: a robot (re)admitted during a run finds the coordinator's fleet table
        // waiting in its merged-hint buffer (sent before its Start)
        self.poll_and_plan(p)?;
        if first {
            self.c.warm_start_entries = self.applier.counters().entries_applied;
        }
        let optimal = p.learner.optimal_len();
        while !p.learner.finished() && !self.plan.stopped() {
            p.learner.begin_episode();
            p.episode_step = 0;
            loop {
                let info = p.learner.step();
                p.steps += 1;
                p.episode_step += 1;
                if share
                    && p.batcher
                        .note(info.state, info.action, info.q, p.steps, monotonic_ns)
                {
                    self.send_hints(p);
                }
                if p.steps.is_multiple_of(state_every) {
                    self.send_state(p, RobotStatus::Running, info.next);
                }
                if p.steps.is_multiple_of(poll_every) {
                    if share && p.batcher.due(p.steps, flush_steps) {
                        self.send_hints(p);
                    }
                    self.poll_and_plan(p)?;
                    // sweeps inside the episode (`--sweep-every`) changed values no step noted
                    if share && p.learner.take_swept_within() {
                        self.offer_planned(p);
                    }
                    if self.plan.stopped() {
                        break;
                    }
                }
                // --pace: a pause every few steps (when off, a countdown that never runs out)
                if self.pacer.step() {
                    self.pause(p, info.next)?;
                    if self.plan.stopped() {
                        break;
                    }
                }
                if info.done {
                    let rec = p.learner.end_episode(info.transition);
                    p.last_episode_steps = rec.steps;
                    p.records.push(rec);
                    if share && p.learner.planned() {
                        self.offer_planned(p);
                        // the merged batches that piled up during replay and sweeps: drained
                        // now, before the latest-wins buffer overwrites them
                        self.poll_and_plan(p)?;
                    }
                    break;
                }
            }
            p.episode_end_ns.push(monotonic_ns());
            p.episode_cum_steps.push(p.steps);
            for (cell, value) in p.learner.take_new_pseudo_targets() {
                // a lifelong robot (`--chain-goals`) keeps its discoveries: every other robot
                // learns another goal, and lossless relays to hundreds of robots busy learning
                // stalled the coordinator (256 robots: a relay not drained within 1 s)
                if self.args.chain_goals {
                    continue;
                }
                self.queue_discovery(p, cell, value);
            }
            self.resend_discoveries();
            if p.steps_to_optimal.is_none() && p.learner.greedy_path_len() == Some(optimal) {
                p.steps_to_optimal = Some(p.steps);
                p.time_to_optimal_s = Some(p.t0.elapsed().as_secs_f64());
                if self.args.stop_at_optimum {
                    break;
                }
            }
        }
        p.completed = !self.plan.stopped();
        p.learn_s = p.t0.elapsed().as_secs_f64();
        p.own_final = p.learner.greedy_path_len();
        Ok(())
    }

    /// Takes in everything waiting ([`poll`](Self::poll)), then, when moves of other robots
    /// joined the model, plans with them before the next step (`Learner::settle_grid_moves`)
    /// and offers the values that changed, as after an episode's sweeps.
    fn poll_and_plan(&mut self, p: &mut Phase) -> Result<(), AgentError> {
        self.poll(Some(p))?;
        if p.learner.settle_grid_moves() && self.args.share.share.hints() {
            self.offer_planned(p);
        }
        Ok(())
    }

    /// After an episode whose replay or sweeps changed values no step noted: offers every tried
    /// pair's value to the batcher (unchanged ones are skipped there) and sends the batch.
    pub(super) fn offer_planned(&mut self, p: &mut Phase) {
        for i in 0..p.learner.tried_pairs().len() {
            let sa = p.learner.tried_pairs()[i];
            let (s, a) = (sa >> 2, (sa & 3) as u8);
            let q = p.learner.q().row(s as usize)[a as usize];
            if p.batcher.offer(s, a, q, p.steps, monotonic_ns) {
                self.send_hints(p);
            }
        }
        // what planning learned goes out now, not `--hint-flush-steps` later
        if !p.batcher.is_empty() {
            self.send_hints(p);
        }
    }

    /// A `--pace` pause: sleeps what the pacer says, then shows where the robot is, shares what
    /// it learned and reads its inbox (a slow pace pauses up to a second per step: a stop must
    /// not wait for the next `--poll-every`, nor the coordinator take the robot for hung).
    pub(super) fn pause(&mut self, p: &mut Phase, at: u32) -> Result<(), AgentError> {
        let nap = self.pacer.pause(monotonic_ns());
        if !nap.is_zero() {
            std::thread::sleep(nap);
        }
        if self.args.share.share.hints() && !p.batcher.is_empty() {
            self.send_hints(p);
        }
        self.send_state(p, RobotStatus::Running, at);
        let _ = self.bus.state.notify();
        self.poll(Some(p))
    }
}
