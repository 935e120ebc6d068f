//! `qfleet-coordinator`: the coordinator process of a qfleet run (started by `qfleet run`) or,
//! with `--plan plan.json`, of one repetition of an experiment (started by `qfleet
//! experiment`; a coordinator started again resumes the experiment from `experiment-checkpoint.json`).
//!
//! Exit codes (the same for runs and experiments):
//! - 0: the run (every phase) completed and every robot reported;
//! - 1: a runtime failure (the bus, a thread);
//! - 2: bad input (an option value, the map, the scenario, the learner options);
//! - 3: a robot was refused at registration (schema or map mismatch);
//! - 4: the run completed, but some robot was lost or sent no report (in some phase, for an
//!   experiment; a hung robot is reported as `hung` and does not change the exit code);
//! - 5: its files could not be written (a full `--out` disk): the result went to the launcher
//!   on stdout as a `result <json>` line; the launcher does not restart it;
//! - 130: interrupted by a signal (a partial result is written when the run had started).

use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use coordinator::experiment::ExperimentPlan;
use coordinator::output;
use coordinator::{CoordArgs, CoordError, RobotOutcome};
use report::OutDir;

/// The coordinator of a qfleet run: admits robots, merges their Q hints, measures the loop.
#[derive(Debug, Parser)]
#[command(name = "qfleet-coordinator", version, about)]
struct Cli {
    #[command(flatten)]
    args: CoordArgs,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    if let Err(e) = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)) {
        report::log_line!("qfleet-coordinator: warning: cannot install the signal handler: {e}");
    }
    if let Some(file) = cli.args.plan.clone() {
        return experiment(&cli.args, &file, &stop);
    }
    match coordinator::run(cli.args, stop) {
        Ok(r) => {
            let incomplete = r
                .robots
                .iter()
                .any(|x| matches!(x.status, RobotOutcome::Lost | RobotOutcome::Missing));
            report::log_line!(
                "qfleet-coordinator: run {} done: {} robots, all optimal: {}, {} Q-updates merged",
                r.run_id,
                r.robots.len(),
                r.all_optimal,
                r.throughput.q_updates_merged
            );
            ended(r.interrupted, incomplete)
        }
        Err(e) => failed(&e),
    }
}

/// `--plan`: one repetition of an experiment; its result goes to `result.json` in `--out`.
fn experiment(args: &CoordArgs, file: &std::path::Path, stop: &AtomicBool) -> ExitCode {
    let done = ExperimentPlan::read(file)
        .map_err(CoordError::from)
        .and_then(|plan| coordinator::experiment::run(args, &plan, stop))
        .and_then(|r| {
            output::write_experiment(&OutDir::new(&args.out), &r)?;
            Ok(r)
        });
    match done {
        Ok(r) => {
            let incomplete = r
                .phases
                .iter()
                .flat_map(|p| &p.robots)
                .any(|x| matches!(x.status, RobotOutcome::Lost | RobotOutcome::Missing));
            report::log_line!(
                "qfleet-coordinator: experiment {} done: {} phases{}, {} coordinator restarts",
                r.run_id,
                r.phases.len(),
                if r.interrupted { " (interrupted)" } else { "" },
                r.coordinator_restarts
            );
            ended(r.interrupted, incomplete)
        }
        Err(e) => failed(&e),
    }
}

/// An error with its sources, `outer: inner: …`.
fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        // a library error often names its cause in its own message too: once is enough
        let msg = c.to_string();
        if !s.contains(&msg) {
            s.push_str(": ");
            s.push_str(&msg);
        }
        cur = c.source();
    }
    s
}

/// The exit code of a finished run or experiment: 130 interrupted, 4 a robot lost or missing,
/// else 0.
fn ended(interrupted: bool, incomplete: bool) -> ExitCode {
    if interrupted {
        ExitCode::from(130)
    } else if incomplete {
        ExitCode::from(4)
    } else {
        ExitCode::SUCCESS
    }
}

/// Says why the coordinator failed, and exits with the code of that failure.
fn failed(e: &CoordError) -> ExitCode {
    report::log_line!("qfleet-coordinator: error: {}", chain(e));
    ExitCode::from(e.exit_code())
}
