//! Which world a run's robots live in ([`World`]) and the options of a shared grid
//! ([`WorldArgs`]): `qfleet run`, the coordinator and manifests read them the same way.

use std::path::{Path, PathBuf};

use clap::{Args, ValueEnum};
use mapf::Instance;
use mapf::lifelong::{Part, Problem, ProblemError, Spec, parse_cells};
use planner::map::{GridMap, MapError};
use serde::{Deserialize, Serialize};

use crate::{ArgsError, MapArgs};

/// Whether the robots of a run share one grid or each learn on a copy of the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum World {
    /// Every robot on a private copy of the map: robots never meet (one start and goal).
    #[default]
    Separate,
    /// One grid: after learning, the robots go from their starts to their goals among each
    /// other, one tick at a time, as the coordinator grants (robot `i` takes line `i` of
    /// `--scen`).
    Shared,
}

impl std::fmt::Display for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            World::Separate => "separate",
            World::Shared => "shared",
        })
    }
}

/// The options of the world a run's robots live in.
#[derive(Debug, Clone, PartialEq, Eq, Args)]
pub struct WorldArgs {
    /// `separate`: every robot learns on its own copy of the map and robots never meet.
    /// `shared`: one grid; robot i takes its start and goal from line i of `--scen`, learns
    /// them, then all move together tick by tick, each only where the coordinator grants
    /// (no two on one cell, no swaps), and the run reports sum of costs, makespan and
    /// `paths.txt`.
    #[arg(long, value_enum, default_value_t = World::Separate)]
    pub world: World,
    /// Shared grid: end the execution after this many ticks even if robots are under way
    /// [default: 8 × the longest single shortest path + 4 × robots + 256].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_ticks: Option<u32>,
    /// Shared grid: at least this many milliseconds per tick, so that a person can follow the
    /// robots with `--live` (0: as fast as the robots answer; at most 10 000, well inside the
    /// robots' wait for the next grant).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=10_000))]
    pub tick_ms: u64,
    /// Shared grid: robots answer with their rankings for every cell they may reach within
    /// this many ticks, and are woken once per N + 1 ticks instead of every tick (0: one
    /// intent per robot per tick; at most 8, the wire's capacity).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_HORIZON, value_parser = clap::value_parser!(u8).range(0..=8))]
    pub intent_horizon: u8,
    /// Shared grid, lifelong: a League of Robot Runners 2023 problem (JSON naming the map,
    /// starts and tasks; tasks dealt round robin). Every robot gets its next goal the tick it
    /// reaches one and the run ends after `--ticks`; the map, starts and goals come from the
    /// problem (no `--map`, `--scen`, `--agents`).
    #[arg(long, value_name = "PROBLEM.json")]
    pub lorr: Option<PathBuf>,
    /// Lifelong: ticks to run (the run always lasts exactly this long).
    #[arg(long, value_name = "T", default_value_t = DEFAULT_TICKS, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub ticks: u32,
}

/// Ticks of a lifelong run unless `--ticks` says otherwise (the competition's and the anchors').
pub const DEFAULT_TICKS: u32 = 1000;

/// The most bytes of one lifelong problem file read (a task list of 1M lines fits).
pub const MAX_LORR_FILE: u64 = 64 << 20;

/// Why a lifelong problem's file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum LifelongFileError {
    /// It cannot be read.
    #[error("cannot read it: {0}")]
    Io(#[from] std::io::Error),
    /// Its map is bad.
    #[error(transparent)]
    Map(#[from] MapError),
    /// Its content breaks the format or the problem's rules.
    #[error(transparent)]
    Problem(#[from] ProblemError),
}

/// A lifelong problem read from its files: the validated problem and the map file it names.
#[derive(Debug, Clone)]
pub struct Lifelong {
    /// The problem.
    pub problem: Problem,
    /// The map file (the problem's `mapFile`, resolved against the problem's folder).
    pub map: PathBuf,
    /// The problem file itself.
    pub file: PathBuf,
}

impl Lifelong {
    /// Robot `robot`'s map options: the problem's map, its start, and the first goal it is
    /// dealt that is not its start (the one it learns first).
    pub fn map_args(&self, robot: usize) -> MapArgs {
        let p = &self.problem;
        let start = p.starts()[robot];
        let goal = (0..p.tasks().len() as u64 + 1)
            .map(|c| p.goal(robot, c))
            .find(|&g| g != start)
            .unwrap_or(start);
        MapArgs {
            map: self.map.display().to_string(),
            start: Some(start),
            goal: Some(goal),
            scen: None,
            scen_index: None,
        }
    }

    /// The fleet of a lifelong run: the problem's team, one robot each. `--robots`/`--agents`
    /// may only repeat it; map, scenario and robots on other hosts come from elsewhere.
    pub fn fleet(
        &self,
        robots: Option<u32>,
        agents: Option<u32>,
        map: &MapArgs,
        remote: u32,
    ) -> Result<u32, ArgsError> {
        let team = self.problem.team() as u32;
        if let Some(asked) = robots.or(agents).filter(|&n| n != team) {
            return Err(ArgsError::LifelongFleet { asked, team });
        }
        if map.scen.is_some() || map.start.is_some() || map.goal.is_some() {
            return Err(ArgsError::Conflict(
                "--lorr names the map, the starts and the tasks: do not also give --scen, \
                 --start or --goal",
            ));
        }
        if remote > 0 {
            return Err(ArgsError::Conflict(
                "a lifelong run (--lorr) runs every robot on this host: --remote-robots is not \
                 supported with it",
            ));
        }
        Ok(team)
    }
}

impl WorldArgs {
    /// The lifelong problem of `--lorr`, read and validated; `None` without `--lorr`.
    pub fn lifelong(&self) -> Result<Option<Lifelong>, ArgsError> {
        let Some(path) = &self.lorr else {
            return Ok(None);
        };
        if !self.shared() {
            return Err(ArgsError::Conflict(
                "--lorr runs a lifelong problem on one shared grid: give --world shared too",
            ));
        }
        load_lorr(path).map(Some)
    }
}

/// Reads a League of Robot Runners 2023 problem and the files it names (relative to it),
/// bounded in size, and validates it; every error names the file at fault.
pub fn load_lorr(path: &Path) -> Result<Lifelong, ArgsError> {
    let at = |f: &Path, e: LifelongFileError| ArgsError::Lifelong {
        file: f.display().to_string(),
        source: Box::new(e),
    };
    let text = |f: &Path| -> Result<String, ArgsError> {
        let bytes = planner::map::read_bounded(f, MAX_LORR_FILE)
            .map_err(|e| at(f, LifelongFileError::Io(e)))?;
        String::from_utf8(bytes).map_err(|_| {
            at(
                f,
                LifelongFileError::Io(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    "not UTF-8 text",
                )),
            )
        })
    };
    let spec = Spec::parse(&text(path)?).map_err(|e| at(path, e.into()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let map_path = dir.join(&spec.map_file);
    let map: GridMap = planner::map::load_map(&map_path.display().to_string())
        .map_err(|e| at(&map_path, e.into()))?;
    let agents = dir.join(&spec.agent_file);
    let starts =
        parse_cells(&text(&agents)?, Part::Agents, &map.grid).map_err(|e| at(&agents, e.into()))?;
    let tasks_file = dir.join(&spec.task_file);
    let tasks = parse_cells(&text(&tasks_file)?, Part::Tasks, &map.grid)
        .map_err(|e| at(&tasks_file, e.into()))?;
    let problem = Problem::new(
        map.grid,
        &starts,
        spec.team_size as usize,
        tasks,
        spec.num_tasks_reveal,
    )
    .map_err(|e| at(path, e.into()))?;
    Ok(Lifelong {
        problem,
        map: map_path,
        file: path.to_path_buf(),
    })
}

/// The intent horizon of a shared grid unless `--intent-horizon` says otherwise.
pub const DEFAULT_HORIZON: u8 = 8;

impl Default for WorldArgs {
    /// What the command line gives when no world option is named.
    fn default() -> Self {
        WorldArgs {
            world: World::Separate,
            max_ticks: None,
            tick_ms: 0,
            intent_horizon: DEFAULT_HORIZON,
            lorr: None,
            ticks: DEFAULT_TICKS,
        }
    }
}

impl WorldArgs {
    /// The options as command-line words, to forward to the coordinator.
    pub fn to_cli(&self) -> Vec<String> {
        let mut v = vec!["--world".to_string(), self.world.to_string()];
        if let Some(t) = self.max_ticks {
            v.extend(["--max-ticks".into(), t.to_string()]);
        }
        if self.tick_ms > 0 {
            v.extend(["--tick-ms".into(), self.tick_ms.to_string()]);
        }
        if self.intent_horizon != DEFAULT_HORIZON {
            v.extend(["--intent-horizon".into(), self.intent_horizon.to_string()]);
        }
        if let Some(p) = &self.lorr {
            v.extend(["--lorr".into(), crate::value_word(&p.display().to_string())]);
        }
        if self.ticks != DEFAULT_TICKS {
            v.extend(["--ticks".into(), self.ticks.to_string()]);
        }
        v
    }

    /// Whether the robots share one grid.
    pub fn shared(&self) -> bool {
        self.world == World::Shared
    }
}

impl MapArgs {
    /// The shared grid of `agents` robots: the map, and robot `i`'s start and goal from line
    /// `i` of `--scen` (MovingAI's "first N agents"), validated before anything starts.
    pub fn instance(&self, agents: u32) -> Result<Instance, ArgsError> {
        let Some(path) = &self.scen else {
            return Err(ArgsError::Conflict(
                "a shared grid takes every robot's start and goal from a scenario: give --scen \
                 FILE (robot i takes line i)",
            ));
        };
        if self.start.is_some() || self.goal.is_some() || self.scen_index.is_some() {
            return Err(ArgsError::Conflict(
                "a shared grid takes robot i's start and goal from line i of --scen; do not give \
                 --start, --goal or --scen-index",
            ));
        }
        let map = planner::map::load_map(&self.map)?;
        let scen = planner::map::load_scen(path)?;
        let instance = Instance::from_scen(&map, &scen, agents as usize)?;
        // a robot learns a path from its start to its goal: one already there has none to learn
        if let Some(i) =
            (0..instance.agents()).find(|&i| instance.starts()[i] == instance.goals()[i])
        {
            return Err(ArgsError::StartIsGoal {
                agent: i,
                cell: instance.starts()[i],
            });
        }
        Ok(instance)
    }
}

/// The robots of this host (`qfleet run`): `robots` (`--robots`), or `agents` (`--agents`)
/// less `remote` (`--remote-robots`, the agents other hosts run), or 4; both given, they must
/// agree, one robot per agent.
pub fn local_robots(
    robots: Option<u32>,
    agents: Option<u32>,
    remote: u32,
) -> Result<u32, ArgsError> {
    let all = |r: u32| u64::from(r) + u64::from(remote);
    match (robots, agents) {
        (Some(r), Some(a)) if r != a && remote == 0 => Err(ArgsError::Fleet(format!(
            "--robots {r} and --agents {a} disagree: one robot per agent (give one of them)"
        ))),
        (Some(r), Some(a)) if all(r) != u64::from(a) => Err(ArgsError::Fleet(format!(
            "--robots {r} on this host and --remote-robots {remote} make {} robots, but \
                 --agents is {a}: one robot per agent",
            all(r)
        ))),
        (Some(n), _) => Ok(n),
        (None, Some(a)) => a.checked_sub(remote).filter(|&n| n > 0).ok_or_else(|| {
            ArgsError::Fleet(format!(
                "--agents {a} with --remote-robots {remote} leaves no robot on this host (at \
                 least one runs here, beside the coordinator)"
            ))
        }),
        (None, None) => Ok(4),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_robots_of_this_host_come_from_robots_or_agents() {
        assert_eq!(local_robots(None, None, 0).unwrap(), 4);
        assert_eq!(local_robots(Some(3), None, 2).unwrap(), 3);
        assert_eq!(local_robots(None, Some(8), 2).unwrap(), 6);
        assert_eq!(local_robots(Some(6), Some(8), 2).unwrap(), 6);
        let e = local_robots(Some(3), Some(4), 0).unwrap_err().to_string();
        assert!(e.contains("disagree"), "{e}");
        let e = local_robots(Some(3), Some(8), 2).unwrap_err().to_string();
        assert!(e.contains("make 5 robots"), "{e}");
        let e = local_robots(None, Some(2), 2).unwrap_err().to_string();
        assert!(e.contains("leaves no robot"), "{e}");
    }

    fn map_args(scen: Option<&str>) -> MapArgs {
        MapArgs {
            map: "builtin:paper-10".into(),
            start: None,
            goal: None,
            scen: scen.map(Into::into),
            scen_index: None,
        }
    }

    #[test]
    fn a_shared_grid_needs_a_scenario_and_nothing_that_picks_one_task() {
        assert!(matches!(
            map_args(None).instance(2),
            Err(ArgsError::Conflict(_))
        ));
        let mut m = map_args(Some("x.scen"));
        m.scen_index = Some(1);
        assert!(matches!(m.instance(2), Err(ArgsError::Conflict(_))));
    }

    #[test]
    fn world_options_round_trip_through_the_command_line() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            w: WorldArgs,
        }
        for w in [
            WorldArgs::default(),
            WorldArgs {
                world: World::Shared,
                max_ticks: Some(77),
                tick_ms: 5,
                intent_horizon: 0,
                lorr: Some("p/problem.json".into()),
                ticks: 500,
            },
        ] {
            let mut argv = vec!["x".to_string()];
            argv.extend(w.to_cli());
            let back = Cli::try_parse_from(argv).unwrap().w;
            assert_eq!(back, w);
        }
    }
}
