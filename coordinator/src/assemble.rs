//! Result building: turns the engine's state, the validated final reports and the robots'
//! own files into a [`RunResult`] or a [`PhaseResult`]. No bus, no decisions.

use std::collections::BTreeMap;

use bus::bus_schema::{FinalReport, RobotStatus};
use hdrhistogram::Histogram;
use planner::task::Task;
use report::hist::{self, LatencyStats, new_hist};
use report::run::{
    GoalPhase, LivenessReport, PhaseResult, RobotEntry, RobotOutcome, RobotPhase, RunResult,
    Throughput,
};
use report::{LatencyPath, OutDir, OutFile, PhaseDetail, RobotHist, RobotResult};

use crate::engine::{Engine, Slot};
use crate::experiment::merged_path_len;
use crate::options::CoordArgs;
use contract::plan::ExperimentPlan;

/// The fleet's loop and merged latency histograms, added up from every robot's `.hdr` files
/// (read once; a robot that wrote none adds nothing).
pub(crate) struct FleetHists {
    pub(crate) loop_h: Histogram<u64>,
    pub(crate) merged_h: Histogram<u64>,
}

impl FleetHists {
    /// Reads `robot-<id>-loop.hdr` and `robot-<id>-merged.hdr` of robots `0..robots`.
    pub(crate) fn read(dir: &OutDir, robots: u32) -> Self {
        let mut f = FleetHists {
            loop_h: new_hist(),
            merged_h: new_hist(),
        };
        for robot in 0..robots {
            for kind in RobotHist::ALL {
                let h = match kind {
                    RobotHist::Loop => &mut f.loop_h,
                    RobotHist::Merged => &mut f.merged_h,
                };
                if let Ok(r) = hist::read_binary(&dir.path(OutFile::RobotHist { robot, kind })) {
                    let _ = h.add(&r);
                }
            }
        }
        f
    }

    /// Every latency path measured: the coordinator's one-way ones and the fleet's.
    pub(crate) fn paths<'a>(&'a self, e: &'a Engine) -> [(LatencyPath, &'a Histogram<u64>); 7] {
        [
            (LatencyPath::StateOneWay, &e.h.state),
            (LatencyPath::DiscoveryOneWay, &e.h.discovery),
            (LatencyPath::HintsOneWay, &e.h.hints),
            (LatencyPath::HintAgeAtMerge, &e.h.hint_age),
            (LatencyPath::ReportOneWay, &e.h.report),
            (LatencyPath::MergedOneWay, &self.merged_h),
            (LatencyPath::Loop, &self.loop_h),
        ]
    }
}

/// A robot's outcome from its report (if any) and what the engine saw.
fn outcome(e: &Engine, id: usize) -> RobotOutcome {
    let slot = &e.robots[id];
    match slot.report {
        Some(r) if r.status == RobotStatus::Finished.as_u8() => RobotOutcome::Finished,
        Some(_) => RobotOutcome::Stopped,
        None if slot.lost => RobotOutcome::Lost,
        None if e.life.is_hung(id) => RobotOutcome::Hung,
        None => RobotOutcome::Missing,
    }
}

fn robot_entry(e: &Engine, id: usize, slot: &Slot, task: &Task, dir: &OutDir) -> RobotEntry {
    let opt = |v: i32| u32::try_from(v).ok();
    // the robot's own file, typed; a lost robot wrote none (or an earlier process's)
    let own: Option<RobotResult> = dir.read_json(OutFile::Robot(id as u32)).ok();
    let own_final_path_len = own.as_ref().and_then(|o| o.own_final_path_len);
    let warm_start_entries = own.as_ref().map(|o| o.counters.warm_start_entries);
    let (restarts, warm_started) = e.life.restarts(id);
    let r: FinalReport = slot.report.unwrap_or(FinalReport {
        final_path_len: -1,
        optimal_path_len: task.optimal_len as i32,
        first_optimal_episode: -1,
        episodes: slot.episode,
        ..FinalReport::ZEROED
    });
    RobotEntry {
        robot_id: id as u32,
        status: outcome(e, id),
        final_path_len: opt(r.final_path_len),
        own_final_path_len: own_final_path_len.filter(|_| slot.report.is_some()),
        optimal_path_len: opt(r.optimal_path_len),
        avg_steps: r.avg_steps,
        episodes: r.episodes,
        first_optimal_episode: opt(r.first_optimal_episode),
        env_steps: r.env_steps,
        seed: slot.seed,
        discoveries_sent: r.discoveries_sent,
        discoveries_acked: r.discoveries_acked,
        hints_sent: r.hints_sent,
        hints_received: r.hints_received,
        hints_applied: r.hints_applied,
        loop_latency_ns: if slot.report.is_some() {
            LatencyStats::from_summary(&r.merged_latency)
        } else {
            LatencyStats::default()
        },
        restarts,
        warm_started,
        warm_start_entries,
    }
}

/// Robots whose accepted report says they stopped without a greedy path to the goal.
fn without_path(e: &Engine) -> Vec<u32> {
    e.robots
        .iter()
        .enumerate()
        .filter(|(_, s)| s.report.is_some_and(|r| r.final_path_len < 0))
        .map(|(i, _)| i as u32)
        .collect()
}

/// The liveness part of a result.
pub(crate) fn liveness(e: &Engine) -> LivenessReport {
    let ids = |f: &dyn Fn(&Slot) -> bool| {
        e.robots
            .iter()
            .enumerate()
            .filter(|(_, r)| f(r))
            .map(|(i, _)| i as u32)
            .collect()
    };
    LivenessReport {
        checks: e.checks,
        lost: ids(&|r| r.lost && r.report.is_none()),
        alive_at_end: ids(&|r| r.alive),
        hung: e.life.hung(),
        restarts: (0..e.robots.len()).map(|i| e.life.restarts(i).0).sum(),
        coordinator_restarts: e.coordinator_restarts,
        discoveries_from_dead: e.disc.from_dead(),
        events: e.life.events().to_vec(),
    }
}

/// How a run's active part ended.
#[derive(Debug, Clone)]
pub(crate) struct RunEnd {
    /// Seconds from Start until every robot finished.
    pub(crate) active_s: f64,
    /// Stopped by a signal.
    pub(crate) interrupted: bool,
    /// Wall time of the whole coordinator run, s.
    pub(crate) elapsed_s: f64,
    /// The shared grid's execution, in a `--world shared` run.
    pub(crate) grid: Option<report::GridResult>,
    /// The lifelong grid, in a `--lorr` run.
    pub(crate) lifelong: Option<report::LifelongResult>,
}

/// The result of a plain run.
pub(crate) fn run_result(
    e: &Engine,
    args: &CoordArgs,
    task: &Task,
    dir: &OutDir,
    hists: &FleetHists,
    end: RunEnd,
) -> RunResult {
    let RunEnd {
        active_s,
        interrupted,
        elapsed_s,
        grid,
        lifelong,
    } = end;
    let robots: Vec<RobotEntry> = e
        .robots
        .iter()
        .enumerate()
        .map(|(id, slot)| robot_entry(e, id, slot, task, dir))
        .collect();
    let latency_ns: BTreeMap<String, LatencyStats> = hists
        .paths(e)
        .into_iter()
        .map(|(k, h)| (k.as_str().to_string(), LatencyStats::of(h)))
        .collect();
    let per_s = |x: u64| {
        if active_s > 0.0 {
            x as f64 / active_s
        } else {
            0.0
        }
    };
    let all_optimal = robots
        .iter()
        .all(|r| r.final_path_len.is_some() && r.final_path_len == r.optimal_path_len);
    let without_path = without_path(e);
    RunResult {
        run_id: args.run_id.clone(),
        map: task.map_name.clone(),
        start: task.start.to_string(),
        goal: task.goal.to_string(),
        wait: args.wait,
        merge: args.merge,
        apply: None,
        all_optimal,
        without_path,
        discoveries_sent: robots.iter().map(|r| r.discoveries_sent).sum(),
        discoveries_received: e.disc.received(),
        discoveries_from_lost: e
            .robots
            .iter()
            .filter(|r| r.lost && r.report.is_none())
            .map(|r| r.disc_from_lost)
            .sum(),
        discovery_duplicates: e.disc.duplicates(),
        pseudo_targets: e.disc.relayed(),
        robots,
        latency_ns,
        throughput: Throughput {
            messages_per_s: per_s(e.messages),
            q_updates_merged_per_s: per_s(e.q_merged),
            messages: e.messages,
            q_updates_merged: e.q_merged,
            fleet_changes: e.fleet_changes(),
            merged_batches_sent: e.merged_sent,
            active_s,
        },
        liveness: liveness(e),
        rejected: e.rejected,
        interrupted,
        elapsed_s,
        // robots on other hosts are `qfleet run`'s to add
        hosts: Vec::new(),
        grid,
        lifelong,
    }
}

/// A robot's env steps at monotonic time `t_ns`, interpolated between its episode ends.
pub(crate) fn steps_at(d: &PhaseDetail, t_ns: u64) -> u64 {
    let (mut t_prev, mut s_prev) = (d.start_ns, 0u64);
    for (&t, &s) in d.episode_end_ns.iter().zip(&d.episode_cum_steps) {
        if t >= t_ns {
            let span = t.saturating_sub(t_prev).max(1) as f64;
            let f = (t_ns.saturating_sub(t_prev)) as f64 / span;
            return s_prev + ((s - s_prev) as f64 * f.clamp(0.0, 1.0)) as u64;
        }
        (t_prev, s_prev) = (t, s);
    }
    s_prev
}

fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// What the experiment driver tracked of one goal during a phase.
pub(crate) struct GoalTrack<'a> {
    /// Environments from each distinct start of the goal's robots.
    pub(crate) envs: &'a [planner::Env],
    /// BFS optimum from each of those starts.
    pub(crate) optimal: &'a [u32],
    /// When the merged table first gave optimal paths from every start.
    pub(crate) merged_optimal_ns: Option<u64>,
}

/// The result of phase `p` of an experiment.
pub(crate) fn phase_result(
    plan: &ExperimentPlan,
    e: &Engine,
    goals: &[GoalTrack<'_>],
    p: usize,
    phase_ns: u64,
    out: &OutDir,
    wall_s: f64,
) -> PhaseResult {
    let details: Vec<Option<PhaseDetail>> = (0..plan.robots)
        .map(|robot| {
            let f = OutFile::RobotPhase {
                robot,
                phase: p as u32,
            };
            out.read_json(f).ok()
        })
        .collect();
    let mut robots = Vec::new();
    for (r, d) in details.iter().enumerate() {
        let g = plan.assignment[p][r];
        let d = d.as_ref();
        let merged_ns = goals[g].merged_optimal_ns;
        robots.push(RobotPhase {
            robot_id: r as u32,
            goal: g,
            status: outcome(e, r),
            episodes: d.map_or(0, |d| d.episodes),
            env_steps: d.map_or(0, |d| d.env_steps),
            avg_steps: d.map_or(0.0, |d| d.avg_steps),
            optimal_path_len: plan.optimal[r][g],
            final_path_len: d.and_then(|d| d.final_path_len),
            steps_to_optimal: d.and_then(|d| d.steps_to_optimal),
            time_to_optimal_s: d.and_then(|d| d.time_to_optimal_s),
            steps_at_merged_optimal: merged_ns.and_then(|t| d.map(|d| steps_at(d, t))),
            discoveries_sent: d.map_or(0, |d| d.discoveries_sent),
            relays_applied: d.map_or(0, |d| d.relays_applied),
            hints_applied: d.map_or(0, |d| d.hints_applied),
        });
    }
    let mut goal_results = Vec::new();
    for (g, gs) in goals.iter().enumerate() {
        let mine: Vec<&RobotPhase> = robots.iter().filter(|r| r.goal == g).collect();
        if mine.is_empty() {
            continue;
        }
        let own: Vec<f64> = mine
            .iter()
            .filter_map(|r| r.steps_to_optimal.map(|s| s as f64))
            .collect();
        let own_t: Vec<f64> = mine.iter().filter_map(|r| r.time_to_optimal_s).collect();
        let merged: Vec<f64> = mine
            .iter()
            .filter_map(|r| r.steps_at_merged_optimal.map(|s| s as f64))
            .collect();
        goal_results.push(GoalPhase {
            goal: g,
            name: plan.goals[g].name.clone(),
            cell: plan.goals[g].cell.to_string(),
            robots: mine.iter().map(|r| r.robot_id).collect(),
            merged_path_len: gs
                .envs
                .iter()
                .map(|env| merged_path_len(&e.tables[g], env))
                .collect(),
            optimal_path_len: gs.optimal.to_vec(),
            merged_optimal: gs.merged_optimal_ns.is_some(),
            merged_time_to_optimal_s: gs
                .merged_optimal_ns
                .map(|t| t.saturating_sub(phase_ns) as f64 / 1e9),
            merged_steps_per_robot: mean(&merged),
            robot_steps_to_optimal: mean(&own),
            robots_reached_optimal: own.len(),
            robot_time_to_optimal_s: mean(&own_t),
            avg_steps: mean(&mine.iter().map(|r| r.avg_steps).collect::<Vec<_>>()).unwrap_or(0.0),
            all_robots_optimal: mine
                .iter()
                .all(|r| r.final_path_len == Some(r.optimal_path_len)),
            relayed: e.disc.relayed_for(g as u32),
        });
    }
    PhaseResult {
        phase: p,
        name: plan.phases[p].name.clone(),
        episodes: plan.phases[p].episodes,
        goals: goal_results,
        discoveries_sent: robots.iter().map(|r| r.discoveries_sent).sum(),
        // filled in by the checkpoint, which knows what earlier coordinators received
        discoveries_received: 0,
        robots,
        wall_s,
        // the execution on a shared grid, if any, is the driver's to add
        grid: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_interpolated_between_episode_ends() {
        let d = PhaseDetail {
            robot_id: 0,
            phase: 0,
            goal_id: 0,
            start: String::new(),
            goal: String::new(),
            episodes: 2,
            env_steps: 300,
            avg_steps: 150.0,
            optimal_path_len: 1,
            final_path_len: None,
            first_optimal_episode: None,
            steps_to_optimal: None,
            time_to_optimal_s: None,
            start_ns: 1000,
            episode_end_ns: vec![2000, 4000],
            episode_cum_steps: vec![100, 300],
            discoveries_sent: 0,
            relays_applied: 0,
            hints_applied: 0,
            finished: true,
        };
        assert_eq!(steps_at(&d, 1500), 50);
        assert_eq!(steps_at(&d, 3000), 200);
        assert_eq!(steps_at(&d, 9000), 300);
    }
}
