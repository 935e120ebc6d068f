//! `qfleet-coordinator`: the coordinator process of a qfleet run (started by `qfleet run`).

use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use coordinator::{CoordArgs, CoordError};

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
        eprintln!("qfleet-coordinator: warning: cannot install the signal handler: {e}");
    }
    match coordinator::run(cli.args, stop) {
        Ok(r) => {
            let lost = !r.liveness.lost.is_empty();
            let missing = r.robots.iter().any(|x| x.status == "missing");
            eprintln!(
                "qfleet-coordinator: run {} done: {} robots, all optimal: {}, {} Q-updates merged",
                r.run_id,
                r.robots.len(),
                r.all_optimal,
                r.throughput.q_updates_merged
            );
            if r.interrupted {
                ExitCode::from(130)
            } else if lost || missing {
                ExitCode::from(4)
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("qfleet-coordinator: error: {e}");
            match e {
                CoordError::Input(_) => ExitCode::from(2),
                CoordError::Refused { .. } => ExitCode::from(3),
                _ => ExitCode::FAILURE,
            }
        }
    }
}
