//! The driver of a plain run: a one-goal, one-phase plan over the engine (`Engine`). Create the run's
//! services, admit the fleet, assign the goal and `Start`, serve until every robot finished,
//! hand out the whole fleet table, `Stop`, collect the reports, write the result.
//!
//! # Surviving its own death
//! While it serves, the coordinator writes `coordinator-checkpoint.json` into the out
//! directory ([`report::checkpoint`]) right after `Start`, about once a second, and at the end.
//! A coordinator that finds a resumable checkpoint of its run (`qfleet run --restart
//! on-failure` started it after the previous one died) takes over from it: the robots
//! re-register with it and replay their discoveries, the plan it sends again is ignored by
//! robots already in that phase, and the result counts the whole run (throughput from the
//! first `Start`, `liveness.coordinator_restarts`, the `coordinatorrestarted` event).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, ROBOT_ID_ALL};
use bus::{CoordinatorBus, Expected, Lister, monotonic_ns};

use crate::assemble::{FleetHists, RunEnd};
use crate::cpwriter::{Sink, Writer};
use crate::engine::{Assignment, Engine, tolerate};
use crate::grid::{self, GridPlan};
use crate::liveness::{Life, start_lister};
use crate::options::{CoordArgs, CoordError, bus_config, secs};
use crate::wait::{Serving, Waiting, serve};
use crate::{assemble, output};
use report::{
    CoordinatorCheckpoint, Durability, GridResult, LifelongResult, OutDir, OutFile, ReadError,
    RunResult, write_json_atomic_with,
};

/// How often the checkpoint is written while the run is served.
const CHECKPOINT_EVERY: Duration = Duration::from_secs(1);

/// Runs the coordinator of one run; `stop` is set by a signal handler (graceful stop: robots
/// are told to stop, their reports collected and a partial result written).
pub fn run(args: CoordArgs, stop: Arc<AtomicBool>) -> Result<RunResult, CoordError> {
    let timeout = secs(args.timeout, "--timeout")?;
    let task = args.map.task()?;
    // a lifelong problem (`--lorr`): read and checked before anything is created
    let lifelong = args
        .world
        .lifelong()?
        .map(|l| crate::lifelong::LifelongPlan {
            ids: crate::ahead::GoalIds::new(l.problem.grid(), l.problem.tasks()),
            lifelong: l,
            ticks: args.world.ticks,
            tick_min: Duration::from_millis(args.world.tick_ms),
        });
    let (Ok(width), Ok(height)) = (
        u16::try_from(task.grid.width()),
        u16::try_from(task.grid.height()),
    ) else {
        return Err(CoordError::MapTooLarge {
            width: task.grid.width(),
            height: task.grid.height(),
        });
    };
    // a shared grid: every robot's start and goal, checked before anything is created
    let grid = match args.world.shared() && lifelong.is_none() {
        true => {
            let instance = args.map.instance(args.robots)?;
            Some(GridPlan {
                max_ticks: args
                    .world
                    .max_ticks
                    .unwrap_or_else(|| GridPlan::default_max_ticks(&instance)),
                scen: args.map.scen.as_ref().map(|p| p.display().to_string()),
                tick_min: Duration::from_millis(args.world.tick_ms),
                horizon: args.world.intent_horizon,
                paths: OutFile::Paths,
                instance,
            })
        }
        false => None,
    };
    let cfg = bus_config(&args, args.robots)?;
    let dir = OutDir::new(&args.out);
    dir.create()?;
    let expected = Expected {
        robots: args.robots,
        map_hash: bus::bus_schema::map_fingerprint(
            task.grid.width(),
            task.grid.height(),
            task.grid.free_flags(),
        ),
        width,
        height,
    };
    let bus = CoordinatorBus::create(&cfg)?;
    let life = Life::new(
        args.robots,
        Duration::from_millis(args.hang_ms),
        args.restarts,
        timeout,
    );
    // one goal for the whole fleet, or one per robot on a shared grid (its own fleet table); a
    // lifelong run's phases come from its learning streams (`lifelong::Learners`)
    let plan: Vec<Assignment> = match (&grid, &lifelong) {
        (None, Some(_)) => Vec::new(),
        (None, None) => vec![
            Assignment {
                goal: 0,
                cell: task.goal,
                phase: 0,
                episodes: 0,
            };
            args.robots as usize
        ],
        (Some(g), _) => (0..args.robots)
            .map(|i| Assignment {
                goal: i,
                cell: g.instance.goals()[i as usize],
                phase: 0,
                episodes: 0,
            })
            .collect(),
    };
    let mut engine = Engine::new(
        expected,
        match (&grid, &lifelong) {
            (_, Some(l)) => l.ids.len() as u32,
            (Some(_), None) => args.robots,
            (None, None) => 1,
        },
        args.merge,
        life,
        cfg.merged_buffer,
        args.out.clone(),
    );
    engine.starts = match (&grid, &lifelong) {
        (Some(g), _) => Some(g.instance.starts().to_vec()),
        (None, Some(l)) => Some(l.lifelong.problem.starts().to_vec()),
        (None, None) => None,
    };
    // every robot learns its task on this map: its reports must agree with it (one task for
    // the fleet, or on a shared grid robot i's own, as its goal i)
    engine.optimum = match (&grid, &lifelong) {
        // set as each goal is sent to be learned, from where it is learned
        (None, Some(l)) => vec![vec![0; l.ids.len()]; args.robots as usize],
        (None, None) => vec![vec![task.optimal_len]; args.robots as usize],
        (Some(g), _) => (0..g.instance.agents())
            .map(|i| {
                let mut per_goal = vec![0; g.instance.agents()];
                per_goal[i] = g.instance.dist_from(i, g.instance.starts()[i]);
                per_goal
            })
            .collect(),
    };
    take_over(&dir, &args, &mut engine);
    let mut cp = Checkpoints::new(dir.clone(), args.run_id.clone());
    let outcome = drive(
        &mut engine,
        &bus,
        &args,
        plan,
        grid.as_ref(),
        lifelong.as_ref(),
        &stop,
        timeout,
        &mut cp,
    );
    let result = outcome.and_then(|(active, interrupted, grid, lifelong)| {
        let hists = FleetHists::read(&dir, args.robots);
        let end = RunEnd {
            active_s: active,
            interrupted,
            elapsed_s: secs_since(engine.began_ns),
            grid,
            lifelong,
        };
        let r = assemble::run_result(&engine, &args, &task, &dir, &hists, end);
        output::write_run(&dir, &r, &engine, &hists)?;
        // the run is over: a coordinator started after this one has nothing to take over
        cp.write(&engine, true);
        Ok(r)
    });
    cp.finish();
    // the last process of the run removes its files; errors here must not hide the result
    if let Err(e) = bus.close() {
        report::log_line!("qfleet-coordinator: warning: cleanup: {e}");
    }
    result
}

/// Seconds from CLOCK_MONOTONIC time `t_ns` (another process's, too) until now.
fn secs_since(t_ns: u64) -> f64 {
    monotonic_ns().saturating_sub(t_ns) as f64 / 1e9
}

/// Resumes `engine` from the out directory's checkpoint when it is this run's, left by a
/// coordinator of the same launcher that died (see the module docs); otherwise starts afresh.
fn take_over(dir: &OutDir, args: &CoordArgs, engine: &mut Engine) {
    let path = dir.path(OutFile::CoordinatorCheckpoint);
    let cp: CoordinatorCheckpoint = match dir.read_json(OutFile::CoordinatorCheckpoint) {
        Ok(cp) => cp,
        Err(ReadError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            return;
        }
        Err(e) => {
            report::log_line!("qfleet-coordinator: warning: not resuming: {e}");
            return;
        }
    };
    let launcher = std::os::unix::process::parent_id();
    match cp.resumable(&args.run_id, args.robots, launcher) {
        Ok(()) => {
            report::log_line!(
                "qfleet-coordinator: taking over run {} from the checkpoint of the coordinator \
                 that died (coordinator restart {}; {} messages, {} Q-updates merged before)",
                args.run_id,
                cp.coordinator_restarts + 1,
                cp.messages,
                cp.q_updates_merged
            );
            engine.resume(cp);
        }
        Err(why) => report::log_line!(
            "qfleet-coordinator: not resuming from {}: {why}",
            path.display()
        ),
    }
}

/// Writes the checkpoint now and then, on a thread of its own ([`crate::cpwriter`]): the
/// serving loop builds it and hands it over, never waiting for the disk. A failed write is
/// warned about once and does not stop the run (the checkpoint only helps a restarted
/// coordinator).
struct Checkpoints {
    run_id: String,
    last: Instant,
    writer: Option<Writer<CoordinatorCheckpoint>>,
}

/// Test hook: `QFLEET_TEST_CHECKPOINT_DELAY_MS` makes every checkpoint write that much slower
/// (at most 60 s), as a slow `--out` disk does (`tests/reliability.rs`
/// `a_slow_out_disk_never_makes_healthy_robots_hung`).
const DELAY_HOOK: &str = "QFLEET_TEST_CHECKPOINT_DELAY_MS";

/// The checkpoint file on disk.
struct CheckpointFile {
    path: std::path::PathBuf,
    delay: Duration,
}

impl Sink<CoordinatorCheckpoint> for CheckpointFile {
    fn write(&mut self, cp: &CoordinatorCheckpoint) -> Result<(), String> {
        std::thread::sleep(self.delay);
        // atomic, without fsync: it is for a coordinator process that dies, not a machine
        write_json_atomic_with(&self.path, cp, Durability::Process).map_err(|e| e.to_string())
    }
}

impl Checkpoints {
    fn new(dir: OutDir, run_id: String) -> Self {
        let delay = std::env::var(DELAY_HOOK)
            .ok()
            .and_then(|v| v.parse::<u64>().ok())
            .map_or(Duration::ZERO, |ms| Duration::from_millis(ms.min(60_000)));
        let sink = CheckpointFile {
            path: dir.path(OutFile::CoordinatorCheckpoint),
            delay,
        };
        let writer = Writer::start(sink, |e| {
            report::log_line!("qfleet-coordinator: warning: checkpoint not written: {e}");
        });
        if let Err(e) = &writer {
            report::log_line!(
                "qfleet-coordinator: warning: no checkpoint writer thread ({e}): no checkpoint \
                 is kept for a restarted coordinator"
            );
        }
        Checkpoints {
            run_id,
            last: Instant::now(),
            writer: writer.ok(),
        }
    }

    /// Hands the checkpoint over if the last one is [`CHECKPOINT_EVERY`] old.
    fn every(&mut self, engine: &Engine) {
        if self.last.elapsed() >= CHECKPOINT_EVERY {
            self.write(engine, false);
        }
    }

    /// Hands the checkpoint over; returns at once.
    fn write(&mut self, engine: &Engine, complete: bool) {
        self.last = Instant::now();
        if let Some(w) = &self.writer {
            w.offer(engine.checkpoint(&self.run_id, complete));
        }
    }

    /// Waits until the last checkpoint handed over is on disk (the run's end).
    fn finish(mut self) {
        if let Some(w) = self.writer.take() {
            w.finish();
        }
    }
}

/// Handshake, start, serve, table handout, the shared grid's execution, stop, reports;
/// returns (active seconds, interrupted, the grid's result, the lifelong grid's result).
#[allow(clippy::too_many_arguments)]
fn drive(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    args: &CoordArgs,
    plan: Vec<Assignment>,
    grid: Option<&GridPlan>,
    lifelong: Option<&crate::lifelong::LifelongPlan>,
    stop: &AtomicBool,
    timeout: Duration,
    cp: &mut Checkpoints,
) -> Result<(f64, bool, Option<GridResult>, Option<LifelongResult>), CoordError> {
    engine.admit_fleet(bus, stop, timeout)?;
    let lister = start_lister(bus)?;
    // a lifelong run's first phase: every robot's first goal to learn
    let (learners, plan) = match lifelong {
        Some(l) => {
            let (learners, first) = crate::lifelong::Learners::first_phase(l, engine);
            (Some(learners), first)
        }
        None => (None, plan),
    };
    engine.start_phase(bus, plan, Command::Start)?;
    // a coordinator that took over keeps the run's first Start as the throughput's time base
    let started_ns = *engine.started_ns.get_or_insert_with(monotonic_ns);
    cp.write(engine, false);
    // a lifelong grid moves at once, while the robots learn: no tick waits for a robot
    if let (Some(l), Some(learners)) = (lifelong, learners) {
        let out = OutDir::new(&args.out);
        let r = crate::lifelong::execute(engine, bus, &lister, l, learners, stop, &out)?;
        let interrupted = r.ended == "stopped" || engine.halted();
        tolerate(bus.stop(ROBOT_ID_ALL))?;
        collect_reports(engine, bus, &lister, timeout)?;
        return Ok((secs_since(started_ns), interrupted, None, Some(r)));
    }
    let how = Waiting {
        strategy: args.wait,
        spin: Duration::from_micros(args.spin_us),
    };
    let progress = args.progress;
    let serving = Serving {
        bus,
        lister: &lister,
        how,
        stop,
    };
    // the shared grid's first look-ahead plan is made on a thread of its own while the robots
    // learn; the execution waits for it if they finish first
    let (served, mut prepared) = grid::prepare_while(grid, || {
        serve(
            engine,
            &serving,
            |_| {},
            |e| {
                if progress {
                    print_progress(e);
                }
                cp.every(e);
                let now = Instant::now();
                (0..e.robots.len()).all(|i| e.done(i, now))
            },
        )
    });
    let interrupted = served?;
    let active = secs_since(started_ns);
    // every robot is done learning (or lost): hand out the whole fleet table (one goal), or
    // move the robots on the shared grid (a goal each), then Stop
    let mut executed = None;
    match grid {
        Some(g) if !interrupted => {
            for goal in 0..engine.tables.len() as u32 {
                engine.flush(bus, goal)?;
            }
            let hang = Duration::from_millis(args.hang_ms);
            let spin = Duration::from_micros(args.spin_us);
            let out = OutDir::new(&args.out);
            let world = prepared.take().unwrap_or_else(|| grid::prepare(g));
            let (r, _) = grid::execute(engine, bus, &lister, g, world, spin, hang, stop, &out)?;
            executed = Some(r);
        }
        Some(_) => {}
        None if !interrupted && args.robots > 1 => {
            engine.resend_table(bus, 0)?;
        }
        None => engine.flush(bus, 0)?,
    }
    let interrupted =
        interrupted || stop.load(std::sync::atomic::Ordering::Relaxed) || engine.halted();
    // a hung robot that does not drain its control buffer must not fail the run
    tolerate(bus.stop(ROBOT_ID_ALL))?;
    collect_reports(engine, bus, &lister, timeout)?;
    Ok((active, interrupted, executed, None))
}

/// `progress <episodes done> <total> <p50 ns> <p99 ns>` on stdout.
fn print_progress(e: &Engine) {
    use std::io::Write;
    let done: u64 = e
        .robots
        .iter()
        .map(|r| u64::from(r.report.map_or(r.episode, |rep| rep.episodes)))
        .sum();
    let total: u64 = e.robots.iter().map(|r| u64::from(r.episodes_total)).sum();
    let age = &e.h.hint_age;
    let (p50, p99) = if age.is_empty() {
        (0, 0)
    } else {
        (age.value_at_quantile(0.5), age.value_at_quantile(0.99))
    };
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "{}",
        contract::lines::progress_line(done, total, p50, p99)
    );
    let _ = out.flush();
}

/// Waits (up to `timeout`) until every robot reported, was lost or is hung.
fn collect_reports(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    lister: &Lister,
    timeout: Duration,
) -> Result<(), CoordError> {
    let deadline = Instant::now() + timeout;
    loop {
        engine.drain(bus)?;
        if (0..engine.robots.len()).all(|i| engine.reported(i)) {
            return Ok(());
        }
        if Instant::now() >= deadline {
            report::log_line!(
                "qfleet-coordinator: no final report from some robots within {timeout:?}"
            );
            return Ok(());
        }
        if let Some(listing) = lister.poll() {
            engine.liveness(bus, listing)?;
        }
        bus.report.wait(Duration::from_millis(10))?;
    }
}
