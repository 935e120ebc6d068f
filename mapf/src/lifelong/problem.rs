//! A lifelong problem in the League of Robot Runners 2023 format, validated before anything runs.
//!
//! The problem file is JSON: `{mapFile, agentFile, teamSize, taskFile, numTasksReveal,
//! taskAssignmentStrategy}` with the three file paths relative to it. The agents and tasks files
//! are a count, then one linear cell id (`row * width + col`) per line. With the strategy
//! `roundrobin` robot `k`'s `c`-th goal is `tasks[(c * teamSize + k) % tasks.len()]`. This module
//! reads texts, never files: the caller reads them (bounded) and names them for errors.

use std::fmt;

use planner::{Cell, Grid};
use serde::{Deserialize, Serialize};

use crate::instance::MAX_AGENTS;

/// Assignment strategies this reader knows (the competition's 2023 names).
pub const STRATEGIES: [&str; 1] = ["roundrobin"];

/// The problem file's fields, as the competition names them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Spec {
    /// The MovingAI map, relative to the problem file.
    pub map_file: String,
    /// The robots' starts, relative to the problem file.
    pub agent_file: String,
    /// How many robots: the first `teamSize` starts.
    pub team_size: u64,
    /// The task cells, relative to the problem file.
    pub task_file: String,
    /// How many goals ahead each robot knows (at least 1 is used).
    pub num_tasks_reveal: u64,
    /// How tasks go to robots: only `roundrobin`.
    pub task_assignment_strategy: String,
}

/// Which of the problem's files an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// The agents file (starts).
    Agents,
    /// The tasks file (goals).
    Tasks,
}

impl fmt::Display for Part {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Part::Agents => "agents file",
            Part::Tasks => "tasks file",
        })
    }
}

/// Why a lifelong problem cannot run; each says what to fix.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProblemError {
    /// The problem JSON does not parse or lacks a field.
    #[error("not a League of Robot Runners 2023 problem: {0}")]
    Spec(String),
    /// A strategy other than round robin.
    #[error("task assignment strategy {0:?} is not supported (supported: {list})", list = STRATEGIES.join(", "))]
    Strategy(String),
    /// `teamSize` 0 or above the fleet limit.
    #[error("teamSize {0}: a lifelong run takes 1 to {MAX_AGENTS} robots")]
    TeamSize(u64),
    /// A line of the agents or tasks file is not a cell id.
    #[error("{part} line {line}: {text:?} is not a cell id (a whole number row*width+col)")]
    NotANumber {
        /// Which file.
        part: Part,
        /// Line number, from 1.
        line: usize,
        /// What the line holds.
        text: String,
    },
    /// A file's count line disagrees with the ids after it, or is missing.
    #[error("{part}: its first line says {said} cells but {found} follow")]
    Count {
        /// Which file.
        part: Part,
        /// What the count line says.
        said: u64,
        /// Ids found after it.
        found: usize,
    },
    /// A cell id past the map's last cell.
    #[error("{part} line {line}: cell id {id} is outside the {width}x{height} map (ids 0 to {})", width * height - 1)]
    OutOfRange {
        /// Which file.
        part: Part,
        /// Line number, from 1.
        line: usize,
        /// The id.
        id: u64,
        /// Map width.
        width: usize,
        /// Map height.
        height: usize,
    },
    /// A cell id on a blocked cell.
    #[error("{part} line {line}: cell id {id} ({},{}) is blocked on the map", cell.x, cell.y)]
    Blocked {
        /// Which file.
        part: Part,
        /// Line number, from 1.
        line: usize,
        /// The id.
        id: u64,
        /// Its cell (x = column).
        cell: Cell,
    },
    /// Fewer starts than robots.
    #[error("teamSize is {team} but the agents file has only {starts} starts")]
    FewStarts {
        /// Robots asked for.
        team: usize,
        /// Starts given.
        starts: usize,
    },
    /// Two robots on one start.
    #[error("robots {first} and {second} both start at ({},{})", cell.x, cell.y)]
    SharedStart {
        /// The lower robot id.
        first: usize,
        /// The higher one.
        second: usize,
        /// The cell.
        cell: Cell,
    },
    /// An empty tasks file.
    #[error("the tasks file holds no task")]
    NoTasks,
    /// A goal of a robot's sequence that its start does not lead to.
    #[error(
        "robot {robot} can never reach its goal ({},{}) (task {task}) from its start ({},{}): \
         they are in different parts of the map",
        goal.x, goal.y, start.x, start.y
    )]
    Unreachable {
        /// The robot.
        robot: usize,
        /// Its start.
        start: Cell,
        /// The unreachable goal.
        goal: Cell,
        /// The task's index in the tasks file (from 0).
        task: usize,
    },
}

/// A validated lifelong problem: the grid, each robot's start, the task list and the rule that
/// deals tasks to robots (round robin).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    grid: Grid,
    starts: Vec<Cell>,
    tasks: Vec<Cell>,
    reveal: u32,
}

impl Spec {
    /// Parses a problem file's JSON and checks its strategy and team size.
    pub fn parse(json: &str) -> Result<Spec, ProblemError> {
        let spec: Spec =
            serde_json::from_str(json).map_err(|e| ProblemError::Spec(e.to_string()))?;
        if !STRATEGIES.contains(&spec.task_assignment_strategy.as_str()) {
            return Err(ProblemError::Strategy(spec.task_assignment_strategy));
        }
        if spec.team_size == 0 || spec.team_size > MAX_AGENTS as u64 {
            return Err(ProblemError::TeamSize(spec.team_size));
        }
        Ok(spec)
    }
}

/// Reads an agents or tasks file: a count, then one cell id a line (blank lines skipped), each
/// inside `grid` and free.
pub fn parse_cells(text: &str, part: Part, grid: &Grid) -> Result<Vec<Cell>, ProblemError> {
    let (w, h) = (grid.width(), grid.height());
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let number = |line: usize, t: &str| {
        t.parse::<u64>().map_err(|_| ProblemError::NotANumber {
            part,
            line,
            text: t.chars().take(40).collect(),
        })
    };
    let said = match lines.next() {
        Some((line, t)) => number(line, t)?,
        None => {
            return Err(ProblemError::Count {
                part,
                said: 0,
                found: 0,
            });
        }
    };
    let mut cells = Vec::new();
    for (line, t) in lines {
        let id = number(line, t)?;
        if id >= (w * h) as u64 {
            return Err(ProblemError::OutOfRange {
                part,
                line,
                id,
                width: w,
                height: h,
            });
        }
        let cell = grid.cell(id as usize);
        if !grid.is_free(cell) {
            return Err(ProblemError::Blocked {
                part,
                line,
                id,
                cell,
            });
        }
        cells.push(cell);
    }
    if said != cells.len() as u64 {
        return Err(ProblemError::Count {
            part,
            said,
            found: cells.len(),
        });
    }
    Ok(cells)
}

/// Connected-component label of every cell (`u32::MAX` on walls).
fn components(grid: &Grid) -> Vec<u32> {
    let mut comp = vec![u32::MAX; grid.len()];
    let mut next = 0;
    let mut stack = Vec::new();
    for s in 0..grid.len() {
        if comp[s] != u32::MAX || !grid.is_free(grid.cell(s)) {
            continue;
        }
        comp[s] = next;
        stack.push(s);
        while let Some(u) = stack.pop() {
            for n in grid.neighbors(grid.cell(u)) {
                let v = grid.index(n);
                if comp[v] == u32::MAX {
                    comp[v] = next;
                    stack.push(v);
                }
            }
        }
        next += 1;
    }
    comp
}

impl Problem {
    /// Validates a problem: `team` robots on the first `team` of `starts` (distinct), a
    /// non-empty task list, every goal a robot is ever dealt reachable from its start.
    pub fn new(
        grid: Grid,
        starts: &[Cell],
        team: usize,
        tasks: Vec<Cell>,
        reveal: u64,
    ) -> Result<Problem, ProblemError> {
        if team == 0 || team > MAX_AGENTS {
            return Err(ProblemError::TeamSize(team as u64));
        }
        if starts.len() < team {
            return Err(ProblemError::FewStarts {
                team,
                starts: starts.len(),
            });
        }
        let starts = starts[..team].to_vec();
        if tasks.is_empty() {
            return Err(ProblemError::NoTasks);
        }
        let mut seen = vec![usize::MAX; grid.len()];
        for (robot, &c) in starts.iter().enumerate() {
            let slot = &mut seen[grid.index(c)];
            if *slot != usize::MAX {
                return Err(ProblemError::SharedStart {
                    first: *slot,
                    second: robot,
                    cell: c,
                });
            }
            *slot = robot;
        }
        // robot k is dealt the tasks j ≡ k (mod gcd(team, m)): check each residue class once
        let comp = components(&grid);
        let m = tasks.len();
        let g = gcd(team, m);
        for (robot, &start) in starts.iter().enumerate() {
            let home = comp[grid.index(start)];
            let bad = (robot % g..m)
                .step_by(g)
                .find(|&j| comp[grid.index(tasks[j])] != home);
            if let Some(task) = bad {
                return Err(ProblemError::Unreachable {
                    robot,
                    start,
                    goal: tasks[task],
                    task,
                });
            }
        }
        Ok(Problem {
            grid,
            starts,
            tasks,
            reveal: reveal.clamp(1, u64::from(u32::MAX)) as u32,
        })
    }

    /// The map.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Each robot's start, by robot id.
    pub fn starts(&self) -> &[Cell] {
        &self.starts
    }

    /// How many robots.
    pub fn team(&self) -> usize {
        self.starts.len()
    }

    /// The task cells, in file order.
    pub fn tasks(&self) -> &[Cell] {
        &self.tasks
    }

    /// How many goals ahead a robot knows (the problem's `numTasksReveal`, at least 1).
    pub fn reveal(&self) -> u32 {
        self.reveal
    }

    /// The task index of robot `robot`'s `c`-th goal (round robin).
    pub fn task_of(&self, robot: usize, c: u64) -> usize {
        let m = self.tasks.len() as u128;
        ((u128::from(c) * self.team() as u128 + robot as u128) % m) as usize
    }

    /// Robot `robot`'s `c`-th goal (counted from 0).
    pub fn goal(&self, robot: usize, c: u64) -> Cell {
        self.tasks[self.task_of(robot, c)]
    }

    /// The competition's id of a cell: `row * width + col`.
    pub fn cell_id(&self, c: Cell) -> u64 {
        self.grid.index(c) as u64
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::map::parse_ascii;

    fn grid(rows: &str) -> Grid {
        parse_ascii("t", rows.as_bytes()).unwrap().grid
    }

    #[test]
    fn round_robin_deals_task_c_times_team_plus_k() {
        let g = grid(".....\n.....\n");
        let tasks: Vec<Cell> = (0..7).map(|i| g.cell(i)).collect();
        let p = Problem::new(g.clone(), &[g.cell(8), g.cell(9)], 2, tasks, 1).unwrap();
        assert_eq!(p.task_of(0, 0), 0);
        assert_eq!(p.task_of(1, 0), 1);
        assert_eq!(p.task_of(0, 1), 2);
        assert_eq!(p.task_of(1, 3), 0, "(3*2+1) % 7");
        assert_eq!(p.goal(1, 3), g.cell(0));
    }

    #[test]
    fn every_bad_file_is_a_named_error() {
        let g = grid("..#\n...\n");
        let err = |t: &str, part| parse_cells(t, part, &g).unwrap_err();
        assert!(matches!(
            err("1\n2\n", Part::Agents),
            ProblemError::Blocked { id: 2, .. }
        ));
        assert!(matches!(
            err("1\n6\n", Part::Tasks),
            ProblemError::OutOfRange { id: 6, .. }
        ));
        assert!(matches!(
            err("2\n1\n", Part::Tasks),
            ProblemError::Count {
                said: 2,
                found: 1,
                ..
            }
        ));
        assert!(matches!(
            err("1\nx\n", Part::Tasks),
            ProblemError::NotANumber { line: 2, .. }
        ));
        assert!(matches!(err("", Part::Tasks), ProblemError::Count { .. }));
        let s = [g.cell(0), g.cell(0)];
        assert!(matches!(
            Problem::new(g.clone(), &s, 2, vec![g.cell(1)], 1),
            Err(ProblemError::SharedStart {
                first: 0,
                second: 1,
                ..
            })
        ));
        assert!(matches!(
            Problem::new(g.clone(), &s[..1], 2, vec![g.cell(1)], 1),
            Err(ProblemError::FewStarts { .. })
        ));
        assert!(matches!(
            Problem::new(g.clone(), &s[..1], 1, vec![], 1),
            Err(ProblemError::NoTasks)
        ));
        assert!(matches!(Spec::parse("{}"), Err(ProblemError::Spec(_))));
        let spec = r#"{"mapFile":"m","agentFile":"a","teamSize":2,"taskFile":"t",
            "numTasksReveal":1,"taskAssignmentStrategy":"greedy"}"#;
        assert!(matches!(Spec::parse(spec), Err(ProblemError::Strategy(_))));
        assert!(Spec::parse(&spec.replace("greedy", "roundrobin")).is_ok());
    }

    #[test]
    fn a_goal_in_another_part_of_the_map_is_refused_for_the_robots_dealt_it() {
        // two rooms: robot 0 starts left, robot 1 right; with 2 robots and 2 tasks robot k only
        // ever gets task k, so a right-room task for robot 1 is fine and one for robot 0 is not
        let g = grid("..#..\n..#..\n");
        let (l, r) = (Cell::new(0, 0), Cell::new(4, 0));
        assert!(
            Problem::new(
                g.clone(),
                &[l, r],
                2,
                vec![Cell::new(1, 1), Cell::new(3, 1)],
                1
            )
            .is_ok()
        );
        let e = Problem::new(g, &[l, r], 2, vec![Cell::new(3, 1), Cell::new(1, 1)], 1).unwrap_err();
        assert!(
            matches!(
                e,
                ProblemError::Unreachable {
                    robot: 0,
                    task: 0,
                    ..
                }
            ),
            "{e}"
        );
    }
}
