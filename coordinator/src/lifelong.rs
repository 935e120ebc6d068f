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
//! # Learning ahead
//! Between ticks (at most every [`SERVE_EVERY`], with the liveness listing) the coordinator
//! serves the robots' learning traffic and keeps every robot learning its next goals
//! ([`crate::ahead`]: which goal, from where, up to the problem's `numTasksReveal` ahead, at
//! least one): each goal is one phase of the robot's protocol, sent to it alone and reported at
//! its end. Phases are numbered per robot; a phase's goal id is its goal cell's, so the robots
//! sent to one cell share one fleet table, and a robot sent to a cell whose table holds values
//! gets the whole table at once (a warm start; merged values do not go out as they change, as
//! they do in other runs: each robot learns another goal). The result counts the goals learned, their
//! environment steps (warm and cold), and the robot-ticks walked towards a goal learned or not.
//! Every move is ranked by map distance to the robot's goal all the same: a robot whose values
//! are not ready moves exactly as one whose values are (the learned values are not read by the
//! resolver; map distance is exact on a known map, and the values at best agree with it).
//!
//! A robot whose process dies leaves the grid at the next tick.
//!
//! At the end the executed paths are checked again by [`mapf::check`](mod@mapf::check) (code that
//! shares nothing with the resolver) and written as `paths.txt` (mapf-visualizer format) and
//! `lorr-output.json` (the competition's output, which its visualiser PlanViz opens).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, Control, GRANT_CAP, Grant, GridState};
use bus::{CoordinatorBus, Lister, SendError, monotonic_ns};
use mapf::lifelong::{Lifelong, LifelongConfig, competition_output};
use planner::Cell;
use report::hist::{new_hist, record};
use report::{LatencyStats, LifelongLearning, LifelongResult, OutDir, OutFile};

use crate::ahead::{GoalIds, LearnAhead, Learning};
use crate::engine::{Assignment, Engine, tolerate};
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
    /// The goal id of every goal cell the problem's tasks name (one fleet table each).
    pub ids: GoalIds,
}

/// The robots' learning streams and the bookkeeping of the learning under way (see the
/// module docs): the IO-free rule is [`LearnAhead`]; this sends its phases and reads the reports.
pub(crate) struct Learners {
    ahead: LearnAhead,
    /// Per robot: when its learning under way was sent, and whether its fleet table held values.
    sent: Vec<(Instant, bool)>,
    /// Goals whose fleet table goes out at the next serve: a warm start, sent once the robot had
    /// time to open the phase (a robot keeps what arrives for a phase it has not opened, but a
    /// batch that arrives before the phase's `AssignGoal` is read as another goal's).
    warm_due: Vec<u32>,
}

impl Learners {
    /// The streams of `plan`'s robots, and the first phase: every robot's first goal to learn
    /// (episodes: the robot's own `--episodes`, named so that the phase is reported at its end).
    pub(crate) fn first_phase(
        plan: &LifelongPlan,
        engine: &mut Engine,
    ) -> (Learners, Vec<Assignment>) {
        let problem = &plan.lifelong.problem;
        engine.live_merges = false;
        let mut ahead = LearnAhead::new(problem.starts(), problem.reveal());
        let now = Instant::now();
        let mut sent = Vec::with_capacity(problem.team());
        let mut first = Vec::with_capacity(problem.team());
        for k in 0..problem.team() {
            let l = ahead.next(k, 0, |c| problem.goal(k, c));
            // a robot whose revealed goals all lie on its start has nothing to learn yet: it is
            // sent its first goal that is not its start, outside its stream (its report counts
            // nowhere)
            let start = problem.starts()[k];
            let goal = l.map_or_else(
                || plan.lifelong.map_args(k).goal.unwrap_or(start),
                |l| l.goal,
            );
            let a = assignment(plan, engine, k, goal, 0, l.map_or(start, |l| l.from));
            first.push(a);
            sent.push((now, false));
        }
        let learners = Learners {
            ahead,
            sent,
            warm_due: Vec::new(),
        };
        (learners, first)
    }

    /// Closes the learnings whose report came in and sends every free robot its next goal to
    /// learn, if one is in its window.
    fn serve(
        &mut self,
        plan: &LifelongPlan,
        engine: &mut Engine,
        bus: &CoordinatorBus,
        world: &Lifelong,
    ) -> Result<(), CoordError> {
        let problem = world.problem();
        for g in std::mem::take(&mut self.warm_due) {
            engine.resend_table(bus, g)?;
        }
        for k in 0..problem.team() {
            if !world.present(k) {
                continue;
            }
            if let Some(l) = self.ahead.busy(k) {
                let id = plan.ids.of(problem.grid(), l.goal);
                match engine.robots[k].report {
                    Some(r) if Some(r.goal_id) == id => {
                        let (at, warm) = self.sent[k];
                        self.ahead
                            .done(k, r.env_steps, at.elapsed().as_secs_f64(), warm);
                    }
                    _ => continue,
                }
            }
            let Some(l) = self
                .ahead
                .next(k, world.goals_reached(k), |c| problem.goal(k, c))
            else {
                continue;
            };
            self.send(plan, engine, bus, k, l)?;
        }
        Ok(())
    }

    /// Sends robot `k` learning `l`: `AssignGoal` and `Phase` to it alone, and its goal's fleet
    /// table at the next serve (a warm start, when it holds values).
    fn send(
        &mut self,
        plan: &LifelongPlan,
        engine: &mut Engine,
        bus: &CoordinatorBus,
        k: usize,
        l: Learning,
    ) -> Result<(), CoordError> {
        let a = assignment(plan, engine, k, l.goal, l.phase, l.from);
        let warm = !engine.tables[a.goal as usize].is_empty();
        if warm && !self.warm_due.contains(&a.goal) {
            self.warm_due.push(a.goal);
        }
        self.sent[k] = (Instant::now(), warm);
        let slot = &mut engine.robots[k];
        slot.report = None;
        slot.finished = false;
        slot.episode = 0;
        engine.assignment[k] = a;
        tolerate(bus.send_control(Control {
            goal_id: a.goal,
            goal_x: a.cell.x,
            goal_y: a.cell.y,
            phase: a.phase,
            episodes: a.episodes,
            ..bus::control(Command::AssignGoal, k as u32)
        }))?;
        tolerate(bus.send_control(Control {
            phase: a.phase,
            episodes: a.episodes,
            ..bus::control(Command::Phase, k as u32)
        }))
    }

    /// What learning cost, for the result.
    fn result(&self) -> LifelongLearning {
        let c = self.ahead.cost();
        let mean = |x: u64, n: u64| if n == 0 { 0.0 } else { x as f64 / n as f64 };
        LifelongLearning {
            ahead: self.ahead.ahead(),
            goals_learned: c.goals,
            warm_started: c.warm,
            env_steps: c.env_steps,
            env_steps_per_goal: mean(c.env_steps, c.goals),
            env_steps_per_warm_goal: mean(c.warm_env_steps, c.warm),
            env_steps_per_cold_goal: mean(c.env_steps - c.warm_env_steps, c.goals - c.warm),
            learn_s_per_goal: if c.goals == 0 {
                0.0
            } else {
                c.learn_s / c.goals as f64
            },
            ticks_goal_learned: c.ticks_learned,
            ticks_goal_unlearned: c.ticks_unlearned,
        }
    }
}

/// Robot `k`'s phase `phase` learning `goal` from `from`: its goal id, its episodes (the
/// robot's own), and the optimum its report must agree with.
fn assignment(
    plan: &LifelongPlan,
    engine: &mut Engine,
    k: usize,
    goal: Cell,
    phase: u32,
    from: Cell,
) -> Assignment {
    let grid = plan.lifelong.problem.grid();
    let id = plan.ids.of(grid, goal).unwrap_or(0);
    if let Some(o) = engine
        .optimum
        .get_mut(k)
        .and_then(|o| o.get_mut(id as usize))
    {
        *o = planner::path::bfs_distances(grid, goal)[grid.index(from)];
    }
    Assignment {
        goal: id,
        cell: goal,
        phase,
        episodes: engine.robots[k].episodes_total.max(1),
    }
}

/// Drives a lifelong run on the bus (see the module docs), writes its files into `out` and
/// returns its result.
pub(crate) fn execute(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    lister: &Lister,
    plan: &LifelongPlan,
    mut learners: Learners,
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
            learners.serve(plan, engine, bus, &world)?;
            served = Instant::now();
        }
        for k in 0..n {
            if world.present(k) {
                learners.ahead.tick(k, world.goals_reached(k));
            }
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
        learning: learners.result(),
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
