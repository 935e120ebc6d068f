//! Experiment manifests: a TOML file that describes a coordinator-driven experiment — the map,
//! the goals, the robots and their start cells, how goals are assigned, the learner, the sharing
//! mode, episodes, seeds and phases.
//!
//! [`parse_manifest`] checks everything that can be checked without reading files (unknown keys,
//! types, ranges, indices); [`Manifest::resolve`] loads the map and scenario and checks cells,
//! reachability and assignments, giving a [`Plan`]. Every error names the field (`phases[1].goals`)
//! and the reason. See `examples/*.toml` for complete manifests.
//!
//! ```toml
//! name = "paper-30, 3 goals, 6 robots"
//! sharing = "both"            # none | discoveries | hints | both
//! episodes = 300              # per phase, unless a phase says otherwise
//! seeds = [1, 2]              # one experiment per seed; robot i gets 1000 × seed + i
//!
//! [map]
//! source = "builtin:paper-30" # or suite:FAMILY-SIZE-INDEX (a generated map of the suite, its
//!                             # far pair as default start and goal), an ASCII map file, or a
//!                             # MovingAI .map (paths relative to this file); `scen` +
//!                             # `scen_index` give default start and goal
//!
//! [[goals]]
//! cell = [29, 29]             # or scen_index = 3 (the goal of that scenario line)
//!
//! [robots]
//! count = 6
//! start = [0, 0]              # all robots; or starts = [[0, 0], [1, 0], …], one per robot
//!
//! [assignment]
//! policy = "round-robin"      # fixed (with goals = [goal index per robot]) | round-robin | nearest
//!
//! [learner]
//! kind = "planning"           # (the default) every learner option of `qfleet learn`, e.g. alpha
//!
//! [[phases]]                  # optional; without phases there is one
//! episodes = 200
//! [[phases]]
//! rotate = 1                  # round-robin shifted by one: every robot gets another goal
//! ```
//!
//! # One shared grid
//! `world = "shared"` (default `"separate"`) puts the robots on one grid: in every phase they
//! learn their goals (each from its manifest start), then the coordinator moves them there
//! among each other, tick by tick (the MAPF execution of `qfleet run --world shared`). Every
//! robot has its own start and goal:
//!
//! ```toml
//! world = "shared"
//! [map]
//! source = "warehouse.map"
//! scen = "warehouse.scen"     # robot i: start and goal of scenario line i (as --scen --agents)
//! [robots]
//! count = 4                   # or starts = [[x, y], …] and goals = [[x, y], …], one per robot
//! [[phases]]
//! [[phases]]
//! rotate = 1                  # robot i takes robot i+1's goal: goals stay distinct
//! ```
//!
//! Every robot learns every phase from its manifest start; each phase's execution starts
//! there too, unless `phase_start = "previous"`: then phase k goes from where phase k − 1 left
//! the robots ([`PhaseStart`]). Each phase is checked as a MAPF instance before anything starts ([`crate::phases`]): two
//! robots on one start, two robots on one goal in a phase (a policy that gives two robots one
//! goal), a goal on a wall or walled in, a goal on the robot's own manifest start, more robots
//! than [`mapf::MAX_AGENTS`] — each an error naming the phase, the robots and the cell.

use std::path::{Path, PathBuf};

use planner::map::{self, GridMap, Scenario};
use planner::task::{self, Task};
use planner::{Cell, EpsilonReading, LearnerKind, QScale, Schedule};
use serde::Deserialize;

use crate::phases::{PhaseProblem, PhaseStart, check_phases};
use crate::{LearnerArgs, MapArgs, ShareMode, World};

/// Most robots a manifest may ask for (the bus's limit).
pub const MAX_ROBOTS: u32 = 256;
/// Most goals a manifest may name.
pub const MAX_GOALS: usize = 64;
/// Most phases a manifest may have.
pub const MAX_PHASES: usize = 64;
/// Most seeds a manifest may list.
pub const MAX_SEEDS: usize = 64;
/// Most episodes of one phase.
pub const MAX_EPISODES: u32 = 10_000_000;

/// Why a manifest was refused: the file, the field path and the reason.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{source_name}: {path}: {reason}")]
pub struct ManifestError {
    /// The manifest's name (its file path, usually).
    pub source_name: String,
    /// Dotted path of the offending field (`phases[1].episodes`), or `(toml)` for syntax.
    pub path: String,
    /// What is wrong.
    pub reason: String,
}

impl AssignPolicy {
    /// The policy as a manifest writes it.
    pub fn word(self) -> &'static str {
        match self {
            AssignPolicy::Fixed => "fixed",
            AssignPolicy::RoundRobin => "round-robin",
            AssignPolicy::Nearest => "nearest",
        }
    }
}

/// How the coordinator gives robots their goals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum AssignPolicy {
    /// An explicit goal index per robot (`goals = [...]`).
    Fixed,
    /// Robot i gets goal (i + rotate) mod goals.
    RoundRobin,
    /// Each robot gets the goal with the shortest BFS path from its start (ties: lower index).
    Nearest,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    name: Option<String>,
    world: Option<World>,
    phase_start: Option<PhaseStart>,
    map: RawMap,
    #[serde(default)]
    goals: Vec<RawGoal>,
    robots: RawRobots,
    assignment: Option<RawAssignment>,
    #[serde(default)]
    learner: RawLearner,
    sharing: Option<ShareMode>,
    episodes: Option<u32>,
    seeds: Option<Vec<u64>>,
    #[serde(default)]
    phases: Vec<RawPhase>,
    stop_at_optimum: Option<bool>,
    timeout_s: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMap {
    source: String,
    scen: Option<String>,
    scen_index: Option<usize>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGoal {
    name: Option<String>,
    // a Vec, not [u32; 2]: serde reads the first two numbers of a longer array and drops the
    // rest, so `cell = [1, 2, 3]` would pass as (1, 2); `cell_of` checks the length
    cell: Option<Vec<u32>>,
    scen_index: Option<usize>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRobots {
    count: u32,
    start: Option<Vec<u32>>,
    starts: Option<Vec<Vec<u32>>>,
    goals: Option<Vec<Vec<u32>>>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAssignment {
    policy: AssignPolicy,
    goals: Option<Vec<usize>>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLearner {
    kind: Option<String>,
    alpha: Option<f32>,
    gamma: Option<f32>,
    epsilon: Option<f32>,
    epsilon_reading: Option<String>,
    schedule: Option<String>,
    q_scale: Option<String>,
    horizon: Option<f32>,
    pseudo: Option<bool>,
    radius: Option<u32>,
    delta: Option<f32>,
    remove_at: Option<f32>,
    max_steps: Option<u32>,
    reward_goal: Option<f32>,
    reward_collision: Option<f32>,
    reward_step: Option<f32>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPhase {
    name: Option<String>,
    episodes: Option<u32>,
    policy: Option<AssignPolicy>,
    assign: Option<Vec<usize>>,
    goals: Option<Vec<usize>>,
    rotate: Option<usize>,
}

/// Where a goal is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum GoalSpec {
    /// An explicit cell.
    Cell(Cell),
    /// The goal of a scenario line.
    Scenario(usize),
    /// The map's own goal (`G`) or the default scenario's.
    Default,
}

/// One goal of the experiment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Goal {
    /// Display name (`goal-<i>` unless given).
    pub name: String,
    /// Where it is.
    pub spec: GoalSpec,
}

/// One phase: how long, and how goals are assigned.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Phase {
    /// Display name (`phase-<i>` unless given).
    pub name: String,
    /// Episodes every robot runs in this phase.
    pub episodes: u32,
    /// Assignment policy in this phase.
    pub policy: AssignPolicy,
    /// For `fixed`: goal index per robot.
    pub fixed: Vec<usize>,
    /// Goal indices taking part (all when empty).
    pub goals: Vec<usize>,
    /// Round-robin shift.
    pub rotate: usize,
}

/// A parsed, checked manifest (files not read yet: see [`Manifest::resolve`]).
#[derive(Debug, Clone)]
pub struct Manifest {
    /// Name of the experiment.
    pub name: String,
    /// Separate copies of the map, or one shared grid (each phase a MAPF execution).
    pub world: World,
    /// Shared grid: where each phase's execution starts.
    pub phase_start: PhaseStart,
    /// Where the manifest came from (for messages and relative paths).
    pub source_name: String,
    /// Map spec as written: `builtin:…`, `suite:…` or a path.
    pub map: String,
    /// Scenario file as written.
    pub scen: Option<String>,
    /// Scenario line for the default start and goal.
    pub scen_index: usize,
    /// Goals.
    pub goals: Vec<Goal>,
    /// Number of robots.
    pub robots: u32,
    /// Start per robot (`None`: the map's or scenario's start).
    pub starts: Vec<Option<Cell>>,
    /// Learner options (episodes and seed are set per phase and robot).
    pub learner: LearnerArgs,
    /// What robots share.
    pub sharing: ShareMode,
    /// Phases, at least one.
    pub phases: Vec<Phase>,
    /// Seeds, at least one.
    pub seeds: Vec<u64>,
    /// A robot ends its phase as soon as its greedy path is optimal.
    pub stop_at_optimum: bool,
    /// Seconds the coordinator waits for registrations and phase reports.
    pub timeout_s: f64,
}

fn err(source: &str, path: impl Into<String>, reason: impl Into<String>) -> ManifestError {
    ManifestError {
        source_name: source.to_string(),
        path: path.into(),
        reason: reason.into(),
    }
}

/// A cell from a manifest's `[x, y]`: exactly two numbers, each at most 65535.
fn cell_of(source: &str, path: &str, c: &[u32]) -> Result<Cell, ManifestError> {
    let &[x, y] = c else {
        return Err(err(
            source,
            path,
            format!(
                "a cell is exactly two numbers [x, y], got {} ({c:?})",
                c.len()
            ),
        ));
    };
    let c = [x, y];
    match (u16::try_from(c[0]), u16::try_from(c[1])) {
        (Ok(x), Ok(y)) => Ok(Cell::new(x, y)),
        _ => Err(err(
            source,
            path,
            format!("cell [{}, {}] is beyond 65535", c[0], c[1]),
        )),
    }
}

fn parse_word<T: std::str::FromStr<Err = String>>(
    source: &str,
    path: &str,
    v: &Option<String>,
) -> Result<Option<T>, ManifestError> {
    v.as_deref()
        .map(|s| s.parse::<T>().map_err(|e| err(source, path, e)))
        .transpose()
}

/// Parses and checks a manifest; `source` names it in errors (usually the file path).
///
/// Reads no file: map and scenario are loaded by [`Manifest::resolve`].
pub fn parse_manifest(source: &str, text: &str) -> Result<Manifest, ManifestError> {
    let raw: RawManifest = toml::from_str(text).map_err(|e| {
        let msg = e.message().trim().to_string();
        let at = e
            .span()
            .map(|s| {
                let line = text
                    .get(..s.start)
                    .map_or(0, |t| t.bytes().filter(|b| *b == b'\n').count())
                    + 1;
                format!("line {line}")
            })
            .unwrap_or_else(|| "(toml)".into());
        err(source, at, msg)
    })?;
    let s = source;
    let robots = raw.robots.count;
    let world = raw.world.unwrap_or_default();
    let shared = world == World::Shared;
    if shared && robots as usize > mapf::MAX_AGENTS {
        return Err(err(
            s,
            "robots.count",
            format!(
                "{robots} robots on one shared grid; it takes at most {}",
                mapf::MAX_AGENTS
            ),
        ));
    }
    if !shared && raw.phase_start.is_some() {
        return Err(err(
            s,
            "phase_start",
            "only with world = \"shared\" (where a phase's execution on the grid starts)",
        ));
    }
    if shared && raw.map.scen_index.is_some() {
        return Err(err(
            s,
            "map.scen_index",
            "a shared world takes robot i's start and goal from scenario line i (or from \
             robots.starts and goals); scen_index picks one task for every robot",
        ));
    }
    if robots == 0 || robots > MAX_ROBOTS {
        return Err(err(
            s,
            "robots.count",
            format!("must be 1..={MAX_ROBOTS}, got {robots}"),
        ));
    }
    if raw.map.source.trim().is_empty() {
        return Err(err(s, "map.source", "must name a map"));
    }
    if raw.map.scen_index.is_some() && raw.map.scen.is_none() {
        return Err(err(s, "map.scen_index", "needs map.scen"));
    }
    let starts = match (&raw.robots.start, &raw.robots.starts) {
        (Some(_), Some(_)) => {
            return Err(err(
                s,
                "robots.starts",
                "give either robots.start (all robots) or robots.starts (one per robot), not both",
            ));
        }
        (Some(c), None) => vec![Some(cell_of(s, "robots.start", c)?); robots as usize],
        (None, Some(v)) => {
            if v.len() != robots as usize {
                return Err(err(
                    s,
                    "robots.starts",
                    format!("has {} cells for {robots} robots", v.len()),
                ));
            }
            v.iter()
                .enumerate()
                .map(|(i, c)| cell_of(s, &format!("robots.starts[{i}]"), c).map(Some))
                .collect::<Result<_, _>>()?
        }
        (None, None) => vec![None; robots as usize],
    };
    if raw.goals.len() > MAX_GOALS {
        return Err(err(s, "goals", format!("at most {MAX_GOALS} goals")));
    }
    let mut goals = Vec::new();
    if let Some(v) = &raw.robots.goals {
        if !raw.goals.is_empty() {
            return Err(err(
                s,
                "robots.goals",
                "give either robots.goals (one per robot) or [[goals]] (assigned by policy), \
                 not both",
            ));
        }
        if v.len() != robots as usize {
            return Err(err(
                s,
                "robots.goals",
                format!("has {} cells for {robots} robots", v.len()),
            ));
        }
        for (i, c) in v.iter().enumerate() {
            goals.push(Goal {
                name: format!("robot-{i}"),
                spec: GoalSpec::Cell(cell_of(s, &format!("robots.goals[{i}]"), c)?),
            });
        }
    } else if shared && raw.goals.is_empty() && raw.map.scen.is_some() {
        // robot i's goal is scenario line i's, as `qfleet run --world shared --scen`
        goals.extend((0..robots as usize).map(|i| Goal {
            name: format!("robot-{i}"),
            spec: GoalSpec::Scenario(i),
        }));
    }
    for (i, g) in raw.goals.iter().enumerate() {
        let spec = match (&g.cell, g.scen_index) {
            (Some(_), Some(_)) => {
                return Err(err(
                    s,
                    format!("goals[{i}]"),
                    "give either cell or scen_index, not both",
                ));
            }
            (Some(c), None) => GoalSpec::Cell(cell_of(s, &format!("goals[{i}].cell"), c)?),
            (None, Some(k)) => {
                if raw.map.scen.is_none() {
                    return Err(err(s, format!("goals[{i}].scen_index"), "needs map.scen"));
                }
                GoalSpec::Scenario(k)
            }
            (None, None) => {
                return Err(err(s, format!("goals[{i}]"), "needs cell or scen_index"));
            }
        };
        let name = g.name.clone().unwrap_or_else(|| format!("goal-{i}"));
        // results and tables are keyed by goal name: two goals of one name would be merged
        // or shadowed in what the user reads
        if let Some(j) = goals.iter().position(|o: &Goal| o.name == name) {
            return Err(err(
                s,
                format!("goals[{i}].name"),
                format!("duplicate goal name {name:?} (also goals[{j}].name)"),
            ));
        }
        goals.push(Goal { name, spec });
    }
    if goals.is_empty() {
        goals.push(Goal {
            name: "goal-0".into(),
            spec: GoalSpec::Default,
        });
    }
    let ngoals = goals.len();
    let check_goal_list = |path: &str, v: &[usize]| -> Result<(), ManifestError> {
        if let Some((j, g)) = v.iter().enumerate().find(|(_, g)| **g >= ngoals) {
            return Err(err(
                s,
                format!("{path}[{j}]"),
                format!("goal index {g} but there are {ngoals} goals (0..{ngoals})"),
            ));
        }
        Ok(())
    };
    let (policy, fixed) = match &raw.assignment {
        Some(a) => (a.policy, a.goals.clone().unwrap_or_default()),
        None => (AssignPolicy::RoundRobin, Vec::new()),
    };
    if raw.assignment.as_ref().is_some_and(|a| a.goals.is_some()) && policy != AssignPolicy::Fixed {
        return Err(err(s, "assignment.goals", "only for policy = \"fixed\""));
    }
    check_goal_list("assignment.goals", &fixed)?;
    let episodes = raw.episodes.unwrap_or(300);
    let check_episodes = |path: &str, e: u32| -> Result<(), ManifestError> {
        if e == 0 || e > MAX_EPISODES {
            return Err(err(s, path, format!("must be 1..={MAX_EPISODES}, got {e}")));
        }
        Ok(())
    };
    check_episodes("episodes", episodes)?;
    if raw.phases.len() > MAX_PHASES {
        return Err(err(s, "phases", format!("at most {MAX_PHASES} phases")));
    }
    let raw_phases = if raw.phases.is_empty() {
        vec![RawPhase {
            name: None,
            episodes: None,
            policy: None,
            assign: None,
            goals: None,
            rotate: None,
        }]
    } else {
        raw.phases.clone()
    };
    let mut phases = Vec::new();
    for (i, p) in raw_phases.iter().enumerate() {
        let path = format!("phases[{i}]");
        let e = p.episodes.unwrap_or(episodes);
        check_episodes(&format!("{path}.episodes"), e)?;
        let pol = p.policy.unwrap_or(policy);
        let fx = p.assign.clone().unwrap_or_else(|| fixed.clone());
        if p.assign.is_some() && pol != AssignPolicy::Fixed {
            return Err(err(
                s,
                format!("{path}.assign"),
                "only for policy = \"fixed\"",
            ));
        }
        check_goal_list(&format!("{path}.assign"), &fx)?;
        if pol == AssignPolicy::Fixed && fx.len() != robots as usize {
            return Err(err(
                s,
                if p.assign.is_some() {
                    format!("{path}.assign")
                } else {
                    "assignment.goals".into()
                },
                format!(
                    "policy \"fixed\" needs one goal index per robot: {} given for {robots} robots",
                    fx.len()
                ),
            ));
        }
        let active = p.goals.clone().unwrap_or_default();
        check_goal_list(&format!("{path}.goals"), &active)?;
        if p.goals.is_some() && active.is_empty() {
            return Err(err(
                s,
                format!("{path}.goals"),
                "must list at least one goal",
            ));
        }
        let mut sorted = active.clone();
        sorted.sort_unstable();
        sorted.dedup();
        if sorted.len() != active.len() {
            return Err(err(s, format!("{path}.goals"), "lists a goal twice"));
        }
        if pol == AssignPolicy::Fixed
            && !active.is_empty()
            && let Some((r, g)) = fx.iter().enumerate().find(|(_, g)| !active.contains(g))
        {
            return Err(err(
                s,
                format!("{path}.assign"),
                format!("robot {r} gets goal {g}, which is not in {path}.goals"),
            ));
        }
        phases.push(Phase {
            name: p.name.clone().unwrap_or_else(|| format!("phase-{i}")),
            episodes: e,
            policy: pol,
            fixed: fx,
            goals: active,
            rotate: p.rotate.unwrap_or(0) % ngoals.max(1),
        });
    }
    let seeds = raw.seeds.clone().unwrap_or_else(|| vec![1]);
    if seeds.is_empty() || seeds.len() > MAX_SEEDS {
        return Err(err(s, "seeds", format!("must list 1..={MAX_SEEDS} seeds")));
    }
    let l = &raw.learner;
    let learner_kind = match &l.kind {
        Some(k) => k
            .parse::<LearnerKind>()
            .map_err(|e| err(s, "learner.kind", e))?,
        None => LearnerKind::Planning,
    };
    let learner = LearnerArgs {
        learner: learner_kind,
        episodes: phases[0].episodes,
        seed: seeds[0],
        alpha: l.alpha.unwrap_or(0.1),
        gamma: l.gamma,
        optimistic: None,
        sweeps: None,
        sweep_every: None,
        replay: None,
        epsilon: l.epsilon,
        epsilon_reading: parse_word::<EpsilonReading>(
            s,
            "learner.epsilon_reading",
            &l.epsilon_reading,
        )?,
        schedule: parse_word::<Schedule>(s, "learner.schedule", &l.schedule)?,
        q_scale: parse_word::<QScale>(s, "learner.q_scale", &l.q_scale)?,
        horizon: l.horizon,
        no_pseudo: l.pseudo == Some(false),
        radius: l.radius,
        delta: l.delta,
        remove_at: l.remove_at,
        max_steps: l.max_steps.unwrap_or(0),
        reward_goal: l.reward_goal.unwrap_or(1.0),
        reward_collision: l.reward_collision.unwrap_or(-1.0),
        reward_step: l.reward_step.unwrap_or(0.0),
    };
    if let Err(e) = learner.config() {
        return Err(err(s, "learner", e.to_string()));
    }
    let timeout_s = raw.timeout_s.unwrap_or(60.0);
    if !(timeout_s.is_finite() && timeout_s > 0.0 && timeout_s <= 86_400.0) {
        return Err(err(
            s,
            "timeout_s",
            format!("must be a number of seconds in (0, 86400], got {timeout_s}"),
        ));
    }
    Ok(Manifest {
        name: raw.name.unwrap_or_else(|| source.to_string()),
        world,
        phase_start: raw.phase_start.unwrap_or_default(),
        source_name: source.to_string(),
        map: raw.map.source,
        scen: raw.map.scen,
        scen_index: raw.map.scen_index.unwrap_or(0),
        goals,
        robots,
        starts,
        learner,
        sharing: raw.sharing.unwrap_or(ShareMode::Hints),
        phases,
        seeds,
        stop_at_optimum: raw.stop_at_optimum.unwrap_or(false),
        timeout_s,
    })
}

/// Largest manifest file read (the biggest example is under 2 KiB).
pub const MAX_MANIFEST_BYTES: u64 = 1024 * 1024;

/// Reads and parses a manifest file: a regular file of at most [`MAX_MANIFEST_BYTES`], never
/// blocking on a FIFO ([`map::read_bounded`]).
pub fn load_manifest(path: &Path) -> Result<Manifest, ManifestError> {
    let name = path.display().to_string();
    let bytes = map::read_bounded(path, MAX_MANIFEST_BYTES)
        .map_err(|e| err(&name, "(file)", format!("cannot read: {e}")))?;
    let text = String::from_utf8(bytes).map_err(|_| err(&name, "(file)", "not UTF-8 text"))?;
    parse_manifest(&name, &text)
}

/// A manifest with its map loaded and every cell, path and assignment checked.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The manifest.
    pub manifest: Manifest,
    /// The map spec to hand to robot-agents (`builtin:…`, `suite:…` or an absolute path).
    pub map_spec: String,
    /// The loaded map.
    pub map: GridMap,
    /// Goal cells, by goal index.
    pub goal_cells: Vec<Cell>,
    /// Start cell per robot.
    pub starts: Vec<Cell>,
    /// BFS optimum per robot and goal: `optimal[robot][goal]`.
    pub optimal: Vec<Vec<u32>>,
    /// Goal index per robot, per phase: `assignment[phase][robot]`.
    pub assignment: Vec<Vec<usize>>,
}

impl Manifest {
    /// Loads the map (and scenario) relative to `base` (the manifest's directory) and checks
    /// cells, reachability and assignments.
    pub fn resolve(self, base: &Path) -> Result<Plan, ManifestError> {
        let s = self.source_name.clone();
        let rel = |p: &str| -> PathBuf {
            let p = Path::new(p);
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                base.join(p)
            }
        };
        let map_spec = if self.map.starts_with("builtin:") || self.map.starts_with("suite:") {
            self.map.clone()
        } else {
            rel(&self.map).display().to_string()
        };
        let m = map::load_map(&map_spec).map_err(|e| err(&s, "map.source", e.to_string()))?;
        let scen: Option<Vec<Scenario>> = match &self.scen {
            Some(p) => {
                Some(map::load_scen(&rel(p)).map_err(|e| err(&s, "map.scen", e.to_string()))?)
            }
            None => None,
        };
        let scen_task = |path: &str, i: usize| -> Result<Task, ManifestError> {
            match &scen {
                Some(sc) => {
                    task::resolve_scenario(&m, sc, i).map_err(|e| err(&s, path, e.to_string()))
                }
                None => Err(err(&s, path, "needs map.scen")),
            }
        };
        let default_task = || -> Result<Task, ManifestError> {
            match &scen {
                Some(_) => scen_task("map.scen_index", self.scen_index),
                None => {
                    task::resolve_task(&m, None, None).map_err(|e| err(&s, "map", e.to_string()))
                }
            }
        };
        let mut goal_cells = Vec::new();
        for (i, g) in self.goals.iter().enumerate() {
            goal_cells.push(match &g.spec {
                GoalSpec::Cell(c) => *c,
                GoalSpec::Scenario(k) => scen_task(&format!("goals[{i}].scen_index"), *k)?.goal,
                GoalSpec::Default => match &scen {
                    Some(_) => default_task()?.goal,
                    None => m.goals.first().copied().ok_or_else(|| {
                        err(&s, "goals", "the map marks no goal 'G': list [[goals]]")
                    })?,
                },
            });
        }
        let shared = self.world == World::Shared;
        let mut starts = Vec::new();
        for (r, st) in self.starts.iter().enumerate() {
            starts.push(match st {
                Some(c) => *c,
                // robot i starts where scenario line i does, as `qfleet run --world shared`
                None if shared && scen.is_some() => {
                    scen_task(&format!("robots (robot {r}: scenario line {r})"), r)?.start
                }
                None => match &scen {
                    Some(_) => default_task()?.start,
                    None => m.start.ok_or_else(|| {
                        err(
                            &s,
                            format!("robots (robot {r})"),
                            "the map marks no start 'S': give robots.start or robots.starts",
                        )
                    })?,
                },
            });
        }
        let optimal = if shared {
            shared_optima(&m.grid, &starts, &goal_cells)
        } else {
            separate_optima(&s, &m, &starts, &goal_cells)?
        };
        let ngoals = goal_cells.len();
        let mut assignment = Vec::new();
        for p in &self.phases {
            let active: Vec<usize> = if p.goals.is_empty() {
                (0..ngoals).collect()
            } else {
                p.goals.clone()
            };
            let row: Vec<usize> = (0..self.robots as usize)
                .map(|r| match p.policy {
                    AssignPolicy::Fixed => p.fixed[r],
                    AssignPolicy::RoundRobin => active[(r + p.rotate) % active.len()],
                    AssignPolicy::Nearest => *active
                        .iter()
                        .min_by_key(|g| (optimal[r][**g], **g))
                        .unwrap_or(&0),
                })
                .collect();
            assignment.push(row);
        }
        if shared
            && let Err(e) =
                check_phases(&m.grid, &starts, &goal_cells, &assignment, self.phase_start)
        {
            let phase = &self.phases[e.phase.min(self.phases.len() - 1)];
            let how = match &e.problem {
                PhaseProblem::Instance(mapf::InstanceError::SharedGoal { .. }) => {
                    format!(" (assignment policy {} of this phase)", phase.policy.word())
                }
                _ => String::new(),
            };
            return Err(err(
                &s,
                format!("phases[{}] ({})", e.phase, phase.name),
                format!("on the shared grid: {}{how}", e.problem),
            ));
        }
        Ok(Plan {
            manifest: self,
            map_spec,
            map: m,
            goal_cells,
            starts,
            optimal,
            assignment,
        })
    }
}

/// BFS optimum of every robot to every goal on a shared grid, one BFS per goal (`u32::MAX`
/// where unreachable, 0 on the goal itself): only the assigned pairs are checked, by
/// [`check_phases`].
fn shared_optima(grid: &planner::Grid, starts: &[Cell], goal_cells: &[Cell]) -> Vec<Vec<u32>> {
    let tables: Vec<Vec<u32>> = goal_cells
        .iter()
        .map(|&g| planner::path::bfs_distances(grid, g))
        .collect();
    starts
        .iter()
        .map(|&st| {
            tables
                .iter()
                .map(|d| d.get(grid.index(st)).copied().unwrap_or(u32::MAX))
                .collect()
        })
        .collect()
}

/// BFS optimum of every robot to every goal on separate copies of the map: every pair must be
/// a task (any robot may be given any goal).
fn separate_optima(
    s: &str,
    m: &GridMap,
    starts: &[Cell],
    goal_cells: &[Cell],
) -> Result<Vec<Vec<u32>>, ManifestError> {
    // one search outward from each goal serves every robot (moves are reversible): a fleet of
    // 256 robots on a 2048 × 2048 map took minutes with one path search per robot and goal
    let fields: Vec<Vec<u32>> = goal_cells
        .iter()
        .map(|gc| planner::path::bfs_distances(&m.grid, *gc))
        .collect();
    let mut optimal = Vec::new();
    for (r, st) in starts.iter().enumerate() {
        let mut row = Vec::new();
        for (g, gc) in goal_cells.iter().enumerate() {
            let d = if m.grid.contains(st.x.into(), st.y.into()) {
                fields[g][m.grid.index(*st)]
            } else {
                u32::MAX
            };
            if d == 0 || d == u32::MAX {
                // not a task: the single-task check says why, in its words
                let e = task::resolve_task(m, Some(*st), Some(*gc)).err();
                return Err(err(
                    s,
                    format!("robots/goals (robot {r} start {st}, goal {g} {gc})"),
                    e.map_or_else(|| "no path".to_string(), |e| e.to_string()),
                ));
            }
            row.push(d);
        }
        optimal.push(row);
    }
    Ok(optimal)
}

impl Plan {
    /// Loads the manifest `file` and resolves it relative to its directory (`qfleet
    /// experiment`, each manifest of `qfleet sweep`).
    pub fn load(file: &Path) -> Result<Plan, ManifestError> {
        let base = file.parent().unwrap_or(Path::new("."));
        load_manifest(file)?.resolve(base)
    }

    /// A task for the live view of an experiment: its map, the first robot's start and the
    /// first goal (the robots' own starts and goals arrive on the bus).
    pub fn view_task(&self) -> Task {
        let start = self.starts.first().copied().unwrap_or(Cell::new(0, 0));
        let goal = self.goal_cells.first().copied().unwrap_or(start);
        Task {
            map_name: self.map.name.clone(),
            grid: self.map.grid.clone(),
            start,
            goal,
            optimal_len: self
                .optimal
                .first()
                .and_then(|o| o.first())
                .copied()
                .unwrap_or(1),
        }
    }

    /// Map options for robot `r` with goal `g` (what a robot-agent is started with).
    pub fn map_args(&self, r: usize, g: usize) -> MapArgs {
        MapArgs {
            map: self.map_spec.clone(),
            start: self.starts.get(r).copied(),
            goal: self.goal_cells.get(g).copied(),
            scen: None,
            scen_index: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "t"
sharing = "both"
episodes = 50
seeds = [3, 4]
[map]
source = "builtin:paper-10"
[[goals]]
cell = [9, 9]
[[goals]]
cell = [0, 9]
[robots]
count = 4
start = [0, 0]
[assignment]
policy = "round-robin"
[learner]
kind = "improved"
remove_at = 0.05
[[phases]]
episodes = 20
[[phases]]
rotate = 1
"#;

    fn e(text: &str) -> ManifestError {
        parse_manifest("m.toml", text).unwrap_err()
    }

    #[test]
    fn a_good_manifest_parses_and_resolves() {
        let m = parse_manifest("m.toml", GOOD).unwrap();
        assert_eq!(m.robots, 4);
        assert_eq!(m.sharing, ShareMode::Both);
        assert_eq!(m.phases.len(), 2);
        assert_eq!(m.phases[0].episodes, 20);
        assert_eq!(m.phases[1].episodes, 50);
        assert_eq!(m.seeds, vec![3, 4]);
        assert_eq!(m.learner.remove_at, Some(0.05));
        let p = m.resolve(Path::new(".")).unwrap();
        assert_eq!(p.assignment, vec![vec![0, 1, 0, 1], vec![1, 0, 1, 0]]);
        assert!(p.optimal[0][0] >= 18);
    }

    /// Says that a test skipped, and why: a copy of `qfleet_suite::skip` (`tests/support/lib.rs`
    /// says why it looks so; `tests/skips.rs` keeps every copy identical).
    fn skip(test: &str, reason: &str) {
        use std::io::Write;
        let line = format!("SKIPPED: {test}: {reason}\n");
        let _ = std::io::stderr().lock().write_all(line.as_bytes());
    }

    /// Resolves every example manifest whose map is (`shared`) or is not in `../shared`; the
    /// manifests checked, or `None` when some of those maps are absent.
    fn resolve_examples(shared: bool) -> Option<usize> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
        let mut checked = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "toml") {
                continue;
            }
            let m = load_manifest(&path).unwrap();
            if m.map.contains("shared/data/movingai") != shared {
                continue;
            }
            if shared && !dir.join(&m.map).exists() {
                return None;
            }
            let plan = m.resolve(&dir).unwrap_or_else(|e| panic!("{e}"));
            assert!(!plan.goal_cells.is_empty(), "{}", path.display());
            if plan.map_spec.starts_with("suite:") {
                let t = planner::suite::from_spec(&plan.map_spec["suite:".len()..]).unwrap();
                assert_eq!(plan.goal_cells, [t.task.goal], "{}", path.display());
                assert!(plan.starts.iter().all(|s| *s == t.task.start));
                let half = if t.split == planner::suite::Split::Tuning {
                    "tuning"
                } else {
                    "heldout"
                };
                let name = path.file_name().unwrap().to_string_lossy();
                assert!(
                    name.starts_with(&format!("sweep-{half}-")),
                    "{name}: the file name must say its map's half ({half})"
                );
            }
            checked += 1;
        }
        Some(checked)
    }

    #[test]
    fn every_example_manifest_resolves() {
        let checked = resolve_examples(false).unwrap();
        assert!(checked >= 9, "{checked} example manifests resolved");
    }

    #[test]
    fn every_example_manifest_on_a_shared_movingai_map_resolves() {
        match resolve_examples(true) {
            Some(checked) => assert!(checked >= 1, "{checked} example manifests resolved"),
            None => skip(
                "qfleet-args manifest::tests::every_example_manifest_on_a_shared_movingai_map_resolves",
                "their maps in ../shared/data/movingai are absent",
            ),
        }
    }

    #[test]
    fn a_cell_is_exactly_two_numbers_with_its_field_path() {
        let x = e(&GOOD.replace("cell = [9, 9]", "cell = [1, 2, 3]"));
        assert_eq!(x.path, "goals[0].cell", "{x}");
        assert!(x.reason.contains("exactly two numbers"), "{x}");
        let x = e(&GOOD.replace("cell = [0, 9]", "cell = [4]"));
        assert_eq!(x.path, "goals[1].cell", "{x}");
        let x = e(&GOOD.replace("start = [0, 0]", "start = [0, 0, 0]"));
        assert_eq!(x.path, "robots.start", "{x}");
        let x = e(&GOOD.replace(
            "start = [0, 0]",
            "starts = [[0, 0], [1, 0], [2, 0, 7], [3, 0]]",
        ));
        assert_eq!(x.path, "robots.starts[2]", "{x}");
    }

    #[test]
    fn duplicate_goal_names_are_refused_with_both_paths() {
        let dup = GOOD
            .replace("cell = [9, 9]", "name = \"dock\"\ncell = [9, 9]")
            .replace("cell = [0, 9]", "name = \"dock\"\ncell = [0, 9]");
        let x = e(&dup);
        assert_eq!(x.path, "goals[1].name", "{x}");
        assert!(x.reason.contains("goals[0].name"), "{x}");
        // a given name may not shadow a default one either
        let x = e(&GOOD.replace("cell = [0, 9]", "name = \"goal-0\"\ncell = [0, 9]"));
        assert_eq!(x.path, "goals[1].name", "{x}");
    }

    #[test]
    fn manifest_files_are_read_bounded_and_never_block() {
        let x = load_manifest(Path::new("/dev/zero")).unwrap_err();
        assert!(x.reason.contains("not a regular file"), "{x}");
        let dir = std::env::temp_dir().join(format!("qfleet-manifest-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let big = dir.join("big.toml");
        std::fs::write(&big, vec![b'#'; MAX_MANIFEST_BYTES as usize + 1]).unwrap();
        let x = load_manifest(&big).unwrap_err();
        assert!(x.reason.contains("larger than the limit"), "{x}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unknown_keys_and_bad_values_name_the_field() {
        let x = e(&GOOD.replace("sharing = \"both\"", "sharing = \"all\""));
        assert!(x.reason.contains("all"), "{x}");
        let x = e(&GOOD.replace("name = \"t\"", "name = \"t\"\ncolour = 3"));
        assert!(x.reason.contains("colour"), "{x}");
        assert!(x.path.starts_with("line 3"), "{x}");
        let x = e(&GOOD.replace("count = 4", "count = 0"));
        assert_eq!(x.path, "robots.count");
        let x = e(&GOOD.replace("episodes = 20", "episodes = 0"));
        assert_eq!(x.path, "phases[0].episodes");
        let x = e(&GOOD.replace("remove_at = 0.05", "remove_at = 2.0"));
        assert_eq!(x.path, "learner");
        let x = e(&GOOD.replace("kind = \"improved\"", "kind = \"clever\""));
        assert_eq!(x.path, "learner.kind");
        let x = e(&GOOD.replace("rotate = 1", "rotate = 1\ngoals = [0, 7]"));
        assert_eq!(x.path, "phases[1].goals[1]");
        assert!(x.reason.contains("2 goals"), "{x}");
        let x = e(&GOOD.replace("policy = \"round-robin\"", "policy = \"fixed\""));
        assert_eq!(x.path, "assignment.goals");
        let x = e(&GOOD.replace(
            "policy = \"round-robin\"",
            "policy = \"fixed\"\ngoals = [0, 1, 1]",
        ));
        assert!(x.reason.contains("3 given for 4 robots"), "{x}");
        let x = e(&GOOD.replace("start = [0, 0]", "start = [0, 0]\nstarts = [[0, 0]]"));
        assert_eq!(x.path, "robots.starts");
        let x = e(&GOOD.replace("cell = [9, 9]", "cell = [70000, 9]"));
        assert_eq!(x.path, "goals[0].cell");
        let x = e(&GOOD.replace("seeds = [3, 4]", "seeds = []"));
        assert_eq!(x.path, "seeds");
        let x = e("this is not toml");
        assert!(x.path.starts_with("line"), "{x}");
        let x = e(&GOOD.replace("[map]\nsource = \"builtin:paper-10\"\n", ""));
        assert!(x.reason.contains("map"), "{x}");
    }

    #[test]
    fn resolve_checks_cells_against_the_map() {
        let m = parse_manifest("m.toml", &GOOD.replace("cell = [9, 9]", "cell = [10, 9]")).unwrap();
        let x = m.resolve(Path::new(".")).unwrap_err();
        assert!(x.path.contains("goal 0"), "{x}");
        assert!(x.reason.contains("outside"), "{x}");
        let m = parse_manifest(
            "m.toml",
            &GOOD.replace("builtin:paper-10", "no/such/map.txt"),
        )
        .unwrap();
        assert_eq!(m.resolve(Path::new(".")).unwrap_err().path, "map.source");
    }

    #[test]
    fn nearest_and_fixed_assignments() {
        let m = parse_manifest(
            "m.toml",
            &GOOD
                .replace(
                    "start = [0, 0]",
                    "starts = [[9, 8], [0, 8], [8, 9], [1, 9]]",
                )
                .replace("policy = \"round-robin\"", "policy = \"nearest\"")
                .replace("rotate = 1", "policy = \"fixed\"\nassign = [1, 1, 0, 0]"),
        )
        .unwrap();
        let p = m.resolve(Path::new(".")).unwrap();
        assert_eq!(p.assignment[0], vec![0, 1, 0, 1]);
        assert_eq!(p.assignment[1], vec![1, 1, 0, 0]);
    }

    const SHARED: &str = r#"
world = "shared"
episodes = 20
[map]
source = "builtin:paper-10"
[robots]
count = 2
starts = [[0, 0], [9, 0]]
goals = [[9, 9], [0, 9]]
[[phases]]
[[phases]]
rotate = 1
"#;

    #[test]
    fn the_world_is_separate_unless_a_manifest_says_shared() {
        assert_eq!(
            parse_manifest("m.toml", GOOD).unwrap().world,
            World::Separate
        );
        assert_eq!(
            parse_manifest("m.toml", SHARED).unwrap().world,
            World::Shared
        );
        let x = e(&SHARED.replace("\"shared\"", "\"sharde\""));
        assert!(x.reason.contains("sharde"), "{x}");
        // every phase goes from the starts, unless the manifest says from where the last ended
        assert_eq!(
            parse_manifest("m.toml", SHARED).unwrap().phase_start,
            PhaseStart::Starts
        );
        let prev = SHARED.replace("episodes = 20", "episodes = 20\nphase_start = \"previous\"");
        let m = parse_manifest("m.toml", &prev).unwrap();
        assert_eq!(m.phase_start, PhaseStart::Previous);
        let p = m.resolve(Path::new(".")).unwrap();
        assert_eq!(p.assignment, vec![vec![0, 1], vec![1, 0]]);
        let x = e(&GOOD.replace("name = \"t\"", "name = \"t\"\nphase_start = \"previous\""));
        assert_eq!(x.path, "phase_start");
    }

    #[test]
    fn robots_goals_give_each_robot_its_own_goal_and_phases_rotate_them() {
        let m = parse_manifest("m.toml", SHARED).unwrap();
        let names: Vec<&str> = m.goals.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(names, ["robot-0", "robot-1"]);
        let p = m.resolve(Path::new(".")).unwrap();
        assert_eq!(p.goal_cells, [Cell::new(9, 9), Cell::new(0, 9)]);
        assert_eq!(p.assignment, vec![vec![0, 1], vec![1, 0]]);
        assert_eq!(p.optimal[0], [18, 9]);
    }

    #[test]
    fn a_shared_world_takes_robot_i_s_start_and_goal_from_scenario_line_i() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/grid");
        let m = load_manifest(&dir.join("warehouse-two-phases.toml")).unwrap();
        assert_eq!(m.world, World::Shared);
        let p = m.resolve(&dir).unwrap();
        let scen = map::load_scen(&dir.join("warehouse.scen")).unwrap();
        assert_eq!(p.starts.len(), 6);
        for (r, line) in scen.iter().take(6).enumerate() {
            assert_eq!(p.starts[r], line.start, "robot {r}");
            assert_eq!(p.goal_cells[r], line.goal, "robot {r}");
        }
        assert_eq!(p.assignment[0], [0, 1, 2, 3, 4, 5]);
        assert_eq!(p.assignment[1], [1, 2, 3, 4, 5, 0]);
    }

    #[test]
    fn shared_world_options_that_do_not_fit_name_the_field() {
        let scen_index = "source = \"m.map\"\nscen = \"m.scen\"\nscen_index = 2";
        let cases: [(&str, &str, &str); 5] = [
            ("count = 2", "count = 257", "robots.count"),
            (
                "goals = [[9, 9], [0, 9]]",
                "goals = [[9, 9]]",
                "robots.goals",
            ),
            (
                "[robots]",
                "[[goals]]\ncell = [1, 1]\n[robots]",
                "robots.goals",
            ),
            (
                "goals = [[9, 9], [0, 9]]",
                "goals = [[9, 9], [0]]",
                "robots.goals[1]",
            ),
            (
                "source = \"builtin:paper-10\"",
                scen_index,
                "map.scen_index",
            ),
        ];
        for (from, to, path) in cases {
            let x = e(&SHARED.replace(from, to));
            assert_eq!(x.path, path, "{to}: {x}");
        }
        assert!(
            e(&SHARED.replace("count = 2", "count = 257"))
                .reason
                .contains("shared grid")
        );
    }

    fn resolve_err(text: &str) -> ManifestError {
        parse_manifest("m.toml", text)
            .unwrap()
            .resolve(Path::new("."))
            .unwrap_err()
    }

    #[test]
    fn every_phase_of_a_shared_world_is_checked_as_an_instance() {
        // two robots on one start
        let x = resolve_err(&SHARED.replace("[9, 0]]", "[0, 0]]"));
        assert_eq!(x.path, "phases[0] (phase-0)");
        assert!(
            x.reason.contains("robots 0 and 1 both start at (0,0)"),
            "{x}"
        );
        // one goal for both in phase 1
        let x = resolve_err(&SHARED.replace("rotate = 1", "policy = \"fixed\"\nassign = [1, 1]"));
        assert_eq!(x.path, "phases[1] (phase-1)");
        assert!(x.reason.contains("both have their goal at (0,9)"), "{x}");
        assert!(x.reason.contains("policy fixed"), "{x}");
        // a policy that gives both robots the nearest goal
        let x = resolve_err(
            &SHARED
                .replace("goals = [[9, 9], [0, 9]]", "")
                .replace(
                    "[robots]",
                    "[[goals]]\ncell = [9, 9]\n[[goals]]\ncell = [0, 9]\n[robots]",
                )
                .replace("starts = [[0, 0], [9, 0]]", "starts = [[8, 9], [9, 8]]")
                .replace("rotate = 1", "policy = \"nearest\""),
        );
        assert_eq!(x.path, "phases[1] (phase-1)", "{x}");
        assert!(x.reason.contains("policy nearest"), "{x}");
        // a goal on the robot's own start, where it learns from
        let x = resolve_err(&SHARED.replace("[0, 9]]", "[9, 0]]"));
        assert!(
            x.reason.contains("robot 1's goal (9,0) is its start"),
            "{x}"
        );
        // a goal off the map
        let x = resolve_err(&SHARED.replace("[0, 9]]", "[0, 10]]"));
        assert!(x.reason.contains("outside"), "{x}");
    }
}
