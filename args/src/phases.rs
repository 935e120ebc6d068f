//! The phases of an experiment on one shared grid (`world = "shared"`), each a MAPF instance
//! from the phase's starts to its goals. Every robot learns every phase from its manifest start
//! (the start its process was started with), so no robot may have that cell as a phase's goal.
//! Where a phase's execution starts is the manifest's choice ([`PhaseStart`]): by default from
//! the manifest's starts again (where the robots learned from), or from where the phase before
//! left the robots — their goals of phase k − 1 when every robot arrived, which is what is
//! planned and checked here.
//!
//! [`check_phases`] checks every phase with [`mapf::Instance::new`], the same rules as a plain
//! run's instance (no second copy of them): two robots on one start, two robots on one goal, a
//! goal on a wall or walled in, more robots than [`mapf::MAX_AGENTS`]. The manifest
//! (`qfleet experiment`, exit 2 before anything starts) and the coordinator's plan check both
//! call it. No IO.

use mapf::{Instance, InstanceError};
use planner::{Cell, Grid};
use serde::{Deserialize, Serialize};

/// Where each phase's execution on a shared grid starts (manifest `phase_start`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PhaseStart {
    /// From the manifest's starts, every phase: the cells the robots learn every phase from,
    /// so their learned values lead them from there (the default).
    #[default]
    Starts,
    /// From where the phase before left the robots (phase 0: the manifest's starts): a fleet
    /// that goes on from goal to goal. Robots still learn from their manifest start, so from
    /// elsewhere they move by values learned for another part of the map.
    Previous,
}

/// What is wrong with one phase of a shared grid.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PhaseProblem {
    /// The phase's starts and goals do not make a MAPF instance.
    #[error("{}", robot_words(.0))]
    Instance(InstanceError),
    /// A robot's goal in the phase is the cell it learns from (its manifest start).
    #[error(
        "robot {robot}'s goal {} is its start in the manifest, where it learns every phase from: \
         it would have no path to learn (give it another goal in this phase)",
        mapf::instance::At(*.cell)
    )]
    StartIsGoal {
        /// The robot.
        robot: usize,
        /// Its start and its goal in the phase.
        cell: Cell,
    },
    /// The plan's parts do not fit (an assignment row or a goal index that does not exist).
    #[error("{0}")]
    Shape(String),
}

/// A phase that cannot run on the shared grid, and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("phase {phase}: {problem}")]
pub struct PhaseError {
    /// The phase (counted from 0).
    pub phase: usize,
    /// What is wrong.
    #[source]
    pub problem: PhaseProblem,
}

/// An instance error in the words of a fleet: robots, not agents (robot `i` is agent `i`).
fn robot_words(e: &InstanceError) -> String {
    use mapf::instance::At;
    match e {
        InstanceError::SharedStart {
            first,
            second,
            cell,
        } => format!("robots {first} and {second} both start at {}", At(*cell)),
        InstanceError::SharedGoal {
            first,
            second,
            cell,
        } => format!(
            "robots {first} and {second} both have their goal at {}: on a shared grid every \
             robot needs a goal of its own",
            At(*cell)
        ),
        InstanceError::Unreachable { agent, start, goal } => format!(
            "robot {agent}: goal {} cannot be reached from {} (walled in)",
            At(*goal),
            At(*start)
        ),
        InstanceError::OnWall { agent, end, cell } => {
            format!("robot {agent}: {end} {} is on a wall", At(*cell))
        }
        InstanceError::Outside {
            agent,
            end,
            cell,
            width,
            height,
        } => format!(
            "robot {agent}: {end} {} is outside the {width}x{height} grid",
            At(*cell)
        ),
        InstanceError::TooManyAgents { agents } => format!(
            "{agents} robots; a shared grid takes at most {}",
            mapf::MAX_AGENTS
        ),
        other => other.to_string(),
    }
}

/// Every robot's goal cell in a phase: `goal_cells[row[r]]` (`None` if an index is out of
/// range).
pub fn phase_goals(goal_cells: &[Cell], row: &[usize]) -> Option<Vec<Cell>> {
    row.iter().map(|&g| goal_cells.get(g).copied()).collect()
}

/// Where phase `p` starts as planned: the manifest's starts for phase 0 and with
/// [`PhaseStart::Starts`], else the goals of phase `p − 1` (every robot arrived); `None` if
/// the plan does not fit.
pub fn planned_starts(
    starts: &[Cell],
    goal_cells: &[Cell],
    assignment: &[Vec<usize>],
    p: usize,
    from: PhaseStart,
) -> Option<Vec<Cell>> {
    match (p, from) {
        (0, _) | (_, PhaseStart::Starts) => Some(starts.to_vec()),
        (_, PhaseStart::Previous) => phase_goals(goal_cells, assignment.get(p - 1)?),
    }
}

/// Checks every phase of a shared grid as planned (see the module docs); the first phase
/// that cannot run, and why. Builds one instance at a time (each holds a distance table per
/// robot), keeps none.
pub fn check_phases(
    grid: &Grid,
    starts: &[Cell],
    goal_cells: &[Cell],
    assignment: &[Vec<usize>],
    from: PhaseStart,
) -> Result<(), PhaseError> {
    let shape = |phase: usize, why: &str| PhaseError {
        phase,
        problem: PhaseProblem::Shape(why.to_string()),
    };
    for (phase, row) in assignment.iter().enumerate() {
        let goals = phase_goals(goal_cells, row)
            .ok_or_else(|| shape(phase, "a goal index out of range"))?;
        if goals.len() != starts.len() {
            return Err(shape(phase, "one goal per robot"));
        }
        let from = planned_starts(starts, goal_cells, assignment, phase, from)
            .ok_or_else(|| shape(phase, "a goal index out of range"))?;
        if let Some((robot, &cell)) = starts
            .iter()
            .zip(&goals)
            .enumerate()
            .find_map(|(r, (s, g))| (s == g).then_some((r, s)))
        {
            return Err(PhaseError {
                phase,
                problem: PhaseProblem::StartIsGoal { robot, cell },
            });
        }
        Instance::new(grid.clone(), from, goals).map_err(|e| PhaseError {
            phase,
            problem: PhaseProblem::Instance(e),
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::map::parse_ascii;

    const S: PhaseStart = PhaseStart::Starts;

    fn c(x: u16, y: u16) -> Cell {
        Cell::new(x, y)
    }

    /// A 5x3 room with a walled-in cell at (4,0).
    fn grid() -> Grid {
        parse_ascii("t", b"...#.\n...##\n.....\n").unwrap().grid
    }

    #[test]
    fn phase_k_starts_where_phase_k_minus_1_ends() {
        let goals = [c(2, 2), c(0, 2), c(2, 0)];
        let assignment = vec![vec![0, 1], vec![1, 2]];
        let starts = [c(0, 0), c(1, 0)];
        let prev = PhaseStart::Previous;
        assert_eq!(
            planned_starts(&starts, &goals, &assignment, 0, prev),
            Some(starts.to_vec())
        );
        assert_eq!(
            planned_starts(&starts, &goals, &assignment, 1, prev),
            Some(vec![c(2, 2), c(0, 2)])
        );
        assert_eq!(planned_starts(&starts, &goals, &assignment, 3, prev), None);
        assert_eq!(
            check_phases(&grid(), &starts, &goals, &assignment, prev),
            Ok(())
        );
        // by default every phase goes from the manifest's starts
        assert_eq!(
            planned_starts(&starts, &goals, &assignment, 1, PhaseStart::Starts),
            Some(starts.to_vec())
        );
        assert_eq!(PhaseStart::default(), PhaseStart::Starts);
    }

    #[test]
    fn two_robots_on_one_start_are_refused_in_phase_0() {
        let e = check_phases(
            &grid(),
            &[c(0, 0), c(0, 0)],
            &[c(2, 2), c(0, 2)],
            &[vec![0, 1]],
            S,
        )
        .unwrap_err();
        assert_eq!(e.phase, 0);
        assert_eq!(e.to_string(), "phase 0: robots 0 and 1 both start at (0,0)");
    }

    #[test]
    fn two_robots_on_one_goal_are_refused_in_the_phase_that_gives_it() {
        let goals = [c(2, 2), c(0, 2)];
        let e = check_phases(
            &grid(),
            &[c(0, 0), c(1, 0)],
            &goals,
            &[vec![0, 1], vec![1, 1]],
            PhaseStart::Previous,
        )
        .unwrap_err();
        assert_eq!(e.phase, 1);
        assert!(
            e.to_string()
                .starts_with("phase 1: robots 0 and 1 both have their goal at (0,2)"),
            "{e}"
        );
    }

    #[test]
    fn a_walled_in_goal_is_refused_with_robot_and_cells() {
        let e = check_phases(&grid(), &[c(0, 0)], &[c(4, 0)], &[vec![0]], S).unwrap_err();
        assert_eq!(
            e.to_string(),
            "phase 0: robot 0: goal (4,0) cannot be reached from (0,0) (walled in)"
        );
        let e = check_phases(&grid(), &[c(0, 0)], &[c(3, 0)], &[vec![0]], S).unwrap_err();
        assert_eq!(e.to_string(), "phase 0: robot 0: goal (3,0) is on a wall");
    }

    #[test]
    fn a_phase_goal_on_a_robots_learning_start_is_refused() {
        // robots swap in phase 0 and come back in phase 1: each would learn from its own goal
        let starts = [c(0, 0), c(2, 2)];
        let goals = [c(0, 0), c(2, 2)];
        let e = check_phases(&grid(), &starts, &goals, &[vec![1, 0], vec![0, 1]], S).unwrap_err();
        assert_eq!(e.phase, 1);
        assert!(matches!(
            e.problem,
            PhaseProblem::StartIsGoal { robot: 0, .. }
        ));
    }

    #[test]
    fn more_robots_than_the_wire_carries_are_refused() {
        let open = Grid::new(20, 20, vec![true; 400]).unwrap();
        let cells: Vec<Cell> = (0..400u16).map(|i| c(i % 20, i / 20)).collect();
        let n = mapf::MAX_AGENTS + 1;
        let goals: Vec<Cell> = cells[n..].iter().chain(&cells[..n]).copied().collect();
        let e = check_phases(&open, &cells[..n], &goals[..n], &[(0..n).collect()], S).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("phase 0: {n} robots; a shared grid takes at most 256")
        );
    }
}
