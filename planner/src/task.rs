//! A task: one map with one start and one goal, checked to be solvable, with its optimum.
//!
//! Built from a map's own `S`/`G` marks, from cells given on the command line, or from a
//! MovingAI scenario. The optimum is the 4-connected BFS length in moves, the figure learned
//! paths are compared with (never the octile length a `.scen` file carries).

use crate::grid::{Cell, Grid};
use crate::map::{GridMap, Scenario};
use crate::path::shortest_moves;
use std::fmt;

/// A solvable path-planning problem: the grid, both ends and the shortest path length.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Task {
    /// The map's name, for reports.
    pub map_name: String,
    /// The grid to move on.
    pub grid: Grid,
    /// Where every episode starts.
    pub start: Cell,
    /// Where every episode ends.
    pub goal: Cell,
    /// Moves on a shortest 4-connected path from start to goal (BFS), at least 1.
    pub optimal_len: u32,
}

/// Which end of a task a cell was meant to be, for error messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endpoint {
    /// The start cell.
    Start,
    /// The goal cell.
    Goal,
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Endpoint::Start => "start",
            Endpoint::Goal => "goal",
        })
    }
}

/// Why a task could not be set up from a map, a scenario or a command-line cell.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TaskError {
    /// Neither the map nor the caller gave a start.
    #[error("no start: the map has no 'S'; give --start X,Y")]
    NoStart,
    /// Neither the map nor the caller gave a goal.
    #[error("no goal: the map has no 'G'; give --goal X,Y")]
    NoGoal,
    /// A start or goal off the grid.
    #[error(
        "{which} {cell} is outside the {width}x{height} map (x is the column, 0 to {}; y the row, 0 to {})",
        width - 1,
        height - 1
    )]
    Outside {
        /// Which end.
        which: Endpoint,
        /// The cell given.
        cell: Cell,
        /// The map's width.
        width: usize,
        /// The map's height.
        height: usize,
    },
    /// A start or goal on an obstacle.
    #[error("{which} {cell} is on an obstacle")]
    Blocked {
        /// Which end.
        which: Endpoint,
        /// The cell given.
        cell: Cell,
    },
    /// Start and goal are one cell: there would be nothing to learn.
    #[error("start and goal are the same cell {cell}")]
    SameCell {
        /// The cell.
        cell: Cell,
    },
    /// No 4-connected path joins start and goal.
    #[error("goal {goal} cannot be reached from start {start} with up/down/left/right moves")]
    Unreachable {
        /// The start.
        start: Cell,
        /// The goal.
        goal: Cell,
    },
    /// A scenario index past the end of the scenario file.
    #[error("scenario {index} does not exist: the file has {count} scenarios, numbered from 0")]
    ScenarioIndex {
        /// The index asked for.
        index: usize,
        /// Scenarios in the file.
        count: usize,
    },
    /// A scenario made for a map of another size.
    #[error(
        "the scenario is for {scenario_map} ({scenario_width}x{scenario_height}) but map '{map}' is {width}x{height}"
    )]
    ScenarioSize {
        /// The map file the scenario names.
        scenario_map: String,
        /// The width the scenario was made for.
        scenario_width: usize,
        /// The height the scenario was made for.
        scenario_height: usize,
        /// The map's name.
        map: String,
        /// The map's width.
        width: usize,
        /// The map's height.
        height: usize,
    },
    /// A command-line cell that is not `X,Y` with coordinates from 0 to 65535.
    #[error("invalid cell '{input}': {problem}")]
    BadCell {
        /// The text given.
        input: String,
        /// What is wrong with it.
        problem: String,
    },
}

/// A task on `map`: `start`/`goal` override the map's `S` and first `G`; both are checked.
pub fn resolve_task(
    map: &GridMap,
    start: Option<Cell>,
    goal: Option<Cell>,
) -> Result<Task, TaskError> {
    let start = start.or(map.start).ok_or(TaskError::NoStart)?;
    let goal = goal
        .or_else(|| map.goals.first().copied())
        .ok_or(TaskError::NoGoal)?;
    checked_task(map, start, goal)
}

/// The task of scenario `index` (0-based, in file order) on `map`, whose size must match it.
pub fn resolve_scenario(map: &GridMap, scen: &[Scenario], index: usize) -> Result<Task, TaskError> {
    let s = scen.get(index).ok_or(TaskError::ScenarioIndex {
        index,
        count: scen.len(),
    })?;
    let (width, height) = (map.grid.width(), map.grid.height());
    if (s.width, s.height) != (width, height) {
        return Err(TaskError::ScenarioSize {
            scenario_map: s.map.clone(),
            scenario_width: s.width,
            scenario_height: s.height,
            map: map.name.clone(),
            width,
            height,
        });
    }
    checked_task(map, s.start, s.goal)
}

/// Checks both ends and computes the optimum.
fn checked_task(map: &GridMap, start: Cell, goal: Cell) -> Result<Task, TaskError> {
    let grid = &map.grid;
    for (which, cell) in [(Endpoint::Start, start), (Endpoint::Goal, goal)] {
        if !grid.contains(cell.x.into(), cell.y.into()) {
            return Err(TaskError::Outside {
                which,
                cell,
                width: grid.width(),
                height: grid.height(),
            });
        }
        if !grid.is_free(cell) {
            return Err(TaskError::Blocked { which, cell });
        }
    }
    if start == goal {
        return Err(TaskError::SameCell { cell: start });
    }
    let optimal_len =
        shortest_moves(grid, start, goal).ok_or(TaskError::Unreachable { start, goal })?;
    Ok(Task {
        map_name: map.name.clone(),
        grid: grid.clone(),
        start,
        goal,
        optimal_len,
    })
}

/// Parses a command-line cell `X,Y` (column, row; spaces around the numbers allowed).
pub fn parse_cell(s: &str) -> Result<Cell, TaskError> {
    let bad = |problem: String| TaskError::BadCell {
        input: s.to_owned(),
        problem,
    };
    let mut parts = s.split(',');
    let (Some(x), Some(y), None) = (parts.next(), parts.next(), parts.next()) else {
        return Err(bad("expected X,Y (column,row), e.g. 3,4".to_owned()));
    };
    let coord = |name: &str, p: &str| -> Result<u16, TaskError> {
        let p = p.trim();
        if p.is_empty() {
            return Err(bad(format!(
                "{name} is missing; expected X,Y (column,row), e.g. 3,4"
            )));
        }
        let digits = p.strip_prefix('-').unwrap_or(p);
        if !digits.bytes().all(|b| b.is_ascii_digit()) || digits.is_empty() {
            return Err(bad(format!("{name} '{p}' is not a whole number")));
        }
        if p.starts_with('-') {
            return Err(bad(format!(
                "{name} {p} is negative; coordinates count from 0 at the top-left cell"
            )));
        }
        p.parse::<u16>()
            .map_err(|_| bad(format!("{name} {p} is too large (at most {})", u16::MAX)))
    };
    Ok(Cell::new(coord("x", x)?, coord("y", y)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{builtin, parse_ascii, parse_scen};

    fn map(text: &str) -> GridMap {
        parse_ascii("t.txt", text.as_bytes()).unwrap()
    }

    #[test]
    fn uses_the_maps_marks() {
        let t = resolve_task(&map("S.#\n.#G\n...\n"), None, None).unwrap();
        assert_eq!((t.start, t.goal), (Cell::new(0, 0), Cell::new(2, 1)));
        assert_eq!(t.optimal_len, 5);
        assert_eq!(t.map_name, "t");
    }

    #[test]
    fn overrides_win_and_first_goal_is_default() {
        let m = map("S..\n.#G\nG..\n");
        let t = resolve_task(&m, None, None).unwrap();
        assert_eq!(t.goal, Cell::new(2, 1));
        let t = resolve_task(&m, Some(Cell::new(2, 0)), Some(Cell::new(0, 2))).unwrap();
        assert_eq!(
            (t.start, t.goal, t.optimal_len),
            (Cell::new(2, 0), Cell::new(0, 2), 4)
        );
    }

    #[test]
    fn missing_start_or_goal() {
        let e = resolve_task(&map("..G\n"), None, None).unwrap_err();
        assert_eq!(e, TaskError::NoStart);
        assert_eq!(
            e.to_string(),
            "no start: the map has no 'S'; give --start X,Y"
        );
        let e = resolve_task(&map("S..\n"), None, None).unwrap_err();
        assert_eq!(e, TaskError::NoGoal);
        assert_eq!(
            e.to_string(),
            "no goal: the map has no 'G'; give --goal X,Y"
        );
        assert!(resolve_task(&map("...\n"), Some(Cell::new(0, 0)), Some(Cell::new(2, 0))).is_ok());
    }

    #[test]
    fn ends_outside_or_on_obstacles() {
        let m = map("S.#\n..G\n");
        let e = resolve_task(&m, Some(Cell::new(3, 0)), None).unwrap_err();
        assert!(
            matches!(
                e,
                TaskError::Outside {
                    which: Endpoint::Start,
                    ..
                }
            ),
            "{e}"
        );
        assert!(
            e.to_string()
                .starts_with("start 3,0 is outside the 3x2 map"),
            "{e}"
        );
        let e = resolve_task(&m, None, Some(Cell::new(0, 2))).unwrap_err();
        assert!(
            matches!(
                e,
                TaskError::Outside {
                    which: Endpoint::Goal,
                    ..
                }
            ),
            "{e}"
        );
        let e = resolve_task(&m, None, Some(Cell::new(2, 0))).unwrap_err();
        assert_eq!(
            e,
            TaskError::Blocked {
                which: Endpoint::Goal,
                cell: Cell::new(2, 0)
            }
        );
        assert_eq!(e.to_string(), "goal 2,0 is on an obstacle");
        let e = resolve_task(&m, Some(Cell::new(2, 0)), None).unwrap_err();
        assert!(matches!(
            e,
            TaskError::Blocked {
                which: Endpoint::Start,
                ..
            }
        ));
    }

    #[test]
    fn unreachable_and_same_cell() {
        let e = resolve_task(&map("S#G\n.#.\n"), None, None).unwrap_err();
        assert!(matches!(e, TaskError::Unreachable { .. }), "{e}");
        assert!(
            e.to_string()
                .contains("goal 2,0 cannot be reached from start 0,0")
        );
        let e = resolve_task(&map("S.G\n"), None, Some(Cell::new(0, 0))).unwrap_err();
        assert_eq!(
            e,
            TaskError::SameCell {
                cell: Cell::new(0, 0)
            }
        );
    }

    #[test]
    fn scenarios_resolve_and_check_size_and_index() {
        let m = map("...\n.#.\n");
        let scen = parse_scen(
            "s.scen",
            b"version 1\n0\tt.map\t3\t2\t0\t0\t2\t1\t3.4\n0\tx.map\t4\t2\t0\t0\t2\t1\t3\n",
        )
        .unwrap();
        let t = resolve_scenario(&m, &scen, 0).unwrap();
        assert_eq!(
            (t.start, t.goal, t.optimal_len),
            (Cell::new(0, 0), Cell::new(2, 1), 3)
        );
        let e = resolve_scenario(&m, &scen, 1).unwrap_err();
        assert!(
            matches!(
                e,
                TaskError::ScenarioSize {
                    scenario_width: 4,
                    ..
                }
            ),
            "{e}"
        );
        assert!(
            e.to_string().contains("x.map (4x2) but map 't' is 3x2"),
            "{e}"
        );
        let e = resolve_scenario(&m, &scen, 2).unwrap_err();
        assert_eq!(e, TaskError::ScenarioIndex { index: 2, count: 2 });
        assert!(e.to_string().contains("has 2 scenarios"));
    }

    #[test]
    fn scenario_end_on_obstacle_is_reported() {
        let m = map("...\n.#.\n");
        let scen = parse_scen("s.scen", b"version 1\n0\tt.map\t3\t2\t0\t0\t1\t1\t2\n").unwrap();
        let e = resolve_scenario(&m, &scen, 0).unwrap_err();
        assert!(
            matches!(
                e,
                TaskError::Blocked {
                    which: Endpoint::Goal,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn builtin_tasks_have_the_papers_lengths() {
        for (name, len) in [("paper-10", 19), ("paper-20", 39), ("paper-30", 58)] {
            let t = resolve_task(&builtin(name).unwrap(), None, None).unwrap();
            assert_eq!(t.optimal_len, len, "{name}");
        }
    }

    #[test]
    fn parses_cells() {
        assert_eq!(parse_cell("3,4"), Ok(Cell::new(3, 4)));
        assert_eq!(parse_cell(" 0 , 65535 "), Ok(Cell::new(0, 65535)));
    }

    #[test]
    fn rejects_bad_cells() {
        for (input, needle) in [
            ("", "expected X,Y"),
            ("3", "expected X,Y"),
            ("3,4,5", "expected X,Y"),
            ("3;4", "expected X,Y"),
            (",4", "x is missing"),
            ("3,", "y is missing"),
            ("a,4", "x 'a' is not a whole number"),
            ("3,4.5", "y '4.5' is not a whole number"),
            ("+3,4", "not a whole number"),
            ("-,3", "x '-' is not a whole number"),
            ("-1,4", "x -1 is negative"),
            ("3,-0", "negative"),
            ("65536,0", "x 65536 is too large (at most 65535)"),
            ("3,99999999999999999999999", "too large"),
        ] {
            let e = parse_cell(input).unwrap_err();
            assert!(matches!(e, TaskError::BadCell { .. }), "{input}: {e}");
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("invalid cell '{input}'")), "{msg}");
            assert!(msg.contains(needle), "{input}: {msg}");
        }
    }
}
