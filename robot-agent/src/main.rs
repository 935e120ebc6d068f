//! `robot-agent`: one simulated robot of a qfleet run (started by `qfleet run` and
//! `qfleet experiment`).
//!
//! Exit codes:
//! - 0: the robot ran its plan to the coordinator's `Stop`, or was stopped by SIGINT/SIGTERM
//!   after the run started and reported cleanly;
//! - 1: a runtime failure (bus error, no coordinator within `--timeout`);
//! - 2: bad input (an option, the map, a learner parameter);
//! - 3: the coordinator refused this robot (schema version, map, id);
//! - 5: its result files could not be written (a final report still went to the coordinator
//!   first); the launcher does not restart it;
//! - 130: interrupted by SIGINT/SIGTERM before the coordinator started the run.

use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::Parser;
use robot_agent::AgentArgs;

/// One robot of a qfleet run: learns its path and shares Q-values with the coordinator.
#[derive(Debug, Parser)]
#[command(name = "robot-agent", version, about)]
struct Cli {
    #[command(flatten)]
    args: AgentArgs,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    // SIGINT/SIGTERM: stop learning, report, exit cleanly (the launcher kills after a grace period)
    if let Err(e) = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)) {
        report::log_line!("robot-agent: warning: cannot install the signal handler: {e}");
    }
    let id = cli.args.robot_id;
    match robot_agent::run(&cli.args, stop) {
        Ok(r) => {
            report::log_line!(
                "robot-agent {id}: {} after {} episodes, final path {} (optimal {}), {} hints applied",
                r.status,
                r.episodes,
                r.final_path_len
                    .map_or("loops".to_string(), |v| v.to_string()),
                r.optimal_path_len,
                r.counters.merged.entries_applied
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            report::log_line!("robot-agent {id}: error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
