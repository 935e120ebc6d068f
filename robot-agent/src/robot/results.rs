//! Result assembly: a phase's summary and detail, the counters with the applier's and the
//! link's folded in, the `FinalReport` a phase ends with, and the robot's `RobotResult`.

use bus::bus_schema::{FinalReport, RobotStatus, SCHEMA_VERSION};
use bus::{BusError, SendError, monotonic_ns};
use planner::Summary;
use report::hist::{self, LatencyStats};
use report::{Counters, EndStatus, PhaseDetail, RobotResult};

use crate::error::AgentError;

use super::{Phase, Robot};

impl Robot<'_> {
    /// The phase's learning summary, read after the merged hints applied so far settled.
    pub(super) fn summary(p: &mut Phase) -> Summary {
        // merged hints applied since the last episode reach the values they bound first (a
        // path read from unpropagated bounds could loop)
        p.learner.settle();
        let final_len = p.learner.greedy_path_len();
        Summary::from_records(&p.records, p.learner.optimal_len(), final_len)
    }

    /// What the robot learned in phase `p` (`robot-<id>-phase-<n>.json`).
    pub(super) fn phase_detail(&self, p: &mut Phase) -> PhaseDetail {
        let s = Self::summary(p);
        let now = self.counters();
        PhaseDetail {
            robot_id: self.args.robot_id,
            phase: p.a.phase,
            goal_id: p.a.goal_id,
            start: p.task.start.to_string(),
            goal: p.task.goal.to_string(),
            episodes: s.episodes,
            env_steps: s.env_steps,
            avg_steps: s.avg_steps,
            optimal_path_len: s.optimal_path_len,
            final_path_len: s.final_path_len,
            first_optimal_episode: s.first_optimal_episode,
            steps_to_optimal: p.steps_to_optimal,
            time_to_optimal_s: p.time_to_optimal_s,
            start_ns: p.start_ns,
            episode_end_ns: p.episode_end_ns.clone(),
            episode_cum_steps: p.episode_cum_steps.clone(),
            discoveries_sent: now.discoveries_sent - p.at_start.discoveries_sent,
            relays_applied: now.relays_applied - p.at_start.relays_applied + p.relays_at_start,
            hints_applied: now.merged.entries_applied - p.at_start.merged.entries_applied,
            finished: p.completed,
        }
    }

    /// The counters with the applier's and the link's folded in.
    pub(super) fn counters(&self) -> Counters {
        Counters {
            merged: *self.applier.counters(),
            link: self.link.counters,
            ..self.c
        }
    }

    /// The phase's `FinalReport`: learning summary, counters, loop latency. A report that
    /// reaches nobody after `Stop` (the coordinator already left) or while the coordinator is
    /// gone is not an error.
    pub(super) fn send_report(&mut self, p: &mut Phase) -> Result<(), AgentError> {
        p.reported = true;
        let s = Self::summary(p);
        let to_i32 = |v: Option<u32>| v.map_or(-1, |x| x.min(i32::MAX as u32) as i32);
        let c = self.counters();
        let rep = FinalReport {
            robot_id: self.args.robot_id,
            schema_version: SCHEMA_VERSION,
            goal_id: p.a.goal_id,
            episodes: s.episodes,
            final_path_len: to_i32(s.final_path_len),
            optimal_path_len: to_i32(Some(s.optimal_path_len)),
            first_optimal_episode: to_i32(s.first_optimal_episode),
            max_steps: s.max_steps,
            status: if p.completed {
                RobotStatus::Finished
            } else {
                RobotStatus::Failed
            }
            .as_u8(),
            avg_steps: s.avg_steps,
            env_steps: s.env_steps,
            elapsed_ns: p.t0.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64,
            discoveries_sent: c.discoveries_sent,
            discoveries_acked: c.discoveries_acked,
            hints_sent: c.hint_batches_sent,
            hints_received: c.merged.batches,
            hints_applied: c.merged.entries_applied,
            merged_latency: hist::summary(self.applier.loop_hist()),
            send_time_ns: monotonic_ns(),
            ..FinalReport::ZEROED
        };
        match self.bus.report.send_and_notify(&rep) {
            Ok(_) => Ok(()),
            // without a coordinator the report waits for the restarted one's repeat of the
            // phase (see the protocol in `crate::experiment`); one that died since the last
            // periodic look is looked for now (CI: a robot ending its phase just after the
            // coordinator was killed exited with "reached no subscriber")
            Err(BusError::Send(
                e @ (SendError::NoSubscriber { .. } | SendError::DeliveryTimeout { .. }),
            )) => {
                let nobody = matches!(e, SendError::NoSubscriber { .. })
                    && (self.plan.stopped() || self.link.alone());
                if nobody || self.link.look_now(&self.bus)? {
                    Ok(())
                } else {
                    Err(e.into())
                }
            }
            Err(e) => Err(e.into()),
        }
    }

    /// The robot's result (`robot-<id>.json`, the launcher's per-robot figures): its last
    /// phase, its counters and latencies.
    pub(super) fn result(&self, p: &mut Phase) -> RobotResult {
        let s = Self::summary(p);
        RobotResult {
            robot_id: self.args.robot_id,
            status: if p.completed {
                EndStatus::Finished
            } else {
                EndStatus::Stopped
            },
            map: self.base.map_name.clone(),
            learner: self.args.learner.learner.to_string(),
            seed: p.learner.config().seed,
            goal_id: p.a.goal_id,
            start: p.task.start.to_string(),
            goal: p.task.goal.to_string(),
            episodes: s.episodes,
            optimal_path_len: s.optimal_path_len,
            final_path_len: s.final_path_len,
            own_final_path_len: p.own_final,
            avg_steps: s.avg_steps,
            max_steps: s.max_steps,
            first_optimal_episode: s.first_optimal_episode,
            env_steps: s.env_steps,
            outcomes: [s.goal_episodes, s.pseudo_episodes, s.capped_episodes],
            learn_s: p.learn_s,
            share: self.args.share.share,
            counters: self.counters(),
            loop_latency_ns: LatencyStats::of(self.applier.loop_hist()),
            merged_latency_ns: LatencyStats::of(&self.merged_hist),
        }
    }
}
