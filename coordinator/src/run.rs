//! The driver of a plain run: a one-goal, one-phase plan over the [`Engine`]. Create the run's
//! services, admit the fleet, assign the goal and `Start`, serve until every robot finished,
//! hand out the whole fleet table, `Stop`, collect the reports, write the result.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, ROBOT_ID_ALL};
use bus::{CoordinatorBus, Expected};

use crate::assemble::{FleetHists, RunEnd};
use crate::engine::{Assignment, Engine, tolerate};
use crate::liveness::{Life, Lister};
use crate::options::{CoordArgs, CoordError, bus_config, secs};
use crate::wait::{Serving, Waiting, serve};
use crate::{assemble, output};
use report::{OutDir, RunResult};

/// How often the liveness thread lists the run's nodes.
pub(crate) const LIST_EVERY: Duration = Duration::from_millis(100);

/// Runs the coordinator of one run; `stop` is set by a signal handler (graceful stop: robots
/// are told to stop, their reports collected and a partial result written).
pub fn run(args: CoordArgs, stop: Arc<AtomicBool>) -> Result<RunResult, CoordError> {
    let t_begin = Instant::now();
    let timeout = secs(args.timeout, "--timeout")?;
    let task = args.map.task()?;
    let (Ok(width), Ok(height)) = (
        u16::try_from(task.grid.width()),
        u16::try_from(task.grid.height()),
    ) else {
        return Err(CoordError::MapTooLarge {
            width: task.grid.width(),
            height: task.grid.height(),
        });
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
    let mut engine = Engine::new(
        expected,
        1,
        args.merge,
        life,
        cfg.merged_buffer,
        args.out.clone(),
    );
    let plan = vec![
        Assignment {
            goal: 0,
            cell: task.goal,
            phase: 0,
            episodes: 0,
        };
        args.robots as usize
    ];
    let outcome = drive(&mut engine, &bus, &args, plan, &stop, timeout);
    let result = outcome.and_then(|(active, interrupted)| {
        let hists = FleetHists::read(&dir, args.robots);
        let end = RunEnd {
            active_s: active,
            interrupted,
            elapsed_s: t_begin.elapsed().as_secs_f64(),
        };
        let r = assemble::run_result(&engine, &args, &task, &dir, &hists, end);
        output::write_run(&dir, &r, &engine, &hists)?;
        Ok(r)
    });
    // the last process of the run removes its files; errors here must not hide the result
    if let Err(e) = bus.close() {
        eprintln!("qfleet-coordinator: warning: cleanup: {e}");
    }
    result
}

/// Handshake, start, serve, table handout, stop, reports; returns (active seconds, interrupted).
fn drive(
    engine: &mut Engine,
    bus: &CoordinatorBus,
    args: &CoordArgs,
    plan: Vec<Assignment>,
    stop: &AtomicBool,
    timeout: Duration,
) -> Result<(f64, bool), CoordError> {
    engine.admit_fleet(bus, stop, timeout)?;
    let lister = Lister::start(bus.config(), LIST_EVERY).map_err(|source| CoordError::Thread {
        what: "liveness",
        source,
    })?;
    engine.start_phase(bus, plan, Command::Start)?;
    let t_start = Instant::now();
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
    let interrupted = serve(
        engine,
        &serving,
        |_| {},
        |e| {
            if progress {
                print_progress(e);
            }
            let now = Instant::now();
            (0..e.robots.len()).all(|i| e.done(i, now))
        },
    )?;
    let active = t_start.elapsed().as_secs_f64();
    // every robot is done learning (or lost): hand out the whole fleet table, then Stop
    if !interrupted && args.robots > 1 {
        engine.resend_table(bus, 0)?;
    } else {
        engine.flush(bus, 0)?;
    }
    // a hung robot that does not drain its control buffer must not fail the run
    tolerate(bus.stop(ROBOT_ID_ALL))?;
    collect_reports(engine, bus, &lister, timeout)?;
    Ok((active, interrupted))
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
    let _ = writeln!(out, "progress {done} {total} {p50} {p99}");
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
            eprintln!("qfleet-coordinator: no final report from some robots within {timeout:?}");
            return Ok(());
        }
        if let Some(listing) = lister.poll() {
            engine.liveness(bus, listing)?;
        }
        bus.report.wait(Duration::from_millis(10))?;
    }
}
