//! Command-line options that several qfleet processes share: which map and task, every
//! learner parameter, and the robots' `--pace` ([`pace`]). `qfleet learn`, `qfleet run`, the
//! robot-agent and the coordinator all parse them the same way, and the launcher forwards them
//! to the processes it starts with [`MapArgs::to_cli`] and [`LearnerArgs::to_cli`].
//!
//! Not here: anything about the bus or the fleet.

pub mod manifest;
pub mod pace;
pub mod phases;
pub mod share_mode;
pub mod world;

pub use manifest::{Manifest, ManifestError, Plan, load_manifest, parse_manifest};
pub use pace::{pace_cli, parse_pace};
pub use share_mode::{ShareMode, ValueBound};
pub use world::{Lifelong, LifelongFileError, World, WorldArgs, load_lorr, local_robots};

use clap::Args;
use planner::map::{self, MapError};
use planner::task::{self, Task, TaskError};
use planner::{
    Cell, ConfigError, EpsilonReading, LearnerConfig, LearnerKind, PolicyConfig, PseudoConfig,
    QScale, Rewards, Schedule,
};
use std::path::PathBuf;

/// Why map options could not be turned into a task.
#[derive(Debug, thiserror::Error)]
pub enum ArgsError {
    /// The map file or built-in name is bad.
    #[error(transparent)]
    Map(#[from] MapError),
    /// Start, goal or scenario do not fit the map.
    #[error(transparent)]
    Task(#[from] TaskError),
    /// `--scen-index` without `--scen`, or a scenario with `--start`/`--goal`.
    #[error("{0}")]
    Conflict(&'static str),
    /// `--robots`, `--agents` and `--remote-robots` do not make one fleet.
    #[error("{0}")]
    Fleet(String),
    /// A learner parameter is out of range.
    #[error("invalid learner option: {0}")]
    Learner(#[from] ConfigError),
    /// The starts and goals of a shared grid do not make an instance (two robots on one start,
    /// a goal walled in, too few scenario lines, …).
    #[error("the shared grid's instance: {0}")]
    Instance(#[from] mapf::InstanceError),
    /// A lifelong problem file (`--lorr`) cannot be read or is not valid.
    #[error("{file}: {source}")]
    Lifelong {
        /// The file at fault.
        file: String,
        /// What is wrong with it (boxed: the problem's errors are large and rare).
        #[source]
        source: Box<LifelongFileError>,
    },
    /// `--robots`/`--agents` that disagree with a lifelong problem's team.
    #[error(
        "--robots/--agents {asked} disagree with the problem's teamSize {team}: a lifelong run \
         has one robot per start of the problem (give neither)"
    )]
    LifelongFleet {
        /// What the options asked for.
        asked: u32,
        /// The problem's team size.
        team: u32,
    },
    /// A shared grid's agent starts on its goal: its robot would have no path to learn.
    #[error(
        "the shared grid's instance: agent {agent} starts on its goal {cell}; a robot learns a \
         path from its start to its goal, so every agent needs a goal elsewhere (line {agent} of \
         --scen)"
    )]
    StartIsGoal {
        /// The agent (scenario line).
        agent: usize,
        /// Its start and goal.
        cell: Cell,
    },
}

fn cell(s: &str) -> Result<Cell, String> {
    task::parse_cell(s).map_err(|e| e.to_string())
}

/// A duration option given in seconds (`--grace`, `--time-limit`, `topic --wait`): `flag`
/// names it in the refusal of a negative or non-finite value.
pub fn seconds(flag: &str, v: f64) -> Result<std::time::Duration, String> {
    std::time::Duration::try_from_secs_f64(v)
        .map_err(|_| format!("{flag} must be a number of seconds >= 0, got {v}"))
}

/// The value parser of a setting written as one word (`--wait hybrid`, `--merge max`,
/// `--share both`): the words of [`report::Word`], each with its help line.
pub fn choice<T: report::Word + Send + Sync>() -> impl clap::builder::TypedValueParser<Value = T> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    PossibleValuesParser::new(
        T::ALL
            .iter()
            .map(|v| PossibleValue::new(v.word()).help(v.help())),
    )
    .try_map(|w| T::from_word(&w).ok_or("not one of the words"))
}

/// A file name as the value of an option: one that begins with `-` would be read as an option,
/// so it gets `./` in front (the same file).
pub fn value_word(name: &str) -> String {
    if name.starts_with('-') {
        format!("./{name}")
    } else {
        name.to_string()
    }
}

/// The map a run uses when none is named (`--map`).
pub const DEFAULT_MAP: &str = "builtin:paper-20";

/// Which map, and which start and goal on it.
#[derive(Debug, Clone, PartialEq, Args)]
pub struct MapArgs {
    /// Map: `builtin:paper-10|paper-20|paper-30`, `suite:FAMILY-SIZE-INDEX` (a generated map of
    /// `qfleet eval`'s suite, e.g. `suite:rooms-64-3`), an ASCII map file, or a MovingAI `.map`.
    #[arg(long, default_value = DEFAULT_MAP)]
    pub map: String,
    /// Start cell `X,Y` (x = column, y = row, from the top-left); overrides the map's `S`.
    #[arg(long, value_parser = cell)]
    pub start: Option<Cell>,
    /// Goal cell `X,Y`; overrides the map's first `G`.
    #[arg(long, value_parser = cell)]
    pub goal: Option<Cell>,
    /// MovingAI scenario file to take start and goal from.
    #[arg(long)]
    pub scen: Option<PathBuf>,
    /// Line of the scenario file to use (0 = first scenario line).
    #[arg(long, requires = "scen")]
    pub scen_index: Option<usize>,
}

impl MapArgs {
    /// Loads the map and resolves start and goal into a checked task with its BFS optimum.
    pub fn task(&self) -> Result<Task, ArgsError> {
        let m = map::load_map(&self.map)?;
        match &self.scen {
            Some(path) => {
                if self.start.is_some() || self.goal.is_some() {
                    return Err(ArgsError::Conflict(
                        "--scen picks start and goal; do not also give --start or --goal",
                    ));
                }
                let scen = map::load_scen(path)?;
                Ok(task::resolve_scenario(
                    &m,
                    &scen,
                    self.scen_index.unwrap_or(0),
                )?)
            }
            None => Ok(task::resolve_task(&m, self.start, self.goal)?),
        }
    }

    /// The options as command-line words, to forward to a child process.
    pub fn to_cli(&self) -> Vec<String> {
        let mut v = vec!["--map".into(), value_word(&self.map)];
        if let Some(c) = self.start {
            v.extend(["--start".into(), c.to_string()]);
        }
        if let Some(c) = self.goal {
            v.extend(["--goal".into(), c.to_string()]);
        }
        if let Some(p) = &self.scen {
            v.extend(["--scen".into(), value_word(&p.display().to_string())]);
        }
        if let Some(i) = self.scen_index {
            v.extend(["--scen-index".into(), i.to_string()]);
        }
        v
    }
}

/// Every learner parameter; unset ones take the chosen learner's defaults.
#[derive(Debug, Clone, PartialEq, Args)]
pub struct LearnerArgs {
    /// Which learner: `planning` (ε-greedy with optimism and Dyna sweeps, chosen on the map
    /// suite; the default everywhere), or the paper's `traditional` ε-greedy or `improved`
    /// dynamic softmax. Planning makes no pseudo targets, so `--share discoveries` relays
    /// nothing with it; hint sharing defaults to the `min` rules that fit its upper bounds.
    #[arg(long, default_value = "planning")]
    pub learner: LearnerKind,
    /// Number of episodes N (also the horizon of the dynamic schedule).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..))]
    pub episodes: u32,
    /// Seed of the learner's random source.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Learning rate α in (0, 1].
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    pub alpha: f32,
    /// Discount γ in [0, 1) (default: 0.6 for the paper's learners, 0.99 for planning).
    #[arg(long, allow_negative_numbers = true)]
    pub gamma: Option<f32>,
    /// ε-greedy learners (traditional, planning): ε (defaults 0.8 and 0.05).
    #[arg(long, allow_negative_numbers = true)]
    pub epsilon: Option<f32>,
    /// ε-greedy learners: whether ε is the greedy or the random-action probability (defaults:
    /// greedy for traditional, random for planning).
    #[arg(long)]
    pub epsilon_reading: Option<EpsilonReading>,
    /// Improved learner: how ε(k) enters the softmax: literal (β = ε), temperature (β = 1/ε) or explore.
    #[arg(long)]
    pub schedule: Option<Schedule>,
    /// Improved learner: scale of Q the softmax sees: raw, range or log.
    #[arg(long)]
    pub q_scale: Option<QScale>,
    /// Improved learner, log scale: moves behind the best that a zero Q counts as.
    #[arg(long)]
    pub horizon: Option<f32>,
    /// Improved learner: turn the multi-target search (pseudo targets) off.
    #[arg(long)]
    pub no_pseudo: bool,
    /// Pseudo targets: radius R (Manhattan) around the goal.
    #[arg(long)]
    pub radius: Option<u32>,
    /// Pseudo targets: value scale δ in (0, 1].
    #[arg(long)]
    pub delta: Option<f32>,
    /// Pseudo targets: removed after this fraction of the episodes, in [0, 1].
    #[arg(long)]
    pub remove_at: Option<f32>,
    /// Initial value of untried actions (optimism; planning default 1, the others 0).
    #[arg(long, allow_negative_numbers = true)]
    pub optimistic: Option<f32>,
    /// Sweeps over every transition seen, after each episode (planning default 3, others 0).
    #[arg(long)]
    pub sweeps: Option<u32>,
    /// Sweeps also every this many steps inside an episode, while the model grows (0 = after
    /// episodes only; planning default 1024, others 0).
    #[arg(long)]
    pub sweep_every: Option<u32>,
    /// Backward replay of each episode: `true` or `false` (planning default true, others false).
    #[arg(long)]
    pub replay: Option<bool>,
    /// Step cap per episode (0 = 50 × free cells, at least 10 000).
    #[arg(long, default_value_t = 0)]
    pub max_steps: u32,
    /// Reward for reaching the goal.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub reward_goal: f32,
    /// Reward for bumping into an obstacle or the border.
    #[arg(long, default_value_t = -1.0, allow_negative_numbers = true)]
    pub reward_collision: f32,
    /// Reward for any other move.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub reward_step: f32,
}

impl LearnerArgs {
    /// The learner configuration these options describe, validated.
    pub fn config(&self) -> Result<LearnerConfig, ArgsError> {
        let mut cfg = LearnerConfig::of_kind(self.learner, self.episodes, self.seed);
        cfg.alpha = self.alpha;
        cfg.gamma = self.gamma.unwrap_or(cfg.gamma);
        if let Some(v) = self.optimistic {
            cfg.extras.optimistic = Some(v);
        }
        if let Some(k) = self.sweeps {
            cfg.extras.sweeps = k;
        }
        if let Some(k) = self.sweep_every {
            cfg.extras.sweep_every = k;
        }
        if let Some(r) = self.replay {
            cfg.extras.replay = r;
        }
        cfg.max_steps = self.max_steps;
        cfg.rewards = Rewards {
            goal: self.reward_goal,
            collision: self.reward_collision,
            step: self.reward_step,
        };
        cfg.policy = match cfg.policy {
            PolicyConfig::EpsilonGreedy { epsilon, reading } => PolicyConfig::EpsilonGreedy {
                epsilon: self.epsilon.unwrap_or(epsilon),
                reading: self.epsilon_reading.unwrap_or(reading),
            },
            PolicyConfig::Softmax {
                schedule,
                scale,
                horizon,
            } => PolicyConfig::Softmax {
                schedule: self.schedule.unwrap_or(schedule),
                scale: self.q_scale.unwrap_or(scale),
                horizon: self.horizon.unwrap_or(horizon),
            },
        };
        if self.no_pseudo {
            cfg.pseudo = None;
        } else if self.radius.is_some() || self.delta.is_some() || self.remove_at.is_some() {
            let d = cfg.pseudo.unwrap_or_default();
            cfg.pseudo = Some(PseudoConfig {
                radius: self.radius.unwrap_or(d.radius),
                delta: self.delta.unwrap_or(d.delta),
                remove_at: self.remove_at.unwrap_or(d.remove_at),
            });
        }
        cfg.validate()?;
        Ok(cfg)
    }

    /// The options as command-line words, to forward to a child process (seed excluded: each
    /// process gets its own).
    pub fn to_cli(&self) -> Vec<String> {
        let mut v: Vec<String> = vec![
            "--learner".into(),
            self.learner.to_string(),
            "--episodes".into(),
            self.episodes.to_string(),
            "--alpha".into(),
            self.alpha.to_string(),
            "--max-steps".into(),
            self.max_steps.to_string(),
            "--reward-goal".into(),
            self.reward_goal.to_string(),
            "--reward-collision".into(),
            self.reward_collision.to_string(),
            "--reward-step".into(),
            self.reward_step.to_string(),
        ];
        let mut opt = |name: &str, val: Option<String>| {
            if let Some(val) = val {
                v.push(name.into());
                v.push(val);
            }
        };
        opt("--gamma", self.gamma.map(|x| x.to_string()));
        opt("--optimistic", self.optimistic.map(|x| x.to_string()));
        opt("--sweeps", self.sweeps.map(|x| x.to_string()));
        opt("--sweep-every", self.sweep_every.map(|x| x.to_string()));
        opt("--replay", self.replay.map(|x| x.to_string()));
        opt("--epsilon", self.epsilon.map(|x| x.to_string()));
        opt(
            "--epsilon-reading",
            self.epsilon_reading.map(|x| x.to_string()),
        );
        opt("--schedule", self.schedule.map(|x| x.to_string()));
        opt("--q-scale", self.q_scale.map(|x| x.to_string()));
        opt("--horizon", self.horizon.map(|x| x.to_string()));
        opt("--radius", self.radius.map(|x| x.to_string()));
        opt("--delta", self.delta.map(|x| x.to_string()));
        opt("--remove-at", self.remove_at.map(|x| x.to_string()));
        if self.no_pseudo {
            v.push("--no-pseudo".into());
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_are_finite_and_not_negative() {
        assert_eq!(seconds("--grace", 0.25).unwrap().as_millis(), 250);
        let e = seconds("--time-limit", -2.0).unwrap_err();
        assert_eq!(e, "--time-limit must be a number of seconds >= 0, got -2");
        assert!(seconds("--wait", f64::INFINITY).is_err());
    }
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        map: MapArgs,
        #[command(flatten)]
        learner: LearnerArgs,
    }

    #[test]
    fn round_trips_through_the_command_line() {
        let cli = Cli::try_parse_from([
            "x",
            "--map",
            "builtin:paper-10",
            "--goal",
            "9,8",
            "--learner",
            "improved",
            "--schedule",
            "literal",
            "--radius",
            "2",
            "--alpha",
            "0.5",
            "--gamma",
            "0.7",
        ])
        .unwrap();
        let mut words = vec!["x".to_string()];
        words.extend(cli.map.to_cli());
        words.extend(cli.learner.to_cli());
        let again = Cli::try_parse_from(words).unwrap();
        assert_eq!(
            cli.learner.config().unwrap(),
            again.learner.config().unwrap()
        );
        assert_eq!(again.map.goal, Some(Cell::new(9, 8)));
        let t = again.map.task().unwrap();
        assert_eq!(t.goal, Cell::new(9, 8));
        let cli = Cli::try_parse_from([
            "x",
            "--learner",
            "planning",
            "--sweeps",
            "5",
            "--replay",
            "false",
            "--optimistic",
            "0.5",
        ])
        .unwrap();
        let mut words = vec!["x".to_string()];
        words.extend(cli.learner.to_cli());
        let again = Cli::try_parse_from(words).unwrap();
        let cfg = again.learner.config().unwrap();
        assert_eq!(cfg, cli.learner.config().unwrap());
        assert_eq!(cfg.extras.sweeps, 5);
        assert!(!cfg.extras.replay);
        assert_eq!(cfg.extras.optimistic, Some(0.5));
        assert_eq!(cfg.gamma, 0.99, "planning's own gamma when none is given");
    }

    #[test]
    fn the_default_learner_is_planning_and_the_papers_are_selectable() {
        let cli = Cli::try_parse_from(["x"]).unwrap();
        let cfg = cli.learner.config().unwrap();
        assert_eq!(cfg, LearnerConfig::planning(1000, 1));
        assert_eq!(ValueBound::of(&cfg), ValueBound::Upper);
        let cli = Cli::try_parse_from(["x", "--learner", "improved"]).unwrap();
        assert_eq!(
            cli.learner.config().unwrap(),
            LearnerConfig::improved(1000, 1)
        );
        assert_eq!(
            ValueBound::of(&cli.learner.config().unwrap()),
            ValueBound::Lower
        );
    }

    #[test]
    fn bad_values_are_errors_not_panics() {
        assert!(Cli::try_parse_from(["x", "--episodes", "0"]).is_err());
        assert!(Cli::try_parse_from(["x", "--episodes", "-3"]).is_err());
        assert!(Cli::try_parse_from(["x", "--goal", "1;2"]).is_err());
        let cli = Cli::try_parse_from(["x", "--alpha", "1.5"]).unwrap();
        assert!(matches!(
            cli.learner.config(),
            Err(ArgsError::Learner(ConfigError::Alpha(_)))
        ));
        let cli = Cli::try_parse_from(["x", "--gamma", "1"]).unwrap();
        assert!(cli.learner.config().is_err());
        let cli = Cli::try_parse_from(["x", "--map", "/nonexistent/map.txt"]).unwrap();
        assert!(cli.map.task().is_err());
    }
}
