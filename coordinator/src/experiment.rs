//! The coordinator of an experiment: drives robots through the phases of a manifest over the
//! control topic, keeps one fleet table per goal (merged only within the goal), relays
//! discoveries, watches the merged greedy path of every goal, and collects per-robot results
//! per phase.
//!
//! # Per phase
//! 1. `AssignGoal` to each robot (goal id and cell, `phase`, `episodes`), then `Start` (phase 0)
//!    or `Phase` to all.
//! 2. Until every robot sent its `FinalReport` for the phase: merge hints into the table of
//!    their goal and send merged batches tagged with it; ack discoveries and relay each distinct
//!    (goal, cell) once; after each merge, walk the merged table's greedy path from the start of
//!    every robot on that goal and note the first time it equals the BFS optimum.
//! 3. Read each robot's `robot-<id>-phase-<p>.json` (its per-episode log) to turn that time into
//!    env steps per robot (interpolated between the robot's episode ends).
//!
//! After the last phase: `Stop` to all.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    Command, Control, DiscoveryAck, DiscoveryRelay, FinalReport, HINT_BATCH_CAP,
    PseudoTargetDiscovery, QHintBatch, ROBOT_ID_ALL, RobotStatus,
};
use bus::{BusConfig, BusError, CoordinatorBus, Expected, check_nodes, monotonic_ns};
use bus_schema::map_fingerprint;
use planner::{Cell, Env};
use qfleet_args::Plan;
use report::{OutDir, OutFile, PhaseDetail};
use serde::{Deserialize, Serialize};

use crate::merge::{FleetTable, MergeRule};
use crate::run::CoordError;

/// One robot's result in one phase.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RobotPhase {
    /// Robot id.
    pub robot_id: u32,
    /// Goal index.
    pub goal: usize,
    /// `finished`, `stopped` or `missing`.
    pub status: String,
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
    /// Wall time of the phase, s.
    pub wall_s: f64,
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
    /// Phases.
    pub phases: Vec<PhaseResult>,
    /// Discoveries received (distinct).
    pub discoveries_received: u64,
    /// Relays sent.
    pub relays_sent: u64,
    /// Q-hint entries merged.
    pub q_updates_merged: u64,
    /// Messages dropped as invalid.
    pub rejected: u64,
    /// Wall time, s.
    pub wall_s: f64,
}

/// What the coordinator needs besides the plan.
#[derive(Debug, Clone)]
pub struct ExperimentOptions {
    /// Run id.
    pub run_id: String,
    /// Seed of this repetition.
    pub seed: u64,
    /// Directory where robots write their phase files.
    pub out: PathBuf,
    /// Merge rule of the fleet tables.
    pub merge: MergeRule,
}

struct Slot {
    next_disc: u64,
    pending: BTreeSet<u64>,
    ack_dirty: bool,
    report: Option<FinalReport>,
    lost: bool,
}

struct GoalState {
    table: FleetTable,
    envs: Vec<Env>,
    optimal: Vec<u32>,
    merged_optimal_ns: Option<u64>,
}

/// Runs one experiment (one seed) over the bus; robots must be started by the caller.
pub fn run_experiment(
    plan: &Plan,
    opts: &ExperimentOptions,
    stop: &AtomicBool,
) -> Result<ExperimentResult, CoordError> {
    let t_begin = Instant::now();
    let m = &plan.manifest;
    let timeout = Duration::from_secs_f64(m.timeout_s);
    let grid = &plan.map.grid;
    let (Ok(width), Ok(height)) = (u16::try_from(grid.width()), u16::try_from(grid.height()))
    else {
        return Err(CoordError::Input("map too large".into()));
    };
    let mut cfg = BusConfig::new(opts.run_id.clone(), m.robots)?;
    cfg.hint_buffer = 64;
    cfg.merged_buffer = (4096 / m.robots as usize).clamp(8, 64);
    cfg.validate()?;
    let bus = CoordinatorBus::create(&cfg)?;
    let expected = Expected {
        robots: m.robots,
        map_hash: map_fingerprint(grid.width(), grid.height(), grid.free_flags()),
        width,
        height,
    };
    let out = drive(plan, opts, &bus, &expected, stop, timeout, t_begin);
    if let Err(e) = bus.close() {
        eprintln!("qfleet experiment: warning: cleanup: {e}");
    }
    out
}

struct Ctx {
    robots: Vec<Slot>,
    goals: Vec<GoalState>,
    relayed: BTreeSet<(u32, u32)>,
    relay_pending: Vec<DiscoveryRelay>,
    relays_sent: u64,
    disc_received: u64,
    q_merged: u64,
    merged_seq: u64,
    rejected: u64,
    assignment: Vec<usize>,
}

fn drive(
    plan: &Plan,
    opts: &ExperimentOptions,
    bus: &CoordinatorBus,
    expected: &Expected,
    stop: &AtomicBool,
    timeout: Duration,
    t_begin: Instant,
) -> Result<ExperimentResult, CoordError> {
    let m = &plan.manifest;
    let grid = &plan.map.grid;
    let cells = grid.len();
    bus.accept_fleet(expected, timeout)?;
    let rewards = m
        .learner
        .config()
        .map_err(|e| CoordError::Input(e.to_string()))?
        .rewards;
    let mut c = Ctx {
        robots: (0..m.robots)
            .map(|_| Slot {
                next_disc: 0,
                pending: BTreeSet::new(),
                ack_dirty: false,
                report: None,
                lost: false,
            })
            .collect(),
        goals: plan
            .goal_cells
            .iter()
            .map(|_| GoalState {
                table: FleetTable::new(cells, opts.merge),
                envs: Vec::new(),
                optimal: Vec::new(),
                merged_optimal_ns: None,
            })
            .collect(),
        relayed: BTreeSet::new(),
        relay_pending: Vec::new(),
        relays_sent: 0,
        disc_received: 0,
        q_merged: 0,
        merged_seq: 0,
        rejected: 0,
        assignment: Vec::new(),
    };
    let mut phases = Vec::new();
    for (p, phase) in m.phases.iter().enumerate() {
        let t_phase = Instant::now();
        let phase_ns = monotonic_ns();
        c.assignment = plan.assignment[p].clone();
        for (g, gs) in c.goals.iter_mut().enumerate() {
            gs.merged_optimal_ns = None;
            gs.envs.clear();
            gs.optimal.clear();
            let mut starts: Vec<(Cell, u32)> = Vec::new();
            for (r, &rg) in c.assignment.iter().enumerate() {
                if rg == g && !starts.iter().any(|(s, _)| *s == plan.starts[r]) {
                    starts.push((plan.starts[r], plan.optimal[r][g]));
                }
            }
            for (s, opt) in starts {
                gs.envs.push(Env::new(grid, s, plan.goal_cells[g], rewards));
                gs.optimal.push(opt);
            }
        }
        for r in &mut c.robots {
            r.report = None;
        }
        for (r, &g) in c.assignment.iter().enumerate() {
            let cell = plan.goal_cells[g];
            bus.send_control(Control {
                goal_id: g as u32,
                goal_x: cell.x,
                goal_y: cell.y,
                phase: p as u32,
                episodes: phase.episodes,
                ..bus::control(Command::AssignGoal, r as u32)
            })?;
        }
        let go = if p == 0 {
            Command::Start
        } else {
            Command::Phase
        };
        bus.send_control(Control {
            phase: p as u32,
            episodes: phase.episodes,
            ..bus::control(go, ROBOT_ID_ALL)
        })?;
        let interrupted = phase_loop(&mut c, bus, stop)?;
        // the reports are in; the phase files were written before them
        let wall_s = t_phase.elapsed().as_secs_f64();
        phases.push(phase_result(plan, &c, p, phase_ns, &opts.out, wall_s));
        if interrupted {
            break;
        }
    }
    match bus.stop(ROBOT_ID_ALL) {
        Ok(_) | Err(BusError::NoSubscriber { .. }) => {}
        Err(e) => return Err(e.into()),
    }
    Ok(ExperimentResult {
        name: m.name.clone(),
        run_id: opts.run_id.clone(),
        seed: opts.seed,
        map: plan.map.name.clone(),
        robots: m.robots,
        sharing: m.sharing.as_cli().into(),
        phases,
        discoveries_received: c.disc_received,
        relays_sent: c.relays_sent,
        q_updates_merged: c.q_merged,
        rejected: c.rejected,
        wall_s: t_begin.elapsed().as_secs_f64(),
    })
}

/// Receives until every robot reported for the phase (or was lost); true if interrupted.
fn phase_loop(c: &mut Ctx, bus: &CoordinatorBus, stop: &AtomicBool) -> Result<bool, CoordError> {
    let mut last_liveness = Instant::now();
    loop {
        let n = drain(c, bus)?;
        if c.robots.iter().all(|r| r.report.is_some() || r.lost) {
            return Ok(false);
        }
        if stop.load(Ordering::Relaxed) {
            return Ok(true);
        }
        if last_liveness.elapsed() >= Duration::from_millis(200) {
            last_liveness = Instant::now();
            let report = check_nodes(bus.config(), true)?;
            let alive: BTreeSet<String> = report.alive().map(|n| n.name.clone()).collect();
            // a report that arrived before the process went away is not a loss
            drain(c, bus)?;
            for (id, slot) in c.robots.iter_mut().enumerate() {
                if slot.report.is_none()
                    && !slot.lost
                    && !alive.contains(&format!("qfleet-robot-{id}"))
                {
                    slot.lost = true;
                    eprintln!("qfleet experiment: robot {id} is gone (its process died)");
                }
            }
        }
        if n == 0 {
            // robots notify after hint batches, discoveries and reports
            let _ = bus.hints.wait(Duration::from_micros(500))?;
        }
    }
}

fn drain(c: &mut Ctx, bus: &CoordinatorBus) -> Result<usize, CoordError> {
    const MAX: usize = 256;
    let mut n = 0;
    while bus.register.receive()?.is_some() {
        n += 1;
    }
    n += bus.state.drain(MAX, |_| {})?;
    n += bus.discovery.drain(MAX, |d| on_discovery(c, d))?;
    for (id, slot) in c.robots.iter_mut().enumerate() {
        if std::mem::take(&mut slot.ack_dirty) && slot.next_disc > 0 {
            bus.ack.send(&DiscoveryAck {
                robot_id: id as u32,
                up_to_seq: slot.next_disc - 1,
                time_ns: monotonic_ns(),
                ..DiscoveryAck::ZEROED
            })?;
        }
    }
    crate::run::send_relays(bus, &mut c.relay_pending, &mut c.relays_sent)?;
    let mut touched = BTreeSet::new();
    for _ in 0..MAX {
        let Some(sample) = bus.hints.receive_sample()? else {
            break;
        };
        n += 1;
        if let Some(g) = on_hints(c, bus, sample.payload())? {
            touched.insert(g);
        }
    }
    for g in touched {
        flush(c, bus, g)?;
        let gs = &mut c.goals[g];
        if gs.merged_optimal_ns.is_none()
            && !gs.envs.is_empty()
            && gs
                .envs
                .iter()
                .zip(&gs.optimal)
                .all(|(env, opt)| merged_path_len(&gs.table, env) == Some(*opt))
        {
            gs.merged_optimal_ns = Some(monotonic_ns());
        }
    }
    while let Some(r) = bus.report.receive()? {
        n += 1;
        match c.robots.get_mut(r.robot_id as usize) {
            Some(slot) => slot.report = Some(r),
            None => c.rejected += 1,
        }
    }
    Ok(n)
}

fn on_discovery(c: &mut Ctx, d: &PseudoTargetDiscovery) {
    let Some(slot) = c.robots.get_mut(d.robot_id as usize) else {
        c.rejected += 1;
        return;
    };
    if d.goal_id as usize >= c.goals.len() || !d.value.is_finite() {
        c.rejected += 1;
        return;
    }
    slot.ack_dirty = true;
    if d.seq < slot.next_disc || !slot.pending.insert(d.seq) {
        return;
    }
    while slot.pending.remove(&slot.next_disc) {
        slot.next_disc += 1;
    }
    c.disc_received += 1;
    let cell = u32::from(d.cell_y) << 16 | u32::from(d.cell_x);
    if c.relayed.insert((d.goal_id, cell)) {
        c.relay_pending.push(DiscoveryRelay {
            origin_robot: d.robot_id,
            goal_id: d.goal_id,
            cell_x: d.cell_x,
            cell_y: d.cell_y,
            value: d.value,
            origin_seq: d.seq,
            origin_ns: d.time_ns,
            ..DiscoveryRelay::ZEROED
        });
    }
}

/// Merges one batch into its goal's table; returns the goal if it was valid.
fn on_hints(
    c: &mut Ctx,
    bus: &CoordinatorBus,
    b: &QHintBatch,
) -> Result<Option<usize>, CoordError> {
    let g = b.goal_id as usize;
    let n = b.count as usize;
    if b.robot_id as usize >= c.robots.len() || g >= c.goals.len() || n > HINT_BATCH_CAP {
        c.rejected += 1;
        return Ok(None);
    }
    let cells = c.goals[g].table.cells();
    for h in &b.entries[..n] {
        if h.cell as usize >= cells || h.action >= 4 || !h.q.is_finite() {
            c.rejected += 1;
            continue;
        }
        c.q_merged += 1;
        if c.goals[g].table.merge(b.robot_id, h, b.oldest_update_ns) {
            flush(c, bus, g)?;
        }
    }
    Ok(Some(g))
}

fn flush(c: &mut Ctx, bus: &CoordinatorBus, g: usize) -> Result<(), CoordError> {
    let table = &mut c.goals[g].table;
    if table.pending() == 0 {
        return Ok(());
    }
    let seq = c.merged_seq;
    bus.merged.send_with(|m| {
        table.take_into(m);
        m.coordinator_seq = seq;
        m.goal_id = g as u32;
        m.send_time_ns = monotonic_ns();
    })?;
    c.merged_seq += 1;
    Ok(())
}

/// The greedy path length of a fleet table from `env`'s start (argmax, first action on ties,
/// unreported entries count as 0), or `None` if it loops or hits a wall.
pub fn merged_path_len(table: &FleetTable, env: &Env) -> Option<u32> {
    let (mut s, goal) = (env.start(), env.goal());
    let limit = table.cells() as u32;
    let mut len = 0;
    while s != goal {
        if len > limit {
            return None;
        }
        let mut best = 0;
        let mut best_q = table.get(s as usize, 0).unwrap_or(0.0);
        for a in 1..4 {
            let q = table.get(s as usize, a).unwrap_or(0.0);
            if q > best_q {
                best = a;
                best_q = q;
            }
        }
        s = env.peek(s, best)?;
        len += 1;
    }
    Some(len)
}

/// A robot's env steps at monotonic time `t_ns`, interpolated between its episode ends.
fn steps_at(d: &PhaseDetail, t_ns: u64) -> u64 {
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

fn phase_result(
    plan: &Plan,
    c: &Ctx,
    p: usize,
    phase_ns: u64,
    out: &Path,
    wall_s: f64,
) -> PhaseResult {
    let m = &plan.manifest;
    let details: Vec<Option<PhaseDetail>> = (0..m.robots)
        .map(|robot| {
            let f = OutFile::RobotPhase {
                robot,
                phase: p as u32,
            };
            OutDir::new(out).read_json(f).ok()
        })
        .collect();
    let mut robots = Vec::new();
    for (r, slot) in c.robots.iter().enumerate() {
        let g = c.assignment[r];
        let d = details[r].as_ref();
        let merged_ns = c.goals[g].merged_optimal_ns;
        robots.push(RobotPhase {
            robot_id: r as u32,
            goal: g,
            status: match (&slot.report, slot.lost) {
                (Some(rep), _) if rep.status == RobotStatus::Finished.as_u8() => "finished",
                (Some(_), _) => "stopped",
                (None, true) => "lost",
                (None, false) => "missing",
            }
            .into(),
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
    let mut goals = Vec::new();
    for (g, gs) in c.goals.iter().enumerate() {
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
        goals.push(GoalPhase {
            goal: g,
            name: m.goals[g].name.clone(),
            cell: plan.goal_cells[g].to_string(),
            robots: mine.iter().map(|r| r.robot_id).collect(),
            merged_path_len: gs
                .envs
                .iter()
                .map(|e| merged_path_len(&gs.table, e))
                .collect(),
            optimal_path_len: gs.optimal.clone(),
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
            relayed: c.relayed.iter().filter(|(gg, _)| *gg as usize == g).count(),
        });
    }
    PhaseResult {
        phase: p,
        name: m.phases[p].name.clone(),
        episodes: m.phases[p].episodes,
        goals,
        robots,
        wall_s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bus::bus_schema::QHint;

    #[test]
    fn merged_path_follows_the_table_and_detects_loops() {
        let grid = planner::Grid::new(3, 1, vec![true; 3]).unwrap();
        let env = Env::new(
            &grid,
            Cell::new(0, 0),
            Cell::new(2, 0),
            planner::Rewards::default(),
        );
        let mut t = FleetTable::new(3, MergeRule::Max);
        assert_eq!(merged_path_len(&t, &env), None);
        // find the action that moves right from cell 0
        let right = (0..4)
            .find(|a| env.peek(0, *a) == Some(1))
            .expect("a move right");
        for cell in 0..2 {
            let h = QHint {
                cell,
                action: right as u8,
                q: 0.5,
                visits: 1,
                ..QHint::ZEROED
            };
            t.merge(0, &h, 1);
        }
        assert_eq!(merged_path_len(&t, &env), Some(2));
    }

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
