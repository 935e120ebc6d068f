//! Every option of the robot-agent process (`robot-agent --help`).

use std::ffi::OsString;
use std::path::PathBuf;

use clap::{Args, Parser};
use qfleet_args::{LearnerArgs, MapArgs};

use crate::Words;
use crate::share::ShareArgs;

/// Seconds a robot waits for the coordinator at start-up and for its next phase (`--timeout`).
pub const DEFAULT_TIMEOUT_S: f64 = 30.0;

/// Every option of the robot-agent process.
#[derive(Debug, Clone, PartialEq, Args)]
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
    #[arg(long, default_value_t = DEFAULT_TIMEOUT_S)]
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
    /// The robot moves on a shared grid after learning (`--world shared`): it sends its answer
    /// to the execution's first tick while it waits for `Execute`, so that tick waits for
    /// nobody.
    #[arg(long)]
    pub shared_grid: bool,
    /// Each phase is learned from the goal of the phase before it (the first from the map's
    /// start): a lifelong robot walks from goal to goal, so it learns each goal from where it
    /// will stand when the goal is dealt.
    #[arg(long)]
    pub chain_goals: bool,
}

/// The robot-agent's command line as clap reads it.
#[derive(Debug, Parser)]
#[command(name = "robot-agent")]
struct AgentLine {
    #[command(flatten)]
    args: AgentArgs,
}

impl AgentArgs {
    /// The options of robot `robot_id` of a fleet of `robots` in run `run_id` on `map`, learning
    /// with `learner` and sharing by `share`; the rest at their defaults.
    pub fn new(
        run_id: impl Into<String>,
        robot_id: u32,
        robots: u32,
        map: MapArgs,
        learner: LearnerArgs,
        share: ShareArgs,
    ) -> Self {
        AgentArgs {
            run_id: run_id.into(),
            robot_id,
            robots,
            map,
            learner,
            share,
            out: None,
            timeout: DEFAULT_TIMEOUT_S,
            schema_version_override: None,
            stop_at_optimum: false,
            pace: None,
            shared_grid: false,
            chain_goals: false,
        }
    }

    /// The options as the robot-agent's command-line words (every option, defaults included).
    pub fn to_args(&self) -> Vec<OsString> {
        let mut w = Words::default();
        w.opt("--run-id", &self.run_id)
            .opt("--robot-id", self.robot_id.to_string())
            .opt("--robots", self.robots.to_string())
            .extend(self.map.to_cli())
            .extend(self.learner.to_cli())
            .opt("--seed", self.learner.seed.to_string())
            .extend(self.share.to_cli())
            .opt("--timeout", self.timeout.to_string())
            .maybe("--schema-version-override", self.schema_version_override)
            .flag("--stop-at-optimum", self.stop_at_optimum)
            .flag("--shared-grid", self.shared_grid)
            .flag("--chain-goals", self.chain_goals)
            .extend(qfleet_args::pace_cli(self.pace));
        if let Some(out) = &self.out {
            w.path("--out", out);
        }
        w.done()
    }

    /// Reads the options from command-line words (without the program name), as the process
    /// does.
    pub fn try_parse_args<I, T>(words: I) -> Result<Self, clap::Error>
    where
        I: IntoIterator<Item = T>,
        T: Into<OsString> + Clone,
    {
        crate::parse::<AgentLine, _, _>(words).map(|c| c.args)
    }

    /// Robot `robot` of a lifelong run on `l`: it starts on its start, and learns each goal it
    /// is dealt from the one before (`--chain-goals`) until its greedy path is optimal.
    pub fn lifelong(&mut self, l: &qfleet_args::Lifelong, robot: u32) {
        self.map = l.map_args(robot as usize);
        self.chain_goals = true;
        self.stop_at_optimum = true;
    }

    /// The options of robot `robot_id` of run `run_id` as another host sent them (`words`,
    /// `qfleet join`): read as the process reads them, refused when an option is unknown, a
    /// value wrong, or they name another run or robot than the slot's; they write into `out`,
    /// whatever the other host asked. The refusal is text from outside, escaped.
    pub fn for_slot(
        words: &[String],
        run_id: &str,
        robot_id: u32,
        out: &std::path::Path,
    ) -> Result<Self, String> {
        let mut a = Self::try_parse_args(words).map_err(|e| {
            format!(
                "host A sent options robot {robot_id} does not take: {}",
                report::escape(e.to_string().lines().next().unwrap_or_default())
            )
        })?;
        if a.run_id != run_id || a.robot_id != robot_id {
            return Err(format!(
                "host A's options for robot {robot_id} name run {} robot {}",
                report::escape(&a.run_id),
                a.robot_id
            ));
        }
        a.out = Some(out.to_path_buf());
        Ok(a)
    }

    /// The clap command of these options (for help texts and the contract's tests).
    pub fn command() -> clap::Command {
        <AgentLine as clap::CommandFactory>::command()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::share::ApplyRule;
    use proptest::prelude::*;
    use qfleet_args::ShareMode;

    fn minimal() -> AgentArgs {
        AgentArgs::try_parse_args(["--run-id", "r", "--robot-id", "0"]).unwrap()
    }

    #[test]
    fn new_holds_the_defaults_the_process_parses() {
        let d = minimal();
        let a = AgentArgs::new("r", 0, 4, d.map.clone(), d.learner.clone(), d.share.clone());
        assert_eq!(a, d);
        assert_eq!(d.share, ShareArgs::default());
    }

    /// A field added to [`AgentArgs`] (or its flattened groups) without its words fails here.
    #[test]
    fn to_args_writes_every_option_the_process_accepts() {
        let mut a = minimal();
        a.map.scen = Some("s.scen".into());
        a.map.scen_index = Some(1);
        a.map.start = Some(planner::Cell::new(0, 0));
        a.map.goal = Some(planner::Cell::new(1, 1));
        let l = &mut a.learner;
        l.gamma = Some(0.5);
        l.epsilon = Some(0.5);
        l.epsilon_reading = Some(planner::EpsilonReading::Random);
        l.schedule = Some(planner::Schedule::Literal);
        l.q_scale = Some(planner::QScale::Raw);
        l.horizon = Some(3.0);
        l.no_pseudo = true;
        l.radius = Some(2);
        l.delta = Some(0.1);
        l.remove_at = Some(0.5);
        l.optimistic = Some(1.0);
        l.sweeps = Some(3);
        l.sweep_every = Some(2);
        l.replay = Some(true);
        a.share.apply = Some(ApplyRule::Blend);
        a.out = Some("/o".into());
        a.schema_version_override = Some(9);
        a.stop_at_optimum = true;
        a.pace = Some(5.0);
        a.shared_grid = true;
        a.chain_goals = true;
        let words: Vec<String> = a
            .to_args()
            .iter()
            .map(|w| w.to_string_lossy().into_owned())
            .collect();
        for long in crate::long_options(&AgentArgs::command()) {
            if long == "--help" || long == "--version" {
                continue;
            }
            assert!(words.contains(&long), "to_args never writes {long}");
        }
        assert_eq!(AgentArgs::try_parse_args(a.to_args()).unwrap(), a);
    }

    fn agent() -> impl Strategy<Value = AgentArgs> {
        (
            (
                "[a-z0-9][a-z0-9-]{0,15}",
                0u32..256,
                1u32..=256,
                any::<u64>(),
            ),
            (
                1u32..100_000,
                -10.0f32..10.0,
                proptest::option::of(0.0f32..1.0),
                proptest::option::of(0.0f32..1.0),
                any::<bool>(),
                proptest::option::of(1u32..10),
            ),
            (
                prop_oneof![
                    Just(ShareMode::None),
                    Just(ShareMode::Discoveries),
                    Just(ShareMode::Hints),
                    Just(ShareMode::Both)
                ],
                proptest::option::of(prop_oneof![
                    Just(ApplyRule::Max),
                    Just(ApplyRule::Blend),
                    Just(ApplyRule::Latest),
                    Just(ApplyRule::Min)
                ]),
                1u32..10_000,
                1u32..=256,
                0.0f32..1.0,
            ),
            (
                proptest::option::of("/[a-z/ ._-]{1,20}"),
                0.001f64..1e6,
                any::<bool>(),
                proptest::option::of(1.0f64..1e7),
            ),
        )
            .prop_map(
                |(
                    (run_id, robot_id, robots, seed),
                    (episodes, alpha, gamma, epsilon, no_pseudo, sweeps),
                    (share, apply, every, hint_batch, min_change),
                    (out, timeout, stop, pace),
                )| {
                    let mut a = minimal();
                    a.run_id = run_id;
                    a.robot_id = robot_id;
                    a.robots = robots;
                    a.learner.seed = seed;
                    a.learner.episodes = episodes;
                    a.learner.alpha = alpha;
                    a.learner.gamma = gamma;
                    a.learner.epsilon = epsilon;
                    a.learner.no_pseudo = no_pseudo;
                    a.learner.sweeps = sweeps;
                    a.share.share = share;
                    a.share.apply = apply;
                    a.share.state_every = every;
                    a.share.poll_every = every;
                    a.share.hint_flush_steps = every;
                    a.share.hint_batch = hint_batch;
                    a.share.hint_min_change = min_change;
                    a.out = out.map(Into::into);
                    a.timeout = timeout;
                    a.stop_at_optimum = stop;
                    a.shared_grid = !stop;
                    a.chain_goals = stop;
                    a.pace = pace;
                    a
                },
            )
    }

    proptest! {
        #[test]
        fn the_robot_reads_back_what_to_args_wrote(a in agent()) {
            let back = AgentArgs::try_parse_args(a.to_args());
            prop_assert_eq!(back.map_err(|e| e.to_string()), Ok(a));
        }
    }

    #[test]
    fn a_joined_slot_takes_only_its_own_run_and_robot() {
        let words = |run: &str, id: u32| -> Vec<String> {
            let id = id.to_string();
            ["--run-id", run, "--robot-id", &id]
                .map(String::from)
                .to_vec()
        };
        let out = std::path::Path::new("/tmp/joined");
        let a = AgentArgs::for_slot(&words("r1", 2), "r1", 2, out).unwrap();
        assert_eq!((a.robot_id, a.out.as_deref()), (2, Some(out)));
        let e = AgentArgs::for_slot(&words("r2", 2), "r1", 2, out).unwrap_err();
        assert!(e.contains("name run r2 robot 2"), "{e}");
        assert!(AgentArgs::for_slot(&words("r1", 3), "r1", 2, out).is_err());
        let mut bad = words("r1", 2);
        bad.push("--no-such-option\u{1b}".into());
        let e = AgentArgs::for_slot(&bad, "r1", 2, out).unwrap_err();
        assert!(e.contains("does not take") && !e.contains('\u{1b}'), "{e}");
    }
}
