//! A MAPF instance: a grid, one start and one goal per agent, and each agent's BFS distance
//! table to its goal. Everything is validated before anything runs, so the resolver and the
//! checker never meet an agent on a wall, two agents on one start, or an unreachable goal.

use planner::map::{GridMap, Scenario};
use planner::path::bfs_distances;
use planner::{Cell, Grid};
use std::fmt;

/// The most agents one shared grid takes: agent ids travel as one byte on the wire.
pub const MAX_AGENTS: usize = 256;

/// The most distance-table entries (agents × cells) an instance may hold: 256 MiB of `u32`.
pub const MAX_TABLE_ENTRIES: usize = 1 << 26;

/// Which end of an agent's task an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// Where the agent starts.
    Start,
    /// Where it must go.
    Goal,
}

impl fmt::Display for End {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            End::Start => "start",
            End::Goal => "goal",
        })
    }
}

/// A cell written `(x,y)` in messages (x = column, y = row).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct At(pub Cell);

impl fmt::Display for At {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({},{})", self.0.x, self.0.y)
    }
}

/// Why an instance cannot be run; each names the agent(s) and cells involved.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InstanceError {
    /// No agents: nothing to coordinate.
    #[error("an instance needs at least one agent")]
    NoAgents,
    /// More agents than the wire carries.
    #[error("{agents} agents asked for; a shared grid takes at most {MAX_AGENTS}")]
    TooManyAgents {
        /// Agents asked for.
        agents: usize,
    },
    /// Starts and goals of different lengths.
    #[error("{starts} starts but {goals} goals: every agent needs one of each")]
    LengthMismatch {
        /// Starts given.
        starts: usize,
        /// Goals given.
        goals: usize,
    },
    /// The scenario file has fewer lines than agents asked for.
    #[error("{agents} agents asked for but the scenario has only {available} start/goal lines")]
    NotEnoughScenarios {
        /// Agents asked for.
        agents: usize,
        /// Scenario lines available.
        available: usize,
    },
    /// A scenario line was made for a map of another size.
    #[error(
        "agent {agent}: its scenario line is for a {scen_width}x{scen_height} map ({scen_map}), \
         but the map is {width}x{height}"
    )]
    WrongMapSize {
        /// Agent (= scenario line, counted from 0).
        agent: usize,
        /// Map file named by the scenario line.
        scen_map: String,
        /// Width the line was made for.
        scen_width: usize,
        /// Height the line was made for.
        scen_height: usize,
        /// The map's width.
        width: usize,
        /// The map's height.
        height: usize,
    },
    /// A start or goal off the grid.
    #[error("agent {agent}: {end} {} is outside the {width}x{height} grid", At(*.cell))]
    Outside {
        /// The agent.
        agent: usize,
        /// Start or goal.
        end: End,
        /// The cell.
        cell: Cell,
        /// Grid width.
        width: usize,
        /// Grid height.
        height: usize,
    },
    /// A start or goal on a blocked cell.
    #[error("agent {agent}: {end} {} is on a wall", At(*.cell))]
    OnWall {
        /// The agent.
        agent: usize,
        /// Start or goal.
        end: End,
        /// The cell.
        cell: Cell,
    },
    /// Two agents start on one cell (a vertex conflict at tick 0).
    #[error("agents {first} and {second} both start at {}", At(*.cell))]
    SharedStart {
        /// The lower agent id.
        first: usize,
        /// The higher agent id.
        second: usize,
        /// The shared cell.
        cell: Cell,
    },
    /// Two agents share a goal (they could never both stay there).
    #[error("agents {first} and {second} both have their goal at {}", At(*.cell))]
    SharedGoal {
        /// The lower agent id.
        first: usize,
        /// The higher agent id.
        second: usize,
        /// The shared cell.
        cell: Cell,
    },
    /// A goal no path leads to from the agent's start.
    #[error("agent {agent}: goal {} cannot be reached from start {}", At(*.goal), At(*.start))]
    Unreachable {
        /// The agent.
        agent: usize,
        /// Its start.
        start: Cell,
        /// Its goal.
        goal: Cell,
    },
    /// Too many distance-table entries for memory (agents × cells).
    #[error(
        "{agents} agents on {cells} cells need {} distance entries; at most {MAX_TABLE_ENTRIES} are supported",
        agents * cells
    )]
    TooLarge {
        /// Agents.
        agents: usize,
        /// Grid cells.
        cells: usize,
    },
}

/// A validated MAPF instance with each agent's BFS distances to its goal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Instance {
    grid: Grid,
    starts: Vec<Cell>,
    goals: Vec<Cell>,
    dist: Vec<Vec<u32>>,
}

impl Instance {
    /// Validates starts and goals on `grid` and computes every agent's distance table.
    pub fn new(grid: Grid, starts: Vec<Cell>, goals: Vec<Cell>) -> Result<Instance, InstanceError> {
        if starts.len() != goals.len() {
            return Err(InstanceError::LengthMismatch {
                starts: starts.len(),
                goals: goals.len(),
            });
        }
        let agents = starts.len();
        if agents == 0 {
            return Err(InstanceError::NoAgents);
        }
        if agents > MAX_AGENTS {
            return Err(InstanceError::TooManyAgents { agents });
        }
        if agents.saturating_mul(grid.len()) > MAX_TABLE_ENTRIES {
            return Err(InstanceError::TooLarge {
                agents,
                cells: grid.len(),
            });
        }
        for (agent, (&s, &g)) in starts.iter().zip(&goals).enumerate() {
            for (end, cell) in [(End::Start, s), (End::Goal, g)] {
                if !grid.contains(i64::from(cell.x), i64::from(cell.y)) {
                    return Err(InstanceError::Outside {
                        agent,
                        end,
                        cell,
                        width: grid.width(),
                        height: grid.height(),
                    });
                }
                if !grid.is_free(cell) {
                    return Err(InstanceError::OnWall { agent, end, cell });
                }
            }
        }
        for (end, cells) in [(End::Start, &starts), (End::Goal, &goals)] {
            let mut seen = vec![usize::MAX; grid.len()];
            for (agent, &c) in cells.iter().enumerate() {
                let slot = &mut seen[grid.index(c)];
                if *slot != usize::MAX {
                    let (first, second) = (*slot, agent);
                    return Err(match end {
                        End::Start => InstanceError::SharedStart {
                            first,
                            second,
                            cell: c,
                        },
                        End::Goal => InstanceError::SharedGoal {
                            first,
                            second,
                            cell: c,
                        },
                    });
                }
                *slot = agent;
            }
        }
        let mut dist = Vec::with_capacity(agents);
        for (agent, (&s, &g)) in starts.iter().zip(&goals).enumerate() {
            let d = bfs_distances(&grid, g);
            if d[grid.index(s)] == u32::MAX {
                return Err(InstanceError::Unreachable {
                    agent,
                    start: s,
                    goal: g,
                });
            }
            dist.push(d);
        }
        Ok(Instance {
            grid,
            starts,
            goals,
            dist,
        })
    }

    /// The first `agents` lines of a scenario file (file order) on `map`; x is the column.
    pub fn from_scen(
        map: &GridMap,
        scen: &[Scenario],
        agents: usize,
    ) -> Result<Instance, InstanceError> {
        if agents == 0 {
            return Err(InstanceError::NoAgents);
        }
        if agents > MAX_AGENTS {
            return Err(InstanceError::TooManyAgents { agents });
        }
        if scen.len() < agents {
            return Err(InstanceError::NotEnoughScenarios {
                agents,
                available: scen.len(),
            });
        }
        let (width, height) = (map.grid.width(), map.grid.height());
        for (agent, s) in scen[..agents].iter().enumerate() {
            if s.width != width || s.height != height {
                return Err(InstanceError::WrongMapSize {
                    agent,
                    scen_map: s.map.clone(),
                    scen_width: s.width,
                    scen_height: s.height,
                    width,
                    height,
                });
            }
        }
        let starts = scen[..agents].iter().map(|s| s.start).collect();
        let goals = scen[..agents].iter().map(|s| s.goal).collect();
        Instance::new(map.grid.clone(), starts, goals)
    }

    /// The grid.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Number of agents.
    pub fn agents(&self) -> usize {
        self.starts.len()
    }

    /// Every agent's start, by agent id.
    pub fn starts(&self) -> &[Cell] {
        &self.starts
    }

    /// Every agent's goal, by agent id.
    pub fn goals(&self) -> &[Cell] {
        &self.goals
    }

    /// Agent `agent`'s BFS distance to its goal from every cell (row-major, `u32::MAX` where
    /// unreachable or blocked); `None` for an unknown agent.
    pub fn dist(&self, agent: usize) -> Option<&[u32]> {
        self.dist.get(agent).map(Vec::as_slice)
    }

    /// Every agent's distance table, by agent id.
    pub fn dist_tables(&self) -> &[Vec<u32>] {
        &self.dist
    }

    /// Agent `agent`'s distance from `c` to its goal (`u32::MAX` if unknown or unreachable).
    pub fn dist_from(&self, agent: usize, c: Cell) -> u32 {
        if !self.grid.contains(i64::from(c.x), i64::from(c.y)) {
            return u32::MAX;
        }
        self.dist
            .get(agent)
            .and_then(|d| d.get(self.grid.index(c)))
            .copied()
            .unwrap_or(u32::MAX)
    }

    /// The sum of single-agent shortest path lengths: no solution's sum of costs is lower.
    pub fn lower_bound(&self) -> u64 {
        (0..self.agents())
            .map(|a| u64::from(self.dist_from(a, self.starts[a])))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::map::{parse_ascii, parse_movingai_map, parse_scen};

    fn grid(t: &str) -> Grid {
        parse_ascii("t", t.as_bytes()).unwrap().grid
    }

    fn c(x: u16, y: u16) -> Cell {
        Cell::new(x, y)
    }

    #[test]
    fn valid_instance_and_lower_bound() {
        let i = Instance::new(
            grid("...\n.#.\n"),
            vec![c(0, 0), c(2, 0)],
            vec![c(2, 1), c(0, 1)],
        )
        .unwrap();
        assert_eq!(i.agents(), 2);
        assert_eq!(i.lower_bound(), 3 + 3);
        assert_eq!(i.dist_from(0, c(2, 1)), 0);
        assert_eq!(i.dist_from(0, c(1, 1)), u32::MAX);
        assert_eq!(i.dist_from(5, c(0, 0)), u32::MAX);
    }

    #[test]
    fn every_validation_error_names_agents_and_cells() {
        let g = grid("..#\n...\n#.#\n");
        let e = |s: Vec<Cell>, t: Vec<Cell>| Instance::new(g.clone(), s, t).unwrap_err();
        assert_eq!(e(vec![], vec![]), InstanceError::NoAgents);
        assert!(matches!(
            e(vec![c(0, 0)], vec![]),
            InstanceError::LengthMismatch {
                starts: 1,
                goals: 0
            }
        ));
        let m = e(vec![c(0, 0), c(3, 1)], vec![c(1, 1), c(0, 1)]).to_string();
        assert_eq!(m, "agent 1: start (3,1) is outside the 3x3 grid");
        let m = e(vec![c(0, 0)], vec![c(2, 0)]).to_string();
        assert_eq!(m, "agent 0: goal (2,0) is on a wall");
        let m = e(vec![c(0, 0), c(0, 0)], vec![c(1, 1), c(0, 1)]).to_string();
        assert_eq!(m, "agents 0 and 1 both start at (0,0)");
        let m = e(vec![c(0, 0), c(1, 0)], vec![c(1, 1), c(1, 1)]).to_string();
        assert_eq!(m, "agents 0 and 1 both have their goal at (1,1)");
        let island = grid("..#.\n..#.\n");
        let m = Instance::new(island, vec![c(0, 0)], vec![c(3, 1)])
            .unwrap_err()
            .to_string();
        assert_eq!(m, "agent 0: goal (3,1) cannot be reached from start (0,0)");
        let many = vec![c(0, 0); MAX_AGENTS + 1];
        assert_eq!(
            e(many.clone(), many),
            InstanceError::TooManyAgents { agents: 257 }
        );
    }

    #[test]
    fn from_scen_takes_the_first_lines_and_checks_the_map_size() {
        let map = parse_movingai_map("m.map", b"type octile\nheight 2\nwidth 3\nmap\n...\n.@.\n")
            .unwrap();
        let scen = parse_scen(
            "s.scen",
            b"version 1\n0\tm.map\t3\t2\t0\t0\t2\t1\t3\n0\tm.map\t3\t2\t2\t0\t0\t1\t3\n0\tm.map\t3\t2\t1\t0\t1\t0\t0\n",
        )
        .unwrap();
        let i = Instance::from_scen(&map, &scen, 2).unwrap();
        assert_eq!(i.starts(), &[c(0, 0), c(2, 0)]);
        assert_eq!(i.goals(), &[c(2, 1), c(0, 1)]);
        let e = Instance::from_scen(&map, &scen, 4).unwrap_err();
        assert_eq!(
            e.to_string(),
            "4 agents asked for but the scenario has only 3 start/goal lines"
        );
        assert_eq!(
            Instance::from_scen(&map, &scen, 0),
            Err(InstanceError::NoAgents)
        );
        let other = parse_scen("s.scen", b"version 1\n0\tx.map\t4\t2\t0\t0\t2\t1\t3\n").unwrap();
        let e = Instance::from_scen(&map, &other, 1).unwrap_err();
        assert_eq!(
            e.to_string(),
            "agent 0: its scenario line is for a 4x2 map (x.map), but the map is 3x2"
        );
    }
}
