//! `qfleet`: learn grid paths with the paper's Q-learners, replicate its results, and run fleets.

mod bar;
mod bench;
mod clean;
mod eval;
mod experiment;
mod join;
mod launch;
mod learn;
mod live;
mod replay;
mod replicate;
mod run;
mod sweep;
mod term;
mod topic;

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use clap::{Parser, Subcommand};
use launcher::Exit;

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
    /// Run a fleet: a coordinator and N robot-agents sharing Q-values over shared memory
    /// (`--world shared`: on one grid, a MAPF instance from `--scen FILE --agents N`).
    Run(Box<run::RunCmd>),
    /// Remove shared-memory files that crashed runs left behind (never a live run's).
    Clean(clean::CleanCmd),
    /// Run an experiment manifest: the coordinator assigns goals and phases to the robots.
    Experiment(experiment::ExperimentCmd),
    /// Measure the value of sharing: N = 1, 2, 4, 8, 16 robots, with and without sharing.
    Sweep(sweep::SweepCmd),
    /// Evaluate learner configurations on the map suite (tuning or held-out half), all cores.
    Eval(eval::EvalCmd),
    /// Benchmark the update loop against raw iceoryx2, Unix sockets and crossbeam; fleet scale.
    Bench(bench::BenchCmd),
    /// Run robots of a run whose coordinator is on another host (`qfleet run … --listen`).
    Join(join::JoinCmd),
    /// Look at a live run from outside: its topics, every message as JSON, message rates.
    Topic(topic::TopicCmd),
    /// Read a recording (`run --record FILE.mcap`) back: per-topic summary, or the live view.
    Replay(replay::ReplayCmd),
}

/// SIGINT/SIGTERM received so far (the first stops a run gracefully, the second kills it).
pub static INTERRUPTS: AtomicU32 = AtomicU32::new(0);
/// Set on the first SIGINT/SIGTERM (a sweep does not retry a run that failed after it).
pub static STOP: AtomicBool = AtomicBool::new(false);

/// Asks the run to stop gracefully, as SIGINT/SIGTERM do (the live view's `q` calls it too).
pub fn request_stop() {
    INTERRUPTS.fetch_add(1, Ordering::SeqCst);
    STOP.store(true, Ordering::SeqCst);
}

/// Installs the SIGINT/SIGTERM handler once for the whole process (runs, experiments, sweeps).
pub fn catch_interrupts() -> anyhow::Result<()> {
    static INSTALLED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    INSTALLED
        .get_or_init(|| ctrlc::set_handler(request_stop).map_err(|e| e.to_string()))
        .clone()
        .map_err(|e| anyhow::anyhow!("installing the Ctrl-C handler: {e}"))
}

/// A library error as the CLI reports it: with [`Exit::BadInput`] (exit code 2) when
/// `bad_input` says the library refused its input, a failure (exit code 1) otherwise.
pub fn classify<E: std::error::Error + Send + Sync + 'static>(
    e: E,
    bad_input: impl Fn(&E) -> bool,
) -> anyhow::Error {
    let bad = bad_input(&e);
    let e = anyhow::Error::new(e);
    if bad { e.context(Exit::BadInput) } else { e }
}

fn main() {
    // SAFETY: first thing in main, before this process starts any thread
    unsafe { bridge::prefer_runtime_threads() };
    let cli = Cli::parse();
    // Hidden parse-only switch for `tests/docs.rs`, which checks that every `qfleet …` command
    // quoted in the docs still parses: with QFLEET_PARSE_ONLY=1 the arguments are parsed exactly
    // as usual (a parse error still exits 2, `--help` still prints), then nothing is run.
    if std::env::var_os("QFLEET_PARSE_ONLY").is_some_and(|v| v == "1") {
        std::process::exit(Exit::Ok.code());
    }
    let result = match cli.command {
        Command::Learn(c) => c.run(),
        Command::Replicate(c) => c.run(),
        Command::Run(c) => c.run(),
        Command::Clean(c) => c.run(),
        Command::Bench(c) => c.run(),
        Command::Experiment(c) => c.run(),
        Command::Sweep(c) => c.run(),
        Command::Eval(c) => c.run(),
        Command::Topic(c) => c.run(),
        Command::Replay(c) => c.run(),
        Command::Join(c) => c.run(),
    };
    let code = match result {
        Ok(()) => Exit::Ok,
        Err(e) => {
            term::warn(&format!("error: {}", report(&e)));
            e.downcast_ref::<Exit>().copied().unwrap_or(Exit::Failure)
        }
    };
    std::process::exit(code.code());
}

/// The error and its causes on one line ([`launcher::exit::one_line`]).
fn report(e: &anyhow::Error) -> String {
    launcher::exit::one_line(e.chain().map(ToString::to_string))
}

#[cfg(test)]
mod tests {
    use super::{Exit, report};
    use anyhow::Context;

    #[test]
    fn an_exit_class_sets_the_code_and_is_not_printed() {
        let e = Err::<(), _>(anyhow::anyhow!("--robots 0"))
            .context(Exit::BadInput)
            .context("checking the command line")
            .unwrap_err();
        assert_eq!(e.downcast_ref::<Exit>(), Some(&Exit::BadInput));
        assert_eq!(report(&e), "checking the command line: --robots 0");
    }
}
