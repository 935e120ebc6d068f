//! Every option of the coordinator process (`qfleet-coordinator --help`) and its wait
//! strategies.
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

use std::ffi::OsString;
use std::path::PathBuf;

use clap::{Args, Parser};
use qfleet_args::{MapArgs, WorldArgs};
pub use report::run::{MergeRule, WaitStrategy};

use crate::Words;

/// The coordinator's `--hang-ms` default: ms of silence after which a running robot is hung
/// (raised for robots on other hosts, see `bridge::listen::hang_ms`).
pub const DEFAULT_HANG_MS: u64 = 2000;

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

/// Seconds the coordinator waits for registrations and for reports after `Stop` (`--timeout`).
pub const DEFAULT_TIMEOUT_S: f64 = 30.0;

/// Every option of the coordinator process.
#[derive(Debug, Clone, PartialEq, Args)]
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
    #[arg(long, value_parser = qfleet_args::choice::<WaitStrategy>(), default_value_t = WaitStrategy::Hybrid)]
    pub wait: WaitStrategy,
    /// Hybrid: microseconds to keep spinning after the last message before blocking
    /// (`qfleet run` passes 0 when robots join from other hosts, see [`spin_us_for`]).
    #[arg(long, default_value_t = DEFAULT_SPIN_US)]
    pub spin_us: u64,
    /// How Q hints are merged into the fleet table (`qfleet run` and `experiment` always pass
    /// the rule that fits the learner, `min` for planning; this default is for a coordinator
    /// started by hand with the paper's learners).
    #[arg(long, value_parser = qfleet_args::choice::<MergeRule>(), default_value_t = MergeRule::Max)]
    pub merge: MergeRule,
    /// Directory for result.json and the .hgrm latency files.
    #[arg(long)]
    pub out: PathBuf,
    /// Seconds to wait for every robot to register, and for reports after `Stop`.
    #[arg(long, default_value_t = DEFAULT_TIMEOUT_S)]
    pub timeout: f64,
    /// Print `progress <episodes done> <total> <p50 ns> <p99 ns>` lines on stdout every 100 ms
    /// ([`crate::lines`]).
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
    #[arg(long, default_value_t = DEFAULT_HANG_MS, value_parser = clap::value_parser!(u64).range(1..))]
    pub hang_ms: u64,
    /// Restarts per robot the launcher may make: the end of the run waits (up to `--timeout`)
    /// for a lost robot to come back while it has restarts left.
    #[arg(long, default_value_t = 0)]
    pub restarts: u32,
    /// Run an experiment: the resolved plan `qfleet experiment` wrote (`plan.json`,
    /// [`crate::plan`]); the fleet size, map, goals, phases and timeout come from it
    /// (`--robots`, the map options and `--timeout` are not used). Its progress is kept in
    /// `experiment-checkpoint.json` in `--out`, and a coordinator started again with the same
    /// run id resumes from it.
    #[arg(long, value_name = "FILE.json")]
    pub plan: Option<PathBuf>,
}

/// The coordinator's command line as clap reads it (the process's `main` has its own name and
/// help around the same [`CoordArgs`]).
#[derive(Debug, Parser)]
#[command(name = "qfleet-coordinator")]
struct CoordLine {
    #[command(flatten)]
    args: CoordArgs,
}

impl CoordArgs {
    /// The options of a run `run_id` writing into `out`, every other option at its default
    /// (the same values `--help` shows; a test keeps them equal).
    pub fn new(run_id: impl Into<String>, out: impl Into<PathBuf>) -> Self {
        CoordArgs {
            run_id: run_id.into(),
            robots: 4,
            map: MapArgs {
                map: qfleet_args::DEFAULT_MAP.into(),
                start: None,
                goal: None,
                scen: None,
                scen_index: None,
            },
            world: WorldArgs::default(),
            wait: WaitStrategy::Hybrid,
            spin_us: DEFAULT_SPIN_US,
            merge: MergeRule::Max,
            out: out.into(),
            timeout: DEFAULT_TIMEOUT_S,
            progress: false,
            hint_buffer: 64,
            merged_buffer: 0,
            hang_ms: DEFAULT_HANG_MS,
            restarts: 0,
            plan: None,
        }
    }

    /// The options as the coordinator's command-line words (every option, defaults included,
    /// so the child runs exactly these values).
    pub fn to_args(&self) -> Vec<OsString> {
        let mut w = Words::default();
        w.opt("--run-id", &self.run_id)
            .opt("--robots", self.robots.to_string())
            .extend(self.map.to_cli())
            .extend(self.world.to_cli())
            .opt("--wait", self.wait.to_string())
            .opt("--spin-us", self.spin_us.to_string())
            .opt("--merge", self.merge.to_string())
            .path("--out", &self.out)
            .opt("--timeout", self.timeout.to_string())
            .flag("--progress", self.progress)
            .opt("--hint-buffer", self.hint_buffer.to_string())
            .opt("--merged-buffer", self.merged_buffer.to_string())
            .opt("--hang-ms", self.hang_ms.to_string())
            .opt("--restarts", self.restarts.to_string());
        if let Some(p) = &self.plan {
            w.path("--plan", p);
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
        crate::parse::<CoordLine, _, _>(words).map(|c| c.args)
    }

    /// The clap command of these options (for help texts and the contract's tests).
    pub fn command() -> clap::Command {
        <CoordLine as clap::CommandFactory>::command()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use qfleet_args::World;

    #[test]
    fn a_coordinator_beside_a_hub_does_not_spin_unless_asked() {
        assert_eq!(spin_us_for(None, 0), DEFAULT_SPIN_US);
        assert_eq!(spin_us_for(None, 4), BRIDGED_SPIN_US);
        assert_eq!(spin_us_for(Some(50), 4), 50);
        assert_eq!(spin_us_for(Some(0), 0), 0);
    }

    #[test]
    fn new_holds_the_defaults_the_process_parses() {
        let parsed = CoordArgs::try_parse_args(["--run-id", "r", "--out", "/o"]).unwrap();
        assert_eq!(CoordArgs::new("r", "/o"), parsed);
    }

    /// Every option the process accepts is written by `to_args` when set: a field added to
    /// [`CoordArgs`] without its words fails here.
    #[test]
    fn to_args_writes_every_option_the_process_accepts() {
        let mut a = CoordArgs::new("r", "/o");
        a.map.scen = Some("s.scen".into());
        a.map.scen_index = Some(1);
        a.map.start = Some(planner::Cell::new(0, 0));
        a.map.goal = Some(planner::Cell::new(1, 1));
        a.world.max_ticks = Some(9);
        a.world.tick_ms = 5;
        a.world.intent_horizon = 3;
        a.world.lorr = Some("p.json".into());
        a.world.ticks = 7;
        a.progress = true;
        a.plan = Some("plan.json".into());
        let words: Vec<String> = a
            .to_args()
            .iter()
            .map(|w| w.to_string_lossy().into_owned())
            .collect();
        for long in crate::long_options(&CoordArgs::command()) {
            if long == "--help" || long == "--version" {
                continue;
            }
            assert!(words.contains(&long), "to_args never writes {long}");
        }
    }

    #[test]
    fn a_file_whose_name_begins_with_a_dash_is_not_read_as_an_option() {
        let mut a = CoordArgs::new("r", "-out");
        a.map.map = "-m.map".into();
        a.plan = Some("-plan.json".into());
        let back = CoordArgs::try_parse_args(a.to_args()).unwrap();
        assert_eq!(back.out, std::path::PathBuf::from("./-out"));
        assert_eq!(back.map.map, "./-m.map");
        assert_eq!(back.plan, Some("./-plan.json".into()));
    }

    fn world() -> impl Strategy<Value = WorldArgs> {
        (
            prop_oneof![Just(World::Separate), Just(World::Shared)],
            proptest::option::of(1u32..100_000),
            0u64..=10_000,
            0u8..=8,
            proptest::option::of("[a-z][a-z0-9/._-]{0,20}\\.json"),
            1u32..=1_000_000,
        )
            .prop_map(|(world, max_ticks, tick_ms, intent_horizon, lorr, ticks)| {
                WorldArgs {
                    world,
                    max_ticks,
                    tick_ms,
                    intent_horizon,
                    lorr: lorr.map(Into::into),
                    ticks,
                }
            })
    }

    fn map() -> impl Strategy<Value = MapArgs> {
        (
            prop_oneof![
                Just("builtin:paper-20".to_string()),
                Just("suite:maze-64-3".to_string()),
                "[a-z/._][a-z/._-]{0,19}\\.map",
            ],
            proptest::option::of((0u16..500, 0u16..500)),
            proptest::option::of((0u16..500, 0u16..500)),
            proptest::option::of((
                "[a-z/._ ][a-z/._ -]{0,19}",
                proptest::option::of(0usize..1000),
            )),
        )
            .prop_map(|(map, start, goal, scen)| MapArgs {
                map,
                start: start.map(|(x, y)| planner::Cell::new(x, y)),
                goal: goal.map(|(x, y)| planner::Cell::new(x, y)),
                scen_index: scen.as_ref().and_then(|s| s.1),
                scen: scen.map(|s| s.0.into()),
            })
    }

    fn coord() -> impl Strategy<Value = CoordArgs> {
        (
            ("[a-z0-9][a-z0-9-]{0,15}", 1u32..=256, map(), world()),
            (
                prop_oneof![
                    Just(WaitStrategy::Spin),
                    Just(WaitStrategy::Event),
                    Just(WaitStrategy::Hybrid)
                ],
                0u64..10_000,
                prop_oneof![
                    Just(MergeRule::Max),
                    Just(MergeRule::Mean),
                    Just(MergeRule::Latest),
                    Just(MergeRule::Min)
                ],
                "/[a-z/ ._-]{1,20}",
                0.001f64..1e6,
                any::<bool>(),
            ),
            (
                0usize..10_000,
                0usize..10_000,
                1u64..1_000_000,
                0u32..100,
                proptest::option::of("[a-z/._][a-z/._-]{0,19}"),
            ),
        )
            .prop_map(
                |(
                    (run_id, robots, map, world),
                    (wait, spin_us, merge, out, timeout, progress),
                    (hint_buffer, merged_buffer, hang_ms, restarts, plan),
                )| CoordArgs {
                    run_id,
                    robots,
                    map,
                    world,
                    wait,
                    spin_us,
                    merge,
                    out: out.into(),
                    timeout,
                    progress,
                    hint_buffer,
                    merged_buffer,
                    hang_ms,
                    restarts,
                    plan: plan.map(Into::into),
                },
            )
    }

    proptest! {
        #[test]
        fn the_coordinator_reads_back_what_to_args_wrote(a in coord()) {
            let back = CoordArgs::try_parse_args(a.to_args());
            prop_assert_eq!(back.map_err(|e| e.to_string()), Ok(a));
        }
    }
}
