//! Why a robot-agent failed, and the exit code each reason gets.

use bus::{BusError, SendError};
use planner::Cell;

/// Why a robot-agent failed.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    /// `--timeout` is not a positive number of seconds.
    #[error("--timeout must be a positive number of seconds, got {0}")]
    Timeout(f64),
    /// A sharing option is out of range.
    #[error(transparent)]
    Share(#[from] contract::ShareOptionError),
    /// The map, task or a learner option is bad.
    #[error(transparent)]
    Args(#[from] qfleet_args::ArgsError),
    /// The learner refused its configuration.
    #[error("invalid learner configuration: {0}")]
    Learner(#[from] planner::ConfigError),
    /// The map does not fit the wire format (cells are `u16` coordinates).
    #[error("maps larger than 65535 cells a side are not supported ({width}x{height})")]
    MapTooLarge {
        /// Map width.
        width: usize,
        /// Map height.
        height: usize,
    },
    /// `--robot-id` is not below `--robots`.
    #[error("--robot-id {robot_id} is outside 0..{robots} (--robots)")]
    RobotId {
        /// The id given.
        robot_id: u32,
        /// The fleet size given.
        robots: u32,
    },
    /// The goal the coordinator assigned cannot be learned on this robot's map.
    #[error("the assigned goal {cell} is unusable: {source}")]
    Goal {
        /// The goal cell.
        cell: Cell,
        /// Why.
        #[source]
        source: qfleet_args::ArgsError,
    },
    /// The coordinator refused this robot (schema version, map, id).
    #[error("{0}")]
    Refused(#[source] BusError),
    /// A signal (SIGINT/SIGTERM) stopped the robot before its coordinator started it.
    #[error("interrupted before the run started")]
    Interrupted,
    /// Any other bus failure.
    #[error(transparent)]
    Bus(BusError),
    /// Writing a result file failed (full disk, missing directory, …).
    #[error("writing results: {0}")]
    Output(#[from] report::WriteError),
    /// Writing a latency histogram failed.
    #[error("writing results: {0}")]
    Hist(#[from] report::HistError),
}

impl From<BusError> for AgentError {
    fn from(e: BusError) -> Self {
        match e {
            BusError::Refused { .. } => AgentError::Refused(e),
            BusError::Interrupted => AgentError::Interrupted,
            e => AgentError::Bus(e),
        }
    }
}

/// A failed send is a bus failure ([`AgentError::Bus`]): a send is never refused or interrupted;
/// the sends whose failure a robot survives match [`SendError`] before it gets here.
impl From<SendError> for AgentError {
    fn from(e: SendError) -> Self {
        AgentError::Bus(e.into())
    }
}

/// Exit code: the robot finished or was stopped cleanly.
pub const EXIT_OK: u8 = 0;
/// Exit code: a runtime failure (bus, coordinator gone, writing results).
pub const EXIT_FAILURE: u8 = 1;
/// Exit code: bad input (options, map, learner parameters, timeout).
pub const EXIT_BAD_INPUT: u8 = 2;
/// Exit code: the coordinator refused this robot.
pub const EXIT_REFUSED: u8 = 3;
/// Exit code: the robot's result files could not be written (its final report, if it had
/// one, reached the coordinator): a restart would learn again only to fail the same way, so
/// the launcher does not restart it.
pub const EXIT_UNWRITTEN: u8 = 5;
/// Exit code: interrupted by SIGINT/SIGTERM before the run started (128 + SIGINT).
pub const EXIT_INTERRUPTED: u8 = 130;

impl AgentError {
    /// The process exit code for this error (see the constants).
    pub fn exit_code(&self) -> u8 {
        match self {
            AgentError::Timeout(_)
            | AgentError::Share(_)
            | AgentError::Args(_)
            | AgentError::Learner(_)
            | AgentError::MapTooLarge { .. }
            | AgentError::RobotId { .. } => EXIT_BAD_INPUT,
            AgentError::Refused(_) => EXIT_REFUSED,
            AgentError::Interrupted => EXIT_INTERRUPTED,
            AgentError::Output(_) => EXIT_UNWRITTEN,
            AgentError::Goal { .. } | AgentError::Bus(_) | AgentError::Hist(_) => EXIT_FAILURE,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_input_interrupted_refused_and_failures_have_distinct_exit_codes() {
        assert_eq!(AgentError::Timeout(0.0).exit_code(), EXIT_BAD_INPUT);
        assert_eq!(
            AgentError::from(BusError::Interrupted).exit_code(),
            EXIT_INTERRUPTED
        );
        let refused = BusError::Refused {
            robot_id: 1,
            reason: "map".into(),
        };
        let e = AgentError::from(refused);
        assert_eq!(e.exit_code(), EXIT_REFUSED);
        assert!(
            std::error::Error::source(&e).is_some(),
            "keeps the bus error"
        );
        let codes = [
            EXIT_OK,
            EXIT_FAILURE,
            EXIT_BAD_INPUT,
            EXIT_REFUSED,
            EXIT_UNWRITTEN,
            EXIT_INTERRUPTED,
        ];
        for (i, a) in codes.iter().enumerate() {
            assert!(codes[i + 1..].iter().all(|b| a != b));
        }
    }
}
