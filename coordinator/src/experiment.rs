//! The driver of an experiment over the engine (`Engine`), in the coordinator process
//! (`qfleet-coordinator --plan plan.json`, started and restarted by `qfleet experiment` through
//! the launcher as `qfleet run` starts its coordinator): robots go through the phases of the
//! [`ExperimentPlan`] over the control topic; one fleet table per goal (merged only within the
//! goal); the merged greedy path of every goal is watched; per-robot results are collected
//! per phase.
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
//! 4. Keep the phase's result in `experiment-checkpoint.json` ([`Checkpoint`]).
//!
//! 5. On a shared grid (`world: "shared"` in the plan): the coordinator executes the phase as
//!    a plain run's execution (`grid::execute`, the same engine): `Execute`, then tick by
//!    tick from the plan's starts to this phase's goals, or with `phase_start: "previous"`
//!    from where the phase before left the robots. The phase's result carries the grid section
//!    and the paths go to `paths-phase-<p>.txt`. Robots learn every phase from their start in
//!    the plan (the cell their process was started with); their ranking answers for any cell
//!    of the map (its learned values, and its own map distance where it never tried a move),
//!    so an execution may start elsewhere.
//!
//! After the last phase: `Stop` to all.
//!
//! # A coordinator restart
//! A coordinator started again with the same run id and out directory finds the checkpoint:
//! it admits the fleet again (the robots, learning alone meanwhile, re-register and replay their
//! discoveries), skips the phases done and starts the phase under way again with the same
//! `AssignGoal` and start command. A robot ignores a repeated assignment of a phase it is in or
//! has finished, and answers the repeat of a phase it already reported with its report again,
//! so the phase ends as if nothing happened. The fleet tables start empty again (the robots
//! keep what they learned); the counts of earlier coordinators are carried in the checkpoint.
//! On a shared grid a finished phase's grid result is in the checkpoint with it, and so is
//! where it left the robots; a phase whose execution was under way is executed again from its
//! starts (with `phase_start: "previous"`, where the phase before left the robots, from the
//! checkpoint). Its half-done moves are not kept: the grid is the coordinator's own record.
//! A robot still in the old execution answers the new grants only once their tick passes the
//! last one it answered (`robot_agent`'s execution loop keeps it), so it is hung for the first
//! ticks of the new one: an obstacle that waits, a known limit.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use bus::bus_schema::{Command, ROBOT_ID_ALL};
use bus::{CoordinatorBus, Expected, monotonic_ns};
use planner::map::GridMap;
use planner::{Cell, Env};
use report::{OutDir, OutFile, ReadError};

use crate::assemble::{self, GoalTrack};
use crate::checkpoint::{Checkpoint, LifeCounts};
use crate::engine::{Assignment, Engine, tolerate};
use crate::grid::{self, GridPlan};
use crate::liveness::{Life, start_lister};
use crate::options::{CoordArgs, CoordError, bus_config, secs};
use crate::wait::{Serving, Waiting, serve};
use bus::Lister;
pub use contract::plan::ExperimentPlan;
use mapf::Instance;
use qfleet_args::World;
use qfleet_args::phases::PhaseStart;
use report::GridResult;
pub use report::run::{ExperimentResult, GoalPhase, PhaseResult, RobotPhase};
use sharing::FleetTable;

/// One goal's merged-path watch during a phase.
struct Watch {
    envs: Vec<Env>,
    optimal: Vec<u32>,
    merged_optimal_ns: Option<u64>,
}

/// Runs (or resumes, see the module docs) the experiment of `plan` with the coordinator
/// options `args` (run id, out directory, merge rule, wait strategy, buffers, `--restarts`,
/// `--hang-ms`); robots must be started (and restarted) by the caller. `stop` is set by a
/// signal handler: the phase under way ends, the robots are stopped, and the result says
/// `interrupted`.
pub fn run(
    args: &CoordArgs,
    plan: &ExperimentPlan,
    stop: &AtomicBool,
) -> Result<ExperimentResult, CoordError> {
    // the plan says which world; `--world shared` with a plan of separate copies is a mistake,
    // said, not silently ignored (the other `--world` options apply to a shared plan)
    if args.world.shared() && plan.world != World::Shared {
        return Err(CoordError::Option {
            option: "--world",
            must: "the plan's world with --plan (the manifest's `world = \"shared\"`)",
            value: args.world.world.to_string(),
        });
    }
    let map = plan.check()?;
    let timeout = secs(plan.timeout_s, "the plan's timeout_s")?;
    let grid = &map.grid;
    let (Ok(width), Ok(height)) = (u16::try_from(grid.width()), u16::try_from(grid.height()))
    else {
        return Err(CoordError::MapTooLarge {
            width: grid.width(),
            height: grid.height(),
        });
    };
    let dir = OutDir::new(&args.out);
    dir.create()?;
    let prev = match dir.read_json::<Checkpoint>(OutFile::ExperimentCheckpoint) {
        Ok(c) => Some(c),
        Err(ReadError::Io { .. }) => None,
        Err(e) => {
            report::log_line!("qfleet-coordinator: warning: {e}; starting the experiment over");
            None
        }
    };
    let mut cp = Checkpoint::resume(
        prev,
        &args.run_id,
        plan.seed,
        plan.phases.len(),
        monotonic_ns(),
    );
    if cp.restarts() > 0 {
        report::log_line!(
            "qfleet-coordinator: restart {} of experiment {}: resuming at phase {} of {}",
            cp.restarts(),
            args.run_id,
            cp.next_phase(),
            plan.phases.len()
        );
    }
    dir.write_json(OutFile::ExperimentCheckpoint, &cp)?;
    let cfg = bus_config(args, plan.robots)?;
    let bus = CoordinatorBus::create(&cfg)?;
    let expected = Expected {
        robots: plan.robots,
        map_hash: bus::bus_schema::map_fingerprint(grid.width(), grid.height(), grid.free_flags()),
        width,
        height,
    };
    let life = Life::new(
        plan.robots,
        Duration::from_millis(args.hang_ms),
        args.restarts,
        timeout,
    );
    let mut engine = Engine::new(
        expected,
        plan.goals.len() as u32,
        args.merge,
        life,
        cfg.merged_buffer,
        args.out.clone(),
    );
    engine.optimum = plan.optimal.clone();
    if plan.world == World::Shared {
        // robots register with their start in the plan: the one they learn from
        engine.starts = Some(plan.starts.clone());
    }
    let ctx = Ctx {
        args,
        plan,
        map: &map,
        dir: &dir,
        timeout,
    };
    let out = drive(&ctx, &mut cp, &mut engine, &bus, stop);
    if let Err(e) = bus.close() {
        report::log_line!("qfleet-coordinator: warning: cleanup: {e}");
    }
    out
}

/// What the driver reads.
struct Ctx<'a> {
    args: &'a CoordArgs,
    plan: &'a ExperimentPlan,
    map: &'a GridMap,
    dir: &'a OutDir,
    timeout: Duration,
}

/// This coordinator process's counts, for the checkpoint.
fn life_counts(e: &Engine) -> LifeCounts {
    LifeCounts {
        received: e.disc.received(),
        from_dead: e.disc.from_dead(),
        relays_sent: e.relays_sent,
        q_updates_merged: e.q_merged,
        rejected: e.rejected,
    }
}

/// The merged-path watch of every goal in phase `p`.
fn watches(plan: &ExperimentPlan, map: &GridMap, p: usize) -> Vec<Watch> {
    let assignment = &plan.assignment[p];
    (0..plan.goals.len())
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
                    .map(|(s, _)| Env::new(&map.grid, *s, plan.goals[g].cell, plan.rewards))
                    .collect(),
                optimal: starts.iter().map(|(_, o)| *o).collect(),
                merged_optimal_ns: None,
            }
        })
        .collect()
}

fn drive(
    ctx: &Ctx<'_>,
    cp: &mut Checkpoint,
    engine: &mut Engine,
    bus: &CoordinatorBus,
    stop: &AtomicBool,
) -> Result<ExperimentResult, CoordError> {
    let plan = ctx.plan;
    engine.admit_fleet(bus, stop, ctx.timeout)?;
    let lister = start_lister(bus)?;
    let how = Waiting {
        strategy: ctx.args.wait,
        spin: Duration::from_micros(ctx.args.spin_us),
    };
    let serving = Serving {
        bus,
        lister: &lister,
        how,
        stop,
    };
    // the phases done, and the one a signal cut short
    let mut ended = cp.clone();
    let mut interrupted = false;
    for p in cp.next_phase()..plan.phases.len() {
        let phase_ns = cp.start_phase(p, monotonic_ns());
        ctx.dir.write_json(OutFile::ExperimentCheckpoint, &*cp)?;
        let mut watches = watches(plan, ctx.map, p);
        let plan_p = plan.assignment[p]
            .iter()
            .map(|&g| Assignment {
                goal: g as u32,
                cell: plan.goals[g].cell,
                phase: p as u32,
                episodes: plan.phases[p].episodes,
            })
            .collect();
        let go = if p == 0 {
            Command::Start
        } else {
            Command::Phase
        };
        // the phase's shared-grid instance is known before its robots learn (from the starts,
        // or where the phase before left them): its first plan is made on a thread of its own
        // while they learn, and the execution waits for it if they finish first
        let gp = match plan.world {
            World::Shared => Some(phase_grid(ctx, cp, p)?),
            _ => None,
        };
        engine.start_phase(bus, plan_p, go)?;
        let (served, prepared) = grid::prepare_while(gp.as_ref(), || {
            serve(
                engine,
                &serving,
                |e| watch_merged(e, &mut watches),
                |e| {
                    let now = std::time::Instant::now();
                    (0..e.robots.len()).all(|i| e.phase_done(i, now))
                },
            )
        });
        interrupted = served?;
        // the reports are in; the phase files were written before them
        let wall_s = monotonic_ns().saturating_sub(phase_ns) as f64 / 1e9;
        let tracks: Vec<GoalTrack<'_>> = watches
            .iter()
            .map(|w| GoalTrack {
                envs: &w.envs,
                optimal: &w.optimal,
                merged_optimal_ns: w.merged_optimal_ns,
            })
            .collect();
        let mut result =
            assemble::phase_result(plan, engine, &tracks, p, phase_ns, ctx.dir, wall_s);
        let mut left_at = None;
        if let (Some(gp), Some(world), false) = (&gp, prepared, interrupted) {
            let (grid, at) = execute_phase(ctx, engine, bus, &lister, stop, p, gp, world)?;
            report::log_line!(
                "qfleet-coordinator: phase {p} on the shared grid: {}",
                grid.line()
            );
            result.grid = Some(grid);
            left_at = Some(at);
            interrupted = stop.load(std::sync::atomic::Ordering::Relaxed);
        }
        ended = cp.clone();
        ended.phase_done(result, life_counts(engine));
        if let Some(at) = left_at {
            ended.left_at(at);
        }
        if interrupted {
            break;
        }
        *cp = ended.clone();
        ctx.dir.write_json(OutFile::ExperimentCheckpoint, &*cp)?;
    }
    tolerate(bus.stop(ROBOT_ID_ALL))?;
    let totals = ended.totals_with(life_counts(engine));
    Ok(ExperimentResult {
        name: plan.name.clone(),
        run_id: ctx.args.run_id.clone(),
        seed: plan.seed,
        map: ctx.map.name.clone(),
        robots: plan.robots,
        sharing: plan.sharing.clone(),
        rules: None,
        phases: ended.phases,
        discoveries_received: totals.discoveries,
        relays_sent: totals.relays_sent,
        q_updates_merged: totals.q_updates_merged,
        rejected: totals.rejected,
        liveness: assemble::liveness(engine),
        coordinator_restarts: cp.restarts(),
        interrupted,
        wall_s: monotonic_ns().saturating_sub(cp.began_ns) as f64 / 1e9,
        // robots on other hosts are `qfleet experiment`'s to add
        hosts: Vec::new(),
    })
}

/// Phase `p`'s shared-grid execution: from the plan's starts, or where the last phase done
/// left the robots (`cp`), to the phase's goals.
fn phase_grid(ctx: &Ctx<'_>, cp: &Checkpoint, p: usize) -> Result<GridPlan, CoordError> {
    let plan = ctx.plan;
    let unfit = |what: String| {
        CoordError::Plan(Box::new(contract::plan::PlanError::Field {
            field: "assignment",
            reason: what,
        }))
    };
    let (Some(goals), Some(planned)) = (plan.phase_goals(p), plan.planned_starts(p)) else {
        return Err(unfit(format!("phase {p} has no goal per robot")));
    };
    let grid = &ctx.map.grid;
    let from = match plan.phase_start {
        PhaseStart::Starts => planned.clone(),
        PhaseStart::Previous => cp.grid_starts(planned.clone()),
    };
    let instance = match Instance::new(grid.clone(), from, goals.clone()) {
        Ok(i) => i,
        // where the last phase left the robots does not make an instance (a robot lost there
        // stood where another stopped): the phase goes from where it was planned to
        Err(e) => {
            report::log_line!(
                "qfleet-coordinator: warning: phase {p} cannot start where phase {} left the \
                 robots ({e}); it starts from the goals of phase {}, as planned",
                p.saturating_sub(1),
                p.saturating_sub(1)
            );
            Instance::new(grid.clone(), planned, goals)
                .map_err(|e| unfit(format!("phase {p} on the shared grid: {e}")))?
        }
    };
    let args = ctx.args;
    Ok(GridPlan {
        max_ticks: args
            .world
            .max_ticks
            .unwrap_or_else(|| GridPlan::default_max_ticks(&instance)),
        scen: None,
        tick_min: Duration::from_millis(args.world.tick_ms),
        horizon: args.world.intent_horizon,
        paths: OutFile::PhasePaths(p as u32),
        instance,
    })
}

/// Executes phase `p` on the shared grid (see the module docs): `gp` is [`phase_grid`]'s,
/// `world` its world made while the robots learned; its result and where it left the robots.
#[allow(clippy::too_many_arguments)]
fn execute_phase(
    ctx: &Ctx<'_>,
    engine: &mut Engine,
    bus: &CoordinatorBus,
    lister: &Lister,
    stop: &AtomicBool,
    p: usize,
    gp: &GridPlan,
    world: mapf::World,
) -> Result<(GridResult, Vec<Cell>), CoordError> {
    let plan = ctx.plan;
    // every robot ranks its moves with what the whole fleet learned of its goal
    let mut flushed = vec![false; engine.tables.len()];
    for &g in &plan.assignment[p] {
        if !std::mem::replace(&mut flushed[g], true) {
            engine.flush(bus, g as u32)?;
        }
    }
    let spin = Duration::from_micros(ctx.args.spin_us);
    let hang = Duration::from_millis(ctx.args.hang_ms);
    grid::execute(engine, bus, lister, gp, world, spin, hang, stop, ctx.dir)
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
    use contract::coordinator::MergeRule;

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
