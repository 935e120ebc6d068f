//! Helpers shared by the integration tests: running a world with converged-robot intents.
#![allow(dead_code)]

use mapf::{Costs, Instance, Intent, Status, World, WorldConfig, check, check::conflicts};
use planner::Cell;
use std::path::PathBuf;

/// The shared MovingAI directory, or `None` (with a visible SKIPPED line) when it is missing.
pub fn movingai(test: &str) -> Option<PathBuf> {
    let dir = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/movingai"
    ));
    if dir.join("random-32-32-10.map").is_file() {
        Some(dir)
    } else {
        skip(
            &format!("mapf {test}"),
            &format!("{} is missing", dir.display()),
        );
        None
    }
}

/// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
/// says why it looks so; `tests/skips.rs` keeps every copy identical).
pub fn skip(test: &str, reason: &str) {
    use std::io::Write;
    let line = format!("SKIPPED: {test}: {reason}\n");
    let _ = std::io::stderr().lock().write_all(line.as_bytes());
}

/// Intents of robots with converged values: every present agent ranks by BFS distance.
pub fn greedy(inst: &Instance, pos: &[Option<Cell>], out: &mut [Option<Intent>]) {
    for (i, (o, p)) in out.iter_mut().zip(pos).enumerate() {
        *o = p.map(|c| Intent::toward(inst.grid(), inst.dist(i).unwrap_or(&[]), c));
    }
}

/// How a run ended.
#[derive(Debug)]
pub struct Run {
    pub world: World,
    pub last: Status,
    pub ticks: u32,
}

/// Steps a world with greedy intents until all arrive, it is unsolvable, or `max_ticks`.
pub fn run(inst: &Instance, config: WorldConfig, max_ticks: u32) -> Run {
    run_world(inst, World::new(inst, config), max_ticks)
}

/// [`run`] from a world made ahead (a coordinator's: [`World::prepare`] ran while the robots
/// learned).
pub fn run_prepared(inst: &Instance, config: WorldConfig, max_ticks: u32) -> Run {
    let mut w = World::new(inst, config);
    w.prepare();
    run_world(inst, w, max_ticks)
}

/// Steps `w` with greedy intents until all arrive, it is unsolvable, or `max_ticks`.
pub fn run_world(inst: &Instance, mut w: World, max_ticks: u32) -> Run {
    let mut intents = vec![None; inst.agents()];
    let mut last = Status::Running;
    while w.tick() < max_ticks && !w.all_arrived() {
        greedy(inst, w.positions(), &mut intents);
        last = w.step(&intents).expect("one intent per agent").status;
        if last == Status::Unsolvable {
            break;
        }
    }
    let ticks = w.tick();
    Run {
        world: w,
        last,
        ticks,
    }
}

/// Checks a finished run's paths with the independent checker; panics with every violation.
pub fn checked(inst: &Instance, w: &World) -> Costs {
    match check(inst.grid(), inst.starts(), inst.goals(), &w.paths()) {
        Ok(c) => c,
        Err(v) => panic!(
            "{} violations ({} conflicts): {:#?}",
            v.len(),
            conflicts(&v),
            &v[..v.len().min(10)]
        ),
    }
}
