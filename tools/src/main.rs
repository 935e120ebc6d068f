//! `qfleet`: learn grid paths with the paper's Q-learners, replicate its results, and run fleets.

mod bench;
mod clean;
mod experiment;
mod join;
mod learn;
mod plots;
mod replicate;
mod run;
mod runplots;
mod supervise;
mod sweep;

use clap::{Parser, Subcommand};

/// Fleets of simulated robots learning grid paths with improved Q-learning.
#[derive(Debug, Parser)]
#[command(name = "qfleet", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Learn a path on one map with one learner.
    Learn(learn::LearnCmd),
    /// Regenerate the paper's Table 1 and figures on the built-in maps.
    Replicate(replicate::ReplicateCmd),
    /// Run a fleet: a coordinator and N robot-agents sharing Q-values over shared memory.
    Run(run::RunCmd),
    /// Remove shared-memory files that crashed runs left behind (never a live run's).
    Clean(clean::CleanCmd),
    /// Run an experiment manifest: the coordinator assigns goals and phases to the robots.
    Experiment(experiment::ExperimentCmd),
    /// Measure the value of sharing: N = 1, 2, 4, 8, 16 robots, with and without sharing.
    Sweep(sweep::SweepCmd),
    /// Benchmark the update loop against raw iceoryx2, Unix sockets and crossbeam; fleet scale.
    Bench(bench::BenchCmd),
    /// Run robots of a run whose coordinator is on another host (`qfleet run … --listen`).
    Join(join::JoinCmd),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Learn(c) => c.run(),
        Command::Replicate(c) => c.run(),
        Command::Run(c) => c.run(),
        Command::Clean(c) => c.run(),
        Command::Bench(c) => c.run(),
        Command::Experiment(c) => c.run(),
        Command::Sweep(c) => c.run(),
        Command::Join(c) => c.run(),
    };
    if let Err(e) = result {
        eprintln!("qfleet: error: {}", report(&e));
        std::process::exit(1);
    }
}

/// The error and its causes on one line, each cause once: library errors often name their
/// cause in their own message too, and `{:#}` would then print it twice.
fn report(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let msg = cause.to_string();
        if out.contains(&msg) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&msg);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::report;
    use anyhow::Context;

    #[test]
    fn each_cause_is_printed_once() {
        let io = std::io::Error::other("disk on fire");
        let inner = anyhow::Error::new(io).context("reading map.txt: disk on fire");
        let e = Err::<(), _>(inner).context("loading the task").unwrap_err();
        assert_eq!(
            report(&e),
            "loading the task: reading map.txt: disk on fire"
        );
    }
}
