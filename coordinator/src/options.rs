//! The coordinator's error type and the helpers that turn its options into a bus
//! configuration. The options themselves are the process contract's [`CoordArgs`] (with the
//! wait strategies documented there), so the launcher builds this process's command line from
//! the same struct it parses.

use std::time::Duration;

use bus::{BusConfig, BusError, SendError};

pub use contract::coordinator::{
    BRIDGED_SPIN_US, CoordArgs, DEFAULT_SPIN_US, MergeRule, WaitStrategy, spin_us_for,
};

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
    Plan(#[source] Box<contract::plan::PlanError>),
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
    /// 5 its files not written (the result went to the launcher on stdout: a restart would
    /// only fail the same way), 1 any other failure.
    pub fn exit_code(&self) -> u8 {
        match self {
            CoordError::Write(_) => 5,
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

/// A failed send is a bus failure to the coordinator's callers ([`BusError::Send`]); the sends
/// whose failure the coordinator tolerates match [`SendError`] before it gets here.
impl From<SendError> for CoordError {
    fn from(e: SendError) -> Self {
        CoordError::Bus(e.into())
    }
}

impl From<contract::plan::PlanError> for CoordError {
    fn from(e: contract::plan::PlanError) -> Self {
        CoordError::Plan(Box::new(e))
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
