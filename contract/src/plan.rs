//! The plan of an experiment as the coordinator process reads it (`qfleet-coordinator --plan
//! FILE.json`): what `qfleet experiment` resolved from a manifest (map, goals, starts, BFS
//! optima, the assignment of every phase) for one seed, written into the seed's out directory
//! as `plan.json`. A restarted coordinator reads the same file again.
//!
//! [`ExperimentPlan::check`] refuses a plan whose parts do not fit together (bad input, exit
//! code 2) before anything starts; the map is loaded again from its spec (`builtin:…`, `suite:…`
//! or a path) and every cell checked on it. A plan on one shared grid (`world: "shared"`) is
//! checked phase by phase as MAPF instances ([`qfleet_args::phases::check_phases`], the
//! manifest's own check).

use std::path::Path;

use planner::map::GridMap;
use planner::{Cell, Rewards};
use qfleet_args::World;
use qfleet_args::phases::{self, PhaseError, PhaseStart};
use serde::{Deserialize, Serialize};

/// One goal of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanGoal {
    /// Display name.
    pub name: String,
    /// Where it is.
    pub cell: Cell,
}

/// One phase of a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanPhase {
    /// Display name.
    pub name: String,
    /// Episodes every robot runs in it.
    pub episodes: u32,
}

/// A resolved experiment for one seed (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExperimentPlan {
    /// Experiment name.
    pub name: String,
    /// Seed of this repetition.
    pub seed: u64,
    /// Separate copies of the map, or one shared grid: every phase ends with the robots
    /// moving to their goals among each other (plans written before worlds existed: separate).
    #[serde(default)]
    pub world: World,
    /// On a shared grid, where each phase's execution starts: the starts, or where the phase
    /// before left the robots.
    #[serde(default)]
    pub phase_start: PhaseStart,
    /// Fleet size: robot ids `0..robots`.
    pub robots: u32,
    /// Sharing mode, as the robots' `--share` word (for the result).
    pub sharing: String,
    /// Seconds to wait for registrations and for each phase's reports.
    pub timeout_s: f64,
    /// The learner's rewards (the merged-path watch walks the same environment).
    pub rewards: Rewards,
    /// Map spec: `builtin:…`, `suite:…` or a path.
    pub map: String,
    /// Goals, by goal index.
    pub goals: Vec<PlanGoal>,
    /// Phases, in order.
    pub phases: Vec<PlanPhase>,
    /// Start cell per robot.
    pub starts: Vec<Cell>,
    /// BFS optimum per robot and goal: `optimal[robot][goal]`.
    pub optimal: Vec<Vec<u32>>,
    /// Goal index per robot, per phase: `assignment[phase][robot]`.
    pub assignment: Vec<Vec<usize>>,
}

/// A plan that does not fit together.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The plan file could not be read or is not a plan (its message names the file and the
    /// cause already, so it is not repeated as a source).
    #[error("{0}")]
    Read(report::ReadError),
    /// Its map cannot be loaded.
    #[error("the plan's map {spec:?}")]
    Map {
        /// The map spec.
        spec: String,
        /// Why.
        #[source]
        source: Box<planner::map::MapError>,
    },
    /// A phase cannot run on the shared grid (two robots on one start or goal, a goal walled
    /// in, …).
    #[error("on the shared grid")]
    Phase(#[source] PhaseError),
    /// A field is out of shape or range.
    #[error("{field}: {reason}")]
    Field {
        /// Which field.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

fn bad(field: &'static str, reason: impl Into<String>) -> PlanError {
    PlanError::Field {
        field,
        reason: reason.into(),
    }
}

impl ExperimentPlan {
    /// The plan of `plan` for one `seed`.
    pub fn of(plan: &qfleet_args::Plan, seed: u64) -> Result<Self, qfleet_args::ArgsError> {
        let m = &plan.manifest;
        Ok(ExperimentPlan {
            name: m.name.clone(),
            seed,
            world: m.world,
            phase_start: m.phase_start,
            robots: m.robots,
            sharing: m.sharing.as_cli().into(),
            timeout_s: m.timeout_s,
            rewards: m.learner.config()?.rewards,
            map: plan.map_spec.clone(),
            goals: m
                .goals
                .iter()
                .zip(&plan.goal_cells)
                .map(|(g, &cell)| PlanGoal {
                    name: g.name.clone(),
                    cell,
                })
                .collect(),
            phases: m
                .phases
                .iter()
                .map(|p| PlanPhase {
                    name: p.name.clone(),
                    episodes: p.episodes,
                })
                .collect(),
            starts: plan.starts.clone(),
            optimal: plan.optimal.clone(),
            assignment: plan.assignment.clone(),
        })
    }

    /// Checks that the parts fit together without the map: fleet size, one start and one
    /// row of optima per robot, one assignment row per phase naming existing goals.
    pub fn check_shape(&self) -> Result<(), PlanError> {
        let n = self.robots as usize;
        if n == 0 || self.robots > bus_schema::MAX_ROBOTS {
            return Err(bad(
                "robots",
                format!(
                    "must be 1..={}, got {}",
                    bus_schema::MAX_ROBOTS,
                    self.robots
                ),
            ));
        }
        if !(self.timeout_s.is_finite() && self.timeout_s > 0.0) {
            return Err(bad(
                "timeout_s",
                format!(
                    "must be a positive number of seconds, got {}",
                    self.timeout_s
                ),
            ));
        }
        if self.goals.is_empty() || self.goals.len() > u32::MAX as usize {
            return Err(bad("goals", "at least one goal"));
        }
        if self.phases.is_empty() {
            return Err(bad("phases", "at least one phase"));
        }
        if let Some(p) = self.phases.iter().position(|p| p.episodes == 0) {
            return Err(bad("phases", format!("phase {p} has no episodes")));
        }
        if self.starts.len() != n {
            return Err(bad(
                "starts",
                format!("one per robot ({n}), got {}", self.starts.len()),
            ));
        }
        if self.optimal.len() != n || self.optimal.iter().any(|r| r.len() != self.goals.len()) {
            return Err(bad("optimal", "one row per robot with one value per goal"));
        }
        if self.assignment.len() != self.phases.len() {
            return Err(bad(
                "assignment",
                format!(
                    "one row per phase ({}), got {}",
                    self.phases.len(),
                    self.assignment.len()
                ),
            ));
        }
        for (p, row) in self.assignment.iter().enumerate() {
            if row.len() != n || row.iter().any(|&g| g >= self.goals.len()) {
                return Err(bad(
                    "assignment",
                    format!(
                        "phase {p}: one goal index below {} per robot",
                        self.goals.len()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// [`check_shape`](Self::check_shape), then loads the map and checks every start and goal
    /// is a free cell on it.
    pub fn check(&self) -> Result<GridMap, PlanError> {
        self.check_shape()?;
        let map = planner::map::load_map(&self.map).map_err(|source| PlanError::Map {
            spec: self.map.clone(),
            source: Box::new(source),
        })?;
        let g = &map.grid;
        let free = |c: Cell| g.contains(i64::from(c.x), i64::from(c.y)) && g.is_free(c);
        if let Some(c) = self.starts.iter().find(|&&c| !free(c)) {
            return Err(bad("starts", format!("{c} is not a free cell of the map")));
        }
        if let Some(goal) = self.goals.iter().find(|goal| !free(goal.cell)) {
            return Err(bad(
                "goals",
                format!("{} is not a free cell of the map", goal.cell),
            ));
        }
        if self.world == World::Shared {
            phases::check_phases(
                g,
                &self.starts,
                &self.goal_cells(),
                &self.assignment,
                self.phase_start,
            )
            .map_err(PlanError::Phase)?;
        }
        Ok(map)
    }

    /// Goal cells, by goal index.
    pub fn goal_cells(&self) -> Vec<Cell> {
        self.goals.iter().map(|g| g.cell).collect()
    }

    /// Every robot's goal cell in phase `p` (`None`: no such phase, or a bad goal index).
    pub fn phase_goals(&self, p: usize) -> Option<Vec<Cell>> {
        phases::phase_goals(&self.goal_cells(), self.assignment.get(p)?)
    }

    /// Where phase `p` starts on a shared grid as planned: the starts, or with
    /// [`PhaseStart::Previous`] the goals of phase `p − 1` after phase 0 (see
    /// [`qfleet_args::phases`]).
    pub fn planned_starts(&self, p: usize) -> Option<Vec<Cell>> {
        phases::planned_starts(
            &self.starts,
            &self.goal_cells(),
            &self.assignment,
            p,
            self.phase_start,
        )
    }

    /// Reads a plan file (JSON of an [`ExperimentPlan`]).
    pub fn read(path: &Path) -> Result<Self, PlanError> {
        let text = std::fs::read_to_string(path).map_err(|source| report::ReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|source| {
            PlanError::Read(report::ReadError::Json {
                path: path.to_path_buf(),
                what: "ExperimentPlan",
                source,
            })
        })
    }
}

impl From<report::ReadError> for PlanError {
    fn from(e: report::ReadError) -> Self {
        PlanError::Read(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> ExperimentPlan {
        ExperimentPlan {
            name: "t".into(),
            seed: 1,
            world: World::Separate,
            phase_start: PhaseStart::Starts,
            robots: 2,
            sharing: "both".into(),
            timeout_s: 10.0,
            rewards: Rewards::default(),
            map: "builtin:paper-10".into(),
            goals: vec![PlanGoal {
                name: "goal-0".into(),
                cell: Cell::new(9, 9),
            }],
            phases: vec![PlanPhase {
                name: "phase-0".into(),
                episodes: 5,
            }],
            starts: vec![Cell::new(0, 0); 2],
            optimal: vec![vec![18]; 2],
            assignment: vec![vec![0, 0]],
        }
    }

    #[test]
    fn a_fitting_plan_passes_and_round_trips_through_json() {
        let p = plan();
        let map = p.check().unwrap();
        assert_eq!(map.grid.width(), 10);
        let back: ExperimentPlan =
            serde_json::from_str(&serde_json::to_string(&p).unwrap()).unwrap();
        assert_eq!(back, p);
    }

    #[test]
    fn parts_that_do_not_fit_are_refused_with_the_field() {
        type Break = fn(&mut ExperimentPlan);
        let cases: [(&str, Break); 7] = [
            ("robots", |p| p.robots = 0),
            ("timeout_s", |p| p.timeout_s = f64::NAN),
            ("phases", |p| p.phases[0].episodes = 0),
            ("starts", |p| p.starts.pop().map(drop).unwrap_or(())),
            ("optimal", |p| p.optimal[1].push(3)),
            ("assignment", |p| p.assignment[0][1] = 1),
            ("assignment", |p| p.assignment.push(vec![0, 0])),
        ];
        for (field, break_it) in cases {
            let mut p = plan();
            break_it(&mut p);
            match p.check() {
                Err(PlanError::Field { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: {other:?}"),
            }
        }
    }

    #[test]
    fn a_shared_plan_is_checked_phase_by_phase_and_round_trips() {
        let mut p = plan();
        p.world = World::Shared;
        p.goals.push(PlanGoal {
            name: "goal-1".into(),
            cell: Cell::new(0, 9),
        });
        p.starts = vec![Cell::new(0, 0), Cell::new(1, 0)];
        p.optimal = vec![vec![18, 9], vec![17, 10]];
        p.assignment = vec![vec![0, 1], vec![1, 0]];
        p.phases.push(PlanPhase {
            name: "phase-1".into(),
            episodes: 5,
        });
        p.check().unwrap();
        assert_eq!(p.planned_starts(1), Some(p.starts.clone()));
        p.phase_start = PhaseStart::Previous;
        p.check().unwrap();
        assert_eq!(
            p.planned_starts(1),
            Some(vec![Cell::new(9, 9), Cell::new(0, 9)])
        );
        assert_eq!(
            p.phase_goals(1),
            Some(vec![Cell::new(0, 9), Cell::new(9, 9)])
        );
        let back: ExperimentPlan =
            serde_json::from_str(&serde_json::to_string(&p).unwrap()).unwrap();
        assert_eq!(back, p);
        // a plan without `world` (written before worlds existed) is a separate one
        let mut v = serde_json::to_value(plan()).unwrap();
        v.as_object_mut().unwrap().remove("world");
        v.as_object_mut().unwrap().remove("phase_start");
        let old: ExperimentPlan = serde_json::from_value(v).unwrap();
        assert_eq!(old.world, World::Separate);
        assert_eq!(old.phase_start, PhaseStart::Starts);
        // two robots on one goal in phase 1: refused with the phase
        p.assignment[1] = vec![1, 1];
        match p.check() {
            Err(PlanError::Phase(e)) => assert_eq!(e.phase, 1, "{e}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn cells_off_the_map_or_on_walls_are_refused() {
        let mut p = plan();
        p.goals[0].cell = Cell::new(10, 0);
        assert!(matches!(
            p.check(),
            Err(PlanError::Field { field: "goals", .. })
        ));
        let mut p = plan();
        p.map = "builtin:nope".into();
        assert!(matches!(p.check(), Err(PlanError::Map { .. })));
    }
}
