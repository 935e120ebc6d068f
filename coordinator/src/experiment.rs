//! The driver of an experiment over the [`Engine`]: robots go through the phases of a
//! manifest over the control topic; one fleet table per goal (merged only within the goal);
//! the merged greedy path of every goal is watched; per-robot results are collected per phase.
//!
//! # Per phase
//! 1. `AssignGoal` to each robot (goal id and cell, `phase`, `episodes`), then `Start` (phase 0)
//!    or `Phase` to all.
//! 2. Until every robot sent its `FinalReport` for the phase (or is lost with no restart to
//!    wait for, or hung): the engine merges hints into the table of their goal, acks and relays
//!    discoveries (each distinct (goal, cell) once) and admits restarted robots (warm-started
//!    from their goal's table); after each drain that merged something, the driver walks the
//!    merged table's greedy path from the start of every robot on that goal and notes the first
//!    time it equals the BFS optimum.
//! 3. Read each robot's `robot-<id>-phase-<p>.json` (its per-episode log) to turn that time into
//!    env steps per robot (interpolated between the robot's episode ends).
//!
//! After the last phase: `Stop` to all.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, ROBOT_ID_ALL};
use bus::{BusConfig, CoordinatorBus, Expected, monotonic_ns};
use planner::{Cell, Env};
use qfleet_args::Plan;

use crate::assemble::{self, GoalTrack};
use crate::engine::{Assignment, Engine, tolerate};
use crate::liveness::{Life, Lister};
use crate::merge::{FleetTable, MergeRule};
use crate::options::{CoordError, WaitStrategy, secs};
use crate::run::LIST_EVERY;
use crate::wait::{Serving, Waiting, serve};
pub use report::run::{ExperimentResult, GoalPhase, PhaseResult, RobotPhase};

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

/// How the experiment's robots are supervised (as `qfleet run`'s `--restart` / `--hang-ms`).
#[derive(Debug, Clone, Copy)]
pub struct Supervision {
    /// Restarts per robot the launcher may make: a phase waits (up to the manifest's timeout)
    /// for a lost robot to come back while it has restarts left.
    pub restarts: u32,
    /// A running robot silent this long is reported hung.
    pub hang: Duration,
}

impl Default for Supervision {
    /// No restarts, the 2 s heartbeat deadline `qfleet run` uses.
    fn default() -> Self {
        Supervision {
            restarts: 0,
            hang: Duration::from_millis(2000),
        }
    }
}

/// One goal's merged-path watch during a phase.
struct Watch {
    envs: Vec<Env>,
    optimal: Vec<u32>,
    merged_optimal_ns: Option<u64>,
}

/// Runs one experiment (one seed) over the bus with no restarts; robots must be started by the
/// caller.
pub fn run_experiment(
    plan: &Plan,
    opts: &ExperimentOptions,
    stop: &AtomicBool,
) -> Result<ExperimentResult, CoordError> {
    run_experiment_with(plan, opts, Supervision::default(), stop)
}

/// Runs one experiment (one seed) over the bus; robots must be started (and restarted, within
/// `sup.restarts`) by the caller.
pub fn run_experiment_with(
    plan: &Plan,
    opts: &ExperimentOptions,
    sup: Supervision,
    stop: &AtomicBool,
) -> Result<ExperimentResult, CoordError> {
    let t_begin = Instant::now();
    let m = &plan.manifest;
    let timeout = secs(m.timeout_s, "the manifest's timeout_s")?;
    let grid = &plan.map.grid;
    let (Ok(width), Ok(height)) = (u16::try_from(grid.width()), u16::try_from(grid.height()))
    else {
        return Err(CoordError::MapTooLarge {
            width: grid.width(),
            height: grid.height(),
        });
    };
    let mut cfg = BusConfig::new(opts.run_id.clone(), m.robots)?;
    cfg.hint_buffer = 64;
    cfg.merged_buffer = (4096 / m.robots as usize).clamp(8, 64);
    cfg.send_timeout = Duration::from_secs(1);
    cfg.validate()?;
    let bus = CoordinatorBus::create(&cfg)?;
    let expected = Expected {
        robots: m.robots,
        map_hash: bus::bus_schema::map_fingerprint(grid.width(), grid.height(), grid.free_flags()),
        width,
        height,
    };
    let life = Life::new(m.robots, sup.hang, sup.restarts, timeout);
    let mut engine = Engine::new(
        expected,
        plan.goal_cells.len() as u32,
        opts.merge,
        life,
        cfg.merged_buffer,
        opts.out.clone(),
    );
    // this coordinator runs inside `qfleet experiment`, whose stdout is the result: its
    // liveness events go to the result only
    engine.events_on_stdout = false;
    let out = drive(plan, opts, &mut engine, &bus, stop, timeout, t_begin);
    if let Err(e) = bus.close() {
        eprintln!("qfleet experiment: warning: cleanup: {e}");
    }
    out
}

fn drive(
    plan: &Plan,
    opts: &ExperimentOptions,
    engine: &mut Engine,
    bus: &CoordinatorBus,
    stop: &AtomicBool,
    timeout: Duration,
    t_begin: Instant,
) -> Result<ExperimentResult, CoordError> {
    let m = &plan.manifest;
    let grid = &plan.map.grid;
    engine.admit_fleet(bus, stop, timeout)?;
    let lister = Lister::start(bus.config(), LIST_EVERY).map_err(|source| CoordError::Thread {
        what: "liveness",
        source,
    })?;
    let rewards = m.learner.config()?.rewards;
    let how = Waiting {
        strategy: WaitStrategy::Hybrid,
        spin: Duration::from_micros(200),
    };
    let serving = Serving {
        bus,
        lister: &lister,
        how,
        stop,
    };
    let out_dir = report::OutDir::new(&opts.out);
    let mut phases = Vec::new();
    for (p, phase) in m.phases.iter().enumerate() {
        let t_phase = Instant::now();
        let phase_ns = monotonic_ns();
        let assignment = &plan.assignment[p];
        let mut watches: Vec<Watch> = (0..plan.goal_cells.len())
            .map(|g| {
                let mut starts: Vec<(Cell, u32)> = Vec::new();
                for (r, &rg) in assignment.iter().enumerate() {
                    if rg == g && !starts.iter().any(|(s, _)| *s == plan.starts[r]) {
                        starts.push((plan.starts[r], plan.optimal[r][g]));
                    }
                }
                Watch {
                    envs: starts
                        .iter()
                        .map(|(s, _)| Env::new(grid, *s, plan.goal_cells[g], rewards))
                        .collect(),
                    optimal: starts.iter().map(|(_, o)| *o).collect(),
                    merged_optimal_ns: None,
                }
            })
            .collect();
        let plan_p = assignment
            .iter()
            .map(|&g| Assignment {
                goal: g as u32,
                cell: plan.goal_cells[g],
                phase: p as u32,
                episodes: phase.episodes,
            })
            .collect();
        let go = if p == 0 {
            Command::Start
        } else {
            Command::Phase
        };
        engine.start_phase(bus, plan_p, go)?;
        let interrupted = serve(
            engine,
            &serving,
            |e| watch_merged(e, &mut watches),
            |e| {
                let now = Instant::now();
                (0..e.robots.len()).all(|i| e.phase_done(i, now))
            },
        )?;
        // the reports are in; the phase files were written before them
        let wall_s = t_phase.elapsed().as_secs_f64();
        let tracks: Vec<GoalTrack<'_>> = watches
            .iter()
            .map(|w| GoalTrack {
                envs: &w.envs,
                optimal: &w.optimal,
                merged_optimal_ns: w.merged_optimal_ns,
            })
            .collect();
        phases.push(assemble::phase_result(
            plan, engine, &tracks, p, phase_ns, &out_dir, wall_s,
        ));
        if interrupted {
            break;
        }
    }
    tolerate(bus.stop(ROBOT_ID_ALL))?;
    Ok(ExperimentResult {
        name: m.name.clone(),
        run_id: opts.run_id.clone(),
        seed: opts.seed,
        map: plan.map.name.clone(),
        robots: m.robots,
        sharing: m.sharing.as_cli().into(),
        phases,
        discoveries_received: engine.disc.received(),
        relays_sent: engine.relays_sent,
        q_updates_merged: engine.q_merged,
        rejected: engine.rejected,
        liveness: assemble::liveness(engine),
        wall_s: t_begin.elapsed().as_secs_f64(),
    })
}

/// Notes, per goal whose table changed, the first time its merged greedy path is optimal from
/// every start.
fn watch_merged(e: &mut Engine, watches: &mut [Watch]) {
    for (g, w) in watches.iter_mut().enumerate() {
        if !std::mem::take(&mut e.touched[g]) || w.merged_optimal_ns.is_some() || w.envs.is_empty()
        {
            continue;
        }
        let table = &e.tables[g];
        if w.envs
            .iter()
            .zip(&w.optimal)
            .all(|(env, opt)| merged_path_len(table, env) == Some(*opt))
        {
            w.merged_optimal_ns = Some(monotonic_ns());
        }
    }
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
}
