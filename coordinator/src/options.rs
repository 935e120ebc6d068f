//! The coordinator's command-line options, its wait strategies and its error type.
//!
//! # Wait strategies
//! - `spin`: poll every inbox in a tight loop (lowest latency, one core busy all the time).
//! - `event`: block on an iceoryx2 `WaitSet` over the inboxes' wake listeners (robots notify
//!   after each hint batch, discovery, report and their final state); no core burnt while idle,
//!   but every wakeup costs a cross-CPU wakeup (tens of µs on a VM).
//! - `hybrid` (default): after any message, keep spinning for `--spin-us`, then block like
//!   `event`. Bursts are served at spin latency, idle time costs nothing.
//!
//! All three also wake every 50 ms for the periodic work: progress lines, the end-of-run check.
//!
//! A coordinator beside a bridge hub (robots on other hosts) spins [`BRIDGED_SPIN_US`] instead
//! of [`DEFAULT_SPIN_US`] ([`spin_us_for`]): the hub forwards every remote message through the
//! coordinator's host, and on a 2-core machine a coordinator spinning 200 µs after each one
//! kept the hub's thread off the CPU it needed to answer.

use std::path::PathBuf;
use std::time::Duration;

use bus::{BusConfig, BusError};
use clap::Args;
use qfleet_args::{MapArgs, WorldArgs};

use crate::merge::MergeRule;

pub use report::run::WaitStrategy;

/// Hybrid wait: µs the coordinator spins after the last message when all robots are local
/// (a local loop is answered at spin latency, ~2 µs, instead of an event wakeup).
pub const DEFAULT_SPIN_US: u64 = 200;

/// Hybrid wait with robots on other hosts: no spinning, the coordinator blocks at once.
///
/// Measured with `qfleet bench --cross-host --only xhost-loop --spin-us S` (2 vCPU, two
/// network namespaces, 2026-12-02): update-loop p50 76–89 µs at S = 0, 122 µs at 20, 300 µs
/// at 200, against a Zenoh ping-pong floor of 55–61 µs (BENCHMARKS.md "Across machines").
pub const BRIDGED_SPIN_US: u64 = 0;

/// The hybrid spin of a run's coordinator: `asked` if the user chose one, else
/// [`BRIDGED_SPIN_US`] when robots join from other hosts and [`DEFAULT_SPIN_US`] otherwise.
pub fn spin_us_for(asked: Option<u64>, remote_robots: u32) -> u64 {
    asked.unwrap_or(if remote_robots > 0 {
        BRIDGED_SPIN_US
    } else {
        DEFAULT_SPIN_US
    })
}

/// Every option of the coordinator process.
#[derive(Debug, Clone, Args)]
pub struct CoordArgs {
    /// Run id shared by all processes of the run.
    #[arg(long)]
    pub run_id: String,
    /// Fleet size: robot ids `0..robots`.
    #[arg(long, default_value_t = 4)]
    pub robots: u32,
    /// Map and goal of the run (robots on another map are refused).
    #[command(flatten)]
    pub map: MapArgs,
    /// One grid for every robot (`--world shared`: robot i's start and goal are line i of
    /// `--scen`) or a copy each.
    #[command(flatten)]
    pub world: WorldArgs,
    /// How to wait for messages.
    #[arg(long, value_enum, default_value_t = WaitStrategy::Hybrid)]
    pub wait: WaitStrategy,
    /// Hybrid: microseconds to keep spinning after the last message before blocking
    /// (`qfleet run` passes 0 when robots join from other hosts, see [`spin_us_for`]).
    #[arg(long, default_value_t = DEFAULT_SPIN_US)]
    pub spin_us: u64,
    /// How Q hints are merged into the fleet table (`qfleet run` and `experiment` always pass
    /// the rule that fits the learner, `min` for planning; this default is for a coordinator
    /// started by hand with the paper's learners).
    #[arg(long, value_enum, default_value_t = MergeRule::Max)]
    pub merge: MergeRule,
    /// Directory for result.json and the .hgrm latency files.
    #[arg(long)]
    pub out: PathBuf,
    /// Seconds to wait for every robot to register, and for reports after `Stop`.
    #[arg(long, default_value_t = 30.0)]
    pub timeout: f64,
    /// Print `progress <episodes done> <total> <p50 ns> <p99 ns>` lines on stdout every 100 ms.
    #[arg(long)]
    pub progress: bool,
    /// Hint batches buffered per robot (latest-wins).
    #[arg(long, default_value_t = 64)]
    pub hint_buffer: usize,
    /// Merged batches buffered per robot (latest-wins); 0 = sized from the fleet within a
    /// shared-memory budget (`bus::merged_buffer_for`: 512 at 4 robots, 20 at 256).
    #[arg(long, default_value_t = 0)]
    pub merged_buffer: usize,
    /// Heartbeat deadline: a running robot silent this long (ms) is reported hung.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..))]
    pub hang_ms: u64,
    /// Restarts per robot the launcher may make: the end of the run waits (up to `--timeout`)
    /// for a lost robot to come back while it has restarts left.
    #[arg(long, default_value_t = 0)]
    pub restarts: u32,
    /// Run an experiment: the resolved plan `qfleet experiment` wrote (`plan.json`); the fleet
    /// size, map, goals, phases and timeout come from it (`--robots`, the map options and
    /// `--timeout` are not used). Its progress is kept in `experiment-checkpoint.json` in `--out`, and a
    /// coordinator started again with the same run id resumes from it.
    #[arg(long, value_name = "FILE.json")]
    pub plan: Option<PathBuf>,
}

/// Why the coordinator failed.
#[derive(Debug, thiserror::Error)]
pub enum CoordError {
    /// An option value out of range.
    #[error("{option} must be {must}, got {value}")]
    Option {
        /// The option, e.g. `--timeout`.
        option: &'static str,
        /// What it must be.
        must: &'static str,
        /// What it was.
        value: String,
    },
    /// The map, scenario or learner options could not be loaded.
    #[error("loading the map, task or learner options")]
    Task(#[from] qfleet_args::ArgsError),
    /// The experiment plan (`--plan`) cannot be read or does not fit together.
    #[error("the experiment plan")]
    Plan(#[source] Box<crate::plan::PlanError>),
    /// The map is larger than the wire format's 65535 cells a side.
    #[error("maps larger than 65535 cells a side are not supported ({width}x{height})")]
    MapTooLarge {
        /// Width in cells.
        width: usize,
        /// Height in cells.
        height: usize,
    },
    /// Stopped by a signal before the run started (nothing to report).
    #[error("interrupted while {0}")]
    Interrupted(&'static str),
    /// A robot was refused at registration (the run cannot go on as asked).
    #[error("refused robot {robot_id}: {reason}")]
    Refused {
        /// The robot.
        robot_id: u32,
        /// Why.
        reason: String,
    },
    /// A bus failure.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// A helper thread could not be started.
    #[error("cannot start the {what} thread")]
    Thread {
        /// Which thread.
        what: &'static str,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// Writing a latency file failed.
    #[error("writing a latency file")]
    Hist(#[from] report::HistError),
    /// Writing the result failed (the error names the file; a full disk says so).
    #[error(transparent)]
    Write(#[from] report::WriteError),
    /// The shared grid's resolver refused a step (a bug: the driver gives one intent slot per
    /// robot).
    #[error("the shared grid: {0}")]
    Grid(String),
}

impl CoordError {
    /// The process exit code for this error: 2 bad input, 130 interrupted, 3 a robot refused,
    /// 1 any other failure.
    pub fn exit_code(&self) -> u8 {
        match self {
            CoordError::Option { .. }
            | CoordError::Task(_)
            | CoordError::Plan(_)
            | CoordError::MapTooLarge { .. }
            | CoordError::Bus(BusError::OpenFiles { .. }) => 2,
            CoordError::Interrupted(_) => 130,
            CoordError::Refused { .. } => 3,
            _ => 1,
        }
    }
}

/// The bus configuration of a run or experiment of `robots` robots with `args`' buffers.
pub(crate) fn bus_config(args: &CoordArgs, robots: u32) -> Result<BusConfig, CoordError> {
    let mut cfg = BusConfig::new(args.run_id.clone(), robots)?;
    cfg.hint_buffer = args.hint_buffer;
    cfg.merged_buffer = if args.merged_buffer == 0 {
        bus::merged_buffer_for(robots)
    } else {
        args.merged_buffer
    };
    // control is the coordinator's only lossless output; a robot that stopped draining it
    // (SIGSTOP, or killed and not cleaned up yet) must not stall the whole run for long
    cfg.send_timeout = Duration::from_secs(1);
    cfg.validate()?;
    Ok(cfg)
}

/// A positive, finite number of seconds as a `Duration`.
pub(crate) fn secs(s: f64, option: &'static str) -> Result<Duration, CoordError> {
    Duration::try_from_secs_f64(s)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| CoordError::Option {
            option,
            must: "a positive number of seconds",
            value: s.to_string(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_coordinator_beside_a_hub_does_not_spin_unless_asked() {
        assert_eq!(spin_us_for(None, 0), DEFAULT_SPIN_US);
        assert_eq!(spin_us_for(None, 4), BRIDGED_SPIN_US);
        assert_eq!(spin_us_for(Some(50), 4), 50);
        assert_eq!(spin_us_for(Some(0), 0), 0);
    }
}
