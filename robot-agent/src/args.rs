//! Every option of the robot-agent process (`robot-agent --help`).

use std::path::PathBuf;

use clap::Args;
use qfleet_args::{LearnerArgs, MapArgs};

use crate::share::ShareArgs;

/// Every option of the robot-agent process.
#[derive(Debug, Clone, Args)]
pub struct AgentArgs {
    /// Run id shared by all processes of the run (names its services and shared memory).
    #[arg(long)]
    pub run_id: String,
    /// This robot's id, `0..robots`.
    #[arg(long)]
    pub robot_id: u32,
    /// Fleet size.
    #[arg(long, default_value_t = 4)]
    pub robots: u32,
    /// Map and task (the goal is the one learned when the coordinator assigns none).
    #[command(flatten)]
    pub map: MapArgs,
    /// Learner parameters (`--seed` is this robot's own seed; `--episodes` the episodes of a
    /// phase whose assignment names none).
    #[command(flatten)]
    pub learner: LearnerArgs,
    /// Sharing options.
    #[command(flatten)]
    pub share: ShareArgs,
    /// Directory for `robot-<id>.json`, the phase details and the robot's latency histograms.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Seconds to wait for the coordinator at start-up and for its next phase or `Stop`.
    #[arg(long, default_value_t = 30.0)]
    pub timeout: f64,
    /// Test hook: register with this schema version instead of the real one.
    #[arg(long, hide = true)]
    pub schema_version_override: Option<u32>,
    /// End a phase after the episode whose greedy path is optimal.
    #[arg(long)]
    pub stop_at_optimum: bool,
    /// Slow to this many environment steps per second (1 to 10 000 000), so that a person can
    /// follow the robot in the live view; it then also publishes its state at every pause.
    #[arg(long, value_name = "STEPS_PER_S", value_parser = qfleet_args::parse_pace)]
    pub pace: Option<f64>,
}
