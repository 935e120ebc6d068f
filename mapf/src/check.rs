//! An independent solution checker, written from the rules and not from the resolver's code:
//! give it a grid, starts, goals and per-agent paths and it returns the costs, or every
//! violation it finds.
//!
//! Rules checked (the MAPF benchmark's one-shot rules): each path starts on its agent's start
//! and ends on its goal; each tick an agent waits or moves to a passable 4-neighbour; no two
//! agents on one cell at one tick (vertex conflict); no two agents exchanging cells between
//! `t` and `t + 1` (swap conflict). Following into a cell being vacated and rotations of
//! cycles are allowed. Paths shorter than the longest are padded by staying on their last cell.
//!
//! Costs: an agent's cost is the tick it last arrived at its goal and never left afterwards
//! (0 if it starts there and never leaves); sum of costs (SoC) and makespan over agents; the
//! lower bound is the sum of BFS distances start → goal.

use crate::instance::At;
use planner::path::bfs_distances;
use planner::{Cell, Grid};
use std::fmt;

/// What a valid solution costs.
#[derive(Debug, Clone, PartialEq)]
pub struct Costs {
    /// Per agent, the tick it last arrived at its goal and stayed.
    pub per_agent: Vec<u32>,
    /// Sum of the per-agent costs.
    pub soc: u64,
    /// The largest per-agent cost.
    pub makespan: u32,
    /// Sum of single-agent BFS distances: no solution costs less.
    pub lower_bound: u64,
    /// `soc / lower_bound` (1.0 when both are 0): 1.0 means nobody waited or detoured.
    pub ratio: f64,
    /// Whether every agent ends on its goal (always true for a solution `check` accepts).
    pub all_arrived: bool,
}

/// One way paths break the rules.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Violation {
    /// The number of paths is not the number of agents.
    AgentCount {
        /// Paths given.
        paths: usize,
        /// Agents (starts) given.
        agents: usize,
    },
    /// An agent's path holds no cell at all.
    EmptyPath {
        /// The agent.
        agent: usize,
    },
    /// A path that does not begin on its agent's start.
    WrongStart {
        /// The agent.
        agent: usize,
        /// Its start.
        start: Cell,
        /// Where its path begins.
        found: Cell,
    },
    /// A path that does not end on its agent's goal.
    NotAtGoal {
        /// The agent.
        agent: usize,
        /// Its goal.
        goal: Cell,
        /// Where its path ends.
        found: Cell,
    },
    /// A cell off the grid or on a wall.
    Blocked {
        /// The agent.
        agent: usize,
        /// The tick.
        tick: usize,
        /// The cell.
        cell: Cell,
    },
    /// A move of more than one step (or a diagonal one).
    Jump {
        /// The agent.
        agent: usize,
        /// The tick the move starts at.
        tick: usize,
        /// From.
        from: Cell,
        /// To.
        to: Cell,
    },
    /// Two agents on one cell at one tick.
    Vertex {
        /// The tick.
        tick: usize,
        /// The agent already there.
        first: usize,
        /// The agent arriving too.
        second: usize,
        /// The cell.
        cell: Cell,
    },
    /// Two agents exchanging cells between `tick` and `tick + 1`.
    Swap {
        /// The tick the exchange starts at.
        tick: usize,
        /// The lower agent id.
        first: usize,
        /// The higher agent id.
        second: usize,
        /// Where `first` starts.
        from: Cell,
        /// Where `first` goes (and `second` comes from).
        to: Cell,
    },
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Violation::AgentCount { paths, agents } => {
                write!(f, "{paths} paths for {agents} agents")
            }
            Violation::EmptyPath { agent } => write!(f, "agent {agent}: empty path"),
            Violation::WrongStart {
                agent,
                start,
                found,
            } => write!(
                f,
                "agent {agent}: path begins at {} but its start is {}",
                At(found),
                At(start)
            ),
            Violation::NotAtGoal { agent, goal, found } => write!(
                f,
                "agent {agent}: path ends at {} but its goal is {}",
                At(found),
                At(goal)
            ),
            Violation::Blocked { agent, tick, cell } => write!(
                f,
                "agent {agent}: tick {tick} at {}, off the grid or on a wall",
                At(cell)
            ),
            Violation::Jump {
                agent,
                tick,
                from,
                to,
            } => write!(
                f,
                "agent {agent}: tick {tick} jumps from {} to {}",
                At(from),
                At(to)
            ),
            Violation::Vertex {
                tick,
                first,
                second,
                cell,
            } => write!(
                f,
                "vertex conflict at tick {tick}: agents {first} and {second} both at {}",
                At(cell)
            ),
            Violation::Swap {
                tick,
                first,
                second,
                from,
                to,
            } => write!(
                f,
                "swap conflict at tick {tick}: agents {first} and {second} exchange {} and {}",
                At(from),
                At(to)
            ),
        }
    }
}

impl Violation {
    /// Whether this is a conflict between two agents (vertex or swap).
    pub fn is_conflict(&self) -> bool {
        matches!(self, Violation::Vertex { .. } | Violation::Swap { .. })
    }
}

/// The cell of a path at `t`, staying on its last cell after its end.
fn at(path: &[Cell], t: usize) -> Cell {
    path.get(t)
        .or(path.last())
        .copied()
        .unwrap_or(Cell::new(0, 0))
}

/// Whether a cell is on the grid and passable.
fn passable(grid: &Grid, c: Cell) -> bool {
    grid.contains(i64::from(c.x), i64::from(c.y)) && grid.is_free(c)
}

/// Checks `paths` (`paths[agent][tick]`) against the rules; the costs if they hold, else every
/// violation found, in tick order.
pub fn check(
    grid: &Grid,
    starts: &[Cell],
    goals: &[Cell],
    paths: &[Vec<Cell>],
) -> Result<Costs, Vec<Violation>> {
    let mut bad = Vec::new();
    let n = starts.len();
    if paths.len() != n || goals.len() != n {
        bad.push(Violation::AgentCount {
            paths: paths.len(),
            agents: n.min(goals.len()),
        });
        return Err(bad);
    }
    for (agent, p) in paths.iter().enumerate() {
        if p.is_empty() {
            bad.push(Violation::EmptyPath { agent });
        }
    }
    if !bad.is_empty() {
        return Err(bad);
    }
    let len = paths.iter().map(Vec::len).max().unwrap_or(1);
    for (agent, p) in paths.iter().enumerate() {
        if p[0] != starts[agent] {
            bad.push(Violation::WrongStart {
                agent,
                start: starts[agent],
                found: p[0],
            });
        }
    }
    // occupancy of the current tick: who is on each cell, stamped by tick to avoid clearing
    let mut who = vec![(usize::MAX, usize::MAX); grid.len()];
    for t in 0..len {
        for (agent, p) in paths.iter().enumerate() {
            let c = at(p, t);
            if !passable(grid, c) {
                bad.push(Violation::Blocked {
                    agent,
                    tick: t,
                    cell: c,
                });
                continue;
            }
            if t > 0 {
                let prev = at(p, t - 1);
                if prev.manhattan(c) > 1 {
                    bad.push(Violation::Jump {
                        agent,
                        tick: t - 1,
                        from: prev,
                        to: c,
                    });
                }
            }
            let slot = &mut who[grid.index(c)];
            if slot.0 == t {
                bad.push(Violation::Vertex {
                    tick: t,
                    first: slot.1,
                    second: agent,
                    cell: c,
                });
            } else {
                *slot = (t, agent);
            }
        }
        if t + 1 == len {
            break;
        }
        // swaps between t and t + 1: agent a moves u -> v while the agent on v at t moves to u
        for (a, p) in paths.iter().enumerate() {
            let (u, v) = (at(p, t), at(p, t + 1));
            if u == v || !passable(grid, v) {
                continue;
            }
            let (stamp, b) = who[grid.index(v)];
            if stamp == t && b != a && a < b && at(&paths[b], t + 1) == u {
                bad.push(Violation::Swap {
                    tick: t,
                    first: a,
                    second: b,
                    from: u,
                    to: v,
                });
            }
        }
    }
    let mut per_agent = Vec::with_capacity(n);
    for (agent, p) in paths.iter().enumerate() {
        let goal = goals[agent];
        let last = at(p, len - 1);
        if last != goal {
            bad.push(Violation::NotAtGoal {
                agent,
                goal,
                found: last,
            });
        }
        let cost = p.iter().rposition(|c| *c != goal).map_or(0, |t| t + 1);
        per_agent.push(u32::try_from(cost).unwrap_or(u32::MAX));
    }
    if !bad.is_empty() {
        return Err(bad);
    }
    let mut lower_bound = 0u64;
    for (s, g) in starts.iter().zip(goals) {
        let d = bfs_distances(grid, *g)[grid.index(*s)];
        lower_bound += u64::from(d);
    }
    let soc: u64 = per_agent.iter().map(|c| u64::from(*c)).sum();
    let makespan = per_agent.iter().copied().max().unwrap_or(0);
    let ratio = if lower_bound == 0 {
        if soc == 0 { 1.0 } else { f64::INFINITY }
    } else {
        soc as f64 / lower_bound as f64
    };
    Ok(Costs {
        per_agent,
        soc,
        makespan,
        lower_bound,
        ratio,
        all_arrived: true,
    })
}

/// The number of vertex and swap conflicts in a list of violations.
pub fn conflicts(violations: &[Violation]) -> usize {
    violations.iter().filter(|v| v.is_conflict()).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::map::parse_ascii;

    fn c(x: u16, y: u16) -> Cell {
        Cell::new(x, y)
    }

    fn grid(t: &str) -> Grid {
        parse_ascii("t", t.as_bytes()).unwrap().grid
    }

    #[test]
    fn costs_of_a_valid_solution() {
        let g = grid("...\n...\n");
        // agent 0 goes right twice; agent 1 steps off its goal and back (cost counts the return)
        let p0 = vec![c(0, 0), c(1, 0), c(2, 0)];
        let p1 = vec![c(1, 1), c(1, 1), c(0, 1), c(1, 1)];
        let costs = check(&g, &[c(0, 0), c(1, 1)], &[c(2, 0), c(1, 1)], &[p0, p1]).unwrap();
        assert_eq!(costs.per_agent, vec![2, 3]);
        assert_eq!(costs.soc, 5);
        assert_eq!(costs.makespan, 3);
        assert_eq!(costs.lower_bound, 2);
        assert_eq!(costs.ratio, 2.5);
        assert!(costs.all_arrived);
    }

    #[test]
    fn following_and_rotation_are_allowed() {
        let g = grid("..\n..\n");
        // a 4-cycle rotates clockwise
        let cyc = [c(0, 0), c(1, 0), c(1, 1), c(0, 1)];
        let paths: Vec<Vec<Cell>> = (0..4).map(|i| vec![cyc[i], cyc[(i + 1) % 4]]).collect();
        let goals: Vec<Cell> = (0..4).map(|i| cyc[(i + 1) % 4]).collect();
        assert!(check(&g, &cyc, &goals, &paths).is_ok());
    }

    #[test]
    fn every_violation_is_reported() {
        let g = grid("...\n.#.\n");
        let starts = [c(0, 0), c(1, 0), c(2, 1)];
        let goals = [c(1, 0), c(0, 0), c(2, 1)];
        let paths = vec![
            vec![c(0, 0), c(1, 0), c(1, 0)],
            vec![c(1, 0), c(0, 0), c(1, 1)],
            vec![c(2, 0), c(0, 1)],
        ];
        let v = check(&g, &starts, &goals, &paths).unwrap_err();
        let text: Vec<String> = v.iter().map(ToString::to_string).collect();
        let expect = [
            "agent 2: path begins at (2,0) but its start is (2,1)",
            "agent 2: tick 0 jumps from (2,0) to (0,1)",
            "agent 1: tick 2 at (1,1), off the grid or on a wall",
            "agent 1: path ends at (1,1) but its goal is (0,0)",
            "agent 2: path ends at (0,1) but its goal is (2,1)",
        ];
        for e in expect {
            assert!(text.iter().any(|t| t == e), "{e} missing in {text:#?}");
        }
        let swap = "swap conflict at tick 0: agents 0 and 1 exchange (0,0) and (1,0)";
        assert!(text.iter().any(|t| t == swap), "{text:#?}");
        assert_eq!(conflicts(&v), 1);
    }

    #[test]
    fn vertex_conflicts_are_counted() {
        let g = grid("...\n");
        let paths = vec![
            vec![c(0, 0), c(1, 0), c(1, 0)],
            vec![c(2, 0), c(1, 0), c(1, 0)],
        ];
        let v = check(&g, &[c(0, 0), c(2, 0)], &[c(1, 0), c(1, 0)], &paths).unwrap_err();
        assert_eq!(conflicts(&v), 2);
        assert!(v.contains(&Violation::Vertex {
            tick: 1,
            first: 0,
            second: 1,
            cell: c(1, 0)
        }));
        assert_eq!(
            check(&g, &[c(0, 0)], &[c(0, 0)], &[]),
            Err(vec![Violation::AgentCount {
                paths: 0,
                agents: 1
            }])
        );
        assert_eq!(
            check(&g, &[c(0, 0)], &[c(0, 0)], &[vec![]]),
            Err(vec![Violation::EmptyPath { agent: 0 }])
        );
    }
}
