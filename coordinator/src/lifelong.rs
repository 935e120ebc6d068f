//! The coordinator as the authority of a lifelong shared grid (`--lorr PROBLEM.json`): a robot
//! gets its next goal the tick it reaches one, and the run ends after `--ticks`, never on
//! arrival.
//!
//! # A tick
//! 1. [`mapf::lifelong::Lifelong::step`] grants every robot one collision-free move (PIBT with
//!    the swap rule over each robot's ranking), counts the robots on their goals and deals them
//!    their next one from the problem's round-robin stream — in the same tick.
//! 2. The configuration is published on `coord/grant` (every robot's cell; `--live`, Foxglove
//!    and `qfleet topic` read it) **without waking anyone**: no tick waits for a robot process.
//!
//! The robots learn meanwhile (the learning traffic is served between ticks, at most every
//! [`SERVE_EVERY`], with the liveness listing): a robot whose process dies leaves the grid at the
//! next tick. Every move is ranked by map distance to the robot's goal: the robots learn their
//! first goal, but their values are not read here yet (the result counts the robot-ticks ranked
//! each way, so a run says which it used).
//!
//! At the end the executed paths are checked again by [`mapf::check`](mod@mapf::check) (code that
//! shares nothing with the resolver) and written as `paths.txt` (mapf-visualizer format) and
//! `lorr-output.json` (the competition's output, which its visualiser PlanViz opens).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{GRANT_CAP, Grant, GridState};
use bus::{CoordinatorBus, Lister, SendError, monotonic_ns};
use mapf::lifelong::{Lifelong, LifelongConfig, competition_output};
use planner::Cell;
use report::hist::{new_hist, record};
use report::{LatencyStats, LifelongResult, OutDir, OutFile};

use crate::engine::Engine;
use crate::options::CoordError;

/// How often the tick loop serves the robots' learning traffic and looks at their liveness.
pub const SERVE_EVERY: Duration = Duration::from_millis(2);

/// A lifelong run to drive: the problem and its limits.
#[derive(Debug, Clone)]
pub struct LifelongPlan {
    /// The problem, its map file and its own file.
    pub lifelong: qfleet_args::Lifelong,
    /// Ticks to run.
    pub ticks: u32,
    /// Shortest time per tick (`--tick-ms`; zero: none).
    pub tick_min: Duration,
}

/// Drives a lifelong run on the bus (see the module docs), writes its files into `out` and
/// returns its result.
pub(crate) fn execute(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    lister: &Lister,
    plan: &LifelongPlan,
    stop: &AtomicBool,
    out: &OutDir,
) -> Result<LifelongResult, CoordError> {
    let problem = &plan.lifelong.problem;
    let n = problem.team();
    let mut world = Lifelong::new(problem, LifelongConfig::default());
    leave_lost(engine, &mut world, 0);
    bus.connect_all()?;
    report::log_line!(
        "qfleet-coordinator: lifelong grid: {n} robots, {} ticks, goals dealt round robin from {} \
         tasks",
        plan.ticks,
        problem.tasks().len()
    );
    let rankings = vec![None; n];
    let mut finished: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut planner_s = Vec::with_capacity(plan.ticks as usize);
    let mut tick_hist = new_hist();
    publish(bus, &world, GridState::Moving)?;
    let mut served = Instant::now();
    let t0 = Instant::now();
    let stopped = loop {
        if world.tick() >= plan.ticks {
            break false;
        }
        if stop.load(Ordering::Relaxed) || engine.halted() {
            break true;
        }
        if served.elapsed() >= SERVE_EVERY {
            engine.drain(bus)?;
            if let Some(listing) = lister.poll() {
                engine.liveness(bus, listing)?;
                let tick = world.tick();
                leave_lost(engine, &mut world, tick);
            }
            served = Instant::now();
        }
        let start = Instant::now();
        let t = world.step(&rankings);
        for &r in world.arrived() {
            finished[r as usize].push(t.tick);
        }
        let took = start.elapsed();
        planner_s.push(took.as_secs_f64());
        record(&mut tick_hist, took.as_nanos() as u64);
        publish(bus, &world, GridState::Moving)?;
        if let Some(rest) = plan.tick_min.checked_sub(start.elapsed()) {
            std::thread::sleep(rest);
        }
    };
    let exec_s = t0.elapsed().as_secs_f64();
    publish(bus, &world, GridState::Ended)?;
    bus.grant.notify()?;
    let paths = world.paths();
    let written = |file: OutFile, bytes: &[u8]| match out.write(file, bytes) {
        Ok(_) => Some(file.name()),
        Err(e) => {
            report::log_line!("qfleet-coordinator: warning: {e}");
            None
        }
    };
    let paths_file = written(OutFile::Paths, mapf::write_paths(&paths).as_bytes());
    let lorr = competition_output(problem, &paths, &finished, &planner_s);
    let lorr_file = written(OutFile::LorrOutput, lorr.to_string().as_bytes());
    let ticks = world.tick();
    let reached = world.reached();
    let second_half = finished
        .iter()
        .flatten()
        .filter(|&&t| t > ticks / 2)
        .count() as f64;
    let result = LifelongResult {
        problem: plan.lifelong.file.display().to_string(),
        agents: n as u32,
        ticks,
        ended: if stopped { "stopped" } else { "ticks" }.into(),
        goals_reached: reached,
        throughput: per_tick(reached as f64, ticks),
        throughput_2nd_half: per_tick(second_half, ticks - ticks / 2),
        robot_goals: (0..n).map(|k| world.goals_reached(k)).collect(),
        robots_lost: (0..n)
            .filter(|&k| !world.present(k))
            .map(|k| k as u32)
            .collect(),
        conflicts: conflicts(problem.grid(), &paths, |k| world.present(k)),
        ticks_by_values: 0,
        ticks_by_distance: (0..n).filter(|&k| world.present(k)).count() as u64 * u64::from(ticks),
        exec_s,
        ticks_per_s: f64::from(ticks) / exec_s.max(1e-9),
        tick_latency_ns: LatencyStats::of(&tick_hist),
        paths_file,
        lorr_file,
    };
    report::log_line!(
        "qfleet-coordinator: lifelong grid: {reached} goals in {ticks} ticks ({:.3} per tick), \
         {:.0} ticks/s",
        result.throughput,
        result.ticks_per_s
    );
    Ok(result)
}

/// `x / ticks`, 0 for no tick.
fn per_tick(x: f64, ticks: u32) -> f64 {
    if ticks == 0 {
        0.0
    } else {
        x / f64::from(ticks)
    }
}

/// Vertex and swap conflicts among the robots that stayed on the grid, by `mapf::check` (its
/// goals: where each robot ended, so that only conflicts count).
fn conflicts(grid: &planner::Grid, paths: &[Vec<Cell>], stayed: impl Fn(usize) -> bool) -> u64 {
    let kept: Vec<Vec<Cell>> = (0..paths.len())
        .filter(|&k| stayed(k))
        .map(|k| paths[k].clone())
        .collect();
    let starts: Vec<Cell> = kept.iter().map(|p| p[0]).collect();
    let ends: Vec<Cell> = kept.iter().map(|p| p[p.len() - 1]).collect();
    match mapf::check(grid, &starts, &ends, &kept) {
        Ok(_) => 0,
        Err(v) => mapf::check::conflicts(&v) as u64,
    }
}

/// Takes every robot the engine declared lost off the grid.
fn leave_lost(engine: &Engine, world: &mut Lifelong, tick: u32) {
    for (id, slot) in engine.robots.iter().enumerate() {
        if (slot.lost || !slot.accepted) && world.remove(id) {
            report::log_line!(
                "qfleet-coordinator: robot {id} left the lifelong grid at tick {tick} (its \
                 process is gone)"
            );
        }
    }
}

/// Publishes where every robot stands now, waking nobody.
fn publish(bus: &CoordinatorBus, world: &Lifelong, state: GridState) -> Result<(), CoordError> {
    let n = world.problem().team();
    let tick = world.tick();
    let r = bus.grant.send_with(|g: &mut Grant| {
        g.tick = tick;
        g.robots = n.min(GRANT_CAP) as u32;
        g.state = state.as_u8();
        g.seq = u64::from(tick);
        for i in 0..n.min(GRANT_CAP) {
            let c = world.position(i);
            g.cell_x[i] = c.x;
            g.cell_y[i] = c.y;
            g.present[i] = u8::from(world.present(i));
        }
        g.send_time_ns = monotonic_ns();
    });
    match r {
        Ok(_) | Err(SendError::NoSubscriber { .. }) => Ok(()),
        Err(e) => Err(e.into()),
    }
}
